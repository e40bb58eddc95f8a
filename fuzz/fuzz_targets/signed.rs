//! What a holder of a trusted key could feed the appliance: the input is
//! `u32 manifest length ‖ manifest ‖ payload`; when the manifest decodes, the harness fixes
//! every section's BLAKE3 to the payload bytes at its offset, re-encodes it, and signs it
//! with the trusted key — so the fuzzer explores everything after authentication
//! (validation, section layout, zstd, certificate decoding, the bound check).
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;
use restage_shared::bundle::{BundleReader, FORMAT_VERSION, MAGIC, Manifest, SIGNATURE_BLOCK_LEN, VerifyOptions};
use ed25519_dalek::{Signer, SigningKey};
use restage_shared::keys::{KeyId, TrustStore, signing_key_from_seed};

fn sign(key: &SigningKey, manifest: &[u8], payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(manifest.len() as u64).to_le_bytes());
    out.extend_from_slice(&SIGNATURE_BLOCK_LEN.to_le_bytes());
    out.extend_from_slice(manifest);
    let sig = key.sign(&out);
    out.extend_from_slice(&KeyId::of(&key.verifying_key()).0);
    out.extend_from_slice(&sig.to_bytes());
    out.extend_from_slice(payload);
    out
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 4 {
        return;
    }
    let mlen = (u32::from_le_bytes(data[..4].try_into().unwrap()) as usize).min(data.len() - 4);
    let (manifest_bytes, payload) = data[4..].split_at(mlen);
    let key = signing_key_from_seed([42; 32]);
    let mut trust = TrustStore::new();
    trust.insert(key.verifying_key(), "fuzz");
    let manifest_bytes = match postcard::from_bytes::<Manifest>(manifest_bytes) {
        Ok(mut m) => {
            m.key_id = KeyId::of(&key.verifying_key());
            let mut at = 0usize;
            for s in &mut m.sections {
                let end = at.saturating_add(s.stored_len.min(usize::MAX as u64) as usize).min(payload.len());
                s.blake3 = *blake3::hash(&payload[at.min(end)..end]).as_bytes();
                at = end;
            }
            postcard::to_stdvec(&m).unwrap()
        }
        Err(_) => manifest_bytes.to_vec(),
    };
    let bundle = sign(&key, &manifest_bytes, payload);
    if let Ok(r) = BundleReader::open(Cursor::new(bundle), &trust, &VerifyOptions::at(1_750_000_000)) {
        let _ = r.verify(|_| Ok(()));
    }
});

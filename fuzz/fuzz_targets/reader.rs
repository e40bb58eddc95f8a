//! Raw bytes as a bundle file: the trusted path (open + verify with a trusted key) and the
//! inspection path (no signature check, so manifest decoding, validation, section hashing,
//! decompression and the bound check are all reachable). Must never panic or over-allocate.
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;
use restage_shared::bundle::{BundleReader, Limits, VerifyOptions};
use restage_shared::keys::{TrustStore, signing_key_from_seed};

fuzz_target!(|data: &[u8]| {
    let mut trust = TrustStore::new();
    trust.insert(signing_key_from_seed([42; 32]).verifying_key(), "fuzz");
    if let Ok(r) = BundleReader::open(Cursor::new(data), &trust, &VerifyOptions::at(1_750_000_000)) {
        let _ = r.verify(|_| Ok(()));
    }
    if let Ok(r) = BundleReader::open_unauthenticated(Cursor::new(data), Limits::default()) {
        let _ = r.verify(|s| {
            // Touch what was handed out.
            std::hint::black_box(s.bytes.iter().fold(0u8, |a, b| a ^ b));
            Ok(())
        });
    }
});

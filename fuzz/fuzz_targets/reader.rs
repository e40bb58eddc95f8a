//! Raw bytes as a bundle file: the trusted path (open + verify with a trusted key) and the
//! inspection path (no signature check: manifest decoding, validation and section hashing;
//! `verify` must refuse it). Must never panic or over-allocate. What follows a signature
//! (zstd, the certificate, the bound check) is the `signed` target's.
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
        if let Ok(i) = r.inspect() {
            // Describing it must not panic either.
            std::hint::black_box((i.describe(), i.summary().to_json().ok()));
        }
    }
    if let Ok(r) = BundleReader::open_unauthenticated(Cursor::new(data), Limits::default()) {
        assert!(matches!(r.verify(|_| Ok(())), Err(restage_shared::bundle::BundleError::Unauthenticated)));
    }
});

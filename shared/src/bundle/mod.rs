//! The signed compensation bundle (format version 1, specified in `docs/bundle-format.md`):
//! the only code that defines a bundle's bytes. [`BundleWriter`] builds and signs;
//! [`BundleReader`] verifies while streaming and hands out nothing unverified.
//!
//! File layout: a 32-byte header (magic, format version, flags, u64 manifest length, u64
//! signature-block length), the postcard [`Manifest`], an 80-byte signature block (key id,
//! Ed25519 signature over header and manifest), then the payload sections back to back in
//! manifest order, each with its length and BLAKE3 hash in the signed manifest.

mod describe;
pub mod example;
mod manifest;
mod reader;
mod summary;
mod writer;

use std::path::PathBuf;

pub use describe::{
    BundleFileError, DEMO_KEY_LINE, LIGHT_NOT_CHECKED, describe, hex, inspect_file, verify_file,
};
pub use manifest::*;
pub use reader::{BundleReader, InspectedBundle, Limits, VerifiedBundle, VerifiedSection, VerifyOptions};
pub use summary::*;
use thiserror::Error;
pub use writer::{BundleInfo, BundleWriter};

use crate::keys::{KeyId, is_demo_key};
use crate::light::LightError;
pub use crate::time::format_utc as utc;
use crate::time::format_utc;

/// First 8 bytes of every bundle.
pub const MAGIC: &[u8; 8] = b"RSTGBNDL";
/// The format version this code reads and writes.
pub const FORMAT_VERSION: u32 = 1;
/// Bytes of the fixed header.
pub const HEADER_LEN: u64 = 32;
/// Bytes of the signature block: key id (16) and Ed25519 signature (64).
pub const SIGNATURE_BLOCK_LEN: u64 = 80;
/// Default cap on the manifest's length, checked before anything is allocated or read.
pub const MAX_MANIFEST_LEN: u64 = 1 << 20;
/// Default cap on a section's stored and raw length (a 4096 x 4096 XRGB frame is 64 MiB).
pub const MAX_SECTION_LEN: u64 = 64 << 20;

/// Why a bundle was refused. Every variant says what was wrong; none is a panic.
#[derive(Debug, Error)]
pub enum BundleError {
    #[error("read or write failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("not a restage bundle (bad magic)")]
    BadMagic,
    #[error("bundle format version {found} is not supported (expected {FORMAT_VERSION})")]
    UnsupportedVersion { found: u32 },
    #[error("header flags {flags:#x} are reserved (expected 0)")]
    ReservedFlags { flags: u32 },
    #[error("manifest length {len} bytes exceeds the limit of {max} (refused before reading it)")]
    ManifestTooLarge { len: u64, max: u64 },
    #[error("signature block length {len} (expected {SIGNATURE_BLOCK_LEN})")]
    SignatureLength { len: u64 },
    #[error("truncated: the file has {file_len} bytes, {what} needs {need}")]
    Truncated { what: String, need: u64, file_len: u64 },
    #[error("{extra} unexpected bytes after the last section")]
    TrailingBytes { extra: u64 },
    #[error("signed by key {key_id}{}, which is not in the trust store", demo_note(.key_id))]
    UnknownKey { key_id: KeyId },
    #[error("the signature does not verify with trusted key {key_id} ({origin})")]
    BadSignature { key_id: KeyId, origin: PathBuf },
    #[error("the manifest names key {manifest}, the signature block key {block}")]
    KeyIdMismatch { manifest: KeyId, block: KeyId },
    #[error("the manifest does not decode: {0}")]
    ManifestDecode(String),
    #[error("the manifest does not encode: {0}")]
    ManifestEncode(String),
    #[error("the manifest is invalid: {0}")]
    ManifestInvalid(#[from] ManifestError),
    #[error("the bundle is not valid before {}; now is {}", format_utc(*.not_before), format_utc(*.now))]
    NotYetValid { not_before: i64, now: i64 },
    #[error("the bundle expired on {}; now is {}", format_utc(*.expires), format_utc(*.now))]
    Expired { expires: i64, now: i64 },
    #[error(
        "object {object}: bundle version {version} is lower than the accepted version {accepted} (rollback refused)"
    )]
    Rollback { object: String, version: u64, accepted: u64 },
    /// `section` names it for people ([`Manifest::section_name`]).
    #[error("{section}: BLAKE3 hash does not match the manifest")]
    SectionHash { index: usize, section: String },
    #[error("{section}: does not decompress to its {raw_len} bytes ({problem})")]
    Decompress { index: usize, section: String, raw_len: u64, problem: String },
    #[error("section {index} changed on disk after it was verified")]
    Changed { index: usize },
    #[error(transparent)]
    Light(#[from] LightError),
    #[error("no section {index} (the bundle has {count})")]
    NoSuchSection { index: usize, count: usize },
    #[error("bundle input: {0}")]
    Input(String),
    #[error(
        "the signature was not verified (opened without a trust store): only the section hashes are checked, \
         the payload is not unpacked and the light check does not run"
    )]
    Unauthenticated,
}

/// " (the public demo key)" for the demo key's id, else nothing.
fn demo_note(id: &KeyId) -> &'static str {
    if is_demo_key(id) { " (the public demo key)" } else { "" }
}

//! Ed25519 signing keys in the files `openssl` makes and reads: private keys as PKCS#8 PEM
//! (`-----BEGIN PRIVATE KEY-----`), public keys as SPKI PEM (`-----BEGIN PUBLIC KEY-----`);
//! the key id derived from the public key; and the appliance's trust directory, which may
//! hold several public keys at once so keys can be rotated. Also the one public demo key
//! ([`demo_signing_key`]), whose private half everyone has.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use base64ct::{Base64, Encoding};
use ed25519_dalek::pkcs8::{DecodePrivateKey, DecodePublicKey};
pub use ed25519_dalek::{SigningKey, VerifyingKey};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Bytes of a key id.
pub const KEY_ID_LEN: usize = 16;
/// Prefix hashed with the raw public key to make a key id (domain separation).
const KEY_ID_DOMAIN: &[u8] = b"restage key id v1\0";
/// Largest PEM file read (a key file is a few hundred bytes).
const MAX_PEM_LEN: u64 = 16 * 1024;

#[derive(Debug, Error)]
pub enum KeyError {
    #[error("cannot access {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} already exists; keys are never overwritten (choose another name or move it away)")]
    Exists { path: PathBuf },
    #[error("{path}: not an Ed25519 {what} key in PEM ({problem})")]
    Pem { path: PathBuf, what: &'static str, problem: String },
    #[error("{path} is larger than {MAX_PEM_LEN} bytes; not a key file")]
    TooLarge { path: PathBuf },
    #[error("{path} holds a private key; only public keys (SPKI PEM) belong in a trust directory")]
    PrivateInTrust { path: PathBuf },
    #[error("trust directory {dir} holds no public key (*.pem)")]
    NoKeys { dir: PathBuf },
    #[error("{text:?} is not a key id (expected {} hex digits)", KEY_ID_LEN * 2)]
    BadKeyId { text: String },
}

/// A key's identity: the first 16 bytes of BLAKE3("restage key id v1\0" || the 32-byte
/// Ed25519 public key). Shown as 32 lowercase hex digits.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct KeyId(pub [u8; KEY_ID_LEN]);

impl KeyId {
    pub fn of(key: &VerifyingKey) -> Self {
        let mut h = blake3::Hasher::new();
        h.update(KEY_ID_DOMAIN);
        h.update(key.as_bytes());
        let mut id = [0u8; KEY_ID_LEN];
        id.copy_from_slice(&h.finalize().as_bytes()[..KEY_ID_LEN]);
        KeyId(id)
    }
}

impl fmt::Display for KeyId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&to_hex(&self.0))
    }
}

impl fmt::Debug for KeyId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "KeyId({self})")
    }
}

impl FromStr for KeyId {
    type Err = KeyError;
    fn from_str(s: &str) -> Result<Self, KeyError> {
        from_hex(s).map(KeyId).ok_or_else(|| KeyError::BadKeyId { text: s.to_owned() })
    }
}

/// `bytes` as lowercase hex digits (key ids, signatures kept as text).
pub fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Exactly `N` bytes written as `2 * N` hex digits (either case); `None` for anything else.
pub fn from_hex<const N: usize>(text: &str) -> Option<[u8; N]> {
    // Digits only: `from_str_radix` alone would also take a sign ("+0").
    if text.len() != 2 * N || !text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let mut out = [0u8; N];
    for (i, b) in out.iter_mut().enumerate() {
        *b = u8::from_str_radix(&text[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(out)
}

/// A signing key from 32 secret bytes (the caller draws them from the OS's random source).
pub fn signing_key_from_seed(seed: [u8; 32]) -> SigningKey {
    SigningKey::from_bytes(&seed)
}

/// What the demo key's 32 secret bytes are the BLAKE3 hash of (see [`demo_signing_key`]).
pub const DEMO_KEY_SEED_TEXT: &str = "restage public demo signing key v1: anyone can sign with it";

/// The demo key's id (`KeyId::of(&demo_signing_key().verifying_key())`), shown as
/// `719bce2f58d595a5f4b1bab1bdb14de4`.
pub const DEMO_KEY_ID: KeyId = KeyId(DEMO_KEY_ID_BYTES);
const DEMO_KEY_ID_BYTES: [u8; KEY_ID_LEN] =
    [0x71, 0x9b, 0xce, 0x2f, 0x58, 0xd5, 0x95, 0xa5, 0xf4, 0xb1, 0xba, 0xb1, 0xbd, 0xb1, 0x4d, 0xe4];

/// THE PUBLIC DEMO KEY. ITS PRIVATE HALF IS PUBLIC: anyone can compute it from this
/// documented derivation (secret bytes = BLAKE3 of [`DEMO_KEY_SEED_TEXT`]) and sign any
/// bundle with it, so a trust directory holding its public key accepts bundles from anyone.
///
/// It exists so the demo (`restage-author demo`) and first trials can run end to end without
/// a key ceremony. Tools say so loudly wherever it appears ([`is_demo_key`]), and the
/// appliance refuses a bundle signed with it unless its configuration sets
/// `allow_demo_key = true`. Never use it for an object on show.
pub fn demo_signing_key() -> SigningKey {
    SigningKey::from_bytes(blake3::hash(DEMO_KEY_SEED_TEXT.as_bytes()).as_bytes())
}

/// Whether `id` is the public demo key's ([`demo_signing_key`]): a bundle signed with it
/// may come from anyone.
pub fn is_demo_key(id: &KeyId) -> bool {
    *id == DEMO_KEY_ID
}

/// DER of an Ed25519 PKCS#8 v1 `PrivateKeyInfo` before its 32 secret bytes (RFC 8410, 7):
/// SEQUENCE { INTEGER 0, SEQUENCE { OID 1.3.101.112 }, OCTET STRING { OCTET STRING (32) } }.
const PKCS8_V1_PREFIX: [u8; 16] =
    [0x30, 0x2e, 0x02, 0x01, 0x00, 0x30, 0x05, 0x06, 0x03, 0x2b, 0x65, 0x70, 0x04, 0x22, 0x04, 0x20];
/// DER of an Ed25519 `SubjectPublicKeyInfo` before its 32 key bytes (RFC 8410, 4):
/// SEQUENCE { SEQUENCE { OID 1.3.101.112 }, BIT STRING (no unused bits, 32 bytes) }.
const SPKI_PREFIX: [u8; 12] = [0x30, 0x2a, 0x30, 0x05, 0x06, 0x03, 0x2b, 0x65, 0x70, 0x03, 0x21, 0x00];

/// `der` as PEM with `label` (RFC 7468: base64 in lines of 64, LF line ends).
fn pem(label: &str, der: &[u8]) -> String {
    let mut out = format!("-----BEGIN {label}-----\n");
    for (i, c) in Base64::encode_string(der).chars().enumerate() {
        if i > 0 && i % 64 == 0 {
            out.push('\n');
        }
        out.push(c);
    }
    out.push_str(&format!("\n-----END {label}-----\n"));
    out
}

/// PKCS#8 v1 PEM (`BEGIN PRIVATE KEY`), exactly what `openssl genpkey -algorithm ed25519`
/// writes. A fixed DER template around the key bytes: it cannot fail.
pub fn private_key_to_pem(key: &SigningKey) -> String {
    let der: Vec<u8> = PKCS8_V1_PREFIX.iter().chain(key.as_bytes()).copied().collect();
    pem("PRIVATE KEY", &der)
}

/// SPKI PEM (`BEGIN PUBLIC KEY`), as `openssl pkey -pubout` writes. A fixed DER template
/// around the key bytes: it cannot fail.
pub fn public_key_to_pem(key: &VerifyingKey) -> String {
    let der: Vec<u8> = SPKI_PREFIX.iter().chain(key.as_bytes()).copied().collect();
    pem("PUBLIC KEY", &der)
}

/// Parses a PKCS#8 PEM private key (v1 or v2). `origin` names the source in errors.
pub fn private_key_from_pem(pem: &str, origin: &Path) -> Result<SigningKey, KeyError> {
    SigningKey::from_pkcs8_pem(pem).map_err(|e| KeyError::Pem {
        path: origin.into(),
        what: "private",
        problem: e.to_string(),
    })
}

/// Parses an SPKI PEM public key. `origin` names the source in errors.
pub fn public_key_from_pem(pem: &str, origin: &Path) -> Result<VerifyingKey, KeyError> {
    if pem.contains("PRIVATE KEY-----") {
        return Err(KeyError::PrivateInTrust { path: origin.into() });
    }
    VerifyingKey::from_public_key_pem(pem).map_err(|e| KeyError::Pem {
        path: origin.into(),
        what: "public",
        problem: e.to_string(),
    })
}

fn read_small(path: &Path) -> Result<String, KeyError> {
    let io = |source| KeyError::Io { path: path.into(), source };
    let len = std::fs::metadata(path).map_err(io)?.len();
    if len > MAX_PEM_LEN {
        return Err(KeyError::TooLarge { path: path.into() });
    }
    let bytes = std::fs::read(path).map_err(io)?;
    String::from_utf8(bytes).map_err(|_| KeyError::Pem {
        path: path.into(),
        what: "PEM",
        problem: "not UTF-8 text".into(),
    })
}

pub fn load_private_key(path: &Path) -> Result<SigningKey, KeyError> {
    private_key_from_pem(&read_small(path)?, path)
}

pub fn load_public_key(path: &Path) -> Result<VerifyingKey, KeyError> {
    public_key_from_pem(&read_small(path)?, path)
}

/// Writes `STEM.pem` (private, mode 0600 on Unix) and `STEM.pub.pem` (public). Refuses to
/// overwrite either file. Returns both paths.
pub fn write_keypair(key: &SigningKey, stem: &Path) -> Result<(PathBuf, PathBuf), KeyError> {
    use std::io::Write;
    let name = stem.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let private = stem.with_file_name(format!("{name}.pem"));
    let public = stem.with_file_name(format!("{name}.pub.pem"));
    for p in [&private, &public] {
        if p.exists() {
            return Err(KeyError::Exists { path: p.clone() });
        }
    }
    let mut opts = std::fs::OpenOptions::new();
    opts.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.mode(0o600);
    }
    let io = |path: &PathBuf| {
        let path = path.clone();
        move |source| KeyError::Io { path, source }
    };
    let mut f = opts.open(&private).map_err(io(&private))?;
    f.write_all(private_key_to_pem(key).as_bytes()).map_err(io(&private))?;
    f.sync_all().map_err(io(&private))?;
    let mut opts = std::fs::OpenOptions::new();
    opts.write(true).create_new(true);
    let mut f = opts.open(&public).map_err(io(&public))?;
    f.write_all(public_key_to_pem(&key.verifying_key()).as_bytes()).map_err(io(&public))?;
    Ok((private, public))
}

/// A trusted public key and where it came from.
#[derive(Clone, Debug)]
pub struct TrustedKey {
    pub key: VerifyingKey,
    pub origin: PathBuf,
}

/// The public keys an appliance (or `restage-author verify`) accepts signatures from.
#[derive(Clone, Debug, Default)]
pub struct TrustStore {
    keys: BTreeMap<KeyId, TrustedKey>,
}

impl TrustStore {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a key; returns its id.
    pub fn insert(&mut self, key: VerifyingKey, origin: impl Into<PathBuf>) -> KeyId {
        let id = KeyId::of(&key);
        self.keys.insert(id, TrustedKey { key, origin: origin.into() });
        id
    }

    /// Every `*.pem` file directly in `dir` must be an Ed25519 SPKI public key; other files
    /// are ignored. A malformed key or a private key is an error, not a skip, so a mistake in
    /// the trust directory is noticed.
    pub fn load_dir(dir: &Path) -> Result<Self, KeyError> {
        let io = |source| KeyError::Io { path: dir.into(), source };
        let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io)?
            .map(|e| e.map(|e| e.path()))
            .collect::<Result<_, _>>()
            .map_err(io)?;
        paths.sort();
        let mut store = Self::new();
        for p in paths {
            if p.extension().is_some_and(|e| e == "pem") && p.is_file() {
                let key = load_public_key(&p)?;
                store.insert(key, p);
            }
        }
        if store.keys.is_empty() {
            return Err(KeyError::NoKeys { dir: dir.into() });
        }
        Ok(store)
    }

    pub fn get(&self, id: &KeyId) -> Option<&TrustedKey> {
        self.keys.get(id)
    }

    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    pub fn ids(&self) -> impl Iterator<Item = &KeyId> {
        self.keys.keys()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_round_trips_and_refuses_what_is_not_exactly_n_bytes() {
        let bytes = [0x00, 0x7f, 0x80, 0xff, 0x1a];
        assert_eq!(to_hex(&bytes), "007f80ff1a");
        assert_eq!(from_hex::<5>("007F80ff1a"), Some(bytes));
        for bad in ["007f80ff1", "007f80ff1a00", "007f80ff1g", "+07f80ff1a", "007f80ff\u{e9}"] {
            assert_eq!(from_hex::<5>(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn the_demo_key_is_the_documented_derivation() {
        let k = demo_signing_key();
        assert_eq!(k.to_bytes(), *blake3::hash(DEMO_KEY_SEED_TEXT.as_bytes()).as_bytes());
        let id = KeyId::of(&k.verifying_key());
        assert_eq!(id, DEMO_KEY_ID);
        assert_eq!(DEMO_KEY_ID.to_string(), "719bce2f58d595a5f4b1bab1bdb14de4");
        assert!(is_demo_key(&id));
        assert!(!is_demo_key(&KeyId::of(&signing_key_from_seed([7; 32]).verifying_key())));
    }

    #[test]
    fn pem_round_trip_and_key_id() {
        let k = signing_key_from_seed([7; 32]);
        let pem = private_key_to_pem(&k);
        assert!(pem.starts_with("-----BEGIN PRIVATE KEY-----"));
        let back = private_key_from_pem(&pem, Path::new("x")).unwrap();
        assert_eq!(back.to_bytes(), k.to_bytes());
        let pubpem = public_key_to_pem(&k.verifying_key());
        let pk = public_key_from_pem(&pubpem, Path::new("y")).unwrap();
        assert_eq!(KeyId::of(&pk), KeyId::of(&k.verifying_key()));
        let id = KeyId::of(&pk);
        assert_eq!(id.to_string().parse::<KeyId>().unwrap(), id);
        assert_ne!(KeyId::of(&signing_key_from_seed([8; 32]).verifying_key()), id);
        assert!(matches!(public_key_from_pem(&pem, Path::new("z")), Err(KeyError::PrivateInTrust { .. })));
        assert!("zz".parse::<KeyId>().is_err());
    }

    #[test]
    fn pem_templates_match_the_pkcs8_encoders() {
        use ed25519_dalek::pkcs8::spki::der::pem::LineEnding;
        use ed25519_dalek::pkcs8::{EncodePrivateKey, EncodePublicKey, KeypairBytes};
        for seed in [[0; 32], [7; 32], [0xff; 32], std::array::from_fn(|i| i as u8)] {
            let k = signing_key_from_seed(seed);
            let kp = KeypairBytes { secret_key: k.to_bytes(), public_key: None };
            assert_eq!(private_key_to_pem(&k), kp.to_pkcs8_pem(LineEnding::LF).unwrap().as_str());
            let public = k.verifying_key().to_public_key_pem(LineEnding::LF).unwrap();
            assert_eq!(public_key_to_pem(&k.verifying_key()), public);
        }
    }

    #[test]
    fn keypair_files_and_trust_dir() {
        let dir = tempfile::tempdir().unwrap();
        let k1 = signing_key_from_seed([1; 32]);
        let k2 = signing_key_from_seed([2; 32]);
        let (private, public) = write_keypair(&k1, &dir.path().join("one")).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(std::fs::metadata(&private).unwrap().permissions().mode() & 0o777, 0o600);
        }
        assert!(matches!(write_keypair(&k1, &dir.path().join("one")), Err(KeyError::Exists { .. })));
        assert_eq!(load_private_key(&private).unwrap().to_bytes(), k1.to_bytes());
        let trust = dir.path().join("trust");
        std::fs::create_dir(&trust).unwrap();
        assert!(matches!(TrustStore::load_dir(&trust), Err(KeyError::NoKeys { .. })));
        std::fs::copy(&public, trust.join("one.pem")).unwrap();
        std::fs::write(trust.join("two.pem"), public_key_to_pem(&k2.verifying_key())).unwrap();
        std::fs::write(trust.join("README"), "not a key").unwrap();
        let store = TrustStore::load_dir(&trust).unwrap();
        assert_eq!(store.len(), 2);
        assert!(store.get(&KeyId::of(&k2.verifying_key())).is_some());
        std::fs::copy(&private, trust.join("oops.pem")).unwrap();
        assert!(matches!(TrustStore::load_dir(&trust), Err(KeyError::PrivateInTrust { .. })));
    }
}

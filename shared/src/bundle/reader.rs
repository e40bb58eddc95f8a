//! Streaming verification of a bundle. [`BundleReader::open`] checks the header, the
//! manifest's signature, validity times and rollback before anything else is read;
//! [`BundleReader::verify`] then reads one section at a time, checks its hash before
//! decompressing or decoding it, and runs the light check on every scene (the certificate
//! must vouch for every lit pixel; the peak irradiance is recomputed from it). Memory: the
//! manifest, the certificate, its coverage maps (a byte per projector pixel), one scene's
//! per-point sums and one section (stored and decompressed) at a time.
//!
//! A file nobody vouches for ([`BundleReader::open_unauthenticated`]) only gets
//! [`BundleReader::inspect`]: section hashes, nothing decompressed or decoded. Within the
//! limits a 140 KB file unpacks to gigabytes and a certificate that costs seconds a scene;
//! that work is for bundles signed by a trusted key.

use std::io::{Read, Seek, SeekFrom};

use ed25519_dalek::{SIGNATURE_LENGTH, Signature};

use super::{
    BundleError, Compression, FORMAT_VERSION, HEADER_LEN, MAGIC, MAX_MANIFEST_LEN, MAX_SECTION_LEN, Manifest,
    ManifestError, SIGNATURE_BLOCK_LEN, SectionKind,
};
use crate::keys::{KEY_ID_LEN, KeyId, TrustStore};
use crate::light::{LightCertificate, LightCheck, PeakIrradiance, StageLimits, XrgbFrame};

/// Size caps applied before allocating, and the reader's own assumptions about the stage.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub max_manifest: u64,
    pub max_section: u64,
    /// Bounds the light check holds certificates' coefficients to (the appliance's, never
    /// the bundle's).
    pub stage: StageLimits,
}

impl Default for Limits {
    fn default() -> Self {
        Self { max_manifest: MAX_MANIFEST_LEN, max_section: MAX_SECTION_LEN, stage: StageLimits::default() }
    }
}

/// What verification depends on besides the bytes and the trusted keys.
#[derive(Clone, Copy)]
pub struct VerifyOptions<'a> {
    /// The one time (Unix seconds) taken at the start of loading; validity is checked
    /// against it and nothing else reads a clock.
    pub now_unix_s: i64,
    /// The last version accepted for an object id (the appliance's ledger). The reader only
    /// reads it: recording a new version is the caller's job, after `verify` returned Ok.
    pub last_accepted: &'a dyn Fn(&str) -> Option<u64>,
    pub limits: Limits,
}

impl std::fmt::Debug for VerifyOptions<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VerifyOptions")
            .field("now_unix_s", &self.now_unix_s)
            .field("limits", &self.limits)
            .finish()
    }
}

impl<'a> VerifyOptions<'a> {
    /// No version accepted before, default limits.
    pub fn at(now_unix_s: i64) -> Self {
        Self { now_unix_s, last_accepted: &|_| None, limits: Limits::default() }
    }
}

/// A bundle whose header, signature, validity and version were checked; sections not yet.
#[derive(Debug)]
pub struct BundleReader<R> {
    src: R,
    manifest: Manifest,
    manifest_hash: [u8; 32],
    key_id: KeyId,
    /// Absolute offset of each section.
    offsets: Vec<u64>,
    file_len: u64,
    authenticated: bool,
    stage: StageLimits,
}

/// A section whose hash was checked, decompressed. Callers keep it (e.g. copy a frame into
/// a scan-out buffer) but must not *use* it until `verify` returned Ok: the scene's bound
/// check completes only after its last frame.
#[derive(Debug)]
pub struct VerifiedSection<'a> {
    pub index: usize,
    pub kind: SectionKind,
    pub bytes: &'a [u8],
}

/// A fully verified bundle: signature with a trusted key, validity, version, every section,
/// every scene's light check. Holds the manifest, certificate, each scene's recomputed peak,
/// and the source for reading frames again later (each re-read is hashed again).
#[derive(Debug)]
pub struct VerifiedBundle<R> {
    pub manifest: Manifest,
    pub certificate: LightCertificate,
    /// Per scene, in manifest order: the peak irradiance recomputed from the certificate,
    /// already checked against the bound (and every lit pixel against the certificate's
    /// coverage). Charge exposure at these values.
    pub peaks: Vec<PeakIrradiance>,
    /// BLAKE3 of the manifest bytes: identifies the exact bundle (two different bundles
    /// with one version have different hashes).
    pub manifest_hash: [u8; 32],
    pub key_id: KeyId,
    src: R,
    offsets: Vec<u64>,
}

/// A bundle described without its payload ([`BundleReader::inspect`]): header and manifest
/// decoded and validated, every section's BLAKE3 checked, nothing decompressed or decoded,
/// no light check.
#[derive(Clone, Debug)]
pub struct InspectedBundle {
    pub manifest: Manifest,
    /// BLAKE3 of the manifest bytes (as [`VerifiedBundle::manifest_hash`]).
    pub manifest_hash: [u8; 32],
    /// The key id in the signature block (equal to the manifest's).
    pub key_id: KeyId,
    /// Whether the signature, validity and version were checked (`open`); false from
    /// `open_unauthenticated`: anyone could have made the file, and it must never be played.
    pub authenticated: bool,
}

/// Bytes hashed at a time by [`BundleReader::inspect`].
const INSPECT_CHUNK: usize = 64 * 1024;

fn read_exact_at<R: Read>(
    src: &mut R,
    buf: &mut [u8],
    what: &str,
    need: u64,
    file_len: u64,
) -> Result<(), BundleError> {
    src.read_exact(buf).map_err(|e| truncated(e, what.to_owned(), need, file_len))
}

// The signature block is read as its two parts.
const _: () = assert!(KEY_ID_LEN + SIGNATURE_LENGTH == SIGNATURE_BLOCK_LEN as usize);

/// The `N` bytes of the fixed header from offset `at` (every field lies inside the header,
/// so the zero fill past its end is never used: this cannot fail).
fn header_field<const N: usize>(header: &[u8; HEADER_LEN as usize], at: usize) -> [u8; N] {
    std::array::from_fn(|i| header.get(at + i).copied().unwrap_or(0))
}

impl<R: Read + Seek> BundleReader<R> {
    /// Reads and checks, in order: header (magic, format, flags, manifest length against the
    /// cap before allocating), the signature over header and manifest with a trusted key
    /// (`verify_strict`), the manifest (decode, key id, consistency), validity against
    /// `opts.now_unix_s`, rollback against `opts.last_accepted`, and the file's length
    /// against the sections' lengths (truncated or appended files are refused here).
    pub fn open(src: R, trust: &TrustStore, opts: &VerifyOptions<'_>) -> Result<Self, BundleError> {
        Self::open_inner(src, Some((trust, opts)), opts.limits)
    }

    /// For describing a file only: reads the header and manifest WITHOUT checking the
    /// signature, validity or version. Such a reader can only be [`inspect`](Self::inspect)ed
    /// (section hashes); [`verify`](Self::verify) refuses it, so neither the payload nor the
    /// light check costs anything for a file from anyone.
    pub fn open_unauthenticated(src: R, limits: Limits) -> Result<Self, BundleError> {
        Self::open_inner(src, None, limits)
    }

    fn open_inner(
        mut src: R,
        auth: Option<(&TrustStore, &VerifyOptions<'_>)>,
        limits: Limits,
    ) -> Result<Self, BundleError> {
        let file_len = src.seek(SeekFrom::End(0))?;
        src.seek(SeekFrom::Start(0))?;
        let mut header = [0u8; HEADER_LEN as usize];
        read_exact_at(&mut src, &mut header, "the header", HEADER_LEN, file_len)?;
        if &header[..8] != MAGIC {
            return Err(BundleError::BadMagic);
        }
        let u32_at = |o: usize| u32::from_le_bytes(header_field(&header, o));
        let u64_at = |o: usize| u64::from_le_bytes(header_field(&header, o));
        let found = u32_at(8);
        if found != FORMAT_VERSION {
            return Err(BundleError::UnsupportedVersion { found });
        }
        let flags = u32_at(12);
        if flags != 0 {
            return Err(BundleError::ReservedFlags { flags });
        }
        let manifest_len = u64_at(16);
        if manifest_len > limits.max_manifest {
            return Err(BundleError::ManifestTooLarge { len: manifest_len, max: limits.max_manifest });
        }
        if manifest_len == 0 {
            return Err(BundleError::ManifestDecode("the manifest is empty".into()));
        }
        let sig_len = u64_at(24);
        if sig_len != SIGNATURE_BLOCK_LEN {
            return Err(BundleError::SignatureLength { len: sig_len });
        }
        let signed_end = (HEADER_LEN + SIGNATURE_BLOCK_LEN)
            .checked_add(manifest_len)
            .ok_or(BundleError::ManifestTooLarge { len: manifest_len, max: limits.max_manifest })?;
        if file_len < signed_end {
            return Err(BundleError::Truncated {
                what: "the manifest and signature".into(),
                need: signed_end,
                file_len,
            });
        }
        // Header and manifest in one buffer: exactly the bytes the signature covers.
        let mut signed = vec![0u8; (HEADER_LEN + manifest_len) as usize];
        signed[..HEADER_LEN as usize].copy_from_slice(&header);
        read_exact_at(&mut src, &mut signed[HEADER_LEN as usize..], "the manifest", signed_end, file_len)?;
        // The signature block: key id, then the signature (SIGNATURE_BLOCK_LEN bytes in all).
        let mut id = [0u8; KEY_ID_LEN];
        read_exact_at(&mut src, &mut id, "the signature block", signed_end, file_len)?;
        let mut sig_bytes = [0u8; SIGNATURE_LENGTH];
        read_exact_at(&mut src, &mut sig_bytes, "the signature block", signed_end, file_len)?;
        let key_id = KeyId(id);
        if let Some((trust, _)) = auth {
            let trusted = trust.get(&key_id).ok_or(BundleError::UnknownKey { key_id })?;
            let signature = Signature::from_bytes(&sig_bytes);
            trusted
                .key
                .verify_strict(&signed, &signature)
                .map_err(|_| BundleError::BadSignature { key_id, origin: trusted.origin.clone() })?;
        }

        // Only signed bytes reach the decoder.
        let manifest_bytes = &signed[HEADER_LEN as usize..];
        let (manifest, rest): (Manifest, &[u8]) = postcard::take_from_bytes(manifest_bytes)
            .map_err(|e| BundleError::ManifestDecode(e.to_string()))?;
        if !rest.is_empty() {
            return Err(BundleError::ManifestDecode(format!("{} bytes after the manifest", rest.len())));
        }
        if manifest.key_id != key_id {
            return Err(BundleError::KeyIdMismatch { manifest: manifest.key_id, block: key_id });
        }
        manifest.validate(limits.max_section)?;
        if let Some((_, opts)) = auth {
            let now = opts.now_unix_s;
            if let Some(not_before) = manifest.not_before_unix_s
                && now < not_before
            {
                return Err(BundleError::NotYetValid { not_before, now });
            }
            if let Some(expires) = manifest.expires_unix_s
                && now >= expires
            {
                return Err(BundleError::Expired { expires, now });
            }
            if let Some(accepted) = (opts.last_accepted)(&manifest.object.id)
                && manifest.version < accepted
            {
                return Err(BundleError::Rollback {
                    object: manifest.object.id.clone(),
                    version: manifest.version,
                    accepted,
                });
            }
        }
        let mut offsets = Vec::with_capacity(manifest.sections.len());
        let mut at = signed_end;
        for (i, s) in manifest.sections.iter().enumerate() {
            offsets.push(at);
            at = at
                .checked_add(s.stored_len)
                .ok_or(BundleError::ManifestInvalid(ManifestError::PayloadOverflow))?;
            if at > file_len {
                return Err(BundleError::Truncated { what: manifest.section_name(i), need: at, file_len });
            }
        }
        if file_len > at {
            return Err(BundleError::TrailingBytes { extra: file_len - at });
        }
        let manifest_hash = *blake3::hash(manifest_bytes).as_bytes();
        Ok(Self {
            src,
            manifest,
            manifest_hash,
            key_id,
            offsets,
            file_len,
            authenticated: auth.is_some(),
            stage: limits.stage,
        })
    }

    /// The verified manifest (signature, validity and version already checked).
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// BLAKE3 of the signed manifest bytes: the bundle's identity in the ledger.
    pub fn manifest_hash(&self) -> &[u8; 32] {
        &self.manifest_hash
    }

    /// The key id in the signature block (equal to the manifest's). Verified with a trusted
    /// key when the reader came from `open`.
    pub fn key_id(&self) -> KeyId {
        self.key_id
    }

    /// Whether the signature, validity and version were checked (`open`, not
    /// `open_unauthenticated`).
    pub fn is_authenticated(&self) -> bool {
        self.authenticated
    }

    /// Checks every section's BLAKE3 against the manifest, streaming through a 64 KiB buffer:
    /// nothing is decompressed or decoded and the light check does not run, so it costs one
    /// hash pass over the file and no memory beyond the manifest, whoever made the file.
    pub fn inspect(mut self) -> Result<InspectedBundle, BundleError> {
        let file_len = self.file_len;
        self.src.seek(SeekFrom::Start(self.offsets.first().copied().unwrap_or(file_len)))?;
        let mut buf = vec![0u8; INSPECT_CHUNK];
        for (i, (s, &at)) in self.manifest.sections.iter().zip(&self.offsets).enumerate() {
            let mut h = blake3::Hasher::new();
            let mut left = s.stored_len;
            while left > 0 {
                let chunk = &mut buf[..left.min(INSPECT_CHUNK as u64) as usize];
                let end = at + s.stored_len;
                let eof = |e| truncated(e, self.manifest.section_name(i), end, file_len);
                self.src.read_exact(chunk).map_err(eof)?;
                h.update(chunk);
                left -= chunk.len() as u64;
            }
            if h.finalize().as_bytes() != &s.blake3 {
                return Err(BundleError::SectionHash { index: i, section: self.manifest.section_name(i) });
            }
        }
        not_grown(&mut self.src, file_len)?;
        Ok(InspectedBundle {
            manifest: self.manifest,
            manifest_hash: self.manifest_hash,
            key_id: self.key_id,
            authenticated: self.authenticated,
        })
    }

    /// Reads every section in order, checks its hash, decompresses it, passes it to `keep`,
    /// decodes and checks the certificate, and refuses any scene that lights a pixel the
    /// certificate does not vouch for or whose recomputed peak irradiance exceeds the light
    /// model's allowed lux ([`LightCheck`], with the stage limits given to `open`). Returns
    /// the verified bundle only if everything passed. Refuses a reader from
    /// `open_unauthenticated` before reading anything ([`BundleError::Unauthenticated`]).
    pub fn verify<F>(mut self, mut keep: F) -> Result<VerifiedBundle<R>, BundleError>
    where
        F: FnMut(VerifiedSection<'_>) -> Result<(), BundleError>,
    {
        if !self.authenticated {
            return Err(BundleError::Unauthenticated);
        }
        self.src.seek(SeekFrom::Start(self.offsets.first().copied().unwrap_or(self.file_len)))?;
        let mut stored = Vec::new();
        let mut raw = Vec::new();
        let m = &self.manifest;
        let file_len = self.file_len;
        let offsets = &self.offsets;
        let read = |src: &mut R, i: usize, stored: &mut Vec<u8>, raw: &mut Vec<u8>| {
            let end = offsets[i] + m.sections[i].stored_len;
            read_section(src, m, i, end, file_len, stored, raw)
        };

        read(&mut self.src, 0, &mut stored, &mut raw)?;
        let bytes = section_bytes(m, 0, &stored, &raw);
        let certificate = LightCertificate::from_bytes(bytes)?;
        let sizes: Vec<(u32, u32)> = m.projectors.iter().map(|p| (p.width, p.height)).collect();
        certificate.validate_for(&m.light, &sizes)?;
        keep(VerifiedSection { index: 0, kind: m.sections[0].kind, bytes })?;

        // Coverage maps built once for every scene.
        let check = LightCheck::new(&m.light, &certificate, &self.stage)?;
        let mut peaks = Vec::with_capacity(m.scenes.len());
        for (s, scene) in m.scenes.iter().enumerate() {
            let mut acc = check.scene(&scene.id);
            for (k, p) in m.projectors.iter().enumerate() {
                let i = m.frame_section_index(s, k);
                read(&mut self.src, i, &mut stored, &mut raw)?;
                let bytes = section_bytes(m, i, &stored, &raw);
                acc.add(k, XrgbFrame { width: p.width, height: p.height, xrgb: bytes })?;
                keep(VerifiedSection { index: i, kind: m.sections[i].kind, bytes })?;
            }
            peaks.push(acc.finish()?);
        }
        drop(check);
        for i in m.frame_section_index(m.scenes.len(), 0)..m.sections.len() {
            read(&mut self.src, i, &mut stored, &mut raw)?;
            let bytes = section_bytes(m, i, &stored, &raw);
            keep(VerifiedSection { index: i, kind: m.sections[i].kind, bytes })?;
        }
        not_grown(&mut self.src, file_len)?;
        Ok(VerifiedBundle {
            manifest: self.manifest,
            certificate,
            peaks,
            manifest_hash: self.manifest_hash,
            key_id: self.key_id,
            src: self.src,
            offsets: self.offsets,
        })
    }
}

/// Refuses a file that has grown since `open` measured it (read just past the last section).
fn not_grown<R: Read + Seek>(src: &mut R, file_len: u64) -> Result<(), BundleError> {
    let mut probe = [0u8; 1];
    if src.read(&mut probe)? != 0 {
        let end = src.seek(SeekFrom::End(0))?;
        return Err(BundleError::TrailingBytes { extra: end.saturating_sub(file_len) });
    }
    Ok(())
}

/// An end of file inside `what` as [`BundleError::Truncated`]; other errors as they are.
fn truncated(e: std::io::Error, what: String, need: u64, file_len: u64) -> BundleError {
    match e.kind() {
        std::io::ErrorKind::UnexpectedEof => BundleError::Truncated { what, need, file_len },
        _ => BundleError::Io(e),
    }
}

fn section_bytes<'b>(m: &Manifest, i: usize, stored: &'b [u8], raw: &'b [u8]) -> &'b [u8] {
    match m.sections[i].compression {
        Compression::None => stored,
        Compression::Zstd => raw,
    }
}

/// Reads section `i` of `m` from the current position into `stored`, checks its hash, and
/// decompresses it into `raw` when compressed.
fn read_section<R: Read>(
    src: &mut R,
    m: &Manifest,
    i: usize,
    end: u64,
    file_len: u64,
    stored: &mut Vec<u8>,
    raw: &mut Vec<u8>,
) -> Result<(), BundleError> {
    let s = &m.sections[i];
    // Lengths were capped by `Manifest::validate` and checked against the file's length.
    stored.clear();
    stored.resize(s.stored_len as usize, 0);
    src.read_exact(stored).map_err(|e| truncated(e, m.section_name(i), end, file_len))?;
    if blake3::hash(stored).as_bytes() != &s.blake3 {
        return Err(BundleError::SectionHash { index: i, section: m.section_name(i) });
    }
    if s.compression == Compression::Zstd {
        raw.clear();
        raw.resize(s.raw_len as usize, 0);
        let bad = |problem: String| BundleError::Decompress {
            index: i,
            section: m.section_name(i),
            raw_len: s.raw_len,
            problem,
        };
        let n =
            zstd::bulk::decompress_to_buffer(stored, raw.as_mut_slice()).map_err(|e| bad(e.to_string()))?;
        if n as u64 != s.raw_len {
            return Err(bad(format!("got {n} bytes")));
        }
    }
    Ok(())
}

impl<R: Read + Seek> VerifiedBundle<R> {
    /// Reads section `index` again (e.g. a frame just before it is shown), checks its hash
    /// against the verified manifest, and returns its decompressed bytes. A file changed
    /// since verification gives [`BundleError::Changed`], never different bytes.
    pub fn read_section(&mut self, index: usize) -> Result<Vec<u8>, BundleError> {
        let Some(s) = self.manifest.sections.get(index).copied() else {
            return Err(BundleError::NoSuchSection { index, count: self.manifest.sections.len() });
        };
        self.src.seek(SeekFrom::Start(self.offsets[index]))?;
        let (mut stored, mut raw) = (Vec::new(), Vec::new());
        let end = self.offsets[index] + s.stored_len;
        match read_section(&mut self.src, &self.manifest, index, end, end, &mut stored, &mut raw) {
            Ok(()) => Ok(if s.compression == Compression::None { stored } else { raw }),
            Err(BundleError::SectionHash { .. } | BundleError::Truncated { .. }) => {
                Err(BundleError::Changed { index })
            }
            Err(e) => Err(e),
        }
    }

    /// Scene `scene`'s frame for projector `projector` (re-read and re-hashed).
    pub fn read_frame(&mut self, scene: usize, projector: usize) -> Result<Vec<u8>, BundleError> {
        if scene >= self.manifest.scenes.len() || projector >= self.manifest.projectors.len() {
            return Err(BundleError::NoSuchSection {
                index: usize::MAX,
                count: self.manifest.sections.len(),
            });
        }
        self.read_section(self.manifest.frame_section_index(scene, projector))
    }
}

#[cfg(test)]
mod tests {
    use std::io::Cursor;

    use super::*;
    use crate::bundle::example::{ExampleSpec, example_frame, example_writer};
    use crate::keys::signing_key_from_seed;

    fn trust() -> (ed25519_dalek::SigningKey, TrustStore) {
        let k = signing_key_from_seed([9; 32]);
        let mut t = TrustStore::new();
        t.insert(k.verifying_key(), "test");
        (k, t)
    }

    #[test]
    fn round_trip_plain_and_zstd() {
        let (key, trust) = trust();
        let spec = ExampleSpec::small();
        for zstd in [false, true] {
            let mut w = example_writer(&spec).unwrap();
            w.set_preview("original", b"\x89PNG not really".to_vec()).unwrap();
            let w = if zstd { w.zstd(3) } else { w };
            let mut bytes = Vec::new();
            let written = w.write(&key, &mut bytes).unwrap();
            assert_eq!(written.sections.iter().any(|s| s.compression == Compression::Zstd), zstd);
            let r =
                BundleReader::open(Cursor::new(bytes), &trust, &VerifyOptions::at(1_800_000_000)).unwrap();
            assert_eq!(r.manifest(), &written);
            let mut kept = Vec::new();
            let mut v = r
                .verify(|s| {
                    kept.push((s.index, s.bytes.len()));
                    Ok(())
                })
                .unwrap();
            assert_eq!(kept.len(), written.sections.len());
            assert_eq!(v.peaks.len(), 2);
            assert!(v.peaks.iter().all(|p| p.lux > 0.0 && p.lux <= 47.5));
            assert_eq!(v.read_frame(1, 1).unwrap(), example_frame(&spec, 1, 1));
            assert_eq!(v.read_section(written.sections.len() - 1).unwrap(), b"\x89PNG not really");
        }
    }

    #[test]
    fn a_file_changed_after_verification_is_not_read() {
        let (key, trust) = trust();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.restage");
        let mut bytes = Vec::new();
        example_writer(&ExampleSpec::small()).unwrap().write(&key, &mut bytes).unwrap();
        std::fs::write(&path, &bytes).unwrap();
        let f = std::fs::File::open(&path).unwrap();
        let mut v = BundleReader::open(f, &trust, &VerifyOptions::at(0)).unwrap().verify(|_| Ok(())).unwrap();
        let last = bytes.len() - 5;
        bytes[last] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        assert!(matches!(v.read_frame(1, 1), Err(BundleError::Changed { .. })));
        v.read_frame(0, 0).unwrap();
    }

    /// Each lying certificate or light model, correctly signed, is refused with the error
    /// that names what is wrong, though the per-point sums alone (the check before coverage)
    /// put its full-white scene within the bound.
    #[test]
    fn lying_certificates_are_refused() {
        use crate::bundle::example::{Lie, lying_frames, lying_parts, lying_writer};
        use crate::light::{LightError, XrgbFrame, max_irradiance};
        let (key, trust) = trust();
        let spec = ExampleSpec::small();
        let honest = crate::bundle::example::example_info(&spec).light;
        for lie in Lie::ALL {
            let (info, cert) = lying_parts(&spec, lie);
            if info.light == honest {
                let [_, (_, white)] = lying_frames(&spec);
                let views: Vec<XrgbFrame> = white
                    .iter()
                    .map(|f| XrgbFrame { width: spec.width, height: spec.height, xrgb: f })
                    .collect();
                let sums = max_irradiance(&info.light, &cert, &views).unwrap();
                // The check before coverage would have let this full-white scene through.
                assert!(sums.lux <= info.light.allowed_lux(), "{lie:?}: {sums:?}");
            }
            let mut bytes = Vec::new();
            lying_writer(&spec, lie).unwrap().write(&key, &mut bytes).unwrap();
            let err = BundleReader::open(Cursor::new(bytes), &trust, &VerifyOptions::at(1_800_000_000))
                .and_then(|r| r.verify(|_| Ok(())))
                .unwrap_err();
            let BundleError::Light(e) = &err else { panic!("{lie:?}: {err}") };
            let named = match lie {
                Lie::ZeroCoefficients => {
                    matches!(e, LightError::ZeroCoefficient { projector: 0, point: 0, .. })
                }
                Lie::TinyCoefficients => matches!(
                    e, LightError::UnderStated { scene, projector: 0, x: 0, y: 0, rgb: [254, 254, 254], .. }
                    if scene == "original"
                ),
                Lie::EmptyBlocks => matches!(
                    e, LightError::Uncovered { scene, projector: 0, x: 0, y: 0, .. } if scene == "original"
                ),
                Lie::OnePixelBlock => matches!(
                    e, LightError::Uncovered { scene, projector: 0, x: 1, y: 0, .. } if scene == "original"
                ),
                Lie::ZeroResponses => matches!(e, LightError::ResponseShort { projector: 0, channel: 0, .. }),
                Lie::ResponsesOnlyAtFull => {
                    matches!(e, LightError::ResponseImplausible { projector: 0, channel: 0, .. })
                }
            };
            assert!(named, "{lie:?}: {err}");
        }
    }

    #[test]
    fn writer_refuses_an_over_bound_scene() {
        let (key, _) = trust();
        let spec = ExampleSpec { lux_per_unit: 40.0, ..ExampleSpec::small() };
        let err = example_writer(&spec).unwrap().write(&key, Vec::new()).unwrap_err();
        assert!(matches!(err, BundleError::Light(crate::light::LightError::OverBound { .. })), "{err}");
    }
}

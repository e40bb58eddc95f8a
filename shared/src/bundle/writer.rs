//! Building and signing a bundle. The writer holds the frames in memory (the authoring
//! workstation has plenty), hashes each stored section, checks every scene against the
//! bound with the same code the appliance runs, then writes header, manifest, signature and
//! sections in the canonical order.

use std::io::Write;

use ed25519_dalek::{Signer, SigningKey};

use super::{
    BundleError, Compression, FORMAT_VERSION, HEADER_LEN, MAGIC, MAX_MANIFEST_LEN, MAX_SECTION_LEN, Manifest,
    ObjectInfo, Projector, SIGNATURE_BLOCK_LEN, Scene, SceneKind, Section, SectionKind,
};
use crate::keys::KeyId;
use crate::light::{LightCertificate, LightCheck, LightModel, StageLimits, XrgbFrame};
use crate::policy::ExposurePolicy;

/// Everything in the manifest except scenes, sections and the key id.
#[derive(Clone, Debug)]
pub struct BundleInfo {
    pub object: ObjectInfo,
    pub version: u64,
    pub created_unix_s: i64,
    pub not_before_unix_s: Option<i64>,
    pub expires_unix_s: Option<i64>,
    pub projectors: Vec<Projector>,
    pub light: LightModel,
    pub policy: ExposurePolicy,
    pub generator: String,
}

struct SceneIn {
    id: String,
    name: String,
    kind: SceneKind,
    frames: Vec<Vec<u8>>,
    preview: Option<Vec<u8>>,
}

/// Builds and signs a bundle.
pub struct BundleWriter {
    info: BundleInfo,
    certificate: LightCertificate,
    scenes: Vec<SceneIn>,
    zstd_level: Option<i32>,
    check_bound: bool,
}

impl std::fmt::Debug for BundleWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BundleWriter")
            .field("object", &self.info.object)
            .field("scenes", &self.scenes.len())
            .finish()
    }
}

impl BundleWriter {
    /// A writer with no scenes yet; sections stored uncompressed.
    pub fn new(info: BundleInfo, certificate: LightCertificate) -> Self {
        Self { info, certificate, scenes: Vec::new(), zstd_level: None, check_bound: true }
    }

    /// Compresses each section with zstd at `level` (1..=19) where that makes it smaller.
    pub fn zstd(mut self, level: i32) -> Self {
        self.zstd_level = Some(level.clamp(1, 19));
        self
    }

    /// Writes scenes without the light check (coverage and bound). Only for making the
    /// refusal fixtures that show the appliance's own check works; never for an exhibit.
    pub fn skip_bound_check_for_test_fixtures(mut self) -> Self {
        self.check_bound = false;
        self
    }

    /// Adds a scene: one XRGB8888 frame per projector, in projector order.
    pub fn add_scene(
        &mut self,
        id: &str,
        name: &str,
        kind: SceneKind,
        frames: Vec<Vec<u8>>,
    ) -> Result<(), BundleError> {
        if frames.len() != self.info.projectors.len() {
            return Err(BundleError::Input(format!(
                "scene {id}: {} frames for {} projectors",
                frames.len(),
                self.info.projectors.len()
            )));
        }
        for (k, (f, p)) in frames.iter().zip(&self.info.projectors).enumerate() {
            if f.len() as u64 != p.frame_len() {
                return Err(BundleError::Input(format!(
                    "scene {id} projector {k}: frame has {} bytes, a {}x{} XRGB8888 frame has {}",
                    f.len(),
                    p.width,
                    p.height,
                    p.frame_len()
                )));
            }
        }
        self.scenes.push(SceneIn { id: id.into(), name: name.into(), kind, frames, preview: None });
        Ok(())
    }

    /// Attaches a PNG preview to the scene with this id.
    pub fn set_preview(&mut self, scene_id: &str, png: Vec<u8>) -> Result<(), BundleError> {
        let s = self
            .scenes
            .iter_mut()
            .find(|s| s.id == scene_id)
            .ok_or_else(|| BundleError::Input(format!("no scene {scene_id:?} for the preview")))?;
        s.preview = Some(png);
        Ok(())
    }

    fn stored(&self, raw: &[u8], kind: SectionKind) -> Result<(Section, Option<Vec<u8>>), BundleError> {
        if let Some(level) = self.zstd_level {
            let z = zstd::bulk::compress(raw, level)?;
            if z.len() < raw.len() {
                let s = Section {
                    kind,
                    compression: Compression::Zstd,
                    stored_len: z.len() as u64,
                    raw_len: raw.len() as u64,
                    blake3: *blake3::hash(&z).as_bytes(),
                };
                return Ok((s, Some(z)));
            }
        }
        let s = Section {
            kind,
            compression: Compression::None,
            stored_len: raw.len() as u64,
            raw_len: raw.len() as u64,
            blake3: *blake3::hash(raw).as_bytes(),
        };
        Ok((s, None))
    }

    /// Checks, signs with `key` and writes the bundle to `out`. Returns the manifest
    /// written. Refuses (before writing anything) a scene the appliance's light check would
    /// refuse with default [`StageLimits`] (a lit pixel the certificate does not vouch for,
    /// or over the bound), an invalid manifest, or a manifest over [`MAX_MANIFEST_LEN`].
    pub fn write<W: Write>(self, key: &SigningKey, mut out: W) -> Result<Manifest, BundleError> {
        let sizes: Vec<(u32, u32)> = self.info.projectors.iter().map(|p| (p.width, p.height)).collect();
        self.certificate.validate_for(&self.info.light, &sizes)?;
        if self.check_bound {
            let check = LightCheck::new(&self.info.light, &self.certificate, &StageLimits::default())?;
            for s in &self.scenes {
                let frames: Vec<XrgbFrame> = s
                    .frames
                    .iter()
                    .zip(&self.info.projectors)
                    .map(|(f, p)| XrgbFrame { width: p.width, height: p.height, xrgb: f })
                    .collect();
                check.check_scene(&s.id, &frames)?;
            }
        }
        // Sections in canonical order; compressed copies kept only where smaller.
        let cert_bytes = self.certificate.to_bytes();
        let mut sections = Vec::new();
        let mut compressed: Vec<Option<Vec<u8>>> = Vec::new();
        let mut raws: Vec<&[u8]> = Vec::new();
        let mut push = |raw: &'_ [u8], kind, sections: &mut Vec<Section>| -> Result<(), BundleError> {
            let (s, z) = self.stored(raw, kind)?;
            sections.push(s);
            compressed.push(z);
            Ok(())
        };
        push(&cert_bytes, SectionKind::Certificate, &mut sections)?;
        raws.push(&cert_bytes);
        for (si, s) in self.scenes.iter().enumerate() {
            for (k, f) in s.frames.iter().enumerate() {
                push(f, SectionKind::Frame { scene: si as u32, projector: k as u32 }, &mut sections)?;
                raws.push(f);
            }
        }
        let np = self.info.projectors.len();
        let mut scenes = Vec::new();
        let mut next_preview = 1 + self.scenes.len() * np;
        for (si, s) in self.scenes.iter().enumerate() {
            let preview = s.preview.as_ref().map(|_| {
                next_preview += 1;
                (next_preview - 1) as u32
            });
            scenes.push(Scene {
                id: s.id.clone(),
                name: s.name.clone(),
                kind: s.kind,
                frames: (0..np).map(|k| (1 + si * np + k) as u32).collect(),
                preview,
            });
        }
        for (si, s) in self.scenes.iter().enumerate() {
            if let Some(p) = &s.preview {
                push(p, SectionKind::Preview { scene: si as u32 }, &mut sections)?;
                raws.push(p);
            }
        }
        let info = self.info.clone();
        let manifest = Manifest {
            object: info.object,
            version: info.version,
            created_unix_s: info.created_unix_s,
            not_before_unix_s: info.not_before_unix_s,
            expires_unix_s: info.expires_unix_s,
            key_id: KeyId::of(&key.verifying_key()),
            projectors: info.projectors,
            scenes,
            light: info.light,
            policy: info.policy,
            sections,
            generator: info.generator,
        };
        manifest.validate(MAX_SECTION_LEN)?;
        write_head(&manifest, key, &mut out)?;
        for (raw, z) in raws.iter().zip(&compressed) {
            out.write_all(z.as_deref().unwrap_or(raw))?;
        }
        out.flush()?;
        Ok(manifest)
    }
}

/// Writes the header, `manifest` and the signature block (signed with `key`, whose id the
/// manifest must carry): everything before the sections.
pub(crate) fn write_head<W: Write>(
    manifest: &Manifest,
    key: &SigningKey,
    out: &mut W,
) -> Result<(), BundleError> {
    let manifest_bytes =
        postcard::to_stdvec(manifest).map_err(|e| BundleError::ManifestEncode(e.to_string()))?;
    let mlen = manifest_bytes.len() as u64;
    if mlen > MAX_MANIFEST_LEN {
        return Err(BundleError::ManifestTooLarge { len: mlen, max: MAX_MANIFEST_LEN });
    }
    let mut signed = Vec::with_capacity(HEADER_LEN as usize + manifest_bytes.len());
    signed.extend_from_slice(MAGIC);
    signed.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    signed.extend_from_slice(&0u32.to_le_bytes());
    signed.extend_from_slice(&mlen.to_le_bytes());
    signed.extend_from_slice(&SIGNATURE_BLOCK_LEN.to_le_bytes());
    signed.extend_from_slice(&manifest_bytes);
    let signature = key.sign(&signed);
    out.write_all(&signed)?;
    out.write_all(&manifest.key_id.0)?;
    out.write_all(&signature.to_bytes())?;
    Ok(())
}

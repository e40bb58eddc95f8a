//! The signed manifest of a bundle (format version 1): what the object is, which version,
//! when it is valid, who signed it, the projectors, the scenes, the light model, the exposure
//! policy, and every payload section's length and BLAKE3 hash. Encoded with postcard; the
//! byte layout around it is in `docs/bundle-format.md`.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::keys::KeyId;
use crate::light::{LightError, LightModel};
use crate::policy::{ExposurePolicy, PolicyError};
use crate::text::printable;
use crate::time::format_utc;

/// Why a manifest is invalid ([`Manifest::validate`]): each variant names the field and, for
/// ranges, what is accepted.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ManifestError {
    #[error("object id {id:?} (expected 1..=64 of [A-Za-z0-9._-])")]
    ObjectId { id: String },
    #[error("{field}: {len} bytes of text (expected at most {MAX_TEXT})")]
    TextTooLong { field: &'static str, len: usize },
    #[error("valid from {} is not before the expiry {}", format_utc(*.not_before), format_utc(*.expires))]
    Validity { not_before: i64, expires: i64 },
    #[error("{count} projectors (expected 1..={MAX_PROJECTORS})")]
    ProjectorCount { count: usize },
    #[error("projector {projector}: {width}x{height} (expected 1..={MAX_SIDE} each side)")]
    ProjectorSize { projector: usize, width: u32, height: u32 },
    #[error("projector {projector}: refresh {refresh_mhz} mHz (expected 1000..=1000000)")]
    Refresh { projector: usize, refresh_mhz: u32 },
    #[error("projector {projector}: name or connector longer than {MAX_TEXT} bytes")]
    ProjectorText { projector: usize },
    #[error("{count} scenes (expected 1..={MAX_SCENES})")]
    SceneCount { count: usize },
    #[error("scene {scene}: id {id:?} (expected 1..=64 of [A-Za-z0-9._-])")]
    SceneId { scene: usize, id: String },
    #[error("scene {scene}: name of {len} bytes (expected at most {MAX_TEXT})")]
    SceneName { scene: usize, len: usize },
    #[error("scene id {id:?} appears twice")]
    SceneTwice { id: String },
    #[error("scene {scene}: frame sections {found:?} (expected {expected:?})")]
    SceneFrames { scene: usize, found: Vec<u32>, expected: Vec<u32> },
    #[error("scene {scene}: preview section {found} (expected {expected})")]
    ScenePreview { scene: usize, found: u32, expected: usize },
    #[error("{found} sections (expected {expected})")]
    SectionCount { found: usize, expected: usize },
    #[error("section {section} is the {found} (expected the {expected})")]
    SectionOrder { section: usize, found: SectionKind, expected: SectionKind },
    #[error("section {section}: {stored_len} bytes stored, {raw_len} raw (at most {max})")]
    SectionTooLarge { section: usize, stored_len: u64, raw_len: u64, max: u64 },
    #[error("section {section}: uncompressed but stored {stored_len} != raw {raw_len}")]
    UncompressedLength { section: usize, stored_len: u64, raw_len: u64 },
    #[error("section {section}: frame of {found} bytes (expected {expected})")]
    FrameLength { section: usize, found: u64, expected: u64 },
    #[error("sections overflow u64")]
    PayloadOverflow,
    #[error("light model has {found} projectors (expected {expected})")]
    LightProjectors { found: usize, expected: usize },
    #[error(transparent)]
    Light(#[from] LightError),
    #[error(transparent)]
    Policy(#[from] PolicyError),
}

/// Most projectors in a bundle.
pub const MAX_PROJECTORS: usize = 8;
/// Most scenes in a bundle.
pub const MAX_SCENES: usize = 64;
/// Longest name or id, bytes.
pub const MAX_TEXT: usize = 256;
/// Largest projector side, pixels (certificate blocks use u16 coordinates).
pub const MAX_SIDE: u32 = 16_384;

/// The object the bundle is for. The appliance tracks the accepted version per `id`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectInfo {
    /// Stable identifier: 1..=64 characters from `[A-Za-z0-9._-]`, e.g. "casas-grandes-jar-17".
    pub id: String,
    /// Human name, e.g. "Casas Grandes effigy jar".
    pub name: String,
}

/// Pixel layout of frame sections.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PixelFormat {
    /// 4 bytes per pixel, little-endian XRGB: bytes B, G, R, X (X = 0); stride `width * 4`.
    Xrgb8888,
}

impl PixelFormat {
    pub fn bytes_per_pixel(self) -> u64 {
        match self {
            PixelFormat::Xrgb8888 => 4,
        }
    }
}

/// A projector as the appliance must drive it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Projector {
    /// Operator-facing name, e.g. "left".
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Refresh rate in millihertz (60 Hz = 60000); the mode the appliance selects.
    pub refresh_mhz: u32,
    /// Connector the projector is normally on, e.g. "HDMI-A-1"; the appliance's config may
    /// override it (emulated stages name connectors "Virtual-1").
    pub connector: Option<String>,
    pub format: PixelFormat,
}

impl Projector {
    /// Bytes of one frame.
    pub fn frame_len(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height) * self.format.bytes_per_pixel()
    }
}

/// What a scene shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SceneKind {
    /// The object as it is (e.g. even light within the bound): what idle may show.
    Original,
    /// A restoration.
    Restoration,
    /// A restoration under virtual lights.
    Relit,
}

/// One scene: a frame per projector.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Scene {
    /// 1..=64 characters from `[A-Za-z0-9._-]`, unique in the bundle.
    pub id: String,
    pub name: String,
    pub kind: SceneKind,
    /// Section index of each projector's frame, in projector order.
    pub frames: Vec<u32>,
    /// Section index of an optional preview (PNG, what a visitor should see).
    pub preview: Option<u32>,
}

/// How a section's bytes are stored. The hash is always over the stored bytes, so nothing
/// unverified reaches the decompressor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Compression {
    None,
    /// A single zstd frame that must decompress to exactly `raw_len` bytes.
    Zstd,
}

/// What a payload section holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SectionKind {
    /// The [`LightCertificate`](crate::light::LightCertificate), postcard.
    Certificate,
    /// Projector `projector`'s frame of scene `scene`, in the projector's pixel format.
    Frame { scene: u32, projector: u32 },
    /// A PNG preview of scene `scene`.
    Preview { scene: u32 },
}

/// In plain words, without names: "light certificate", "frame of scene 0, projector 1",
/// "preview of scene 2" ([`Manifest::section_name`] adds the names).
impl std::fmt::Display for SectionKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SectionKind::Certificate => write!(f, "light certificate"),
            SectionKind::Frame { scene, projector } => {
                write!(f, "frame of scene {scene}, projector {projector}")
            }
            SectionKind::Preview { scene } => write!(f, "preview of scene {scene}"),
        }
    }
}

/// One payload section. Sections follow the signature block back to back in manifest
/// order, so offsets are implied and no two can overlap.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Section {
    pub kind: SectionKind,
    pub compression: Compression,
    /// Bytes in the file.
    pub stored_len: u64,
    /// Bytes after decompression (equal to `stored_len` when not compressed).
    pub raw_len: u64,
    /// BLAKE3 of the stored bytes.
    pub blake3: [u8; 32],
}

/// The manifest. Field order is the postcard wire order: never reorder within version 1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub object: ObjectInfo,
    /// Monotonic per object: the appliance refuses a version lower than one it accepted.
    pub version: u64,
    /// Unix seconds (UTC) when the bundle was made.
    pub created_unix_s: i64,
    /// Not valid before this Unix time, if set.
    pub not_before_unix_s: Option<i64>,
    /// Not valid at or after this Unix time, if set.
    pub expires_unix_s: Option<i64>,
    /// The signing key's id; must equal the signature block's.
    pub key_id: KeyId,
    pub projectors: Vec<Projector>,
    pub scenes: Vec<Scene>,
    pub light: LightModel,
    pub policy: ExposurePolicy,
    pub sections: Vec<Section>,
    /// The tool and version that wrote the bundle (free text, informational).
    pub generator: String,
}

fn id_ok(s: &str) -> bool {
    (1..=64).contains(&s.len()) && s.bytes().all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b))
}

impl Manifest {
    /// Section index of scene `s`, projector `k`'s frame in the canonical order:
    /// certificate, then frames scene-major, then previews.
    pub fn frame_section_index(&self, s: usize, k: usize) -> usize {
        1 + s * self.projectors.len() + k
    }

    /// Checks everything that can be checked without the payload: ranges, ids, the
    /// canonical section order, frame sizes against projectors, and the light model and
    /// policy. `max_section` caps each section's stored and raw length.
    pub fn validate(&self, max_section: u64) -> Result<(), ManifestError> {
        if !id_ok(&self.object.id) {
            return Err(ManifestError::ObjectId { id: self.object.id.clone() });
        }
        for (field, t) in [("object name", &self.object.name), ("generator", &self.generator)] {
            if t.len() > MAX_TEXT {
                return Err(ManifestError::TextTooLong { field, len: t.len() });
            }
        }
        if let (Some(not_before), Some(expires)) = (self.not_before_unix_s, self.expires_unix_s)
            && not_before >= expires
        {
            return Err(ManifestError::Validity { not_before, expires });
        }
        let np = self.projectors.len();
        if !(1..=MAX_PROJECTORS).contains(&np) {
            return Err(ManifestError::ProjectorCount { count: np });
        }
        for (k, p) in self.projectors.iter().enumerate() {
            if !(1..=MAX_SIDE).contains(&p.width) || !(1..=MAX_SIDE).contains(&p.height) {
                return Err(ManifestError::ProjectorSize { projector: k, width: p.width, height: p.height });
            }
            if !(1_000..=1_000_000).contains(&p.refresh_mhz) {
                return Err(ManifestError::Refresh { projector: k, refresh_mhz: p.refresh_mhz });
            }
            if p.name.len() > MAX_TEXT || p.connector.as_ref().is_some_and(|c| c.len() > MAX_TEXT) {
                return Err(ManifestError::ProjectorText { projector: k });
            }
        }
        let ns = self.scenes.len();
        if !(1..=MAX_SCENES).contains(&ns) {
            return Err(ManifestError::SceneCount { count: ns });
        }
        let mut expected: Vec<SectionKind> = vec![SectionKind::Certificate];
        for s in 0..ns as u32 {
            for k in 0..np as u32 {
                expected.push(SectionKind::Frame { scene: s, projector: k });
            }
        }
        for (s, scene) in self.scenes.iter().enumerate() {
            if !id_ok(&scene.id) {
                return Err(ManifestError::SceneId { scene: s, id: scene.id.clone() });
            }
            if scene.name.len() > MAX_TEXT {
                return Err(ManifestError::SceneName { scene: s, len: scene.name.len() });
            }
            if self.scenes[..s].iter().any(|o| o.id == scene.id) {
                return Err(ManifestError::SceneTwice { id: scene.id.clone() });
            }
            let want: Vec<u32> = (0..np).map(|k| self.frame_section_index(s, k) as u32).collect();
            if scene.frames != want {
                return Err(ManifestError::SceneFrames {
                    scene: s,
                    found: scene.frames.clone(),
                    expected: want,
                });
            }
            if let Some(p) = scene.preview {
                if p as usize != expected.len() {
                    return Err(ManifestError::ScenePreview { scene: s, found: p, expected: expected.len() });
                }
                expected.push(SectionKind::Preview { scene: s as u32 });
            }
        }
        if self.sections.len() != expected.len() {
            return Err(ManifestError::SectionCount { found: self.sections.len(), expected: expected.len() });
        }
        for (i, (sec, want)) in self.sections.iter().zip(&expected).enumerate() {
            if sec.kind != *want {
                return Err(ManifestError::SectionOrder { section: i, found: sec.kind, expected: *want });
            }
            if sec.stored_len > max_section || sec.raw_len > max_section {
                return Err(ManifestError::SectionTooLarge {
                    section: i,
                    stored_len: sec.stored_len,
                    raw_len: sec.raw_len,
                    max: max_section,
                });
            }
            if sec.compression == Compression::None && sec.stored_len != sec.raw_len {
                return Err(ManifestError::UncompressedLength {
                    section: i,
                    stored_len: sec.stored_len,
                    raw_len: sec.raw_len,
                });
            }
            if let SectionKind::Frame { projector, .. } = sec.kind {
                let want = self.projectors[projector as usize].frame_len();
                if sec.raw_len != want {
                    return Err(ManifestError::FrameLength {
                        section: i,
                        found: sec.raw_len,
                        expected: want,
                    });
                }
            }
        }
        if self.light.projectors.len() != np {
            return Err(ManifestError::LightProjectors { found: self.light.projectors.len(), expected: np });
        }
        self.light.validate()?;
        let ids: Vec<&str> = self.scenes.iter().map(|s| s.id.as_str()).collect();
        self.policy.validate(&ids)?;
        Ok(())
    }

    /// Sum of the sections' stored lengths (u64, checked).
    pub fn payload_len(&self) -> Option<u64> {
        self.sections.iter().try_fold(0u64, |a, s| a.checked_add(s.stored_len))
    }

    /// Section `index` as people know it, for messages: "section 2 (frame of scene 0
    /// 'restored', projector 1 'left')"; names escaped with [`printable`].
    pub fn section_name(&self, index: usize) -> String {
        let scene = |s: u32| match self.scenes.get(s as usize) {
            Some(sc) => format!("scene {s} '{}'", printable(&sc.id)),
            None => format!("scene {s}"),
        };
        let what = match self.sections.get(index).map(|s| s.kind) {
            None => return format!("section {index}"),
            Some(SectionKind::Certificate) => "light certificate".to_string(),
            Some(SectionKind::Frame { scene: s, projector: k }) => match self.projectors.get(k as usize) {
                Some(p) => format!("frame of {}, projector {k} '{}'", scene(s), printable(&p.name)),
                None => format!("frame of {}, projector {k}", scene(s)),
            },
            Some(SectionKind::Preview { scene: s }) => format!("preview of {}", scene(s)),
        };
        format!("section {index} ({what})")
    }

    /// The scene with this id.
    pub fn scene(&self, id: &str) -> Option<(usize, &Scene)> {
        self.scenes.iter().enumerate().find(|(_, s)| s.id == id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bundle::example::{ExampleSpec, example_writer};
    use crate::bundle::{BundleError, MAX_SECTION_LEN};
    use crate::keys::signing_key_from_seed;

    fn manifest() -> Manifest {
        let key = signing_key_from_seed([3; 32]);
        example_writer(&ExampleSpec::small()).unwrap().write(&key, Vec::new()).unwrap()
    }

    #[test]
    fn validation_names_what_is_wrong() {
        let good = manifest();
        good.validate(MAX_SECTION_LEN).unwrap();
        let refused = |f: &dyn Fn(&mut Manifest)| {
            let mut m = good.clone();
            f(&mut m);
            m.validate(MAX_SECTION_LEN).unwrap_err()
        };
        assert_eq!(refused(&|m| m.projectors.clear()), ManifestError::ProjectorCount { count: 0 });
        let e = refused(&|m| m.scenes[1].id = m.scenes[0].id.clone());
        assert_eq!(e, ManifestError::SceneTwice { id: "original".into() });
        let e = refused(&|m| m.projectors[1].refresh_mhz = 5);
        assert_eq!(e.to_string(), "projector 1: refresh 5 mHz (expected 1000..=1000000)");
        let e = refused(&|m| m.generator = "g".repeat(MAX_TEXT + 1));
        assert_eq!(e, ManifestError::TextTooLong { field: "generator", len: MAX_TEXT + 1 });
        let e = refused(&|m| m.scenes[0].name = "n".repeat(MAX_TEXT + 1));
        assert_eq!(e, ManifestError::SceneName { scene: 0, len: MAX_TEXT + 1 });
        let e = refused(&|m| m.sections[1].raw_len += 4);
        assert!(matches!(e, ManifestError::UncompressedLength { section: 1, .. }), "{e}");
        let e = refused(&|m| m.policy.max_showing_s = 0);
        assert!(matches!(e, ManifestError::Policy(_)), "{e}");
        // In a BundleError the message keeps its prefix.
        let e = BundleError::from(ManifestError::SceneCount { count: 0 });
        assert_eq!(e.to_string(), "the manifest is invalid: 0 scenes (expected 1..=64)");
    }
}

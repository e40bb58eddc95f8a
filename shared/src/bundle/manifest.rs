//! The signed manifest of a bundle (format version 1): what the object is, which version,
//! when it is valid, who signed it, the projectors, the scenes, the light model, the exposure
//! policy, and every payload section's length and BLAKE3 hash. Encoded with postcard; the
//! byte layout around it is in `docs/bundle-format.md`.

use serde::{Deserialize, Serialize};

use crate::keys::KeyId;
use crate::light::LightModel;
use crate::policy::ExposurePolicy;

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
    pub fn validate(&self, max_section: u64) -> Result<(), String> {
        if !id_ok(&self.object.id) {
            return Err(format!("object id {:?} (expected 1..=64 of [A-Za-z0-9._-])", self.object.id));
        }
        for t in [&self.object.name, &self.generator] {
            if t.len() > MAX_TEXT {
                return Err(format!("text longer than {MAX_TEXT} bytes"));
            }
        }
        if let (Some(a), Some(b)) = (self.not_before_unix_s, self.expires_unix_s)
            && a >= b
        {
            return Err(format!("not-before {a} is not before expiry {b}"));
        }
        let np = self.projectors.len();
        if !(1..=MAX_PROJECTORS).contains(&np) {
            return Err(format!("{np} projectors (expected 1..={MAX_PROJECTORS})"));
        }
        for (k, p) in self.projectors.iter().enumerate() {
            if !(1..=MAX_SIDE).contains(&p.width) || !(1..=MAX_SIDE).contains(&p.height) {
                return Err(format!(
                    "projector {k}: {}x{} (expected 1..={MAX_SIDE} each side)",
                    p.width, p.height
                ));
            }
            if !(1_000..=1_000_000).contains(&p.refresh_mhz) {
                return Err(format!(
                    "projector {k}: refresh {} mHz (expected 1000..=1000000)",
                    p.refresh_mhz
                ));
            }
            if p.name.len() > MAX_TEXT || p.connector.as_ref().is_some_and(|c| c.len() > MAX_TEXT) {
                return Err(format!("projector {k}: name or connector longer than {MAX_TEXT} bytes"));
            }
        }
        let ns = self.scenes.len();
        if !(1..=MAX_SCENES).contains(&ns) {
            return Err(format!("{ns} scenes (expected 1..={MAX_SCENES})"));
        }
        let mut expected: Vec<SectionKind> = vec![SectionKind::Certificate];
        for s in 0..ns as u32 {
            for k in 0..np as u32 {
                expected.push(SectionKind::Frame { scene: s, projector: k });
            }
        }
        for (s, scene) in self.scenes.iter().enumerate() {
            if !id_ok(&scene.id) || scene.name.len() > MAX_TEXT {
                return Err(format!("scene {s}: id {:?} (expected 1..=64 of [A-Za-z0-9._-])", scene.id));
            }
            if self.scenes[..s].iter().any(|o| o.id == scene.id) {
                return Err(format!("scene id {:?} appears twice", scene.id));
            }
            let want: Vec<u32> = (0..np).map(|k| self.frame_section_index(s, k) as u32).collect();
            if scene.frames != want {
                return Err(format!("scene {s}: frame sections {:?} (expected {want:?})", scene.frames));
            }
            if let Some(p) = scene.preview {
                if p as usize != expected.len() {
                    return Err(format!("scene {s}: preview section {p} (expected {})", expected.len()));
                }
                expected.push(SectionKind::Preview { scene: s as u32 });
            }
        }
        if self.sections.len() != expected.len() {
            return Err(format!("{} sections (expected {})", self.sections.len(), expected.len()));
        }
        for (i, (sec, want)) in self.sections.iter().zip(&expected).enumerate() {
            if sec.kind != *want {
                return Err(format!("section {i} is {:?} (expected {want:?})", sec.kind));
            }
            if sec.stored_len > max_section || sec.raw_len > max_section {
                return Err(format!(
                    "section {i}: {} bytes stored, {} raw (at most {max_section})",
                    sec.stored_len, sec.raw_len
                ));
            }
            if sec.compression == Compression::None && sec.stored_len != sec.raw_len {
                return Err(format!(
                    "section {i}: uncompressed but stored {} != raw {}",
                    sec.stored_len, sec.raw_len
                ));
            }
            if let SectionKind::Frame { projector, .. } = sec.kind {
                let want = self.projectors[projector as usize].frame_len();
                if sec.raw_len != want {
                    return Err(format!("section {i}: frame of {} bytes (expected {want})", sec.raw_len));
                }
            }
        }
        if self.light.projectors.len() != np {
            return Err(format!(
                "light model has {} projectors (expected {np})",
                self.light.projectors.len()
            ));
        }
        self.light.validate().map_err(|e| e.to_string())?;
        let ids: Vec<&str> = self.scenes.iter().map(|s| s.id.as_str()).collect();
        self.policy.validate(&ids).map_err(|e| e.to_string())?;
        Ok(())
    }

    /// Sum of the sections' stored lengths (u64, checked).
    pub fn payload_len(&self) -> Option<u64> {
        self.sections.iter().try_fold(0u64, |a, s| a.checked_add(s.stored_len))
    }

    /// The scene with this id.
    pub fn scene(&self, id: &str) -> Option<(usize, &Scene)> {
        self.scenes.iter().enumerate().find(|(_, s)| s.id == id)
    }
}

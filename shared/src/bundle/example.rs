//! Synthetic bundles for tests, the benchmark and the fuzzer: flat geometry (certificate
//! point `(u, v)` is lit by the same spot of every projector), smooth frames with a little
//! texture, and a certificate whose coefficients the caller picks so a scene lands under or
//! over the bound on purpose; and correctly signed bundles whose certificate or light model
//! lies ([`lying_writer`]), which the light check must refuse; and a small file that
//! inflates to the reader's limits ([`inflating_bundle`]), which inspection must not unpack.

use std::io::Write;

use ed25519_dalek::SigningKey;

use super::{
    BundleError, BundleInfo, BundleWriter, Compression, MAX_SECTION_LEN, Manifest, ObjectInfo, PixelFormat,
    Projector, Scene, SceneKind, Section, SectionKind,
};
use crate::keys::KeyId;
use crate::light::{CertificateMap, Footprint, LightCertificate, RESPONSE_LEVELS, example_light_model};
use crate::policy::{ExposurePolicy, Sensitivity};

/// Shape of a synthetic bundle.
#[derive(Clone, Debug)]
pub struct ExampleSpec {
    pub projectors: usize,
    pub scenes: usize,
    pub width: u32,
    pub height: u32,
    /// Certificate points every `step` projector pixels in x and y.
    pub step: u32,
    /// `L_ik` of every footprint; with E_bound 50 lx, margin 5 % and black 0.01, full white
    /// from `n` projectors gives `n * 1.01 * lux_per_unit` lux.
    pub lux_per_unit: f32,
    /// Scales the frames' values (255 = reaches full white somewhere).
    pub peak_value: u8,
    pub version: u64,
    pub created_unix_s: i64,
    pub expires_unix_s: Option<i64>,
    pub not_before_unix_s: Option<i64>,
}

impl ExampleSpec {
    /// A small in-bound bundle: 2 projectors of 32x24, 2 scenes.
    pub fn small() -> Self {
        Self {
            projectors: 2,
            scenes: 2,
            width: 32,
            height: 24,
            step: 4,
            lux_per_unit: 15.0,
            peak_value: 255,
            version: 3,
            created_unix_s: 1_700_000_000,
            expires_unix_s: None,
            not_before_unix_s: None,
        }
    }
}

/// Frame of scene `s`, projector `k`: a diagonal gradient with hashed texture, XRGB8888.
pub fn example_frame(spec: &ExampleSpec, s: usize, k: usize) -> Vec<u8> {
    let (w, h) = (spec.width as usize, spec.height as usize);
    let mut out = Vec::with_capacity(w * h * 4);
    for y in 0..h {
        for x in 0..w {
            let base = ((x + y + 17 * s + 29 * k) % (w + h)) as f32 / (w + h) as f32;
            let hash = ((x as u32).wrapping_mul(0x9E37_79B9) ^ (y as u32).wrapping_mul(0x85EB_CA6B)) >> 29;
            let v = ((base * 0.9 + hash as f32 / 80.0) * f32::from(spec.peak_value)).min(255.0) as u8;
            out.extend_from_slice(&[v / 2, v, v.saturating_sub(10), 0]);
        }
    }
    out
}

/// The certificate: points on a `step` grid, each lit by a `(2 step + 1)`-wide block.
pub fn example_certificate(spec: &ExampleSpec) -> LightCertificate {
    let (w, h, st) = (spec.width, spec.height, spec.step.max(1));
    let mut centres = Vec::new();
    let mut y = st / 2;
    while y < h {
        let mut x = st / 2;
        while x < w {
            centres.push((x, y));
            x += st;
        }
        y += st;
    }
    let fp = |&(x, y): &(u32, u32)| Footprint {
        x0: x.saturating_sub(st) as u16,
        y0: y.saturating_sub(st) as u16,
        x1: (x + st + 1).min(w) as u16,
        y1: (y + st + 1).min(h) as u16,
        lux_per_unit: spec.lux_per_unit,
    };
    LightCertificate {
        points: centres.len() as u32,
        point_px: centres.iter().map(|&(x, y)| [x as u16, y as u16]).collect(),
        projectors: (0..spec.projectors)
            .map(|_| CertificateMap { width: w, height: h, footprints: centres.iter().map(fp).collect() })
            .collect(),
    }
}

/// The manifest fields of a synthetic bundle.
pub fn example_info(spec: &ExampleSpec) -> BundleInfo {
    BundleInfo {
        object: ObjectInfo { id: "test-jar-1".into(), name: "Synthetic jar".into() },
        version: spec.version,
        created_unix_s: spec.created_unix_s,
        not_before_unix_s: spec.not_before_unix_s,
        expires_unix_s: spec.expires_unix_s,
        projectors: (0..spec.projectors)
            .map(|k| Projector {
                name: format!("p{k}"),
                width: spec.width,
                height: spec.height,
                refresh_mhz: 60_000,
                connector: Some(format!("HDMI-A-{}", k + 1)),
                format: PixelFormat::Xrgb8888,
            })
            .collect(),
        light: example_light_model(spec.projectors, 50.0),
        policy: ExposurePolicy::cie157(Sensitivity::High),
        generator: "restage-shared example".into(),
    }
}

/// A writer holding the whole synthetic bundle (scene 0 "original", the rest restorations).
pub fn example_writer(spec: &ExampleSpec) -> Result<BundleWriter, BundleError> {
    let mut w = BundleWriter::new(example_info(spec), example_certificate(spec));
    for s in 0..spec.scenes {
        let frames = (0..spec.projectors).map(|k| example_frame(spec, s, k)).collect();
        let (id, kind) = if s == 0 {
            ("original".to_string(), SceneKind::Original)
        } else {
            (format!("restored-{s}"), SceneKind::Restoration)
        };
        w.add_scene(&id, &id, kind, frames)?;
    }
    Ok(w)
}

/// Ways a signed bundle can lie about its light so that a bright scene is charged little or
/// nothing: what the light check must refuse.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lie {
    /// Every coefficient `L_ik` is 0.
    ZeroCoefficients,
    /// Every coefficient is a positive speck (1e-9 lx per unit), under any plausible floor.
    TinyCoefficients,
    /// Every block is empty: "no projector reaches any point".
    EmptyBlocks,
    /// One point has a single-pixel block; every other block is empty.
    OnePixelBlock,
    /// Every response curve is all zeros.
    ZeroResponses,
    /// Response curves are 0 below 255 and 1 at 255: full white honest, the rest free.
    ResponsesOnlyAtFull,
}

impl Lie {
    pub const ALL: [Lie; 6] = [
        Lie::ZeroCoefficients,
        Lie::TinyCoefficients,
        Lie::EmptyBlocks,
        Lie::OnePixelBlock,
        Lie::ZeroResponses,
        Lie::ResponsesOnlyAtFull,
    ];
}

/// The manifest fields and certificate of [`lying_writer`]'s bundle.
pub fn lying_parts(spec: &ExampleSpec, lie: Lie) -> (BundleInfo, LightCertificate) {
    let mut info = example_info(spec);
    let mut cert = example_certificate(spec);
    let every = |cert: &mut LightCertificate, f: &mut dyn FnMut(usize, &mut Footprint)| {
        for m in &mut cert.projectors {
            for (i, fp) in m.footprints.iter_mut().enumerate() {
                f(i, fp);
            }
        }
    };
    match lie {
        Lie::ZeroCoefficients => every(&mut cert, &mut |_, f| f.lux_per_unit = 0.0),
        Lie::TinyCoefficients => every(&mut cert, &mut |_, f| f.lux_per_unit = 1e-9),
        Lie::EmptyBlocks => every(&mut cert, &mut |_, f| *f = Footprint::default()),
        Lie::OnePixelBlock => every(&mut cert, &mut |i, f| {
            *f = if i == 0 {
                Footprint { x0: 0, y0: 0, x1: 1, y1: 1, lux_per_unit: spec.lux_per_unit }
            } else {
                Footprint::default()
            }
        }),
        Lie::ZeroResponses => {
            for p in &mut info.light.projectors {
                p.response = std::array::from_fn(|_| vec![0.0; RESPONSE_LEVELS]);
            }
        }
        Lie::ResponsesOnlyAtFull => {
            for p in &mut info.light.projectors {
                p.response = std::array::from_fn(|_| {
                    (0..RESPONSE_LEVELS).map(|v| if v == RESPONSE_LEVELS - 1 { 1.0 } else { 0.0 }).collect()
                });
            }
        }
    }
    (info, cert)
}

/// The scenes of [`lying_writer`]: "original" at 254 grey, "white" at full white, XRGB.
pub fn lying_frames(spec: &ExampleSpec) -> [(&'static str, Vec<Vec<u8>>); 2] {
    let len = (spec.width * spec.height * 4) as usize;
    let frame = |v: u8| (0..len).map(|i| if i % 4 == 3 { 0 } else { v }).collect::<Vec<u8>>();
    let frames = |v| (0..spec.projectors).map(|_| frame(v)).collect();
    [("original", frames(254)), ("white", frames(255))]
}

/// Full-white frames (and a 254-grey scene) under a certificate or light model that lies as
/// `lie` says; the writer's own light check is off, so the bundle is correctly signed and
/// only the reader's check stands between it and the projectors. With honest data these
/// scenes are within the bound (`spec` as [`ExampleSpec::small`]).
pub fn lying_writer(spec: &ExampleSpec, lie: Lie) -> Result<BundleWriter, BundleError> {
    let (info, cert) = lying_parts(spec, lie);
    let mut w = BundleWriter::new(info, cert).skip_bound_check_for_test_fixtures();
    for (id, frames) in lying_frames(spec) {
        let kind = if id == "original" { SceneKind::Original } else { SceneKind::Restoration };
        w.add_scene(id, id, kind, frames)?;
    }
    Ok(w)
}

/// Side of [`inflating_bundle`]'s projectors: a 4096 x 4096 XRGB frame is exactly
/// [`MAX_SECTION_LEN`] (64 MiB).
pub const INFLATING_SIDE: u32 = 4096;

/// A correctly signed bundle that is small on disk and as large as the reader's limits allow
/// once unpacked: 8 projectors of 4096 x 4096, `scenes` scenes (1..=64) of black frames, each
/// frame a zstd section of about 2.4 KB that decompresses to 64 MiB, and a certificate whose
/// coverage maps are a byte per projector pixel (128 MiB). With `heavy_certificate` the
/// certificate has 2^19 points whose blocks read the most pixels the work bound allows
/// (16 per projector pixel, every scene), stored as a zstd section; without it, one point.
/// Everything is within the format's limits and the light bound, so a full verification
/// unpacks and checks it all (64 scenes: 32 GiB of frames). Writes it to `out`; returns its
/// manifest.
pub fn inflating_bundle<W: Write>(
    scenes: usize,
    heavy_certificate: bool,
    key: &SigningKey,
    mut out: W,
) -> Result<Manifest, BundleError> {
    const PROJECTORS: usize = 8;
    let side = INFLATING_SIDE;
    // One black frame, compressed as a stream so it never exists uncompressed in memory.
    let mut z = zstd::stream::Encoder::new(Vec::new(), 3)?;
    z.set_pledged_src_size(Some(MAX_SECTION_LEN))?;
    z.include_contentsize(true)?;
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..MAX_SECTION_LEN >> 20 {
        z.write_all(&zeros)?;
    }
    let frame = z.finish()?;
    let projectors: Vec<Projector> = (0..PROJECTORS)
        .map(|k| Projector {
            name: format!("p{k}"),
            width: side,
            height: side,
            refresh_mhz: 60_000,
            connector: None,
            format: PixelFormat::Xrgb8888,
        })
        .collect();
    // Heavy: 16 x 32 blocks on a grid, 2^19 of them: 16 reads per projector pixel in all.
    let footprints: Vec<Footprint> = if heavy_certificate {
        (0..1u32 << 19)
            .map(|i| {
                let (x0, y0) = ((i % 256 * 16) as u16, (i / 256 % 128 * 32) as u16);
                Footprint { x0, y0, x1: x0 + 16, y1: y0 + 32, lux_per_unit: 1.0 }
            })
            .collect()
    } else {
        vec![Footprint::default()]
    };
    let raw_certificate = LightCertificate {
        points: footprints.len() as u32,
        point_px: vec![],
        projectors: (0..PROJECTORS)
            .map(|_| CertificateMap { width: side, height: side, footprints: footprints.clone() })
            .collect(),
    }
    .to_bytes();
    let (certificate, compression) = if heavy_certificate {
        (zstd::bulk::compress(&raw_certificate, 19)?, Compression::Zstd)
    } else {
        (raw_certificate.clone(), Compression::None)
    };
    let section = |kind, bytes: &[u8], compression, raw_len| Section {
        kind,
        compression,
        stored_len: bytes.len() as u64,
        raw_len,
        blake3: *blake3::hash(bytes).as_bytes(),
    };
    let mut sections =
        vec![section(SectionKind::Certificate, &certificate, compression, raw_certificate.len() as u64)];
    for s in 0..scenes as u32 {
        for k in 0..PROJECTORS as u32 {
            let kind = SectionKind::Frame { scene: s, projector: k };
            sections.push(section(kind, &frame, Compression::Zstd, MAX_SECTION_LEN));
        }
    }
    let manifest = Manifest {
        object: ObjectInfo { id: "inflating-1".into(), name: "Small file, large unpacked".into() },
        version: 1,
        created_unix_s: 1_700_000_000,
        not_before_unix_s: None,
        expires_unix_s: None,
        key_id: KeyId::of(&key.verifying_key()),
        projectors,
        scenes: (0..scenes)
            .map(|s| Scene {
                id: if s == 0 { "original".into() } else { format!("s{s}") },
                name: format!("black {s}"),
                kind: if s == 0 { SceneKind::Original } else { SceneKind::Restoration },
                frames: (0..PROJECTORS).map(|k| (1 + s * PROJECTORS + k) as u32).collect(),
                preview: None,
            })
            .collect(),
        light: example_light_model(PROJECTORS, 50.0),
        policy: ExposurePolicy::cie157(Sensitivity::High),
        sections,
        generator: "restage-shared example (inflating)".into(),
    };
    manifest.validate(MAX_SECTION_LEN)?;
    super::writer::write_head(&manifest, key, &mut out)?;
    out.write_all(&certificate)?;
    for _ in 0..scenes * PROJECTORS {
        out.write_all(&frame)?;
    }
    out.flush()?;
    Ok(manifest)
}

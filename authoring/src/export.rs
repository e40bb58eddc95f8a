//! Export: turns compensation's output (one 8-bit frame per scene per projector, the light
//! certificate) plus the stage model and a bundle description (TOML) into a signed bundle
//! through `restage_shared::bundle`. The description:
//!
//! ```toml
//! version = 3                          # monotonic per object
//! stage = "stage"                      # stage model folder (responses, black, lux_at_1m)
//! certificate = "comp/certificate.bin" # LightCertificate from compensation
//! valid_days = 365                     # optional: expiry = created + days
//! not_before_unix_s = 1767225600       # optional
//!
//! [object]
//! id = "jar-17"
//! name = "Casas Grandes jar"
//!
//! [light]
//! e_bound_lux = 50.0
//! safety_margin = 0.05                 # scenes must stay under E_bound * (1 - margin)
//! ambient_lux = 0.0                    # optional
//! lux_shares = [0.21, 0.72, 0.07]      # optional; without it, lux = brightest channel
//!
//! [policy]                             # optional; CIE 157 class preset, fields override it
//! class = "high"                       # high | medium | low
//! max_showing_s = 60
//! cooldown_s = 30
//! idle = "off"                         # off | black | scene:<id>
//!
//! [[projectors]]                       # one per projector, in stage-model order
//! name = "left"
//! refresh_hz = 60.0
//! connector = "HDMI-A-1"
//!
//! [[scenes]]
//! id = "original"
//! name = "As found"
//! kind = "original"                    # original | restoration | relit
//! frames = ["comp/original/p0.png", "comp/original/p1.png", "comp/original/p2.png"]
//! preview = "comp/original/preview.png" # optional
//! ```
//!
//! Relative paths are relative to the description file. Frame PNGs hold 8-bit device values
//! (not sRGB-decoded); their size is the projector's resolution.

use std::path::{Path, PathBuf};

use restage_shared::bundle::{BundleInfo, BundleWriter, ObjectInfo, PixelFormat, Projector, SceneKind};
use restage_shared::light::{LightCertificate, LightModel, LuxWeighting, RESPONSE_LEVELS, xrgb_from_rgb};
use restage_shared::policy::{ExposurePolicy, IdleMode, Sensitivity};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::stage_model::{StageModel, StageModelError};

#[derive(Debug, Error)]
pub enum ExportError {
    #[error("cannot read {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("bundle description {path}: {source}")]
    Toml { path: PathBuf, source: toml::de::Error },
    #[error("bundle description {path}: {problem}")]
    Description { path: PathBuf, problem: String },
    #[error(transparent)]
    Stage(#[from] StageModelError),
    #[error("certificate {path}: {source}")]
    Certificate { path: PathBuf, source: restage_shared::light::LightError },
    #[error("frame {path}: {problem}")]
    Frame { path: PathBuf, problem: String },
    #[error(transparent)]
    Bundle(#[from] restage_shared::bundle::BundleError),
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDesc {
    pub id: String,
    pub name: String,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LightDesc {
    pub e_bound_lux: f64,
    pub safety_margin: f64,
    #[serde(default)]
    pub ambient_lux: f64,
    #[serde(default)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lux_shares: Option<[f32; 3]>,
}

#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyDesc {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub class: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_showing_s: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cooldown_s: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub daily_budget_lxh: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub annual_budget_lxh: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warn_at: Option<Vec<f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub idle: Option<String>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorDesc {
    pub name: String,
    #[serde(default = "sixty")]
    pub refresh_hz: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub connector: Option<String>,
}

fn sixty() -> f64 {
    60.0
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDesc {
    pub id: String,
    pub name: String,
    pub kind: String,
    pub frames: Vec<PathBuf>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preview: Option<PathBuf>,
}

/// The bundle description file (see the module docs).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BundleDescription {
    pub version: u64,
    pub stage: PathBuf,
    pub certificate: PathBuf,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub valid_days: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub not_before_unix_s: Option<i64>,
    pub object: ObjectDesc,
    pub light: LightDesc,
    #[serde(default)]
    pub policy: PolicyDesc,
    pub projectors: Vec<ProjectorDesc>,
    pub scenes: Vec<SceneDesc>,
}

impl BundleDescription {
    /// Reads the TOML; relative paths inside are made relative to its folder.
    pub fn load(path: &Path) -> Result<Self, ExportError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ExportError::Io { path: path.into(), source })?;
        let mut d: Self =
            toml::from_str(&text).map_err(|source| ExportError::Toml { path: path.into(), source })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        fix(&mut d.stage);
        fix(&mut d.certificate);
        for s in &mut d.scenes {
            s.frames.iter_mut().for_each(fix);
            if let Some(p) = &mut s.preview {
                fix(p);
            }
        }
        Ok(d)
    }
}

/// The exposure policy from a description (class preset, then overrides).
pub fn policy_from(desc: &PolicyDesc) -> Result<ExposurePolicy, String> {
    let class = match desc.class.as_deref().unwrap_or("high") {
        "high" => Sensitivity::High,
        "medium" => Sensitivity::Medium,
        "low" => Sensitivity::Low,
        c => return Err(format!("policy class {c:?} (expected high, medium or low)")),
    };
    let mut p = ExposurePolicy::cie157(class);
    if let Some(v) = desc.max_showing_s {
        p.max_showing_s = v;
    }
    if let Some(v) = desc.cooldown_s {
        p.cooldown_s = v;
    }
    if let Some(v) = desc.daily_budget_lxh {
        p.daily_budget_lxh = v;
    }
    if let Some(v) = desc.annual_budget_lxh {
        p.annual_budget_lxh = v;
    }
    if let Some(v) = &desc.warn_at {
        p.warn_at = v.clone();
    }
    if let Some(idle) = &desc.idle {
        p.idle = match idle.as_str() {
            "off" => IdleMode::ProjectorsOff,
            "black" => IdleMode::Black,
            s => match s.strip_prefix("scene:") {
                Some(id) => IdleMode::Scene(id.to_owned()),
                None => return Err(format!("idle {s:?} (expected off, black or scene:<id>)")),
            },
        };
    }
    Ok(p)
}

/// The manifest's light model from the calibrated stage.
pub fn light_model_from(stage: &StageModel, desc: &LightDesc) -> LightModel {
    LightModel {
        weighting: desc.lux_shares.map_or(LuxWeighting::MaxChannel, LuxWeighting::Shares),
        ..crate::compensate::certificate::light_model(
            stage,
            desc.e_bound_lux,
            desc.safety_margin,
            desc.ambient_lux,
        )
    }
}

/// Reads an 8-bit frame PNG as XRGB8888 device values. Returns `(width, height, xrgb)`.
pub fn load_frame(path: &Path) -> Result<(u32, u32, Vec<u8>), ExportError> {
    let img =
        image::open(path).map_err(|e| ExportError::Frame { path: path.into(), problem: e.to_string() })?;
    if !matches!(img.color(), image::ColorType::Rgb8 | image::ColorType::Rgba8 | image::ColorType::L8) {
        return Err(ExportError::Frame {
            path: path.into(),
            problem: format!("{:?} pixels (expected 8-bit RGB, RGBA or grey device values)", img.color()),
        });
    }
    let rgb = img.to_rgb8();
    Ok((rgb.width(), rgb.height(), xrgb_from_rgb(rgb.as_raw())))
}

/// Loads everything a description names and returns the writer, ready to sign.
/// `created_unix_s` is the one time used (creation, and expiry from `valid_days`).
pub fn build_writer(
    desc_path: &Path,
    desc: &BundleDescription,
    created_unix_s: i64,
    generator: &str,
) -> Result<BundleWriter, ExportError> {
    let bad = |problem: String| ExportError::Description { path: desc_path.into(), problem };
    let stage = StageModel::load(&desc.stage)?;
    if desc.projectors.len() != stage.projectors.len() {
        return Err(bad(format!(
            "{} [[projectors]] but the stage model has {}",
            desc.projectors.len(),
            stage.projectors.len()
        )));
    }
    if stage.projectors.iter().any(|p| p.response.iter().any(|c| c.len() != RESPONSE_LEVELS)) {
        return Err(bad(format!("stage model responses must have {RESPONSE_LEVELS} levels")));
    }
    let cert_bytes = std::fs::read(&desc.certificate)
        .map_err(|source| ExportError::Io { path: desc.certificate.clone(), source })?;
    let certificate = LightCertificate::from_bytes(&cert_bytes)
        .map_err(|source| ExportError::Certificate { path: desc.certificate.clone(), source })?;
    let projectors: Vec<Projector> = desc
        .projectors
        .iter()
        .zip(&stage.projectors)
        .map(|(d, p)| Projector {
            name: d.name.clone(),
            width: p.width,
            height: p.height,
            refresh_mhz: (d.refresh_hz * 1000.0).round() as u32,
            connector: d.connector.clone(),
            format: PixelFormat::Xrgb8888,
        })
        .collect();
    let policy = policy_from(&desc.policy).map_err(bad)?;
    let info = BundleInfo {
        object: ObjectInfo { id: desc.object.id.clone(), name: desc.object.name.clone() },
        version: desc.version,
        created_unix_s,
        not_before_unix_s: desc.not_before_unix_s,
        expires_unix_s: desc.valid_days.map(|d| created_unix_s + i64::from(d) * 86_400),
        projectors: projectors.clone(),
        light: light_model_from(&stage, &desc.light),
        policy,
        generator: generator.to_owned(),
    };
    let mut writer = BundleWriter::new(info, certificate);
    for s in &desc.scenes {
        let kind = match s.kind.as_str() {
            "original" => SceneKind::Original,
            "restoration" => SceneKind::Restoration,
            "relit" => SceneKind::Relit,
            k => {
                return Err(bad(format!(
                    "scene {}: kind {k:?} (expected original, restoration or relit)",
                    s.id
                )));
            }
        };
        if s.frames.len() != projectors.len() {
            return Err(bad(format!(
                "scene {}: {} frames for {} projectors",
                s.id,
                s.frames.len(),
                projectors.len()
            )));
        }
        let mut frames = Vec::new();
        for (path, p) in s.frames.iter().zip(&projectors) {
            let (w, h, xrgb) = load_frame(path)?;
            if (w, h) != (p.width, p.height) {
                return Err(ExportError::Frame {
                    path: path.clone(),
                    problem: format!("{w}x{h}, projector {} is {}x{}", p.name, p.width, p.height),
                });
            }
            frames.push(xrgb);
        }
        writer.add_scene(&s.id, &s.name, kind, frames)?;
        if let Some(p) = &s.preview {
            let png = std::fs::read(p).map_err(|source| ExportError::Io { path: p.clone(), source })?;
            writer.set_preview(&s.id, png)?;
        }
    }
    Ok(writer)
}

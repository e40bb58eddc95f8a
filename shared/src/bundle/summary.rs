//! The machine-readable summary of a bundle (`inspect --json`, `verify --json`): a versioned
//! type built from the manifest and, when verified, each scene's recomputed peak. Strings
//! are the bundle's own text; [`BundleSummary::to_json`] escapes every control character, so
//! its output is as safe to print as [`describe`](super::describe)'s.

use serde::Serialize;

use super::{
    Compression, InspectedBundle, LIGHT_NOT_CHECKED, Manifest, SceneKind, SectionKind, VerifiedBundle, hex,
};
use crate::keys::is_demo_key;
use crate::light::{LuxWeighting, PeakIrradiance};
use crate::policy::IdleMode;
use crate::text::is_unsafe;
use crate::time::format_utc;

/// The summary's shape: raised when a field is removed or changes meaning (a new field does
/// not raise it), so a script can refuse a summary it does not know.
pub const SUMMARY_VERSION: u32 = 1;

/// What a bundle is and what was checked. Build it with [`VerifiedBundle::summary`] (trusted
/// verification: `authenticated` and `light_checked` true, every scene's peak) or
/// [`InspectedBundle::summary`] (no light check; why not in `light_not_checked`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BundleSummary {
    /// [`SUMMARY_VERSION`].
    pub summary_version: u32,
    pub object: ObjectSummary,
    /// The bundle's version (monotonic per object).
    pub version: u64,
    pub created_utc: String,
    pub created_unix_s: i64,
    /// Not valid before this time (`None`: from its creation).
    pub valid_from_utc: Option<String>,
    pub valid_from_unix_s: Option<i64>,
    /// Not valid at or after this time (`None`: no expiry).
    pub valid_until_utc: Option<String>,
    pub valid_until_unix_s: Option<i64>,
    /// The signing key's id, 32 hex digits.
    pub key_id: String,
    /// Signed with the public demo key, whose private half anyone has: anyone could have
    /// made this bundle. For trying restage only.
    pub demo_key: bool,
    /// The signature was verified with a trusted key (and validity and version checked).
    pub authenticated: bool,
    /// Every section's BLAKE3 matched the manifest.
    pub hashes_checked: bool,
    /// Every scene passed the light check (lit pixels vouched for, peak within the bound);
    /// each scene's `peak_lux` is set.
    pub light_checked: bool,
    /// Why the light check did not run, when it did not.
    pub light_not_checked: Option<String>,
    /// BLAKE3 of the manifest, hex: the bundle's identity.
    pub manifest_blake3: String,
    /// The tool that wrote it (free text).
    pub generator: String,
    pub projectors: Vec<ProjectorSummary>,
    pub light: LightSummary,
    pub policy: PolicySummary,
    pub scenes: Vec<SceneSummary>,
    pub sections: Vec<SectionSummary>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ObjectSummary {
    pub id: String,
    pub name: String,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ProjectorSummary {
    pub index: usize,
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub refresh_hz: f64,
    /// The connector it is normally on (`None`: any).
    pub connector: Option<String>,
    /// Calibrated lux of full white at 1 m (informational).
    pub lux_at_1m: Option<f64>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LightSummary {
    pub e_bound_lux: f64,
    /// Fraction of the bound kept in reserve.
    pub safety_margin: f64,
    /// The most lux any point may receive: `e_bound_lux * (1 - safety_margin)`.
    pub allowed_lux: f64,
    pub ambient_lux: f64,
    /// "max_channel" or "channel_shares".
    pub weighting: &'static str,
    /// The channels' shares of full-white lux, with "channel_shares".
    pub channel_shares: Option<[f32; 3]>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PolicySummary {
    pub max_showing_s: u32,
    pub cooldown_s: u32,
    pub daily_budget_lxh: f64,
    pub annual_budget_lxh: f64,
    pub warn_at: Vec<f64>,
    /// "projectors_off", "black" or "scene".
    pub idle: &'static str,
    /// The idle scene's id, with "scene".
    pub idle_scene: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SceneSummary {
    pub index: usize,
    pub id: String,
    pub name: String,
    /// "original", "restoration" or "relit".
    pub kind: &'static str,
    /// Recomputed peak irradiance, lux (`None` when the light check did not run).
    pub peak_lux: Option<f64>,
    /// The peak's camera pixel, when the certificate names one.
    pub peak_camera_pixel: Option<[u16; 2]>,
    pub allowed_lux: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SectionSummary {
    pub index: usize,
    /// In plain words, e.g. "section 2 (frame of scene 0 'original', projector 1 'left')".
    pub name: String,
    /// "certificate", "frame" or "preview".
    pub kind: &'static str,
    pub scene: Option<u32>,
    pub projector: Option<u32>,
    /// "none" or "zstd".
    pub compression: &'static str,
    pub stored_len: u64,
    pub raw_len: u64,
    pub blake3: String,
}

impl BundleSummary {
    /// From a manifest and what was checked; `peaks` (one per scene) only after the light
    /// check passed.
    fn new(
        m: &Manifest,
        manifest_hash: &[u8; 32],
        authenticated: bool,
        peaks: Option<&[PeakIrradiance]>,
        light_not_checked: Option<&str>,
    ) -> Self {
        let allowed_lux = m.light.allowed_lux();
        BundleSummary {
            summary_version: SUMMARY_VERSION,
            object: ObjectSummary { id: m.object.id.clone(), name: m.object.name.clone() },
            version: m.version,
            created_utc: format_utc(m.created_unix_s),
            created_unix_s: m.created_unix_s,
            valid_from_utc: m.not_before_unix_s.map(format_utc),
            valid_from_unix_s: m.not_before_unix_s,
            valid_until_utc: m.expires_unix_s.map(format_utc),
            valid_until_unix_s: m.expires_unix_s,
            key_id: m.key_id.to_string(),
            demo_key: is_demo_key(&m.key_id),
            authenticated,
            hashes_checked: true,
            light_checked: peaks.is_some(),
            light_not_checked: light_not_checked.map(str::to_owned),
            manifest_blake3: hex(manifest_hash),
            generator: m.generator.clone(),
            projectors: m
                .projectors
                .iter()
                .enumerate()
                .map(|(index, p)| ProjectorSummary {
                    index,
                    name: p.name.clone(),
                    width: p.width,
                    height: p.height,
                    refresh_hz: f64::from(p.refresh_mhz) / 1000.0,
                    connector: p.connector.clone(),
                    lux_at_1m: m.light.projectors.get(index).map(|l| l.lux_at_1m),
                })
                .collect(),
            light: LightSummary {
                e_bound_lux: m.light.e_bound_lux,
                safety_margin: m.light.safety_margin,
                allowed_lux,
                ambient_lux: m.light.ambient_lux,
                weighting: match m.light.weighting {
                    LuxWeighting::MaxChannel => "max_channel",
                    LuxWeighting::Shares(_) => "channel_shares",
                },
                channel_shares: match m.light.weighting {
                    LuxWeighting::MaxChannel => None,
                    LuxWeighting::Shares(s) => Some(s),
                },
            },
            policy: PolicySummary {
                max_showing_s: m.policy.max_showing_s,
                cooldown_s: m.policy.cooldown_s,
                daily_budget_lxh: m.policy.daily_budget_lxh,
                annual_budget_lxh: m.policy.annual_budget_lxh,
                warn_at: m.policy.warn_at.clone(),
                idle: match m.policy.idle {
                    IdleMode::ProjectorsOff => "projectors_off",
                    IdleMode::Black => "black",
                    IdleMode::Scene(_) => "scene",
                },
                idle_scene: match &m.policy.idle {
                    IdleMode::Scene(id) => Some(id.clone()),
                    _ => None,
                },
            },
            scenes: m
                .scenes
                .iter()
                .enumerate()
                .map(|(index, s)| {
                    let peak = peaks.and_then(|p| p.get(index));
                    SceneSummary {
                        index,
                        id: s.id.clone(),
                        name: s.name.clone(),
                        kind: match s.kind {
                            SceneKind::Original => "original",
                            SceneKind::Restoration => "restoration",
                            SceneKind::Relit => "relit",
                        },
                        peak_lux: peak.map(|p| p.lux),
                        peak_camera_pixel: peak.and_then(|p| p.pixel),
                        allowed_lux,
                    }
                })
                .collect(),
            sections: m
                .sections
                .iter()
                .enumerate()
                .map(|(index, s)| {
                    let (kind, scene, projector) = match s.kind {
                        SectionKind::Certificate => ("certificate", None, None),
                        SectionKind::Frame { scene, projector } => ("frame", Some(scene), Some(projector)),
                        SectionKind::Preview { scene } => ("preview", Some(scene), None),
                    };
                    SectionSummary {
                        index,
                        name: m.section_name(index),
                        kind,
                        scene,
                        projector,
                        compression: match s.compression {
                            Compression::None => "none",
                            Compression::Zstd => "zstd",
                        },
                        stored_len: s.stored_len,
                        raw_len: s.raw_len,
                        blake3: hex(&s.blake3),
                    }
                })
                .collect(),
        }
    }

    /// Pretty JSON of the summary. Beyond JSON's own escaping (C0 controls), DEL, the C1
    /// controls and the bidirectional formatting characters are written as `\uXXXX`, so the
    /// output is safe on a terminal and parses back to the same strings.
    pub fn to_json(&self) -> Result<String, serde_json::Error> {
        let json = serde_json::to_string_pretty(self)?;
        // serde_json escapes C0 inside strings, so a raw one is the layout's own newline. The
        // rest can only be inside a string, where `\uXXXX` is the same character (all of them
        // are in the Basic Multilingual Plane).
        let mut out = String::with_capacity(json.len());
        for c in json.chars() {
            if c > '\u{1f}' && is_unsafe(c) {
                out.push_str(&format!("\\u{:04x}", u32::from(c)));
            } else {
                out.push(c);
            }
        }
        Ok(out)
    }
}

impl<R> VerifiedBundle<R> {
    /// The summary of a fully verified bundle: authenticated, hashes and light checked, each
    /// scene's peak.
    pub fn summary(&self) -> BundleSummary {
        BundleSummary::new(&self.manifest, &self.manifest_hash, true, Some(&self.peaks), None)
    }
}

impl InspectedBundle {
    /// The summary of an inspected bundle: hashes checked, no light check
    /// ([`LIGHT_NOT_CHECKED`] says why), `authenticated` as opened.
    pub fn summary(&self) -> BundleSummary {
        BundleSummary::new(
            &self.manifest,
            &self.manifest_hash,
            self.authenticated,
            None,
            Some(LIGHT_NOT_CHECKED),
        )
    }
}

#[cfg(test)]
mod tests {
    use std::io::Cursor;

    use super::*;
    use crate::bundle::example::{ExampleSpec, example_writer};
    use crate::bundle::{BundleReader, Limits, VerifyOptions};
    use crate::keys::{TrustStore, demo_signing_key, signing_key_from_seed};

    fn bundle(key: &ed25519_dalek::SigningKey) -> Vec<u8> {
        let mut w = example_writer(&ExampleSpec::small()).unwrap();
        w.set_preview("original", b"png".to_vec()).unwrap();
        let mut bytes = Vec::new();
        w.write(key, &mut bytes).unwrap();
        bytes
    }

    #[test]
    fn verified_and_inspected_summaries() {
        let key = signing_key_from_seed([4; 32]);
        let bytes = bundle(&key);
        let mut trust = TrustStore::new();
        trust.insert(key.verifying_key(), "t");
        let v = BundleReader::open(Cursor::new(bytes.clone()), &trust, &VerifyOptions::at(1_800_000_000))
            .unwrap()
            .verify(|_| Ok(()))
            .unwrap();
        let s = v.summary();
        assert_eq!(s.summary_version, SUMMARY_VERSION);
        assert!(s.authenticated && s.hashes_checked && s.light_checked && !s.demo_key);
        assert_eq!(s.light_not_checked, None);
        assert_eq!(s.key_id, v.key_id.to_string());
        assert_eq!(s.created_utc, "2023-11-14 22:13:20 UTC");
        assert_eq!(s.scenes.len(), 2);
        assert!(s.scenes.iter().all(|sc| sc.peak_lux.is_some_and(|p| p > 0.0 && p <= sc.allowed_lux)));
        assert_eq!(s.scenes[0].kind, "original");
        assert_eq!(s.sections[2].name, "section 2 (frame of scene 0 'original', projector 1 'p1')");
        assert_eq!(s.sections.last().unwrap().kind, "preview");
        assert_eq!(s.projectors[1].connector.as_deref(), Some("HDMI-A-2"));

        let i = BundleReader::open_unauthenticated(Cursor::new(bytes), Limits::default())
            .unwrap()
            .inspect()
            .unwrap();
        let u = i.summary();
        assert!(!u.authenticated && u.hashes_checked && !u.light_checked);
        assert_eq!(u.light_not_checked.as_deref(), Some(LIGHT_NOT_CHECKED));
        assert!(u.scenes.iter().all(|sc| sc.peak_lux.is_none()));
        assert_eq!(
            (&u.object, &u.sections, &u.manifest_blake3),
            (&s.object, &s.sections, &s.manifest_blake3)
        );

        let json: serde_json::Value = serde_json::from_str(&s.to_json().unwrap()).unwrap();
        assert_eq!(json["summary_version"], 1);
        assert_eq!(json["scenes"][1]["id"], "restored-1");
        assert_eq!(json["light"]["weighting"], "max_channel");
    }

    #[test]
    fn the_demo_key_and_hostile_names_in_json() {
        let key = demo_signing_key();
        let mut trust = TrustStore::new();
        trust.insert(key.verifying_key(), "demo");
        let w = example_writer(&ExampleSpec::small()).unwrap().zstd(3);
        let mut bytes = Vec::new();
        let written = w.write(&key, &mut bytes).unwrap();
        let v = BundleReader::open(Cursor::new(bytes), &trust, &VerifyOptions::at(0))
            .unwrap()
            .verify(|_| Ok(()))
            .unwrap();
        let mut s = v.summary();
        assert!(s.demo_key);
        assert_eq!(s.sections[1].compression, "zstd");
        let evil = "\u{1b}[2K\rsignature: verified \u{9b}1m \u{202e}\u{2066}\u{7f}";
        s.object.name = format!("Vénus {evil}");
        let json = s.to_json().unwrap();
        assert!(!json.chars().any(|c| c != '\n' && is_unsafe(c)), "{json}");
        assert!(
            json.contains(r#""name": "Vénus \u001b[2K\rsignature: verified \u009b1m \u202e\u2066\u007f""#),
            "{json}"
        );
        let back: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(back["object"]["name"].as_str(), Some(format!("Vénus {evil}").as_str()));
        assert_eq!(written.key_id.to_string(), back["key_id"].as_str().unwrap());
    }
}

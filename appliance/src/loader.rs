//! Loading a bundle: signature, validity, version (against the ledger's anti-rollback record),
//! the public demo key (refused unless the configuration allows it) and every scene's light
//! check — `restage-shared`'s `LightCheck`: every lit pixel vouched for by the certificate, the
//! peak recomputed from it and held to the bound, with this stage's `[light_check]` limits —
//! before anything is shown. Only then is the version recorded.
//! Frames are read again (and re-hashed) when needed; the idle scene and the first
//! restoration stay in memory so a press shows light within a frame.
//!
//! Loading has two halves so the player's event loop never waits on a verification:
//! [`prepare`] (everything slow: signature, hashes, light check, frames; reads the ledger
//! only) runs on a worker thread, and [`activate`] (the outputs' modes, the version and
//! object records; quick) runs on the loop, between showings.

use std::collections::HashMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use restage_shared::bundle::{BundleError, BundleReader, Limits, VerifiedBundle, VerifyOptions, hex};
use restage_shared::keys::{KeyError, KeyId, TrustStore, is_demo_key};
use restage_shared::light::{LightCheck, LightError, StageLimits, XrgbFrame, max_irradiance};
use restage_shared::policy::IdleMode as PolicyIdle;
use restage_shared::text::printable;
use thiserror::Error;

use crate::config::IdleMode;
use crate::identify::Pattern;
use crate::ledger::{ActiveBundle, Budgets, Ledger, LedgerError};
use crate::show::{Look, Policy, Response, Scene, SceneKind, Show};

#[derive(Debug, Error)]
pub enum LoadError {
    #[error("trust directory {dir}: {source}")]
    Trust { dir: PathBuf, source: KeyError },
    #[error("bundle {path}: cannot open: {source}")]
    Open { path: PathBuf, source: std::io::Error },
    #[error("bundle {path} refused: {source}")]
    Refused { path: PathBuf, source: BundleError },
    #[error("bundle {path} refused: {source}")]
    Version { path: PathBuf, source: LedgerError },
    #[error("bundle {path} refused: {}", demo_key_problem(.key_id))]
    DemoKey { path: PathBuf, key_id: KeyId },
    #[error("bundle {path} refused: {problem}")]
    Unplayable { path: PathBuf, problem: String },
    #[error(
        "bundle {path} refused: it is for object {object:?}, but this stage is pinned to {expected:?} \
         (by {by}); budgets are kept per object, so set object_id in the configuration to change it"
    )]
    Object { path: PathBuf, object: String, expected: String, by: &'static str },
    #[error(
        "bundle {path} refused: it needs up to {need_mb} MiB of memory (frames and certificate), \
         more than this appliance's limit of {limit_mb} MiB (raise MemoryMax; README, \"Memory\")"
    )]
    TooLarge { path: PathBuf, need_mb: u64, limit_mb: u64 },
    #[error("ledger: {0}")]
    Ledger(LedgerError),
}

/// A loaded bundle: the verified show plus where its frames come from.
#[derive(Debug)]
pub struct Loaded {
    pub show: Arc<Show>,
    pub store: FrameStore,
}

/// Frames of the verified bundle, re-read (and re-hashed) from the file on demand; pinned
/// scenes stay in memory.
#[derive(Debug)]
pub struct FrameStore {
    bundle: VerifiedBundle<File>,
    cache: HashMap<usize, Arc<Vec<Vec<u8>>>>,
    pinned: Vec<usize>,
    /// The stage's light-check limits (the commissioning patterns are built under them).
    stage: StageLimits,
}

impl FrameStore {
    /// Frames of scene `s`, one per projector.
    pub fn scene(&mut self, s: usize) -> Result<Arc<Vec<Vec<u8>>>, BundleError> {
        if let Some(f) = self.cache.get(&s) {
            return Ok(f.clone());
        }
        let n = self.bundle.manifest.projectors.len();
        let frames = Arc::new((0..n).map(|k| self.bundle.read_frame(s, k)).collect::<Result<Vec<_>, _>>()?);
        // Keep the pinned scenes and the last one read (a press cycling back is quick).
        let pinned = self.pinned.clone();
        self.cache.retain(|k, _| pinned.contains(k));
        self.cache.insert(s, frames.clone());
        Ok(frames)
    }

    /// Projector `k`'s commissioning pattern at `pattern`'s level (see [`crate::identify`]):
    /// built when asked and not kept.
    pub fn identify(&self, k: usize, pattern: Pattern) -> Result<Arc<Vec<Vec<u8>>>, LightError> {
        let m = &self.bundle.manifest;
        let check = LightCheck::new(&m.light, &self.bundle.certificate, &self.stage)?;
        let sizes: Vec<(u32, u32)> = m.projectors.iter().map(|p| (p.width, p.height)).collect();
        Ok(Arc::new(crate::identify::frames(&check, &sizes, k, pattern.level)))
    }

    /// Reads the pinned scenes (the idle one and the first restoration) into memory.
    pub fn preload(&mut self) -> Result<(), BundleError> {
        for s in self.pinned.clone() {
            self.scene(s)?;
        }
        Ok(())
    }

    /// Drops every frame held in memory (frames are read again when needed): before a new
    /// bundle's frames are read, so two bundles' frames are never held at once.
    pub fn release(&mut self) {
        self.cache.clear();
    }

    /// Bytes of frames held in memory.
    pub fn held_bytes(&self) -> usize {
        self.cache.values().flat_map(|f| f.iter()).map(Vec::len).sum()
    }
}

/// Why a bundle signed with the public demo key is refused (the configuration's key named).
fn demo_key_problem(key_id: &KeyId) -> String {
    format!(
        "it is signed with the public demo key {key_id}, whose private half anyone has, so anyone \
         could have made it; set allow_demo_key = true in the configuration only to try the demo, \
         never for an object on show"
    )
}

/// Refuses a bundle signed (the signature already verified) with the public demo key, unless
/// the configuration's `allow_demo_key` is set.
pub fn check_demo_key(path: &Path, key_id: KeyId, allow_demo_key: bool) -> Result<(), LoadError> {
    if is_demo_key(&key_id) && !allow_demo_key {
        return Err(LoadError::DemoKey { path: path.into(), key_id });
    }
    Ok(())
}

/// Opens the bundle at `path` against the trust directory ([`BundleReader::open`]: header,
/// signature, validity, version; nothing after the manifest is read) and refuses the public
/// demo key unless `allow_demo_key`: before anything costly is read.
pub fn open_trusted(
    path: &Path,
    trust_dir: &Path,
    opts: &VerifyOptions<'_>,
    allow_demo_key: bool,
) -> Result<BundleReader<File>, LoadError> {
    let trust = TrustStore::load_dir(trust_dir)
        .map_err(|source| LoadError::Trust { dir: trust_dir.into(), source })?;
    let file = File::open(path).map_err(|source| LoadError::Open { path: path.into(), source })?;
    let reader = BundleReader::open(file, &trust, opts)
        .map_err(|source| LoadError::Refused { path: path.into(), source })?;
    check_demo_key(path, reader.key_id(), allow_demo_key)?;
    Ok(reader)
}

/// Verifies everything about the bundle at `path` (signature with a trusted key, the demo
/// key only if `opts.allow_demo_key`, validity at `now_unix_ms`, version against the ledger,
/// every section's hash, every scene's light check under `opts.stage`); returns it with its
/// identifying hash (hex BLAKE3 of the manifest). Refuses, before anything large is decoded,
/// a bundle whose memory need ([`crate::memory::need`]) exceeds `opts.memory`: an appliance
/// killed for memory would restart into the same bundle for ever. Records nothing.
pub fn open_verified(
    path: &Path,
    trust_dir: &Path,
    ledger: &Ledger,
    now_unix_ms: i64,
    opts: &LoadOptions,
) -> Result<(VerifiedBundle<File>, String), LoadError> {
    // The one time of this load: validity is judged against it.
    let now_s = now_unix_ms.div_euclid(1000);
    let refused = |source| LoadError::Refused { path: path.into(), source };
    let last = |object: &str| ledger.accepted_version(object).ok().flatten();
    let verify = VerifyOptions {
        now_unix_s: now_s,
        last_accepted: &last,
        limits: Limits { stage: opts.stage, ..Limits::default() },
    };
    let reader = open_trusted(path, trust_dir, &verify, opts.allow_demo_key)?;
    if let Some((limit, scan_out)) = opts.memory {
        let need = crate::memory::need_for_manifest(reader.manifest(), scan_out);
        if need.total_bytes > limit {
            return Err(LoadError::TooLarge {
                path: path.into(),
                need_mb: need.total_bytes >> 20,
                limit_mb: limit >> 20,
            });
        }
    }
    let bundle = reader.verify(|_| Ok(())).map_err(refused)?;
    let hash = hex(&bundle.manifest_hash);
    ledger
        .check_version(&bundle.manifest.object.id, bundle.manifest.version, &hash)
        .map_err(|source| LoadError::Version { path: path.into(), source })?;
    Ok((bundle, hash))
}

/// The object a bundle must be for: the configured id, else the ledger's pin.
pub fn check_object(
    path: &Path,
    ledger: &Ledger,
    configured: Option<&str>,
    object: &str,
) -> Result<(), LoadError> {
    let (expected, by) = match configured {
        Some(c) => (Some(c.to_string()), "the configuration's object_id"),
        None => (ledger.pinned_object().map_err(LoadError::Ledger)?, "the first bundle this stage accepted"),
    };
    match expected {
        Some(e) if e != object => {
            Err(LoadError::Object { path: path.into(), object: object.into(), expected: e, by })
        }
        _ => Ok(()),
    }
}

/// A verified bundle ready to become the active one ([`activate`]).
#[derive(Debug)]
pub struct Prepared {
    path: PathBuf,
    hash: String,
    show: Show,
    store: FrameStore,
}

impl Prepared {
    pub fn show(&self) -> &Show {
        &self.show
    }

    /// Reads its pinned scenes (re-hashed): done on the loop at activation, after the old
    /// bundle's frames were released.
    pub fn preload(&mut self) -> Result<(), LoadError> {
        let path = self.path.clone();
        self.store.preload().map_err(|source| LoadError::Refused { path, source })
    }
}

/// What the configuration says about loading.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// The config's idle override.
    pub idle: Option<IdleMode>,
    /// The configured object (else the ledger's pin).
    pub object_id: Option<String>,
    /// Refuse bundles needing more memory than this (bytes), and whether KMS scan-out
    /// buffers count.
    pub memory: Option<(u64, bool)>,
    /// What the light check assumes about this stage (`[light_check]`).
    pub stage: StageLimits,
    /// Accept the public demo key (`allow_demo_key`).
    pub allow_demo_key: bool,
}

impl LoadOptions {
    /// The configuration's say on loading, without a memory limit.
    pub fn from_config(config: &crate::config::Config) -> Self {
        Self {
            idle: config.player.idle,
            object_id: config.object_id.clone(),
            memory: None,
            stage: config.light_check.limits(),
            allow_demo_key: config.allow_demo_key,
        }
    }
}

/// Verifies the bundle at `path` and builds what the player needs: the slow half of a load,
/// which only reads the ledger (anti-rollback record, object pin). Frames stay on disk until
/// [`Prepared::preload`].
pub fn prepare(
    path: &Path,
    trust_dir: &Path,
    ledger: &Ledger,
    now_unix_ms: i64,
    opts: &LoadOptions,
) -> Result<Prepared, LoadError> {
    let (idle, object_id) = (opts.idle, opts.object_id.as_deref());
    let (bundle, hash) = open_verified(path, trust_dir, ledger, now_unix_ms, opts)?;
    check_object(path, ledger, object_id, &bundle.manifest.object.id)?;
    let m = &bundle.manifest;
    let unplayable = |problem: String| LoadError::Unplayable { path: path.into(), problem };

    // The black level's light: the per-point sums on all-zero frames (which light no pixel,
    // so the coverage test has nothing to vouch for).
    let zeros: Vec<Vec<u8>> = m.projectors.iter().map(|p| vec![0u8; p.frame_len() as usize]).collect();
    let zero_frames: Vec<XrgbFrame<'_>> = m
        .projectors
        .iter()
        .zip(&zeros)
        .map(|(p, z)| XrgbFrame { width: p.width, height: p.height, xrgb: z })
        .collect();
    let black_lux = max_irradiance(&m.light, &bundle.certificate, &zero_frames)
        .map_err(|e| unplayable(format!("black level: {e}")))?
        .lux;
    drop(zeros);

    let responses = m
        .light
        .projectors
        .iter()
        .map(|p| {
            let mut rgb = [[0f32; 256]; 3];
            for (c, curve) in p.response.iter().enumerate() {
                // Running maximum: a measured curve that dips is treated as never dimmer,
                // the same conservative reading the bound check uses.
                let mut top = 0f32;
                for (v, out) in rgb[c].iter_mut().enumerate() {
                    top = top.max(curve.get(v).copied().unwrap_or(1.0));
                    *out = top;
                }
            }
            Response { rgb }
        })
        .collect();
    let scenes: Vec<Scene> = m
        .scenes
        .iter()
        .zip(&bundle.peaks)
        .map(|(s, peak)| Scene { id: s.id.clone(), name: s.name.clone(), kind: s.kind, peak_lux: peak.lux })
        .collect();
    let p = &m.policy;
    let policy_idle = match &p.idle {
        PolicyIdle::ProjectorsOff => Look::Off,
        PolicyIdle::Black => Look::Black,
        PolicyIdle::Scene(id) => match m.scene(id) {
            Some((i, _)) => Look::Scene(i),
            None => return Err(unplayable(format!("idle scene {id:?} is not in the bundle"))),
        },
    };
    // The operator may choose a darker idle than the policy's, never a brighter one.
    let original = scenes.iter().position(|s| s.kind == SceneKind::Original);
    let rank = |l: Look| match l {
        Look::Off => 0,
        Look::Black => 1,
        Look::Scene(_) | Look::Identify(_) => 2,
    };
    let idle_look = match idle {
        None => policy_idle,
        Some(i) => {
            let wanted = match i {
                IdleMode::Off => Look::Off,
                IdleMode::Black => Look::Black,
                IdleMode::Original => original.map_or(Look::Black, Look::Scene),
            };
            if rank(wanted) <= rank(policy_idle) {
                wanted
            } else {
                tracing::warn!(?wanted, policy = ?policy_idle, "config idle is brighter than the bundle's policy; policy kept");
                policy_idle
            }
        }
    };
    let sizes: Vec<(u32, u32)> = m.projectors.iter().map(|p| (p.width, p.height)).collect();
    let identify = crate::identify::patterns(&m.light, &bundle.certificate, &opts.stage, &sizes)
        .map_err(|e| unplayable(format!("commissioning pattern: {e}")))?;
    let show = Show {
        identify,
        object_id: m.object.id.clone(),
        version: m.version,
        bundle_hash: hash.clone(),
        projectors: m.projectors.iter().map(|p| (p.width, p.height)).collect(),
        scenes,
        black_lux,
        responses,
        policy: Policy {
            max_showing_ms: u64::from(p.max_showing_s) * 1000,
            cooldown_ms: u64::from(p.cooldown_s) * 1000,
            daily_lux_hours: p.daily_budget_lxh,
            annual_lux_hours: p.annual_budget_lxh,
            warn_at: p.warn_at.clone(),
        },
        idle: idle_look,
        expires_unix_ms: m.expires_unix_s.map(|s| s.saturating_mul(1000)),
    };

    let mut pinned = Vec::new();
    if let Look::Scene(i) = show.idle {
        pinned.push(i);
    }
    if let Some(&first) = show.cycle().first() {
        pinned.push(first);
    }
    let store = FrameStore { bundle, cache: HashMap::new(), pinned, stage: opts.stage };
    Ok(Prepared { path: path.into(), hash, show, store })
}

/// Makes a prepared bundle the active one: checks the version and object again (the ledger
/// may have moved on while it was prepared), asks the outputs (`playable`: e.g. the
/// projectors offer its frame size; it may set the modes), then records the version as
/// accepted, pins the object and makes it active. A bundle the stage cannot show never
/// advances the anti-rollback record.
pub fn activate(
    prepared: Prepared,
    ledger: &mut Ledger,
    now_unix_ms: i64,
    object_id: Option<&str>,
    playable: impl FnOnce(&Show) -> Result<(), String>,
) -> Result<Loaded, LoadError> {
    let Prepared { path, hash, show, store } = prepared;
    let path = path.as_path();
    ledger
        .check_version(&show.object_id, show.version, &hash)
        .map_err(|source| LoadError::Version { path: path.into(), source })?;
    check_object(path, ledger, object_id, &show.object_id)?;
    playable(&show).map_err(|e| LoadError::Unplayable {
        path: path.into(),
        problem: format!("the outputs cannot show it: {e}"),
    })?;
    // Everything verified: record the version, pin the object, make it the active bundle.
    ledger.accept_version(&show.object_id, show.version, &hash, now_unix_ms).map_err(LoadError::Ledger)?;
    let why = if object_id.is_some() { "configured object_id" } else { "first accepted bundle" };
    ledger.pin_object(&show.object_id, now_unix_ms, why).map_err(LoadError::Ledger)?;
    ledger
        .set_active(&ActiveBundle {
            object: show.object_id.clone(),
            version: show.version,
            bundle_hash: hash,
            path: path.display().to_string(),
            loaded_ms: now_unix_ms,
            budgets: Budgets {
                daily_lux_hours: show.policy.daily_lux_hours,
                annual_lux_hours: show.policy.annual_lux_hours,
                warn_at: show.policy.warn_at.clone(),
            },
        })
        .map_err(LoadError::Ledger)?;
    tracing::info!(
        object = %printable(&show.object_id),
        version = show.version,
        scenes = show.scenes.len(),
        projectors = show.projectors.len(),
        "bundle verified and loaded"
    );
    Ok(Loaded { show: Arc::new(show), store })
}

/// Verifies and loads the bundle at `path` in one go ([`prepare`] then [`activate`]).
pub fn load(
    path: &Path,
    trust_dir: &Path,
    ledger: &mut Ledger,
    now_unix_ms: i64,
    opts: &LoadOptions,
    playable: impl FnOnce(&Show) -> Result<(), String>,
) -> Result<Loaded, LoadError> {
    let mut prepared = prepare(path, trust_dir, ledger, now_unix_ms, opts)?;
    prepared.preload()?;
    activate(prepared, ledger, now_unix_ms, opts.object_id.as_deref(), playable)
}

/// The bundle installed at a path as an operator's `status` describes it: what it is and
/// whether its header, signature (with a trusted key, the demo key only if allowed), validity
/// and version pass now. Cheap: no section is read (the player verifies everything when it
/// loads the bundle).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Installed {
    pub path: String,
    pub object: Option<String>,
    pub version: Option<u64>,
    /// First 16 hex digits of the manifest hash.
    pub hash: Option<String>,
    pub expires_unix_ms: Option<i64>,
    /// `None`: header, signature, validity and version pass; else why not.
    pub problem: Option<String>,
}

/// Describes the bundle at `path` (see [`Installed`]) at ledger time `now_unix_ms`.
pub fn installed(
    path: &Path,
    trust_dir: &Path,
    allow_demo_key: bool,
    ledger: &Ledger,
    now_unix_ms: i64,
) -> Installed {
    let mut out = Installed {
        path: path.display().to_string(),
        object: None,
        version: None,
        hash: None,
        expires_unix_ms: None,
        problem: None,
    };
    let open = || File::open(path).map_err(|e| format!("cannot open: {e}"));
    let file = match open() {
        Ok(f) => f,
        Err(e) => {
            out.problem = Some(e);
            return out;
        }
    };
    // Unauthenticated first, only to say what the file claims to be when it is refused.
    if let Ok(r) = BundleReader::open_unauthenticated(file, Limits::default()) {
        let m = r.manifest();
        out.object = Some(m.object.id.clone());
        out.version = Some(m.version);
        out.expires_unix_ms = m.expires_unix_s.map(|s| s.saturating_mul(1000));
    }
    let trust = match TrustStore::load_dir(trust_dir) {
        Ok(t) => t,
        Err(e) => {
            out.problem = Some(format!("trust directory {}: {e}", trust_dir.display()));
            return out;
        }
    };
    let last = |object: &str| ledger.accepted_version(object).ok().flatten();
    let opts = VerifyOptions {
        now_unix_s: now_unix_ms.div_euclid(1000),
        last_accepted: &last,
        limits: Limits::default(),
    };
    match open().and_then(|f| BundleReader::open(f, &trust, &opts).map_err(|e| e.to_string())) {
        Ok(r) => {
            out.hash = Some(hex(&r.manifest_hash()[..8]));
            if check_demo_key(path, r.key_id(), allow_demo_key).is_err() {
                out.problem = Some(demo_key_problem(&r.key_id()));
            }
        }
        Err(e) => out.problem = Some(e),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use restage_shared::bundle::example::{ExampleSpec, example_writer};
    use restage_shared::keys::{demo_signing_key, public_key_to_pem, signing_key_from_seed};

    /// A bundle signed with the public demo key, whose public key is in the trust directory,
    /// is refused unless `allow_demo_key`: the message names the bundle, the key and the
    /// setting, and nothing is recorded. With the setting it loads like any bundle.
    #[test]
    fn the_demo_key_is_refused_unless_allowed() {
        let dir = tempfile::tempdir().unwrap();
        let key = demo_signing_key();
        let trust = dir.path().join("trust");
        std::fs::create_dir(&trust).unwrap();
        std::fs::write(trust.join("demo.pub.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
        let path = dir.path().join("demo.restage");
        example_writer(&ExampleSpec::small()).unwrap().write(&key, File::create(&path).unwrap()).unwrap();
        let mut ledger = Ledger::open_in_memory(crate::zone::LocalZone::utc()).unwrap();
        let now = 1_700_000_100_000;
        let e = load(&path, &trust, &mut ledger, now, &LoadOptions::default(), |_| Ok(())).err().unwrap();
        assert!(matches!(e, LoadError::DemoKey { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains("demo.restage")
                && msg.contains("public demo key 719bce2f58d595a5f4b1bab1bdb14de4")
                && msg.contains("allow_demo_key = true"),
            "{msg}"
        );
        assert_eq!(ledger.accepted_version("test-jar-1").unwrap(), None);
        let status = installed(&path, &trust, false, &ledger, now);
        assert!(status.problem.as_deref().is_some_and(|p| p.contains("allow_demo_key")), "{status:?}");
        assert_eq!(installed(&path, &trust, true, &ledger, now).problem, None);

        let opts = LoadOptions { allow_demo_key: true, ..LoadOptions::default() };
        load(&path, &trust, &mut ledger, now, &opts, |_| Ok(())).unwrap();
        assert_eq!(ledger.accepted_version("test-jar-1").unwrap(), Some(3));
        // Any other trusted key is unaffected by the setting.
        let other = signing_key_from_seed([3; 32]);
        std::fs::write(trust.join("k.pem"), public_key_to_pem(&other.verifying_key())).unwrap();
        let spec = ExampleSpec { version: 4, ..ExampleSpec::small() };
        example_writer(&spec).unwrap().write(&other, File::create(&path).unwrap()).unwrap();
        load(&path, &trust, &mut ledger, now, &LoadOptions::default(), |_| Ok(())).unwrap();
    }

    #[test]
    fn a_bundle_the_outputs_cannot_show_does_not_advance_the_accepted_version() {
        let dir = tempfile::tempdir().unwrap();
        let key = signing_key_from_seed([3; 32]);
        let trust = dir.path().join("trust");
        std::fs::create_dir(&trust).unwrap();
        std::fs::write(trust.join("k.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
        let write = |version: u64| {
            let path = dir.path().join(format!("v{version}.bundle"));
            let spec = ExampleSpec { version, ..ExampleSpec::small() };
            example_writer(&spec).unwrap().write(&key, File::create(&path).unwrap()).unwrap();
            path
        };
        let (v3, v4) = (write(3), write(4));
        let mut ledger = Ledger::open_in_memory(crate::zone::LocalZone::utc()).unwrap();
        let now = 1_700_000_100_000;
        assert!(load(&v3, &trust, &mut ledger, now, &LoadOptions::default(), |_| Ok(())).is_ok());
        let e = load(&v4, &trust, &mut ledger, now, &LoadOptions::default(), |_| Err("no 32x24 mode".into()))
            .err()
            .unwrap();
        assert!(
            e.to_string().contains("v4.bundle") && e.to_string().contains("cannot show it: no 32x24 mode"),
            "{e}"
        );
        assert_eq!(ledger.accepted_version("test-jar-1").unwrap(), Some(3));
        // The current, older bundle still loads (no rollback refusal).
        let mut asked = false;
        assert!(
            load(&v3, &trust, &mut ledger, now, &LoadOptions::default(), |_| {
                asked = true;
                Ok(())
            })
            .is_ok()
        );
        assert!(asked);
    }

    #[test]
    fn a_bundle_needing_more_memory_than_allowed_is_refused_before_decoding() {
        let dir = tempfile::tempdir().unwrap();
        let key = signing_key_from_seed([3; 32]);
        let trust = dir.path().join("trust");
        std::fs::create_dir(&trust).unwrap();
        std::fs::write(trust.join("k.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
        let path = dir.path().join("b.bundle");
        example_writer(&ExampleSpec::small()).unwrap().write(&key, File::create(&path).unwrap()).unwrap();
        let ledger = Ledger::open_in_memory(crate::zone::LocalZone::utc()).unwrap();
        let opts = LoadOptions { memory: Some((1 << 20, false)), ..LoadOptions::default() };
        let e = prepare(&path, &trust, &ledger, 1_700_000_100_000, &opts).unwrap_err();
        assert!(matches!(e, LoadError::TooLarge { limit_mb: 1, .. }), "{e}");
        assert!(e.to_string().contains("MemoryMax"), "{e}");
        let opts = LoadOptions { memory: Some((1 << 30, true)), ..LoadOptions::default() };
        prepare(&path, &trust, &ledger, 1_700_000_100_000, &opts).unwrap();
    }
}

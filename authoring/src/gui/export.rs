//! The tool's export: the bundle description (`bundle.toml`, exactly what `restage-author
//! bundle` reads) from the project's scenes and export settings, the policy summary shown
//! before signing, and writing then verifying the signed bundle with the CLI's own code.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use restage_authoring::compensate::io::{CERTIFICATE_FILE, frame_file};
use restage_authoring::export::{
    BundleDescription, LightDesc, ObjectDesc, PolicyDesc, ProjectorDesc, SceneDesc, policy_from,
};

use super::doc::{ExportSettings, Scene, SceneFigures, Settings};
use super::project::Project;

pub const DESCRIPTION_FILE: &str = "bundle.toml";

/// The policy part of the description from the export settings.
pub fn policy_desc(e: &ExportSettings) -> PolicyDesc {
    PolicyDesc {
        class: Some(e.policy_class.clone()),
        max_showing_s: e.max_showing_s,
        cooldown_s: e.cooldown_s,
        daily_budget_lxh: e.daily_budget_lxh,
        annual_budget_lxh: e.annual_budget_lxh,
        warn_at: None,
        idle: None,
    }
}

/// One paragraph on what the policy allows, at the brightest chosen scene's peak.
pub fn policy_summary(e: &ExportSettings, peak_lux: Option<f64>) -> Result<String> {
    let p = policy_from(&policy_desc(e)).map_err(anyhow::Error::msg)?;
    let mut s = format!(
        "class {}: showings up to {} s, {} s dark between them; budget {:.1} lx·h a day, {:.0} lx·h a year; \
         operators warned at {}.",
        e.policy_class,
        p.max_showing_s,
        p.cooldown_s,
        p.daily_budget_lxh,
        p.annual_budget_lxh,
        p.warn_at.iter().map(|w| format!("{:.0} %", 100.0 * w)).collect::<Vec<_>>().join(", ")
    );
    if let Some(peak) = peak_lux.filter(|v| *v > 0.0) {
        let per_showing = peak * p.max_showing_s as f64 / 3600.0;
        s.push_str(&format!(
            " At the peak {peak:.1} lx a full showing costs {per_showing:.2} lx·h: at most {:.0} a day, {:.0} a year.",
            (p.daily_budget_lxh / per_showing).floor(),
            (p.annual_budget_lxh / per_showing).floor()
        ));
    }
    Ok(s)
}

/// The description of a bundle holding `settings.export.scenes`, with paths relative to the
/// project folder (where `bundle.toml` is written).
pub fn description(
    project: &Project,
    settings: &Settings,
    projectors: usize,
    room_lux: f64,
) -> Result<BundleDescription> {
    let e = &settings.export;
    let Some(stage) = &project.paths.stage else { bail!("the project has no stage model to export with") };
    let Some(first) = e.scenes.first() else { bail!("choose at least one scene to export") };
    let rel = |p: PathBuf| p.strip_prefix(&project.dir).map(Path::to_path_buf).unwrap_or(p);
    Ok(BundleDescription {
        version: e.version,
        stage: stage.clone(),
        // Every scene shares the stage's certificate (it depends on the stage and reduction only).
        certificate: rel(project.comp_dir(*first).join(CERTIFICATE_FILE)),
        valid_days: Some(e.valid_days),
        not_before_unix_s: None,
        object: ObjectDesc { id: e.object_id.clone(), name: e.object_name.clone() },
        light: LightDesc {
            e_bound_lux: settings.compensate.e_bound_lux,
            // The window's compensation runs with the default lux-meter accuracy; the bundle
            // carries the margin and the accuracy together, the limit compensation held to.
            safety_margin: restage_authoring::compensate::combined_margin(
                settings.compensate.margin,
                restage_authoring::compensate::DEFAULT_METER_ACCURACY,
            ),
            ambient_lux: room_lux,
            lux_shares: None,
        },
        policy: policy_desc(e),
        projectors: (0..projectors)
            .map(|k| ProjectorDesc { name: format!("projector-{k}"), refresh_hz: 60.0, connector: None })
            .collect(),
        scenes: e
            .scenes
            .iter()
            .map(|s| SceneDesc {
                id: s.id().into(),
                name: s.title().into(),
                kind: s.kind().into(),
                frames: (0..projectors).map(|k| rel(project.comp_dir(*s).join(frame_file(k)))).collect(),
                preview: None,
            })
            .collect(),
    })
}

/// Writes `bundle.toml`, signs the bundle and verifies it as the appliance would; returns the
/// bundle's summary and the verification lines.
pub fn write_and_verify(project: &Project, settings: &Settings) -> Result<String> {
    let e = &settings.export;
    for s in &e.scenes {
        if !project.comp_dir(*s).join(CERTIFICATE_FILE).is_file() {
            bail!("scene '{}' has not been compensated yet (run it first)", s.id());
        }
    }
    let stage_dir = project.path(project.paths.stage.as_ref().context("the project has no stage model")?);
    let model = restage_authoring::stage_model::StageModel::load(&stage_dir)
        .with_context(|| format!("loading {}", stage_dir.display()))?;
    let room = room_lux(project, e.scenes.first().copied().unwrap_or(Scene::Restored))?;
    let desc = description(project, settings, model.projectors.len(), room)?;
    let desc_path = project.path(DESCRIPTION_FILE);
    std::fs::write(&desc_path, toml::to_string(&desc).context("serialising the bundle description")?)
        .with_context(|| format!("writing {}", desc_path.display()))?;
    if e.key.trim().is_empty() {
        bail!("choose a signing key (or make one)");
    }
    let key = project.path(&e.key);
    let out = project.path(&e.out);
    let manifest = crate::steps::bundle::write(&crate::steps::bundle::BundleArgs {
        description: desc_path,
        key,
        out: out.clone(),
        zstd: 3,
        created: None,
        overwrite: crate::steps::Overwrite { force: true },
    })?;
    let trust = project.path(&e.trust);
    let verified = crate::steps::verify::report(&crate::steps::verify::VerifyArgs::now_with_defaults(
        out.clone(),
        trust,
    ))?;
    Ok(format!("wrote {}\n{}{verified}", out.display(), restage_shared::bundle::describe(&manifest, None)))
}

/// The room light compensation counted (its `compensation.json`), lux.
fn room_lux(project: &Project, scene: Scene) -> Result<f64> {
    Ok(restage_authoring::compensate::io::Summary::load(&project.comp_dir(scene))?.stats.room_lux)
}

/// The brightest certificate peak among the chosen scenes.
pub fn peak_of(scenes: &[Scene], figures: &std::collections::HashMap<Scene, SceneFigures>) -> Option<f64> {
    scenes.iter().filter_map(|s| figures.get(s)).map(|f| f.peak_lux).reduce(f64::max)
}

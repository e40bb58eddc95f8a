//! The demo's top-level report: `index.html` in its output folder, every step's pictures with
//! captions, axes and colour bars, figures and light certificates read back from the files the
//! chain wrote. [`gather`] reads; [`page`] and [`svg`] only build strings.

mod calibration;
mod compensation;
pub mod page;
pub mod svg;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use restage_authoring::calibrate::geometry::GeometryReport;
use restage_authoring::calibrate::photometric::{PHOTOMETRIC_FILE, PhotometricSummary, footprint_scale};
use restage_authoring::calibrate::report::depth_range;
use restage_authoring::calibrate::transport::footprint_energy;
use restage_authoring::capture_set::{Axis, CaptureManifest, Pattern};
use restage_authoring::compensate::io::{SUMMARY_FILE, Summary, frame_file};
use restage_authoring::contact_sheet::sheet_patterns;
use restage_authoring::export::{BundleDescription, policy_from};
use restage_authoring::stage_model::StageModel;

use self::page::{Bundle, Entry, Inputs, Projector, Scene};

/// The report's file name, at the top of the folder.
pub const INDEX: &str = "index.html";

/// Reads what the demo wrote in `out` and writes `out/index.html`; returns its path.
pub fn write(out: &Path) -> Result<PathBuf> {
    let inputs = gather(out)?;
    let path = out.join(INDEX);
    std::fs::write(&path, page::render(&inputs)).with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// Reads every file the page shows. A missing file leaves its part empty (the page says so);
/// a file that is there but unreadable is an error naming it.
pub fn gather(out: &Path) -> Result<Inputs> {
    let mut inp = Inputs::default();
    let summary_txt = read_optional(&out.join("summary.txt"))?;
    let line = |prefix: &str| {
        summary_txt.as_deref().and_then(|t| t.lines().find(|l| l.starts_with(prefix))).map(str::to_string)
    };

    let capture = out.join("capture");
    if capture.join("capture.json").exists() {
        let m = CaptureManifest::load(&capture)?;
        inp.capture_source = Some(m.source.clone());
        inp.camera = Some((m.camera.width, m.camera.height));
        inp.sheet_columns = (0..m.projectors.len())
            .map(|k| sheet_patterns(&m, k).iter().map(pattern_name).collect())
            .collect();
    }
    inp.pictures = pictures(out)?;

    let stage = out.join("stage");
    if let Some(text) = read_optional(&stage.join("report.json"))? {
        let g: GeometryReport = serde_json::from_str(&text).with_context(|| {
            format!("{} is not a calibration report", stage.join("report.json").display())
        })?;
        inp.geometry = Some(g);
    }
    if let Some(text) = read_optional(&stage.join(PHOTOMETRIC_FILE))? {
        let p: PhotometricSummary = serde_json::from_str(&text).with_context(|| {
            format!("{} is not a photometric summary", stage.join(PHOTOMETRIC_FILE).display())
        })?;
        inp.photometric = Some(p);
    }
    if stage.join("stage.bin").exists() {
        let model = StageModel::load(&stage).with_context(|| format!("reading {}", stage.display()))?;
        inp.depth_mm = depth_range(&model.points);
        inp.projectors = model
            .projectors
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let energy = model.transport.get(k).map(|t| footprint_energy(t, p.width, p.height));
                Projector {
                    width: p.width,
                    height: p.height,
                    black: p.black,
                    response: p.response.clone(),
                    footprint_scale: energy
                        .filter(|e| e.iter().any(|v| v.is_finite()))
                        .map(|e| footprint_scale(&e)),
                }
            })
            .collect();
    }

    let description = out.join("bundle.toml");
    let desc = if description.exists() { Some(BundleDescription::load(&description)?) } else { None };
    if let Some(d) = &desc {
        inp.object = Some(d.object.name.clone());
    }
    let comp = out.join("comp");
    let mut ids: Vec<String> =
        desc.as_ref().map_or_else(Vec::new, |d| d.scenes.iter().map(|s| s.id.clone()).collect());
    // Scenes compensated but not in the bundle still get their section, after the bundle's.
    if let Ok(dirs) = std::fs::read_dir(&comp) {
        let mut more: Vec<String> = dirs
            .filter_map(|e| e.ok())
            .filter(|e| e.path().join(SUMMARY_FILE).exists())
            .filter_map(|e| e.file_name().to_str().map(str::to_string))
            .filter(|id| !ids.contains(id))
            .collect();
        more.sort();
        ids.extend(more);
    }
    for id in ids {
        let dir = comp.join(&id);
        if !dir.join(SUMMARY_FILE).exists() {
            continue;
        }
        let summary = Summary::load(&dir)?;
        let rel_dir = format!("comp/{id}");
        let frames: Vec<String> = (0..inp.projectors.len().max(count_frames(&dir)))
            .map(|k| format!("{rel_dir}/{}", frame_file(k)))
            .filter(|r| inp.pictures.contains_key(r))
            .collect();
        let name = desc
            .as_ref()
            .and_then(|d| d.scenes.iter().find(|s| s.id == id))
            .map_or_else(|| id.clone(), |s| s.name.clone());
        let report = dir.join("report").join("index.html").exists().then(|| format!("{rel_dir}/report"));
        let check_line = line(&format!("step 6 compensate {id} "));
        inp.scenes.push(Scene { id, name, dir: rel_dir, summary, frames, report, check_line });
    }

    let bundle_file = out.join("demo.restage");
    if let Ok(meta) = std::fs::metadata(&bundle_file) {
        let policy = desc.as_ref().map(|d| d.policy.clone()).unwrap_or_default();
        inp.bundle = Some(Bundle {
            policy: policy_from(&policy).ok(),
            file: "demo.restage".into(),
            bytes: meta.len(),
            description: "bundle.toml".into(),
            trust: "trust/".into(),
            keys: "keys/".into(),
            policy_class: policy.class,
            verify_line: line("step 8 verify"),
        });
    }
    inp.summary_txt = summary_txt;
    inp.files = entries(out)?;
    Ok(inp)
}

fn read_optional(path: &Path) -> Result<Option<String>> {
    match std::fs::read_to_string(path) {
        Ok(t) => Ok(Some(t)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e).with_context(|| format!("reading {}", path.display())),
    }
}

/// How many `proj<k>.png` frames a folder holds (counting up from 0).
fn count_frames(dir: &Path) -> usize {
    (0..).take_while(|&k| dir.join(frame_file(k)).exists()).count()
}

/// The size of every PNG outside `capture/` (its thousands of camera images are shown through
/// the contact sheet), plus the photo.
fn pictures(out: &Path) -> Result<BTreeMap<String, (u32, u32)>> {
    let mut found = BTreeMap::new();
    let mut stack = vec![(out.to_path_buf(), String::new())];
    while let Some((dir, rel)) = stack.pop() {
        for entry in std::fs::read_dir(&dir).with_context(|| format!("listing {}", dir.display()))? {
            let entry = entry?;
            let Some(name) = entry.file_name().to_str().map(str::to_string) else { continue };
            let rel_path = if rel.is_empty() { name.clone() } else { format!("{rel}/{name}") };
            let kind = entry.file_type()?;
            if kind.is_dir() && !(rel.is_empty() && ["capture", "keys", "trust"].contains(&name.as_str())) {
                stack.push((entry.path(), rel_path));
            } else if kind.is_file() && name.ends_with(".png") {
                found.insert(rel_path, png_size(&entry.path())?);
            }
        }
    }
    let photo = out.join("capture").join("photo.png");
    if photo.exists() {
        found.insert("capture/photo.png".into(), png_size(&photo)?);
    }
    Ok(found)
}

fn png_size(path: &Path) -> Result<(u32, u32)> {
    image::image_dimensions(path).with_context(|| format!("reading the size of {}", path.display()))
}

/// The folder's top-level entries with their sizes, largest first.
fn entries(out: &Path) -> Result<Vec<Entry>> {
    let mut list = Vec::new();
    for entry in std::fs::read_dir(out).with_context(|| format!("listing {}", out.display()))? {
        let entry = entry?;
        let Some(name) = entry.file_name().to_str().map(str::to_string) else { continue };
        let dir = entry.file_type()?.is_dir();
        list.push(Entry { bytes: disk_bytes(&entry.path())?, name, dir });
    }
    list.sort_by(|a, b| b.bytes.cmp(&a.bytes).then(a.name.cmp(&b.name)));
    Ok(list)
}

/// Bytes of a file, or of everything under a folder (links not followed).
fn disk_bytes(path: &Path) -> Result<u64> {
    let meta = std::fs::symlink_metadata(path).with_context(|| format!("reading {}", path.display()))?;
    if !meta.is_dir() {
        return Ok(meta.len());
    }
    let mut sum = 0;
    for entry in std::fs::read_dir(path).with_context(|| format!("listing {}", path.display()))? {
        sum += disk_bytes(&entry?.path())?;
    }
    Ok(sum)
}

/// A contact-sheet tile's name for people.
fn pattern_name(p: &Pattern) -> String {
    let axis = |a: &Axis| match a {
        Axis::X => "x",
        Axis::Y => "y",
    };
    match p {
        Pattern::White => "white".into(),
        Pattern::Black => "black".into(),
        Pattern::GrayCode { axis: a, bit, inverted } => {
            format!("Gray {} bit {bit}{}", axis(a), if *inverted { " inv." } else { "" })
        }
        Pattern::Phase { axis: a, step, .. } => format!("phase {} step {step}", axis(a)),
        Pattern::Dots { spacing, .. } => format!("dots every {spacing} px"),
        Pattern::Ramp { channel, level } => {
            format!("{} {level}", ["red", "green", "blue"].get(*channel as usize).unwrap_or(&"channel"))
        }
    }
}

#[cfg(test)]
mod tests {
    use restage_authoring::compensate::Stats;

    use super::*;

    #[test]
    fn the_page_reads_what_the_chain_wrote_and_links_it_relatively() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("my demo");
        let scene = out.join("comp").join("restored");
        std::fs::create_dir_all(&scene).unwrap();
        let summary = Summary {
            version: 1,
            e_bound_lux: 150.0,
            m: "8".into(),
            margin: 0.05,
            meter_accuracy: 0.1,
            clip_fraction: 0.01,
            certificate_reduction: 2,
            stats: Stats { peak_lux: 141.25, limit_lux: 142.5, covered_points: 10, ..Stats::default() },
        };
        std::fs::write(scene.join(SUMMARY_FILE), serde_json::to_string(&summary).unwrap()).unwrap();
        image::RgbImage::new(16, 12).save(scene.join(frame_file(0))).unwrap();
        image::RgbImage::new(20, 10).save(out.join("before_restored_target.png")).unwrap();
        std::fs::write(
            out.join("summary.txt"),
            "step 6 compensate restored (1.0 s): certificate peak 141.2 lx, TRUE peak 99.0 lx\n\
             step 8 verify (2.0 s): bundle verified against trust\n",
        )
        .unwrap();

        let index = write(&out).unwrap();
        assert_eq!(index, out.join(INDEX));
        let html = std::fs::read_to_string(&index).unwrap();
        assert!(html.contains(r#"<image href="comp/restored/proj0.png" width="16" height="12"/>"#), "{html}");
        assert!(html.contains(r#"<image href="before_restored_target.png""#));
        assert!(html.contains("Peak illuminance found: <strong>141.25 lx</strong>"));
        assert!(html.contains("TRUE peak 99.0 lx"));
        assert!(html.contains(&format!("<code>stage/report.png</code> {}", page::MISSING)));
        assert!(html.contains(r#"<a href="comp/"><code>comp/</code></a>"#));
        assert!(!html.contains(tmp.path().to_str().unwrap()), "an absolute path in the page");
    }
}

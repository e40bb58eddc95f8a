//! Helpers for the end-to-end tests in `tests/tests/`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// Path of the `restage-author` binary, built (once per test process) with the same profile
/// as the running test. Cargo only exposes `CARGO_BIN_EXE_*` to a package's own tests, and
/// this crate tests the binaries of others.
pub fn author_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| build_bin("restage-authoring", "restage-author"))
}

/// Path of the `restage-appliance` binary (built once per test process, like `author_bin`).
pub fn appliance_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| build_bin("restage-appliance", "restage-appliance"))
}

/// Set by `.ci/run`: the binaries beside the test executable were built by the same `cargo test
/// --workspace` that runs the tests (it builds every package's binaries for their own tests,
/// with the run's features and profile), so they are used as they are. Without it a `cargo
/// build` of the one package makes sure they are current; in CI that build was a second,
/// cold build of each binary's whole dependency tree in another profile (minutes on 2 cores).
pub const BINS_PREBUILT_ENV: &str = "RESTAGE_BINS_PREBUILT";

fn build_bin(package: &str, bin: &str) -> PathBuf {
    // The test executable lives in target/<profile>/deps/.
    let exe = std::env::current_exe().expect("test executable path");
    let profile_dir = exe.parent().and_then(Path::parent).expect("target/<profile>/deps layout");
    let path = profile_dir.join(format!("{bin}{}", std::env::consts::EXE_SUFFIX));
    if std::env::var_os(BINS_PREBUILT_ENV).is_some_and(|v| v == "1") {
        assert!(path.is_file(), "{BINS_PREBUILT_ENV}=1 but {} was not built", path.display());
        return path;
    }
    let release = profile_dir.file_name().is_some_and(|n| n == "release");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(["build", "--quiet", "-p", package, "--bin", bin]);
    if release {
        cmd.arg("--release");
    }
    let status = cmd.status().expect("cargo runs");
    assert!(status.success(), "building {bin} failed");
    assert!(path.is_file(), "{} was not built", path.display());
    path
}

/// Runs `restage-author` with `args` and extra environment variables.
pub fn run_author(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(author_bin());
    cmd.args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("restage-author starts")
}

/// Every file under `dir`, relative, sorted.
pub fn files_under(dir: &Path) -> Vec<PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).expect("readable dir") {
            let p = e.expect("dir entry").path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                out.push(p.strip_prefix(root).expect("under root").to_path_buf());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// Writes the virtual bowl's small diffusely lit photo as `photo.png`, picks drawn from its
/// deteriorated labels as `picks.json`, and its object mask as `mask.png` into `dir`; returns
/// the dense truth and the picks (for `restage-author classify`).
pub fn bowl_inputs(
    dir: &Path,
) -> (restage_authoring::classify::LabelMap, restage_authoring::classify::Picks) {
    use restage_authoring::classify::{LabelMap, MASKED, picks_from_labels};
    use restage_authoring::eval::classify::{PICKS_PER_CLASS, scene_case};
    let case = scene_case(
        restage_authoring::stage_sim::SceneName::Bowl,
        [240, 180],
        2,
        restage_authoring::stage_sim::RigVariation::Seeded,
    )
    .expect("the bowl");
    let present: Vec<usize> =
        (0..case.names.len()).filter(|&c| case.truth.data.contains(&(c as u8))).collect();
    let dense = LabelMap::from_vec(
        case.truth.width,
        case.truth.height,
        case.truth
            .data
            .iter()
            .map(|&l| present.iter().position(|&c| c == l as usize).map_or(MASKED, |d| d as u8))
            .collect(),
    )
    .expect("a label map");
    let names: Vec<String> = present.iter().map(|&c| case.names[c].clone()).collect();
    let display: Vec<Option<[u8; 3]>> = present.iter().map(|&c| case.display[c]).collect();
    let picks = picks_from_labels(&dense, &names, &display, PICKS_PER_CLASS, 1).expect("picks");
    case.photo.save_linear16(&dir.join("photo.png")).expect("photo written");
    picks.save(&dir.join("picks.json")).expect("picks written");
    let mask: Vec<u8> = dense.data.iter().map(|&l| if l == MASKED { 0 } else { 255 }).collect();
    image::GrayImage::from_raw(dense.width, dense.height, mask)
        .expect("one byte per pixel")
        .save(dir.join("mask.png"))
        .expect("mask written");
    (dense, picks)
}

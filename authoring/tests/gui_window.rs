//! `restage-author gui` in a real window: under Xvfb with Mesa's lavapipe (CPU Vulkan) the
//! tool opens the demo's output as a project, shows each view, and its screenshots are compared
//! with the golden images in `tests/golden/gui/` within a tolerance. `RESTAGE_UPDATE_GOLDEN=1`
//! rewrites them; every screenshot (and a difference image for a failing one) is kept under
//! `$CARGO_TARGET_TMPDIR/gui-screenshots/` for a person to look at. Without Xvfb the tests fail
//! naming the package, unless `RESTAGE_NO_GUI_OK=1`. Also: no graphics adapter and no display
//! give a clear message, not a crash; and the same demo run's `index.html` renders in headless
//! Chromium (screenshots in `$CARGO_TARGET_TMPDIR/report-screenshots/`).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_restage-author");

/// A private X server for one test, stopped on drop.
struct Xvfb {
    child: Child,
    display: String,
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        // SIGTERM, not SIGKILL: a killed Xvfb leaves its socket and lock file in /tmp, and a
        // later run that takes the same number would find a socket no server listens on.
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        if nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).is_err() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

fn xvfb() -> Option<Xvfb> {
    if Command::new("Xvfb").arg("-help").stderr(Stdio::null()).stdout(Stdio::null()).status().is_err() {
        if std::env::var_os("RESTAGE_NO_GUI_OK").is_some() {
            eprintln!("skipped: no Xvfb (RESTAGE_NO_GUI_OK is set)");
            return None;
        }
        panic!(
            "Xvfb is missing: apt-get install xvfb mesa-vulkan-drivers (or set RESTAGE_NO_GUI_OK=1 to skip)"
        );
    }
    // `-displayfd`: the server takes a free display number itself (tests run in parallel and CI
    // may have other servers) and writes it once it accepts connections, so there is no race
    // between a socket appearing and the server listening on it.
    let mut child = Command::new("Xvfb")
        .args(["-displayfd", "1", "-screen", "0", "1280x800x24", "-nolisten", "tcp", "-noreset"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting Xvfb");
    let mut line = String::new();
    let stdout = child.stdout.take().expect("Xvfb's stdout");
    let _ = std::io::BufRead::read_line(&mut std::io::BufReader::new(stdout), &mut line);
    let n: u32 = match line.trim().parse() {
        Ok(n) => n,
        Err(_) => {
            let _ = child.kill();
            let _ = child.wait();
            panic!("Xvfb did not start (it wrote {line:?} for its display number)");
        }
    };
    Some(Xvfb { child, display: format!(":{n}") })
}

fn gui(display: &str) -> Command {
    let mut c = Command::new(BIN);
    c.arg("gui").env("DISPLAY", display).env_remove("WAYLAND_DISPLAY").env("RUST_LOG", "warn");
    c
}

fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/gui")
}

/// (fraction of pixels off by more than 24 levels in a channel, mean absolute difference).
fn compare(a: &image::RgbImage, b: &image::RgbImage) -> (f64, f64, image::RgbImage) {
    let mut diff = image::RgbImage::new(a.width(), a.height());
    let (mut off, mut sum) = (0usize, 0u64);
    for ((p, q), d) in a.pixels().zip(b.pixels()).zip(diff.pixels_mut()) {
        let m = (0..3).map(|c| p.0[c].abs_diff(q.0[c])).max().unwrap();
        sum += (0..3).map(|c| p.0[c].abs_diff(q.0[c]) as u64).sum::<u64>();
        if m > 24 {
            off += 1;
            d.0 = [255, 0, 255];
        } else {
            d.0 = p.0.map(|v| v / 3);
        }
    }
    let n = (a.width() * a.height()) as f64;
    (off as f64 / n, sum as f64 / (3.0 * n), diff)
}

#[test]
fn every_view_matches_its_golden_screenshot() {
    let Some(x) = xvfb() else { return };
    let tmp = tempfile::tempdir().unwrap();
    // The demo's whole chain (about two minutes on two cores); its output folder is a project
    // whose relighting and compensations the tool runs before the screenshots.
    let project = tmp.path().join("demo");
    let demo = Command::new(BIN)
        .args(["demo", "--out", project.to_str().unwrap(), "--device", "cpu"])
        .env("RUST_LOG", "error")
        .output()
        .unwrap();
    assert!(demo.status.success(), "running the demo:\n{}", String::from_utf8_lossy(&demo.stderr));
    // The demo's report page, in a real browser: here, so that the demo runs once.
    report_renders_in_chromium(&project);
    let shots = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("gui-screenshots");
    let _ = std::fs::remove_dir_all(&shots);
    let out = gui(&x.display)
        .arg(&project)
        .args(["--screenshots", shots.to_str().unwrap(), "--window", "1024x640"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "the scripted window failed:\n{stderr}");
    let mut names: Vec<PathBuf> = std::fs::read_dir(&shots).unwrap().map(|e| e.unwrap().path()).collect();
    names.sort();
    assert_eq!(names.len(), 8, "one screenshot per view: {names:?}");
    eprintln!("screenshots kept in {}", shots.display());
    let update = std::env::var_os("RESTAGE_UPDATE_GOLDEN").is_some();
    let golden = golden_dir();
    std::fs::create_dir_all(&golden).unwrap();
    let mut failures = Vec::new();
    for shot in &names {
        let name = shot.file_name().unwrap();
        let g = golden.join(name);
        if update {
            std::fs::copy(shot, &g).unwrap();
            continue;
        }
        let a = image::open(shot).unwrap().to_rgb8();
        // A blank or single-colour screenshot would mean the view drew nothing.
        let first = a.get_pixel(0, 0).0;
        assert!(a.pixels().any(|p| p.0 != first), "{} is blank", shot.display());
        let Ok(b) = image::open(&g) else {
            failures.push(format!("{}: no golden image (run with RESTAGE_UPDATE_GOLDEN=1)", g.display()));
            continue;
        };
        let b = b.to_rgb8();
        if a.dimensions() != b.dimensions() {
            failures.push(format!(
                "{}: {:?} vs golden {:?}",
                name.to_string_lossy(),
                a.dimensions(),
                b.dimensions()
            ));
            continue;
        }
        let (off, mean, diff) = compare(&a, &b);
        eprintln!(
            "{}: {:.3} % of pixels off, mean difference {mean:.3}",
            name.to_string_lossy(),
            100.0 * off
        );
        if off > 0.005 || mean > 1.5 {
            let d = shots.join(format!("diff-{}", name.to_string_lossy()));
            diff.save(&d).unwrap();
            failures.push(format!(
                "{}: {:.2} % pixels off, mean {mean:.2} (difference: {})",
                name.to_string_lossy(),
                100.0 * off,
                d.display()
            ));
        }
    }
    assert!(failures.is_empty(), "screenshots differ from the golden images:\n{}", failures.join("\n"));
}

fn chromium() -> Option<&'static str> {
    ["chromium", "chromium-browser", "google-chrome"].into_iter().find(|b| {
        Command::new(b).arg("--version").stdout(Stdio::null()).stderr(Stdio::null()).status().is_ok()
    })
}

/// Headless Chromium opens the demo's `index.html` from disk (so its relative links and
/// pictures load as they would for a person) at a desktop and a phone width: it exits 0 and
/// each screenshot shows pictures, not one flat colour. The screenshots are kept under
/// `$CARGO_TARGET_TMPDIR/report-screenshots/`. `RESTAGE_SKIP_BROWSER=1` skips this, as it does
/// the appliance's status page test.
fn report_renders_in_chromium(project: &Path) {
    if std::env::var_os("RESTAGE_SKIP_BROWSER").is_some_and(|v| v == "1") {
        eprintln!("skipped: RESTAGE_SKIP_BROWSER=1 (the demo's report is not rendered in a browser)");
        return;
    }
    let browser = chromium().expect(
        "no chromium: install Debian's package `chromium` (apt-get install -y chromium), \
         or set RESTAGE_SKIP_BROWSER=1 to skip the report's screenshot",
    );
    let index = project.join("index.html");
    assert!(index.exists(), "the demo wrote no {}", index.display());
    let shots = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report-screenshots");
    let _ = std::fs::remove_dir_all(&shots);
    std::fs::create_dir_all(&shots).unwrap();
    for (name, width, height) in [("report-desktop.png", 1280, 4000), ("report-phone.png", 390, 3000)] {
        let png = shots.join(name);
        let profile = tempfile::tempdir().unwrap();
        let mut child = Command::new(browser)
            .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run"])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg(format!("--screenshot={}", png.display()))
            .arg(format!("--window-size={width},{height}"))
            .arg(format!("file://{}", index.display()))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(120);
        let status = loop {
            if let Some(st) = child.try_wait().unwrap() {
                break st;
            }
            if Instant::now() > deadline {
                let _ = child.kill();
                panic!("chromium took over 120 s on {}", index.display());
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        let mut err = String::new();
        let _ = child.stderr.take().map(|mut e| std::io::Read::read_to_string(&mut e, &mut err));
        assert!(status.success() && png.exists(), "chromium failed ({status}): {err}");
        let shot = image::open(&png).unwrap().to_rgb8();
        assert_eq!(shot.dimensions(), (width, height), "{}", png.display());
        // Pictures, false colours and plots give many colours; text on white alone, a few hundred.
        let colours: std::collections::HashSet<[u8; 3]> = shot.pixels().map(|p| p.0).collect();
        let white = shot.pixels().filter(|p| p.0 == [255; 3]).count() as f64 / (width * height) as f64;
        eprintln!("{}: {} colours, {:.0} % white", png.display(), colours.len(), 100.0 * white);
        assert!(colours.len() > 1000 && white < 0.97, "{}: a blank page?", png.display());
    }
}

#[test]
fn no_graphics_adapter_is_a_clear_message() {
    let Some(x) = xvfb() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let photo = tmp.path().join("photo.png");
    image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8 * 4, y as u8 * 5, 90])).save(&photo).unwrap();
    let project = tmp.path().join("p");
    let out = gui(&x.display)
        .arg(&project)
        .args(["--from-photo", photo.to_str().unwrap()])
        // No Vulkan driver at all.
        .env("VK_ICD_FILENAMES", tmp.path().join("none.json"))
        .env("VK_DRIVER_FILES", tmp.path().join("none.json"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("no graphics adapter") && stderr.contains("--no-window"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn no_display_is_a_clear_message() {
    let tmp = tempfile::tempdir().unwrap();
    let photo = tmp.path().join("photo.png");
    image::RgbImage::from_fn(32, 24, |x, _| image::Rgb([x as u8, 0, 0])).save(&photo).unwrap();
    let out = Command::new(BIN)
        .args(["gui", tmp.path().join("p").to_str().unwrap(), "--from-photo", photo.to_str().unwrap()])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("no display") && stderr.contains("--no-window"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    // Checked before any work: no project was made.
    assert!(!tmp.path().join("p").exists());
}

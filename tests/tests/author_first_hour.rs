//! The conservator's first hour with `restage-author`, one test per thing a new user tried
//! (see the issue "The conservator's first hour"): files are never written over or deleted
//! silently, arguments are checked before any work and in plain words, misspelt keys are
//! named, errors print once without a backtrace, JPEG photos are read, key names are safe,
//! and completions and man pages exist.

use std::path::Path;

use restage_tests::{bowl_inputs, run_author};

fn text(o: &std::process::Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn p(dir: &Path, f: &str) -> String {
    dir.join(f).to_str().unwrap().to_owned()
}

#[test]
fn the_demo_refuses_a_folder_of_someone_elses_files_and_deletes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d2");
    std::fs::create_dir_all(out.join("keys")).unwrap();
    std::fs::write(out.join("keys/museum-2026.pem"), "the museum's own key").unwrap();
    let o = run_author(&["demo", "--out", out.to_str().unwrap()], &[]);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("not an earlier demo's") && t.contains("--force"), "{t}");
    assert_eq!(std::fs::read_to_string(out.join("keys/museum-2026.pem")).unwrap(), "the museum's own key");
    // Nothing was written: no marker, no capture.
    assert_eq!(restage_tests::files_under(&out), [Path::new("keys/museum-2026.pem")]);
}

#[test]
fn steps_refuse_to_write_over_outputs_unless_forced() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bowl_inputs(d);
    let classify = |force: bool| {
        let mut a = vec![
            "classify".to_string(),
            p(d, "photo.png"),
            "--picks".into(),
            p(d, "picks.json"),
            "--out".into(),
            p(d, "existing"),
        ];
        if force {
            a.push("--force".into());
        }
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        run_author(&a, &[])
    };
    std::fs::create_dir_all(d.join("existing")).unwrap();
    std::fs::write(d.join("existing/notes.txt"), "mine").unwrap();
    let o = classify(false);
    assert!(!o.status.success());
    assert!(text(&o).contains("already holds files") && text(&o).contains("--force"), "{}", text(&o));
    assert!(!d.join("existing/labels.png").exists(), "nothing written when refused");
    let o = classify(true);
    assert!(o.status.success(), "{}", text(&o));
    assert!(d.join("existing/labels.png").is_file());
    assert_eq!(
        std::fs::read_to_string(d.join("existing/notes.txt")).unwrap(),
        "mine",
        "--force deletes nothing"
    );

    // A single output file: the bundle.
    std::fs::write(d.join("existing.restage"), "an older bundle").unwrap();
    let o = run_author(
        &["bundle", &p(d, "bundle.toml"), "--key", &p(d, "k.pem"), "--out", &p(d, "existing.restage")],
        &[],
    );
    assert!(!o.status.success());
    assert!(text(&o).contains("already exists") && text(&o).contains("--force"), "{}", text(&o));
    assert_eq!(std::fs::read_to_string(d.join("existing.restage")).unwrap(), "an older bundle");
}

#[test]
fn negative_numbers_are_values_refused_with_a_reason_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let compensate = |extra: &[&str]| {
        let mut a = vec!["compensate", "no-stage", "no.png", "--out"];
        let out = p(d, "comp");
        a.push(&out);
        a.extend_from_slice(extra);
        run_author(&a, &[])
    };
    let o = compensate(&["--ebound-lux", "-150"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("E_bound -150 lux is invalid"), "{}", text(&o));
    let o = compensate(&["--ebound-lux", "150", "--m", "-1"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("smoothness exponent m = -1 is invalid"), "{}", text(&o));
    assert!(!text(&o).contains("unexpected argument"), "{}", text(&o));

    // Checked before decoding a capture (which does not even exist here) or making a folder.
    let o = run_author(&["calibrate", "no-capture", "--known-distance-mm=-600", "--out", &p(d, "cal")], &[]);
    assert!(!o.status.success());
    assert!(text(&o).contains("--known-distance-mm -600"), "{}", text(&o));
    assert!(!d.join("cal").exists(), "no output folder left behind");
}

#[test]
fn a_bound_above_cie_157_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let o = run_author(
        &["compensate", "no-stage", "no.png", "--ebound-lux", "100000", "--out", &p(dir.path(), "c")],
        &[],
    );
    assert!(text(&o).contains("CIE 157"), "{}", text(&o));
}

#[test]
fn a_misspelt_key_in_picks_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bowl_inputs(d);
    let picks = std::fs::read_to_string(d.join("picks.json")).unwrap();
    assert!(picks.contains("\"pixels\""), "the picks format names its pixels `pixels`");
    std::fs::write(d.join("typo.json"), picks.replacen("\"pixels\"", "\"pixel\"", 1)).unwrap();
    let o = run_author(
        &["classify", &p(d, "photo.png"), "--picks", &p(d, "typo.json"), "--out", &p(d, "o")],
        &[],
    );
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("unknown field `pixel`") && t.contains("typo.json"), "{t}");
}

#[test]
fn an_error_is_one_line_with_its_causes_once_and_no_backtrace() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bowl_inputs(d);
    let o = run_author(
        &["classify", &p(d, "missing.png"), "--picks", &p(d, "picks.json"), "--out", &p(d, "o")],
        &[("RUST_BACKTRACE", "1")],
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.matches("error:").count(), 1, "{err}");
    assert!(!err.to_lowercase().contains("backtrace"), "{err}");
    assert_eq!(err.matches("missing.png").count(), 2, "the file is named in the error and its cause: {err}");
    assert!(err.lines().count() <= 3, "{err}");
}

#[test]
fn a_jpeg_photo_is_classified() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bowl_inputs(d);
    let photo = image::open(d.join("photo.png")).unwrap().to_rgb8();
    photo.save(d.join("photo.jpg")).unwrap();
    let o = run_author(
        &["classify", &p(d, "photo.jpg"), "--picks", &p(d, "picks.json"), "--out", &p(d, "o")],
        &[],
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(d.join("o/labels.png").is_file());
}

#[test]
fn keygen_refuses_key_file_extensions_and_writes_into_folders() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for bad in ["foo.pub", "foo.pem", "foo.pub.pem"] {
        let o = run_author(&["keygen", "--out", &p(d, bad)], &[]);
        assert!(!o.status.success(), "{bad}");
        assert!(text(&o).contains("without an extension"), "{}", text(&o));
    }
    assert!(restage_tests::files_under(d).is_empty(), "nothing written");
    let folder = format!("{}/", p(d, "keys"));
    let o = run_author(&["keygen", "--out", &folder], &[]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(d.join("keys/restage-key.pem").is_file() && d.join("keys/restage-key.pub.pem").is_file());
    assert!(!d.join("keys.pem").exists());
}

#[test]
fn completions_and_man_pages_are_written() {
    let o = run_author(&["completions", "bash"], &[]);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("restage-author"));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("man");
    let o = run_author(&["man", "--out", out.to_str().unwrap()], &[]);
    assert!(o.status.success(), "{}", text(&o));
    let top = std::fs::read_to_string(out.join("restage-author.1")).unwrap();
    assert!(top.contains(".TH") && top.contains("compensate"), "{top}");
    assert!(out.join("restage-author-compensate.1").is_file());
}

/// A small bundle signed with the public demo key, valid until 2027-01-15 08:00:00 UTC, and a
/// trust folder holding the demo key's public half.
fn demo_signed_bundle(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    use restage_shared::bundle::example::{ExampleSpec, example_writer};
    let spec = ExampleSpec { expires_unix_s: Some(1_800_000_000), ..ExampleSpec::small() };
    let key = restage_shared::keys::demo_signing_key();
    let mut bytes = Vec::new();
    example_writer(&spec).unwrap().write(&key, &mut bytes).unwrap();
    let bundle = dir.join("demo.restage");
    std::fs::write(&bundle, &bytes).unwrap();
    std::fs::create_dir_all(dir.join("keys")).unwrap();
    let (_, public) = restage_shared::keys::write_keypair(&key, &dir.join("keys/demo")).unwrap();
    let trust = dir.join("trust");
    std::fs::create_dir_all(&trust).unwrap();
    std::fs::copy(public, trust.join("demo.pub.pem")).unwrap();
    (bundle, trust)
}

#[test]
fn verify_speaks_in_dates_and_names_the_demo_key_loudly() {
    let dir = tempfile::tempdir().unwrap();
    let (bundle, trust) = demo_signed_bundle(dir.path());
    let (b, t) = (bundle.to_str().unwrap(), trust.to_str().unwrap());
    let o = run_author(&["verify", b, "--trust", t, "--now", "2025-01-01"], &[]);
    assert!(o.status.success(), "{}", text(&o));
    let out = text(&o);
    assert!(out.contains("DEMO KEY") && out.contains("anyone can sign"), "{out}");
    assert!(out.contains("valid at 2025-01-01 00:00:00 UTC, until 2027-01-15 08:00:00 UTC"), "{out}");

    let o = run_author(&["verify", b, "--trust", t, "--now", "2027-12-31T10:00:00Z"], &[]);
    assert!(!o.status.success());
    let out = text(&o);
    assert!(out.contains("2027-01-15 08:00:00 UTC") && !out.contains("Unix s"), "{out}");

    let o = run_author(&["verify", b, "--trust", t, "--now", "2025-01-01", "--json"], &[]);
    assert!(o.status.success(), "{}", text(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((v["demo_key"].as_bool(), v["authenticated"].as_bool()), (Some(true), Some(true)), "{v}");
    assert_eq!(v["summary_version"].as_u64(), Some(1));

    // Without a trust folder: inspected, not verified, and it says so.
    let o = run_author(&["inspect", b], &[]);
    assert!(o.status.success(), "{}", text(&o));
    let out = text(&o);
    assert!(out.contains("NOT CHECKED") && out.contains("DEMO KEY"), "{out}");
}

#[test]
fn a_tampered_bundle_is_refused_in_plain_words() {
    let dir = tempfile::tempdir().unwrap();
    let (bundle, trust) = demo_signed_bundle(dir.path());
    let mut bytes = std::fs::read(&bundle).unwrap();
    let n = bytes.len();
    bytes[n - 200] ^= 0x55; // inside the last section
    std::fs::write(&bundle, &bytes).unwrap();
    let o = run_author(
        &["verify", bundle.to_str().unwrap(), "--trust", trust.to_str().unwrap(), "--now", "2025-01-01"],
        &[],
    );
    assert!(!o.status.success());
    let out = text(&o);
    assert!(out.contains("section") && !out.contains("Frame {") && !out.contains("{ scene"), "{out}");
}

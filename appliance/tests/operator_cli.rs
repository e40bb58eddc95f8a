//! The operator's commands on a stage: `install`, then `status` says what is installed and
//! until when; `ledger export --csv` writes the light history a loan agreement asks for and
//! never overwrites a file; the configuration path defaults to /etc/restage/appliance.toml.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use restage_appliance::ledger::{ActiveBundle, Budgets, Ledger};
use restage_appliance::player::{Accountant, LightKind};
use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};

struct Stage {
    _dir: tempfile::TempDir,
    root: PathBuf,
    config: PathBuf,
}

fn stage() -> Stage {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().to_path_buf();
    let key = signing_key_from_seed([5; 32]);
    for d in ["trust", "state", "frames"] {
        std::fs::create_dir(root.join(d)).unwrap();
    }
    std::fs::write(root.join("trust/k.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
    // Expires 2100-01-01: far ahead of any test machine's clock.
    let spec = ExampleSpec { expires_unix_s: Some(4_102_444_800), ..ExampleSpec::small() };
    example_writer(&spec)
        .unwrap()
        .write(&key, std::fs::File::create(root.join("new.restage")).unwrap())
        .unwrap();
    let config = root.join("appliance.toml");
    std::fs::write(
        &config,
        format!(
            "trust_dir = \"{0}/trust\"\nstate_dir = \"{0}/state\"\n[output]\nkind = \"headless\"\ndir = \"{0}/frames\"\n",
            root.display()
        ),
    )
    .unwrap();
    Stage { _dir: dir, root, config }
}

fn appliance(args: &[&str], config: &Path) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_restage-appliance"))
        .args(args)
        .arg("--config")
        .arg(config)
        .env("RESTAGE_LOG", "warn")
        .output()
        .unwrap();
    (o.status.success(), String::from_utf8_lossy(&o.stdout).into(), String::from_utf8_lossy(&o.stderr).into())
}

#[test]
fn status_names_the_installed_bundle_and_its_expiry_before_it_plays() {
    let s = stage();
    let bundle = s.root.join("new.restage");
    let (ok, _, err) = appliance(&["install", bundle.to_str().unwrap()], &s.config);
    assert!(ok, "{err}");
    let (ok, out, err) = appliance(&["status"], &s.config);
    assert!(ok, "{err}");
    assert!(out.contains("installed: test-jar-1 version 3"), "{out}");
    assert!(out.contains("expires 2100-01-01"), "{out}");
    assert!(out.contains("playing: nothing yet"), "{out}");
    assert!(!out.contains("REFUSED"), "{out}");
    let (ok, out, _) = appliance(&["status", "--json"], &s.config);
    assert!(ok);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["installed"]["version"], 3);
    assert_eq!(v["installed"]["expires_unix_ms"], 4_102_444_800_000i64);

    // A trust directory that no longer holds the signer's key: status says so.
    std::fs::remove_file(s.root.join("trust/k.pem")).unwrap();
    let (ok, out, _) = appliance(&["status"], &s.config);
    assert!(ok);
    assert!(out.contains("REFUSED"), "{out}");
}

#[test]
fn ledger_export_writes_every_exposure_and_refuses_to_overwrite() {
    let s = stage();
    let state = s.root.join("state");
    {
        let mut l = Ledger::open_stage(&state, restage_appliance::zone::LocalZone::utc()).unwrap();
        l.set_active(&ActiveBundle {
            object: "test-jar-1".into(),
            version: 3,
            bundle_hash: "ab".repeat(32),
            path: "x".into(),
            loaded_ms: 1_000,
            budgets: Budgets { daily_lux_hours: 100.0, annual_lux_hours: 1000.0, warn_at: vec![] },
        })
        .unwrap();
        // 120 lx for 30 s (1 lx·h), committed; 60 lx reserved for 60 s, never committed.
        let a = l.reserve(LightKind::Showing, "restored", 120.0, 10_000, 40_000).unwrap();
        l.commit(a, 40_000).unwrap();
        l.reserve(LightKind::Idle, "original", 60.0, 100_000, 160_000).unwrap();
    }
    let (ok, out, err) = appliance(&["ledger", "export", "--csv"], &s.config);
    assert!(ok, "{err}");
    let mut r = csv::Reader::from_reader(out.as_bytes());
    let rows: Vec<csv::StringRecord> = r.records().map(Result::unwrap).collect();
    assert_eq!(rows.len(), 2, "{out}");
    assert_eq!(&rows[0][2], "restored");
    assert_eq!(&rows[0][9], "1.000000");
    assert_eq!(&rows[1][10], "reservation (counted in full)");

    let file = s.root.join("history.csv");
    std::fs::write(&file, "the conservator's notes").unwrap();
    let (ok, _, err) = appliance(&["ledger", "export", "--csv", "--out", file.to_str().unwrap()], &s.config);
    assert!(!ok && err.contains("history.csv"), "{err}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "the conservator's notes");
}

#[test]
fn the_configuration_defaults_to_etc_restage() {
    let o = Command::new(env!("CARGO_BIN_EXE_restage-appliance")).arg("status").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    if Path::new("/etc/restage/appliance.toml").exists() {
        return; // a real stage: nothing to learn here
    }
    assert!(!o.status.success() && err.contains("/etc/restage/appliance.toml"), "{err}");
}

#[test]
fn identify_lights_one_projector_within_the_bound_and_the_ledger_pays() {
    let s = stage();
    let sock = s.root.join("control.sock");
    let mut text = std::fs::read_to_string(&s.config).unwrap();
    text.push_str(&format!("[inputs]\ncontrol_socket = \"{}\"\n", sock.display()));
    std::fs::write(&s.config, text).unwrap();
    let bundle = s.root.join("new.restage");
    assert!(appliance(&["install", bundle.to_str().unwrap()], &s.config).0);
    let _run = common::Running::start(&s.config);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    while !sock.exists() {
        assert!(std::time::Instant::now() < deadline, "the appliance did not open its control socket");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    // Projector 3 of a 2-projector bundle: refused, naming the count.
    let (ok, _, err) = appliance(&["identify", "--projector", "3"], &s.config);
    assert!(!ok && err.contains("2 projectors"), "{err}");
    let (ok, out, err) = appliance(&["identify", "--projector", "2", "--seconds", "1"], &s.config);
    assert!(ok && out.contains("ok identifying projector 2"), "{out}{err}");
    std::thread::sleep(std::time::Duration::from_millis(1500));

    // The recorder saw a frame set where only projector 2 (index 1) is lit.
    let frames = s.root.join("frames");
    let log = std::fs::read_to_string(frames.join("log.tsv")).unwrap();
    let lit = |file: &str| std::fs::read(frames.join("frames").join(file)).unwrap().iter().any(|&b| b > 0);
    let identify_shown = log.lines().any(|l| {
        let f: Vec<&str> = l.split('\t').collect();
        f.len() == 5 && f[2] == "show" && !lit(f[3]) && lit(f[4])
    });
    assert!(identify_shown, "{log}");

    // And the ledger paid for it, under the bound the example model allows (47.5 lx).
    let (ok, csv_text, err) = appliance(&["ledger", "export", "--csv"], &s.config);
    assert!(ok, "{err}");
    let mut r = csv::Reader::from_reader(csv_text.as_bytes());
    let row = r
        .records()
        .map(Result::unwrap)
        .find(|r| &r[1] == "identify")
        .unwrap_or_else(|| panic!("no identify row in {csv_text}"));
    assert_eq!(&row[2], "identify:1");
    let lux: f64 = row[3].parse().unwrap();
    eprintln!("identify pattern of projector 2: {lux} lx paid");
    assert!(lux > 0.0 && lux <= 47.5, "{lux}");
}

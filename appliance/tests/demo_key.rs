//! A bundle signed with the public demo key, whose public key is in the trust directory (as
//! the demo chain's `trust/demo.pub.pem` is), is refused by `verify`, `install` and `status`
//! unless the operator says otherwise (`--allow-demo-key`, `allow_demo_key = true`): anyone
//! can sign with that key. The refusal names the bundle, the key and the setting.

use std::path::{Path, PathBuf};
use std::process::Command;

use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::keys::{DEMO_KEY_ID, demo_signing_key, public_key_to_pem};

struct Stage {
    _dir: tempfile::TempDir,
    root: PathBuf,
    bundle: PathBuf,
}

impl Stage {
    fn new() -> Stage {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().to_path_buf();
        for d in ["trust", "state", "frames"] {
            std::fs::create_dir(root.join(d)).unwrap();
        }
        let key = demo_signing_key();
        std::fs::write(root.join("trust/demo.pub.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
        let bundle = root.join("demo.restage");
        let spec = ExampleSpec { expires_unix_s: Some(4_102_444_800), ..ExampleSpec::small() };
        example_writer(&spec).unwrap().write(&key, std::fs::File::create(&bundle).unwrap()).unwrap();
        Stage { _dir: dir, root, bundle }
    }

    /// Writes the configuration, with `allow_demo_key` set or not.
    fn config(&self, allow_demo_key: Option<bool>) -> PathBuf {
        let config = self.root.join("appliance.toml");
        let allow = allow_demo_key.map_or(String::new(), |a| format!("allow_demo_key = {a}\n"));
        std::fs::write(
            &config,
            format!(
                "trust_dir = \"{0}/trust\"\n{allow}state_dir = \"{0}/state\"\n[output]\nkind = \"headless\"\ndir = \"{0}/frames\"\n",
                self.root.display()
            ),
        )
        .unwrap();
        config
    }
}

fn appliance(args: &[&str], config: Option<&Path>) -> (bool, String) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_restage-appliance"));
    c.args(args).env("RESTAGE_LOG", "warn");
    if let Some(config) = config {
        c.arg("--config").arg(config);
    }
    let o = c.output().unwrap();
    (
        o.status.success(),
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)),
    )
}

fn names_bundle_key_and_setting(out: &str) {
    assert!(
        out.contains("demo.restage")
            && out.contains(&format!("public demo key {DEMO_KEY_ID}"))
            && out.contains("allow_demo_key = true"),
        "{out}"
    );
}

#[test]
fn verify_refuses_the_demo_key_unless_allowed() {
    let s = Stage::new();
    let (bundle, trust) = (s.bundle.to_str().unwrap(), s.root.join("trust"));
    let trust = trust.to_str().unwrap();
    let (ok, out) = appliance(&["verify", bundle, "--trust", trust], None);
    assert!(!ok, "{out}");
    names_bundle_key_and_setting(&out);
    let (ok, out) = appliance(&["verify", bundle, "--trust", trust, "--allow-demo-key"], None);
    assert!(ok, "{out}");
    assert!(out.contains("signature DEMO KEY — its private half is public"), "{out}");
    assert!(out.contains("OK: signature verified with key") && out.contains("the public DEMO KEY"), "{out}");
}

#[test]
fn install_and_status_refuse_the_demo_key_unless_configured() {
    let s = Stage::new();
    let bundle = s.bundle.to_str().unwrap();
    for allow in [None, Some(false)] {
        let (ok, out) = appliance(&["install", bundle], Some(&s.config(allow)));
        assert!(!ok, "{out}");
        names_bundle_key_and_setting(&out);
        assert!(!s.root.join("state/active.bundle").exists());
    }
    let (ok, out) = appliance(&["install", bundle], Some(&s.config(Some(true))));
    assert!(ok, "{out}");
    assert!(s.root.join("state/active.bundle").exists());
    let (ok, out) = appliance(&["status"], Some(&s.config(Some(true))));
    assert!(ok && !out.contains("REFUSED"), "{out}");
    // The setting taken back: status says the installed bundle would be refused, and why.
    let (ok, out) = appliance(&["status"], Some(&s.config(None)));
    assert!(ok, "{out}");
    assert!(
        out.contains("REFUSED: it is signed with the public demo key") && out.contains("allow_demo_key"),
        "{out}"
    );
}

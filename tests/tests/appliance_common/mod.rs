//! Shared set-up for the appliance's end-to-end tests: a signed bundle from the shared crate's
//! writer with a generated key, a trust directory, a state directory, a headless recorder and
//! a config file; helpers to start the appliance process and to read what it showed.

#![allow(dead_code)]

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use restage_appliance::ledger::Ledger;
use restage_appliance::output::headless::{Record, read_log};
use restage_shared::bundle::example::{ExampleSpec, example_certificate, example_frame, example_info};
use restage_shared::bundle::{BundleWriter, SceneKind};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};
use restage_shared::light::{LightCertificate, LightModel, XrgbFrame, max_irradiance};
use restage_shared::policy::{ExposurePolicy, IdleMode};

/// The process under test (integration tests get its path from cargo; the figures example
/// finds it beside its own directory).
pub const BIN: &str = match option_env!("CARGO_BIN_EXE_restage-appliance-under-test") {
    Some(p) => p,
    None => "restage-appliance-under-test",
};
pub const OBJECT: &str = "test-jar-1";

/// A stage in a temporary folder.
pub struct Stage {
    pub dir: tempfile::TempDir,
    pub spec: ExampleSpec,
    pub light: LightModel,
    pub cert: LightCertificate,
}

impl Stage {
    /// A 3-scene bundle (original + 2 restorations) of `spec`'s size, idle = the original
    /// scene, 1 s showings, no cooldown, large budgets; installed as the active bundle.
    pub fn new(spec: ExampleSpec) -> Stage {
        let dir = tempfile::tempdir().unwrap();
        for d in ["trust", "state", "rec"] {
            std::fs::create_dir(dir.path().join(d)).unwrap();
        }
        let key = signing_key_from_seed([7; 32]);
        std::fs::write(dir.path().join("trust/test.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
        let light = example_info(&spec).light;
        let cert = example_certificate(&spec);
        let stage = Stage { dir, spec, light, cert };
        stage.write_bundle(&stage.spec, OBJECT, &stage.path("state/active.bundle"));
        stage
    }

    /// Writes a bundle of `spec` for `object`, signed with the trusted key: at least three
    /// scenes (the first the original, the others restorations), idle = the original scene,
    /// 1 s showings, no cooldown, large budgets.
    pub fn write_bundle(&self, spec: &ExampleSpec, object: &str, path: &Path) {
        let policy = ExposurePolicy {
            max_showing_s: 1,
            cooldown_s: 0,
            daily_budget_lxh: 1e6,
            annual_budget_lxh: 1e7,
            warn_at: vec![0.75, 0.9],
            idle: IdleMode::Scene("original".into()),
        };
        self.write_bundle_with(spec, object, path, policy);
    }

    /// `write_bundle` with another exposure policy.
    pub fn write_bundle_with(&self, spec: &ExampleSpec, object: &str, path: &Path, policy: ExposurePolicy) {
        let key = signing_key_from_seed([7; 32]);
        let mut info = example_info(spec);
        info.object.id = object.into();
        info.policy = policy;
        let mut w = BundleWriter::new(info, example_certificate(spec));
        for s in 0..spec.scenes.max(3) {
            let frames = (0..spec.projectors).map(|k| example_frame(spec, s, k)).collect();
            let (id, kind) = if s == 0 {
                ("original".to_string(), SceneKind::Original)
            } else {
                (format!("restored-{s}"), SceneKind::Restoration)
            };
            w.add_scene(&id, &id, kind, frames).unwrap();
        }
        // Written beside, then renamed: a running appliance never reads half a file.
        let tmp = path.with_extension("tmp");
        w.write(&key, std::fs::File::create(&tmp).unwrap()).unwrap();
        std::fs::rename(&tmp, path).unwrap();
    }

    pub fn path(&self, p: &str) -> PathBuf {
        self.dir.path().join(p)
    }

    /// Writes `config.toml`: the standard keys plus `extra` TOML (sections appended).
    pub fn config(&self, player: &str, ledger: &str, inputs: &str) -> PathBuf {
        let text = format!(
            "trust_dir = {:?}\nstate_dir = {:?}\n[player]\n{player}\n[ledger]\n{ledger}\n\
             [output]\nkind = \"headless\"\ndir = {:?}\nprojectors = {}\n[inputs]\n{inputs}\n",
            self.path("trust"),
            self.path("state"),
            self.path("rec"),
            self.spec.projectors
        );
        let p = self.path("config.toml");
        std::fs::write(&p, text).unwrap();
        p
    }

    /// Starts the appliance (stdin piped, stdout and stderr to files in the stage).
    pub fn spawn(&self, config: &Path) -> Child {
        Command::new(BIN)
            .args(["run", "--config"])
            .arg(config)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(
                std::fs::OpenOptions::new().create(true).append(true).open(self.path("stderr.log")).unwrap(),
            )
            .spawn()
            .unwrap()
    }

    /// The recorder's log.
    pub fn records(&self) -> Vec<Record> {
        read_log(&self.path("rec")).unwrap_or_default()
    }

    /// Marks "dark from now" in the recorder log (after the test killed the process), with
    /// the test's own reading of the clocks. A kill that came before the recorder wrote its
    /// first line leaves no log yet: create it.
    pub fn mark_dark(&self) {
        let mut f =
            std::fs::OpenOptions::new().create(true).append(true).open(self.path("rec/log.tsv")).unwrap();
        f.write_all(format!("{}\t{}\tblank\n", unix_us(), boot_us()).as_bytes()).unwrap();
    }

    /// Peak lux of a recorded frame set, by the shared crate's bound check on the frames the
    /// recorder wrote (fade frames included).
    pub fn lux_of(&self, frames: &[String], cache: &mut HashMap<Vec<String>, f64>) -> f64 {
        if frames.is_empty() {
            return 0.0;
        }
        if let Some(l) = cache.get(frames) {
            return *l;
        }
        let bytes: Vec<Vec<u8>> =
            frames.iter().map(|f| std::fs::read(self.path("rec/frames").join(f)).unwrap()).collect();
        let refs: Vec<XrgbFrame<'_>> = bytes
            .iter()
            .map(|b| XrgbFrame { width: self.spec.width, height: self.spec.height, xrgb: b })
            .collect();
        let lux = max_irradiance(&self.light, &self.cert, &refs).unwrap().lux;
        cache.insert(frames.to_vec(), lux);
        lux
    }

    /// Every lit stretch the recorder saw must be covered, at every instant, by ledger rows
    /// paying at least its lux (reserved before it began; committed after it ended, or
    /// handed over to a new reservation first). The recorder's times are CLOCK_BOOTTIME,
    /// read by the kernel for the recorder and for this test, never through the appliance's
    /// clock; each run's anchor in the ledger maps them onto ledger time. Returns how many
    /// stretches were checked.
    pub fn assert_every_lit_stretch_paid(&self, ledger: &Ledger) -> usize {
        self.assert_paid(ledger, &self.records())
    }

    /// `assert_every_lit_stretch_paid` over `recs` (a prefix of the records, say).
    pub fn assert_paid(&self, ledger: &Ledger, recs: &[Record]) -> usize {
        let rows = ledger.exposure_rows(OBJECT).unwrap();
        let runs = ledger.runs().unwrap();
        let mut cache = HashMap::new();
        let mut checked = 0;
        for w in recs.windows(2) {
            let lux = self.lux_of(&w[0].frames, &mut cache);
            if lux <= 0.0 {
                continue;
            }
            let Some(from_us) = ledger_us(&runs, w[0].boot_us) else {
                panic!("light at boot {} us before any run was recorded", w[0].boot_us)
            };
            let to_us = from_us + (w[1].boot_us as i128 - w[0].boot_us as i128);
            let mut paying: Vec<(i128, i128)> = rows
                .iter()
                .filter(|r| r.lux >= lux * (1.0 - 1e-9))
                .map(|r| (i128::from(r.start_ms) * 1000, i128::from(r.end_ms) * 1000))
                .filter(|&(s, e)| e >= from_us && s <= to_us)
                .collect();
            paying.sort();
            // Sweep: the covered prefix of [from, to] must reach `to` without a gap.
            let mut covered = from_us;
            for (s, e) in paying {
                if s <= covered {
                    covered = covered.max(e);
                }
            }
            assert!(
                covered >= to_us,
                "light of {lux} lx from {from_us} to {to_us} us (ledger time; {:?}) is paid only until {covered} us \
                 ({} us unpaid)",
                w[0].frames,
                to_us - covered
            );
            checked += 1;
        }
        checked
    }

    /// The exposure (lx·h) the recorder saw: each record's light until the next record.
    pub fn true_exposure(&self) -> f64 {
        let recs = self.records();
        let mut cache = HashMap::new();
        let mut lux_us = 0.0;
        for w in recs.windows(2) {
            let dt = w[1].boot_us.saturating_sub(w[0].boot_us) as f64;
            lux_us += self.lux_of(&w[0].frames, &mut cache) * dt;
        }
        lux_us / 3.6e9
    }

    /// Lit stretches showing anything but the idle frames (restorations and their fades), in
    /// ms, by the recorder's clock. `idle`: the idle scene's frame files, if it is lit.
    pub fn showing_stretches_ms(&self, idle: Option<&[String]>) -> Vec<f64> {
        let (mut out, mut since) = (Vec::new(), None);
        for r in self.records() {
            if !r.frames.is_empty() && idle.is_none_or(|i| r.frames != i) {
                since.get_or_insert(r.boot_us);
            } else if let Some(s) = since.take() {
                out.push((r.boot_us - s) as f64 / 1000.0);
            }
        }
        out
    }

    /// The first frames the recorder saw lit (the idle scene, where it is lit).
    pub fn first_lit(&self) -> Vec<String> {
        self.records().into_iter().find(|r| !r.frames.is_empty()).map(|r| r.frames).unwrap_or_default()
    }

    /// Peak lux of scene `s` of the stage's bundle (0: the original, the idle scene).
    pub fn scene_lux(&self, s: usize) -> f64 {
        let frames: Vec<Vec<u8>> =
            (0..self.spec.projectors).map(|k| example_frame(&self.spec, s, k)).collect();
        let refs: Vec<XrgbFrame<'_>> = frames
            .iter()
            .map(|b| XrgbFrame { width: self.spec.width, height: self.spec.height, xrgb: b })
            .collect();
        max_irradiance(&self.light, &self.cert, &refs).unwrap().lux
    }
}

/// Ledger time (us) of a boot-clock instant: the latest run anchored at or before it.
pub fn ledger_us(runs: &[(i64, u64)], boot_us: u64) -> Option<i128> {
    runs.iter()
        .rev()
        .find(|(_, b)| u128::from(*b) * 1000 <= u128::from(boot_us))
        .map(|&(l, b)| i128::from(l) * 1000 + (i128::from(boot_us) - i128::from(b) * 1000))
}

/// Now, CLOCK_BOOTTIME microseconds, read by this process.
pub fn boot_us() -> u64 {
    restage_appliance::clock::boot_us()
}

/// Now, Unix microseconds.
pub fn unix_us() -> u128 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_micros()
}

/// Sends one line to the control socket and returns the answer, retrying the connection
/// until `timeout` (the appliance may still be starting).
pub fn ask(socket: &Path, command: &str, timeout: Duration) -> Option<String> {
    let start = Instant::now();
    while start.elapsed() < timeout {
        if let Ok(mut s) = std::os::unix::net::UnixStream::connect(socket) {
            s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            if s.write_all(format!("{command}\n").as_bytes()).is_ok() {
                let mut line = String::new();
                if BufReader::new(s).read_line(&mut line).is_ok() && !line.is_empty() {
                    return Some(line.trim_end().to_string());
                }
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    None
}

/// Waits until the control socket's status satisfies `f`.
pub fn wait_status(
    socket: &Path,
    timeout: Duration,
    f: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let s = ask(socket, "status", Duration::from_secs(5)).expect("status answer");
        let v: serde_json::Value = serde_json::from_str(&s).expect("status is JSON");
        if f(&v) {
            return v;
        }
        assert!(start.elapsed() < timeout, "status never matched; last: {v}");
        std::thread::sleep(Duration::from_millis(30));
    }
}

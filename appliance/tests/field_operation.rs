//! An unattended stage as an operator meets it, through the real program: PJLink projector
//! simulators on loopback (one reporting a lamp error), the status page read with a real HTTP
//! client, opening hours in the museum's time zone. Open: the projectors are powered on, the
//! page says idle and lists them, the lamp error is an alert; a stop mutes the projectors (the
//! second dark layer) and so does the program's exit. Closed: the projectors go to standby,
//! the page says closed and a press is refused.

mod common;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use common::Running;

use restage_appliance::pjlink::PowerState;
use restage_appliance::pjlink::sim::{Fault, SimConfig, SimProjector};
use restage_shared::bundle::example::{ExampleSpec, example_writer};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};

struct Stage {
    dir: tempfile::TempDir,
    port: u16,
}

/// One test of this file at a time, held from before its simulators take their ports: the
/// status page's port is picked free and bound by the appliance only a moment later, so a
/// test running beside could take the same one (seen once in CI: one test read the other's
/// page). A test that failed while holding it leaves nothing the next one minds.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

impl Stage {
    fn new(hours: &str, projectors: &[&SimProjector]) -> Stage {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        for d in ["trust", "state", "rec"] {
            std::fs::create_dir(root.join(d)).unwrap();
        }
        let key = signing_key_from_seed([9; 32]);
        std::fs::write(root.join("trust/k.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
        let spec = ExampleSpec { expires_unix_s: Some(4_102_444_800), ..ExampleSpec::small() };
        example_writer(&spec)
            .unwrap()
            .write(&key, std::fs::File::create(root.join("state/active.bundle")).unwrap())
            .unwrap();
        // A free port for the status page (taken back by the appliance a moment later).
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let mut pj =
            String::from("[pjlink]\npoll_s = 1\nbusy_poll_ms = 100\ntimeout_ms = 500\nretry_max_s = 1\n");
        for (i, p) in projectors.iter().enumerate() {
            pj.push_str(&format!(
                "[[pjlink.projectors]]\naddress = \"{}\"\nname = \"p{}\"\n",
                p.address(),
                i + 1
            ));
        }
        let config = format!(
            "name = \"Gallery 3, retable\"\ntrust_dir = {:?}\nstate_dir = {:?}\ntime_zone = \"Europe/Amsterdam\"\n\
             [output]\nkind = \"headless\"\ndir = {:?}\nprojectors = 2\n\
             [inputs]\ncontrol_socket = {:?}\n[status]\nenabled = true\nlisten = \"127.0.0.1:{port}\"\n\
             {pj}[hours]\n{hours}\n",
            root.join("trust"),
            root.join("state"),
            root.join("rec"),
            root.join("control.sock"),
        );
        std::fs::write(root.join("config.toml"), config).unwrap();
        Stage { dir, port }
    }

    fn path(&self, p: &str) -> PathBuf {
        self.dir.path().join(p)
    }

    fn start(&self) -> Running {
        Running::start(&self.path("config.toml"))
    }

    fn get(&self, path: &str) -> Option<String> {
        let agent: ureq::Agent =
            ureq::Agent::config_builder().timeout_global(Some(Duration::from_secs(5))).build().into();
        let mut r = agent.get(format!("http://127.0.0.1:{}{path}", self.port)).call().ok()?;
        r.body_mut().read_to_string().ok()
    }

    /// Waits until `/status.json` satisfies `f`.
    fn wait_status(&self, f: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
        let start = Instant::now();
        let mut last = serde_json::Value::Null;
        while start.elapsed() < Duration::from_secs(30) {
            if let Some(v) = self.get("/status.json").and_then(|t| serde_json::from_str(&t).ok()) {
                if f(&v) {
                    return v;
                }
                last = v;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!("the status page never matched; last: {last:#}");
    }

    fn ask(&self, command: &str) -> String {
        common::ask(&self.path("control.sock"), command, Duration::from_secs(20)).expect("an answer")
    }
}

fn wait_for(what: &str, f: impl Fn() -> bool) {
    let start = Instant::now();
    while !f() {
        assert!(start.elapsed() < Duration::from_secs(30), "timed out waiting: {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn projector<'a>(v: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    v["projectors"]
        .as_array()
        .and_then(|a| a.iter().find(|p| p["name"] == name))
        .unwrap_or(&serde_json::Value::Null)
}

/// The simulators run on this runtime's threads while the test thread waits.
fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap()
}

#[test]
fn open_stage_powers_the_projectors_reports_them_and_mutes_when_dark() {
    let _serial = serial();
    let rt = runtime();
    let good = rt.block_on(SimProjector::start(SimConfig::default())).unwrap();
    let lamp = rt
        .block_on(SimProjector::start(SimConfig { fault: Fault::LampError, seed: 2, ..SimConfig::default() }))
        .unwrap();
    let every_day: String = ["mon", "tue", "wed", "thu", "fri", "sat", "sun"]
        .iter()
        .map(|d| format!("{d} = [\"00:00-24:00\"]\n"))
        .collect();
    let stage = Stage::new(&every_day, &[&good, &lamp]);
    let mut run = stage.start();

    // Powered on (after its warm-up), and unmuted: light is wanted while open.
    wait_for("projector 1 on", || good.power() == PowerState::On);
    let v = stage.wait_status(|v| {
        v["state"]["kind"] == "idle"
            && projector(v, "p1")["power"] == "on"
            && projector(v, "p1")["muted"] == false
    });
    assert_eq!(v["opening"]["open"], true, "{v:#}");
    assert_eq!(v["clock"]["zone"], "Europe/Amsterdam");
    assert_eq!(v["appliance"]["name"], "Gallery 3, retable");
    assert_eq!(v["bundle"]["status"], "loaded");
    assert_eq!(v["bundle"]["object_id"], "test-jar-1");
    assert!(good.commands().iter().any(|c| c.contains("POWR 1")), "{:?}", good.commands());

    // The lamp error is on the page, per projector and as an alert.
    let v = stage
        .wait_status(|v| v["alerts"].as_array().is_some_and(|a| a.iter().any(|x| x["kind"] == "projector")));
    assert!(projector(&v, "p2")["errors"].as_array().is_some_and(|e| !e.is_empty()), "{v:#}");
    let metrics = stage.get("/metrics").unwrap();
    assert!(metrics.contains("restage_projector_reachable{projector=\"p1\"} 1"), "{metrics}");
    assert!(stage.get("/").unwrap().contains("p2"));

    // Operator stop: the outputs go dark and the projectors mute as a second layer.
    assert_eq!(stage.ask("stop"), "ok dark");
    wait_for("projector 1 muted after stop", || good.mute().video);
    // A reload brings light back, and the mute comes off.
    assert!(stage.ask("reload").starts_with("ok"));
    wait_for("projector 1 unmuted after reload", || !good.mute().video);

    // The program's exit leaves the projectors muted.
    run.stop();
    assert!(good.mute().video, "muted at exit");
}

#[test]
fn closed_stage_keeps_the_projectors_in_standby_and_refuses_presses() {
    let _serial = serial();
    let rt = runtime();
    let sim = rt
        .block_on(SimProjector::start(SimConfig { power: PowerState::On, ..SimConfig::default() }))
        .unwrap();
    // Open on one day in 2099 only: closed now.
    let stage = Stage::new("[hours.open_dates]\n\"2099-01-01\" = [\"10:00-17:00\"]\n", &[&sim]);
    let _run = stage.start();
    wait_for("standby", || sim.power() == PowerState::Off);
    let v = stage.wait_status(|v| v["state"]["kind"] == "closed");
    assert_eq!(v["opening"]["open"], false, "{v:#}");
    let answer = stage.ask("press");
    assert!(answer.contains("closed"), "{answer}");
    // Never told to power on.
    assert!(!sim.commands().iter().any(|c| c.contains("POWR 1")), "{:?}", sim.commands());
}

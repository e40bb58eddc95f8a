//! The appliance's figures, printed (not asserted): press-to-frame latency in the headless
//! output, resident memory with a 3-scene bundle of 3 x 1400x1050 projectors, and CPU used
//! while idle over 60 s. Run after building the process under test:
//! `cargo build -p restage-tests --bin restage-appliance-under-test &&
//!  cargo run -p restage-tests --example appliance_figures`

#[path = "../tests/appliance_common/mod.rs"]
mod appliance_common;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use appliance_common::{Stage, ask, unix_us, wait_status};
use restage_shared::bundle::example::ExampleSpec;

fn proc_field(pid: u32, key: &str) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    s.lines().find(|l| l.starts_with(key)).and_then(|l| l.split_whitespace().nth(1)).unwrap().parse().unwrap()
}

fn cpu_ticks(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    let after = &s[s.rfind(')').unwrap() + 2..];
    let f: Vec<&str> = after.split_whitespace().collect();
    f[11].parse::<u64>().unwrap() + f[12].parse::<u64>().unwrap()
}

fn main() {
    let bin = std::env::current_exe()
        .unwrap()
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .join("restage-appliance-under-test");
    assert!(bin.exists(), "build it first: cargo build -p restage-tests --bin restage-appliance-under-test");
    let spec = ExampleSpec {
        projectors: 3,
        scenes: 3,
        width: 1400,
        height: 1050,
        step: 8,
        lux_per_unit: 10.0,
        ..ExampleSpec::small()
    };
    eprintln!("writing a 3-scene bundle of 3 x 1400x1050 ...");
    let stage = Stage::new(spec);
    let sock: PathBuf = stage.path("control.sock");
    // Idle off, so the idle figures are the appliance's own, not idle light renewals.
    let config = stage.config(
        "idle = \"off\"\nfade_ms = 0\nmin_press_interval_ms = 0\nmax_showing_ms = 200",
        "",
        &format!("control_socket = {sock:?}"),
    );
    let mut child = std::process::Command::new(&bin).args(["run", "--config"]).arg(&config).spawn().unwrap();
    let pid = child.id();
    let t = Instant::now();
    wait_status(&sock, Duration::from_secs(120), |v| v["state"] == "idle");
    eprintln!("start to idle (verify + load): {:.0} ms", t.elapsed().as_secs_f64() * 1e3);

    // Press to frame: the control socket's press, to the recorder's timestamp of the frame.
    let mut lat = Vec::new();
    for _ in 0..20 {
        wait_status(&sock, Duration::from_secs(10), |v| v["state"] == "idle");
        let n = stage.records().len();
        let t0 = unix_us();
        ask(&sock, "press", Duration::from_secs(5)).unwrap();
        let recs = stage.records();
        let shown = recs[n..].iter().find(|r| !r.frames.is_empty()).expect("a frame after the press");
        lat.push((shown.unix_us - t0) as f64 / 1000.0);
    }
    lat.sort_by(f64::total_cmp);
    println!(
        "press to frame (headless, 3 x 1400x1050): median {:.2} ms, max {:.2} ms over {} presses",
        lat[lat.len() / 2],
        lat[lat.len() - 1],
        lat.len()
    );
    wait_status(&sock, Duration::from_secs(10), |v| v["state"] == "idle");
    println!(
        "resident memory: VmRSS {} kB now, VmHWM {} kB peak",
        proc_field(pid, "VmRSS:"),
        proc_field(pid, "VmHWM:")
    );

    let hz = 100.0; // USER_HZ on Linux
    let c0 = cpu_ticks(pid);
    std::thread::sleep(Duration::from_secs(60));
    let c1 = cpu_ticks(pid);
    println!(
        "idle CPU over 60 s: {:.3} s ({:.3} %)",
        (c1 - c0) as f64 / hz,
        (c1 - c0) as f64 / hz / 60.0 * 100.0
    );
    println!("resident memory after idle: VmRSS {} kB", proc_field(pid, "VmRSS:"));
    let _ = child.kill();
    let _ = child.wait();
}

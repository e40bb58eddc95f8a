//! Memory against frame size: the appliance with a bundle of 3 x 1920x1200 projectors, taken
//! through start, idle, a showing with its cross-fade, cycling every scene, and a reload of a
//! second bundle of the same size. Its peak resident memory (VmHWM) must stay within
//! `restage_appliance::memory::need`, the figure the README's table and the unit's
//! `MemoryMax` come from.

mod appliance_common;

use std::time::Duration;

use appliance_common::{BIN, OBJECT, Stage, ask, wait_status};
use restage_appliance::memory;
use restage_shared::bundle::example::{ExampleSpec, example_certificate};

fn vm_kb(pid: u32, key: &str) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    s.lines().find(|l| l.starts_with(key)).and_then(|l| l.split_whitespace().nth(1)).unwrap().parse().unwrap()
}

#[test]
fn peak_memory_at_3x1920x1200_stays_within_the_formula() {
    let spec = ExampleSpec {
        projectors: 3,
        scenes: 4,
        width: 1920,
        height: 1200,
        step: 8,
        lux_per_unit: 10.0,
        ..ExampleSpec::small()
    };
    let stage = Stage::new(spec.clone());
    let sock = stage.path("control.sock");
    let config = stage.config(
        "fade_ms = 300\nfade_fps = 10\nmin_press_interval_ms = 0\nmax_showing_ms = 1000",
        "",
        &format!("control_socket = {sock:?}"),
    );
    let mut child = std::process::Command::new(BIN)
        .args(["run", "--config"])
        .arg(&config)
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    let mut phases = Vec::new();
    wait_status(&sock, Duration::from_secs(120), |v| v["state"] == "idle");
    phases.push(("idle", vm_kb(pid, "VmRSS:")));
    // A showing cycling through every restoration, then its fade.
    assert!(ask(&sock, "press", Duration::from_secs(5)).unwrap().contains("showing"));
    for _ in 0..3 {
        std::thread::sleep(Duration::from_millis(150));
        ask(&sock, "press", Duration::from_secs(5)).unwrap();
    }
    phases.push(("showing", vm_kb(pid, "VmRSS:")));
    wait_status(&sock, Duration::from_secs(10), |v| v["state"] == "idle" || v["state"] == "cooldown");
    phases.push(("after fade", vm_kb(pid, "VmRSS:")));
    // A reload of a newer bundle of the same size.
    let next = ExampleSpec { version: spec.version + 1, ..spec.clone() };
    stage.write_bundle(&next, OBJECT, &stage.path("state/active.bundle"));
    assert!(ask(&sock, "reload", Duration::from_secs(120)).unwrap().starts_with("ok"));
    wait_status(&sock, Duration::from_secs(10), |v| v["bundle"]["version"] == next.version);
    phases.push(("after reload", vm_kb(pid, "VmRSS:")));
    let peak_kb = vm_kb(pid, "VmHWM:");
    let _ = child.kill();
    let _ = child.wait();

    let sizes = vec![(spec.width, spec.height); spec.projectors];
    let points = u64::from(example_certificate(&spec).points);
    let need = memory::need(&sizes, points, false);
    eprintln!(
        "FIGURES memory: 3 x 1920x1200, {points} certificate points: {phases:?} kB RSS; peak {peak_kb} kB; \
         formula {} kB (frames {} kB)",
        need.total_bytes / 1024,
        need.frame_bytes / 1024
    );
    assert!(peak_kb * 1024 <= need.total_bytes, "peak {peak_kb} kB above the formula's {need:?}");
}

//! The DRM/KMS output on an emulated three-head stage machine: QEMU (software emulation)
//! boots a stock Debian kernel with a virtio-gpu of three outputs; the appliance binary runs
//! inside as DRM master with its serial button input on the guest's second serial port. The
//! test presses the button through that port and reads every head's picture with QMP
//! `screendump`: the original scene after start, the restoration pixel for pixel after a
//! press, the original again after the exposure timer, a projector unplugged and plugged back
//! (hot-plug, through the connector's sysfs `status`), a DRM change uevent re-probing and
//! keeping every head, a bundle of a size no head offers
//! refused without advancing the anti-rollback record, a second DRM master refused, a start
//! with one projector unplugged (set up when it appears), and every head black (not the
//! console) after SIGKILL. It prints the start-to-first-light and press-to-flip figures from the
//! appliance's flip-event log.
//!
//! Needs `qemu-system-x86_64` and the tools of `tests/qemu/prepare.sh` (apt packages
//! `qemu-system-x86 busybox-static cpio kmod xz-utils`); `RESTAGE_SKIP_QEMU=1` skips it.

mod qemu_common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use qemu_common::{Boot, H, HEADS, MACHINE, Qmp, W, expect_heads, field, spec, stamp_s};
use restage_appliance::output::kms::xrgb8888_to_rgb8;
use restage_shared::bundle::example::{ExampleSpec, example_frame};

/// Length of a showing (the exposure timer), seconds.
const SHOWING_S: u32 = 3;
/// Width of a bundle no head can show (no standard mode is 624 wide).
const BAD_W: u32 = 624;

/// Trust key, bundle (original + one restoration, short showings) and config for the guest.
fn payload(dir: &Path, atomic: bool) {
    qemu_common::write_trust(&dir.join("trust"));
    std::fs::create_dir_all(dir.join("state")).unwrap();
    let spec = spec();
    let policy = qemu_common::policy(SHOWING_S);
    // The bundle played, and a newer one of a frame size no head offers.
    let odd = ExampleSpec { width: BAD_W, version: spec.version + 1, ..spec.clone() };
    qemu_common::write_bundle(&dir.join("state/active.bundle"), &spec, &policy);
    qemu_common::write_bundle(&dir.join("bad.bundle"), &odd, &policy);
    let config = "trust_dir = \"/restage/trust\"\nstate_dir = \"/var/lib/restage\"\n\
                  [player]\nfade_ms = 300\nfade_fps = 10\nmin_press_interval_ms = 100\n\
                  [output]\nkind = \"kms\"\ncard = \"/dev/dri/card0\"\n\
                  connectors = [\"Virtual-1\", \"Virtual-2\", \"Virtual-3\"]\n\
                  [inputs.serial]\npath = \"/dev/ttyS1\"\nbaud = 115200\n";
    let config = config.replace("[inputs.serial]", &format!("atomic = {atomic}\n[inputs.serial]"));
    std::fs::write(dir.join("config.toml"), config).unwrap();
}

#[test]
fn atomic_three_heads_original_restoration_timer_hotplug_second_master_and_black_after_kill() {
    let _one = MACHINE.lock().unwrap_or_else(|e| e.into_inner());
    scenario(true);
}

#[test]
fn legacy_modeset_three_heads_same_scenario() {
    let _one = MACHINE.lock().unwrap_or_else(|e| e.into_inner());
    scenario(false);
}

fn scenario(atomic: bool) {
    if qemu_common::skipped("the emulated three-head test") {
        return;
    }
    let t0 = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    payload(&d.join("payload"), atomic);
    let vm = qemu_common::prepare(d, &d.join("payload"), None);

    let (qmp_path, serial_path): (PathBuf, PathBuf) = (d.join("qmp.sock"), d.join("button.sock"));
    // fbcon=map:9 maps the console to a framebuffer that does not exist: what the README's
    // install section prescribes, so no head shows console text when the appliance is gone.
    // RESTAGE_QEMU_FBCON overrides it (e.g. "fbcon=nodefer") to watch the test catch the
    // console.
    let fbcon = std::env::var("RESTAGE_QEMU_FBCON").unwrap_or_else(|_| "fbcon=map:9".into());
    let accel = qemu_common::accel();
    let (_guest, mut con) = qemu_common::boot(Boot {
        vm: &vm,
        append: fbcon,
        button: serial_path.clone(),
        qmp: Some(qmp_path.clone()),
        args: Vec::new(),
        echo: true,
    });
    let boot = Instant::now();
    let mut qmp = Qmp::connect(&qmp_path);

    let started = con.wait_for(&["appliance starting"], Duration::from_secs(120));
    let first = con.wait_for(&["first light"], Duration::from_secs(60));
    con.wait_for(&["appliance running"], Duration::from_secs(60));
    eprintln!("guest booted and appliance running after {:.1} s", boot.elapsed().as_secs_f64());

    let spec = spec();
    let scene = |s: usize| -> Vec<Vec<u8>> {
        (0..HEADS).map(|k| xrgb8888_to_rgb8(&example_frame(&spec, s, k))).collect()
    };
    let (original, restored) = (scene(0), scene(1));
    assert_ne!(original, restored);
    let shots = d.join(if atomic { "atomic" } else { "legacy" });
    std::fs::create_dir_all(&shots).unwrap();
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &original,
        Duration::from_secs(10),
        "the original scene after start",
    );

    let mut button = qemu_common::button(&serial_path);
    button.write_all(b"PRESS\n").unwrap();
    let press = con.wait_for(&["press", "source=\"serial\""], Duration::from_secs(20));
    let flip = con.wait_for(&["page flip complete", "lit=true"], Duration::from_secs(20));
    // The showing lasts SHOWING_S; screendumps take a fraction of that.
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &restored,
        Duration::from_millis(500),
        "the restoration after PRESS",
    );

    // The exposure timer ends the showing (then a 0.3 s fade) and the original returns.
    con.wait_for(&["showing ended", "timer"], Duration::from_secs(20));
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &original,
        Duration::from_secs(20),
        "the original after the exposure timer",
    );

    // Hot-plug: projector 2 disappears (its connector forced off through sysfs; the
    // appliance notices by its HOTPLUG uevent or, as virtio-gpu sends none for this, by its
    // connector-state watch) and its output is switched off.
    con.command("unplug Virtual-2");
    con.wait_for(&["projector lost", "Virtual-2"], Duration::from_secs(20));
    let start = Instant::now();
    while qmp.screendump(&shots, 1).2 == original[1] {
        assert!(start.elapsed() < Duration::from_secs(5), "the unplugged head still shows the scene");
        std::thread::sleep(Duration::from_millis(100));
    }
    // A press while it is gone: the other two show the restoration.
    button.write_all(b"PRESS\n").unwrap();
    con.wait_for(&["page flip complete", "heads=2", "lit=true"], Duration::from_secs(20));
    expect_heads(
        &mut qmp,
        &shots,
        Some(&[0, 2]),
        &restored,
        Duration::from_millis(500),
        "the restoration on the remaining heads",
    );
    // It comes back during the showing and is set up again, without a restart, with the
    // frame it should show now (the restoration), not the one it had when it left.
    con.command("plug Virtual-2");
    con.wait_for(&["set up again after hot-plug", "Virtual-2"], Duration::from_secs(20));
    expect_heads(
        &mut qmp,
        &shots,
        Some(&[1]),
        &restored,
        Duration::from_millis(500),
        "the returning head shows the current scene",
    );
    con.wait_for(&["showing ended", "timer"], Duration::from_secs(20));
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &original,
        Duration::from_secs(20),
        "the original on all heads after re-plug",
    );

    // A second appliance on the same card is refused (one DRM master) and the first keeps on.
    con.command("second");
    let refused = con.wait_for(&["second appliance exited"], Duration::from_secs(30));
    assert!(!refused.contains("status 0"), "{refused}");
    assert!(
        con.seen.iter().any(|l| l.contains("cannot become DRM master")),
        "the second appliance did not name the DRM master problem"
    );
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &original,
        Duration::from_secs(2),
        "the first appliance still shows",
    );

    // The uevent path (virtio-gpu sends no uevent for the sysfs toggles above, so the
    // connector-state watch noticed those): a DRM change uevent (here a synthetic one, as
    // `udevadm trigger` sends; the kernel gives synthetic events no HOTPLUG=1) makes the
    // appliance re-probe, and with nothing changed every head is kept as it is.
    con.command("uevent");
    con.wait_for(&["DRM change uevent"], Duration::from_secs(20));
    con.wait_for(&["connectors re-probed", "plan=[Keep, Keep, Keep]"], Duration::from_secs(20));

    // A newer bundle whose frame size no projector offers is refused, naming the connector
    // and what it offers; the picture stays, and the refusal does not advance the
    // anti-rollback record (the current bundle, an older version, still loads afterwards).
    con.command("load bad");
    con.wait_for(&["refused", &format!("offers no {BAD_W}x{H} mode")], Duration::from_secs(30));
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &original,
        Duration::from_secs(2),
        "the picture after a refused bundle",
    );
    con.command("load good");
    con.wait_for(&["bundle verified and loaded", "version=3"], Duration::from_secs(30));
    expect_heads(&mut qmp, &shots, None, &original, Duration::from_secs(10), "the original after reloading");

    // A projector off when the appliance starts: the others play, and it is set up when it
    // appears (no refusal to start, no restart needed).
    con.command("unplug Virtual-3");
    con.wait_for(&["projector lost", "Virtual-3"], Duration::from_secs(20));
    con.command("restart");
    con.wait_for(&["projector not connected", "Virtual-3"], Duration::from_secs(60));
    con.wait_for(&["appliance running"], Duration::from_secs(60));
    expect_heads(
        &mut qmp,
        &shots,
        Some(&[0, 1]),
        &original,
        Duration::from_secs(10),
        "the original on the connected heads after a start without projector 3",
    );
    con.command("plug Virtual-3");
    con.wait_for(&["set up again after hot-plug", "Virtual-3"], Duration::from_secs(20));
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &original,
        Duration::from_secs(5),
        "all three heads once projector 3 appears",
    );

    // SIGKILL: no chance to blank. The kernel restores its fbdev console framebuffer, which
    // fbcon=map:9 keeps empty: every head must be black, not console text.
    con.command("kill");
    con.wait_for(&["GUEST: appliance killed"], Duration::from_secs(20));
    let black = vec![0u8; (W * H * 3) as usize];
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &vec![black; HEADS],
        Duration::from_secs(10),
        "every head black after SIGKILL",
    );
    con.command("off");

    let (start_us, first_us) = (field(&started, "mono_us").unwrap(), field(&first, "flip_mono_us").unwrap());
    let (press_us, flip_us) = (field(&press, "mono_us").unwrap(), field(&flip, "flip_mono_us").unwrap());
    assert!(
        first_us > start_us && flip_us > press_us,
        "timestamps out of order: {started} {first} {press} {flip}"
    );
    let commit_us = field(&flip, "commit_mono_us").unwrap();
    eprintln!(
        "FIGURES ({} modeset, emulated machine, {accel}): appliance start to first light {:.1} ms; \
         press to page-flip completion {:.1} ms (press to commit {:.1} ms, commit to flip event {:.1} ms); \
         whole test {:.1} s",
        if atomic { "atomic" } else { "legacy" },
        (first_us - start_us) as f64 / 1000.0,
        (flip_us - press_us) as f64 / 1000.0,
        (commit_us - press_us) as f64 / 1000.0,
        (flip_us - commit_us) as f64 / 1000.0,
        t0.elapsed().as_secs_f64()
    );
    // Where start-up time goes (guest wall clock of the log lines).
    let at = |what: &str| con.seen.iter().find(|l| l.contains(what)).and_then(|l| stamp_s(l));
    if let (Some(a), Some(m), Some(l), Some(f)) =
        (at("appliance starting"), at("DRM master"), at("projector mode chosen"), at("first light"))
    {
        eprintln!(
            "FIGURES start-up breakdown: to DRM master {:.0} ms, then ledger open + bundle verification {:.0} ms, then modes + first flip {:.0} ms",
            (m - a) * 1000.0,
            (l - m) * 1000.0,
            (f - l) * 1000.0
        );
    }
    if !atomic {
        assert!(con.seen.iter().any(|l| l.contains("atomic=false")), "the legacy path was not taken");
    }
}

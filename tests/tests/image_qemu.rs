//! The stage machine's image (`tools/image/build.sh`) on the emulated three-head machine: QEMU
//! with UEFI firmware (OVMF) boots the image from a virtio disk, provisioned as a museum would
//! (`tools/image/provision.sh`: configuration, trust key and bundle on the data partition).
//! Every head's picture is read with QMP `screendump` from the moment of power-on: nothing but
//! no signal, black, or the original scene fading in may appear (no boot loader or kernel text,
//! no login prompt; the emulated firmware's own screen is told apart and timed); then the
//! original scene, the restoration after a serial PRESS, the original after the exposure
//! timer. The service console on the first serial port is used as staff would: it reports a
//! read-only squashfs root from slot A, the data partition at /var grown to the disk's end, the
//! appliance active, a persistent journal and the hardware watchdog armed. Then a USB stick
//! plugged in through QMP: its new bundle installed and shown, its tampered one refused; a
//! second stick beside it refused by name, the first left mounted; pulled out, unmounted; a
//! stick with a file system the stage does not take refused by name. Then image updates from a second disk
//! (a stick): an unsigned and a corrupt one refused with nothing written, a signed one whose
//! appliance cannot start tried once and rolled back to v1 by the machine itself, a good one
//! booted, marked good, with the ledger's rows intact. Prints the figures.
//!
//! Needs `RESTAGE_IMAGE` (the `.img` that `tools/image/build.sh` wrote; `.ci/run` builds it),
//! `qemu-system-x86_64`, OVMF (`ovmf`) and the image tools (`tools/image/host-packages`);
//! `RESTAGE_SKIP_QEMU=1` or `RESTAGE_SKIP_IMAGE=1` (`.ci/run` without root) skips it.

mod qemu_common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use qemu_common::{H, HEADS, MACHINE, Qmp, W, expect_heads, spec};
use restage_appliance::output::kms::xrgb8888_to_rgb8;
use restage_appliance::sysupdate;
use restage_shared::bundle::example::{ExampleSpec, example_frame};
use restage_shared::keys::{SigningKey, public_key_to_pem, signing_key_from_seed};

/// Length of a showing (the exposure timer), seconds.
const SHOWING_S: u32 = 3;
/// How much larger than the image the emulated machine's disk is.
const GROWN: u64 = 1 << 30;
/// OVMF as Debian's `ovmf` package installs it.
const OVMF_CODE: &str = "/usr/share/OVMF/OVMF_CODE_4M.fd";
const OVMF_VARS: &str = "/usr/share/OVMF/OVMF_VARS_4M.fd";

/// The key the test's image updates are signed with (its public half is on the data
/// partition's update-trust).
fn update_key() -> SigningKey {
    signing_key_from_seed([9; 32])
}

fn run(cmd: &mut Command) {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// What the museum puts on the data partition (mounted at /var on the machine): the
/// configuration and trust key (`/etc/restage` points to `lib/restage-etc`) and the bundle in
/// the appliance's state folder (a `DynamicUser=` service's, under `lib/private`).
fn data_partition(dir: &Path) {
    let etc = dir.join("lib/restage-etc");
    qemu_common::write_trust(&etc.join("trust"));
    std::fs::create_dir_all(etc.join("update-trust")).unwrap();
    std::fs::write(etc.join("update-trust/vendor.pem"), public_key_to_pem(&update_key().verifying_key()))
        .unwrap();
    let state = dir.join("lib/private/restage");
    std::fs::create_dir_all(&state).unwrap();
    std::os::unix::fs::symlink("private/restage", dir.join("lib/restage")).unwrap();
    qemu_common::write_bundle(&state.join("active.bundle"), &spec(), &qemu_common::policy(SHOWING_S));
    let config = "trust_dir = \"/etc/restage/trust\"\nstate_dir = \"/var/lib/restage\"\n\
                  inbox_dir = \"/media/stick\"\n\
                  [player]\nfade_ms = 300\nfade_fps = 10\nmin_press_interval_ms = 100\n\
                  [output]\nkind = \"kms\"\ncard = \"/dev/dri/card0\"\n\
                  connectors = [\"Virtual-1\", \"Virtual-2\", \"Virtual-3\"]\natomic = true\n\
                  [inputs.serial]\npath = \"/dev/ttyS1\"\nbaud = 115200\n";
    std::fs::write(etc.join("appliance.toml"), config).unwrap();
}

/// What a head may show before the appliance's picture is up: no signal (QEMU's placeholder,
/// `no_signal`), black of any size, or a frame of the scene's size nowhere brighter than the
/// scene (the appliance fading in).
fn dark_or_fading_in(got: &(u32, u32, Vec<u8>), no_signal: &(u32, u32, Vec<u8>), scene: &[u8]) -> bool {
    got == no_signal
        || qemu_says_no_signal(got)
        || got.2.iter().all(|&v| v == 0)
        || ((got.0, got.1) == (W, H) && got.2.iter().zip(scene).all(|(g, s)| g <= s))
}

/// QEMU's own picture for a head the guest does not drive ("Display output is not active.",
/// "Guest has not initialized the display (yet)."): one line of grey text across the middle
/// of a black screen. Boot or console text starts at the top; the scene is not grey.
fn qemu_says_no_signal(got: &(u32, u32, Vec<u8>)) -> bool {
    let (w, h) = (got.0 as usize, got.1 as usize);
    got.2.chunks_exact(3).enumerate().all(|(i, px)| {
        let y = i / w;
        px == [0, 0, 0] || (px[0] == px[1] && px[1] == px[2] && y.abs_diff(h / 2) < 16)
    })
}

#[test]
fn the_image_boots_dark_plays_a_showing_and_serves_its_console() {
    let _one = MACHINE.lock().unwrap_or_else(|e| e.into_inner());
    if qemu_common::skipped("the image test") {
        return;
    }
    if std::env::var("RESTAGE_SKIP_IMAGE").is_ok_and(|v| v == "1") {
        eprintln!("RESTAGE_SKIP_IMAGE=1: the image test is skipped");
        return;
    }
    let image = PathBuf::from(std::env::var("RESTAGE_IMAGE").unwrap_or_else(|_| {
        panic!(
            "RESTAGE_IMAGE is not set: build the image (sudo tools/image/build.sh OUT) and set \
             RESTAGE_IMAGE=OUT/restage-VERSION.img, or RESTAGE_SKIP_IMAGE=1 to skip"
        )
    }));
    assert!(image.is_file(), "RESTAGE_IMAGE={} is not a file", image.display());
    assert!(Path::new(OVMF_CODE).is_file(), "{OVMF_CODE} not found: apt-get install ovmf");
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();

    // The museum's copy of the image, provisioned (the emulated heads report no modes, so
    // they are forced on, as a projector without EDID would be; the journal is forwarded to
    // the serial console for the test to read).
    let disk = d.join("disk.img");
    run(Command::new("cp").arg("--sparse=always").arg(&image).arg(&disk));
    data_partition(&d.join("data"));
    let video: Vec<String> = (1..=HEADS).map(|k| format!("video=Virtual-{k}:{W}x{H}@60e")).collect();
    let provision = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/image/provision.sh");
    run(Command::new("bash")
        .arg(&provision)
        .arg(&disk)
        .arg("--data")
        .arg(d.join("data"))
        .args(["--kernel-args", &format!("{} systemd.journald.forward_to_console=1", video.join(" "))]));
    // Written to a disk larger than the image, as every stage machine's is: the data partition
    // takes the rest at first boot.
    let image_len = std::fs::metadata(&disk).unwrap().len();
    std::fs::OpenOptions::new().write(true).open(&disk).unwrap().set_len(image_len + GROWN).unwrap();
    let stick = d.join("stick.img");
    let (new_spec, new_version) = bundle_stick(&d.join("stick"), &stick);
    // A second FAT stick (plugged in while the first is in) and one with a file system the
    // stage does not mount.
    let second = d.join("second.img");
    run(Command::new("mkfs.vfat").args(["-C", "-n", "SECOND"]).arg(&second).arg("4096"));
    let odd = d.join("odd.img");
    std::fs::create_dir_all(d.join("odd")).unwrap();
    std::fs::write(d.join("odd/new.bundle"), b"not looked at").unwrap();
    run(Command::new("mksquashfs").arg(d.join("odd")).arg(&odd).args(["-noappend", "-quiet"]));
    let updates = d.join("updates.img");
    update_disk(&image.with_extension("update"), &d.join("updates"), &updates);
    let vars = d.join("OVMF_VARS.fd");
    std::fs::copy(OVMF_VARS, &vars).unwrap();

    let (qmp_path, button_path) = (d.join("qmp.sock"), d.join("button.sock"));
    // `-no-reboot`: the guest's reset ends QEMU and `restart` starts it again on the same disk
    // and firmware variables, a power cycle in place of a warm reset. OVMF under software
    // emulation hung on the warm reset after "reboot: Restarting system" (no firmware line for
    // 300 s) in two of five CI runs, always at the third reboot; a cold start never hung.
    let start = |stopped: bool| {
        let mut cmd = Command::new("qemu-system-x86_64");
        cmd.args([
            "-machine",
            "q35",
            "-accel",
            &qemu_common::accel(),
            "-m",
            "1024",
            "-nodefaults",
            "-no-reboot",
        ])
        .args(if stopped { &["-S"][..] } else { &[][..] })
        .args(["-drive", &format!("if=pflash,format=raw,unit=0,readonly=on,file={OVMF_CODE}")])
        .args(["-drive", &format!("if=pflash,format=raw,unit=1,file={}", vars.display())])
        .args(["-drive", &format!("if=virtio,format=raw,file={}", disk.display())])
        // The updates, as a service technician's stick would bring them (/dev/vdb).
        .args(["-drive", &format!("if=virtio,format=raw,readonly=on,file={}", updates.display())])
        .args(["-device", "virtio-gpu-pci,max_outputs=3,id=gpu0", "-vga", "none", "-display", "none"])
        // A USB controller, for the stick with bundles plugged in later (QMP device_add).
        .args(["-device", "qemu-xhci,id=xhci"])
        // A hardware watchdog for systemd's RuntimeWatchdogSec to arm.
        .args(["-device", "i6300esb"])
        .args(["-serial", "stdio"])
        .args(["-serial", &format!("unix:{},server=on,wait=off", button_path.display())])
        .args(["-qmp", &format!("unix:{},server=on,wait=off", qmp_path.display())]);
        let (guest, con) = qemu_common::spawn(cmd, true);
        let qmp = Qmp::connect(&qmp_path);
        (guest, con, qmp)
    };
    // After the guest's reboot: QEMU has ended (or ends soon); power on again.
    let restart = |mut guest: qemu_common::Guest, mut con: qemu_common::Console| {
        wait_off(&mut guest, &mut con, "reset after its reboot");
        drop(guest);
        start(false)
    };
    let (mut guest, mut con, mut qmp) = start(true);
    let shots = d.join("image");
    std::fs::create_dir_all(&shots).unwrap();

    // Before power-on (QEMU started stopped): what each head shows with no signal at all.
    let no_signal: Vec<_> = (0..HEADS).map(|k| qmp.screendump(&shots, k)).collect();
    let spec = spec();
    let (original, restored) = (scene_of(&spec, 0), scene_of(&spec, 1));

    // Power on, and watch every head until all show the original scene. The emulated
    // firmware (OVMF) draws its logo on head 0 at its own resolution before anything of the
    // image runs, and nothing the image does can stop that (a stage PC's firmware setup has a
    // setting for it): a picture at a size other than the scene's (the firmware's mode, not
    // the kernel's), lit only in the screen's central ninth (where boot logos go), is the
    // firmware's logo; it is timed and reported. Anything else that is not dark (boot
    // loader or kernel text, which starts at the top left; a login prompt) fails.
    qmp.execute(serde_json::json!({"execute": "cont"}));
    let power_on = Instant::now();
    let mut first_signal: [Option<Duration>; HEADS] = [None; HEADS];
    // Head 0 in the firmware's mode (not the scene's size), then in the kernel's.
    let (mut firmware_mode, mut kernel_mode) = (false, false);
    let mut firmware_until = None;
    let mut dumps = 0usize;
    let scene_up = loop {
        let t = power_on.elapsed();
        assert!(t < Duration::from_secs(300), "the original scene did not appear within 300 s of power-on");
        let mut all = true;
        for k in 0..HEADS {
            let got = qmp.screendump(&shots, k);
            dumps += 1;
            if got != no_signal[k] && first_signal[k].is_none() {
                first_signal[k] = Some(t);
            }
            if k == 0 && got != no_signal[0] {
                firmware_mode |= (got.0, got.1) != (W, H);
                kernel_mode |= firmware_mode && (got.0, got.1) == (W, H);
            }
            if (got.0, got.1) == (W, H) && got.2 == original[k] {
                continue;
            }
            all = false;
            if dark_or_fading_in(&got, &no_signal[k], &original[k]) {
                continue;
            }
            if k == 0 && !kernel_mode && (got.0, got.1) != (W, H) {
                firmware_until = Some(t);
                continue;
            }
            let keep = shots.join(format!("not-dark-head{k}.png"));
            std::fs::copy(shots.join(format!("head{k}.png")), &keep).unwrap();
            if let Ok(dir) = std::env::var("RESTAGE_QEMU_SHOTS") {
                std::fs::create_dir_all(&dir).unwrap();
                let _ = std::fs::copy(&keep, Path::new(&dir).join(format!("image-not-dark-head{k}.png")));
            }
            panic!(
                "head {k} showed something other than dark or the original scene after the firmware {:.1} s after power-on ({}x{}; {}; console so far:\n{})",
                t.as_secs_f64(),
                got.0,
                got.1,
                keep.display(),
                con.seen.join("\n")
            );
        }
        if all {
            break power_on.elapsed();
        }
        con.pump_until(Instant::now() + Duration::from_millis(100));
    };
    eprintln!(
        "the original scene on every head {:.1} s after power-on ({dumps} screendumps; before it dark{})",
        scene_up.as_secs_f64(),
        firmware_until.map_or(String::new(), |t| format!(
            ", but for the firmware's screen on head 0 until {:.1} s",
            t.as_secs_f64()
        ))
    );

    let mut button = qemu_common::button(&button_path);
    button.write_all(b"PRESS\n").unwrap();
    expect_heads(&mut qmp, &shots, None, &restored, Duration::from_secs(2), "the restoration after PRESS");
    let pressed = Instant::now();
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &original,
        Duration::from_secs(20),
        "the original after the exposure timer",
    );
    assert!(pressed.elapsed() > Duration::from_secs(SHOWING_S as u64 - 1), "the showing ended early");

    // The service console: a root shell on ttyS0.
    let login = con.wait_for_at(&["automatic login"], Duration::from_secs(120)).0;
    let first = first_signal.iter().flatten().min().copied();
    eprintln!(
        "FIGURES (image, emulated machine, {}): power-on to first signal on a head {}; the firmware's own screen (logo, boot manager lines) on head 0 until {}; to the original scene on every head {:.1} s; to the console's login {:.1} s",
        qemu_common::accel(),
        first.map_or("never (no head lit before the scene)".into(), |t| format!("{:.1} s", t.as_secs_f64())),
        firmware_until.map_or("never".into(), |t| format!("{:.1} s", t.as_secs_f64())),
        scene_up.as_secs_f64(),
        (login - power_on).as_secs_f64(),
    );
    let v1 = std::fs::read_to_string(image.with_extension("packages"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("restage-appliance ").map(str::to_string))
        .expect("the image's package list names the appliance");
    let report = machine_report(&mut con);
    for want in [
        format!("image=restage-{v1} "),
        "root=squashfs /dev/vda2".into(),
        "ro=ro".into(),
        "var=/dev/vda4".into(),
        "app=active".into(),
        "journals=1".into(),
        "watchdog=active".into(),
        "gettys=0".into(),
        "config=/var/lib/restage-etc".into(),
        "trust=test.pem".into(),
        "slot=a ".into(),
        "entries=restage-a.conf.".into(),
    ] {
        assert!(report.contains(&want), "service console report lacks {want:?}: {report}");
    }

    let var_mib: u64 = report
        .split_once("var_mib=")
        .and_then(|(_, r)| r.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no /var size in the report: {report}"));
    assert!(
        var_mib > 512 + (GROWN >> 20) * 9 / 10,
        "/var is {var_mib} MiB: the data partition (512 MiB in the image) did not take the disk's extra {} MiB",
        GROWN >> 20
    );
    eprintln!(
        "the data partition's file system after the first boot: {var_mib} MiB (512 MiB in the image, disk {} MiB larger)",
        GROWN >> 20
    );

    // The bundle inbox: an operator plugs in a USB stick holding a new signed bundle and a
    // tampered one. The new one is installed between showings and plays from the next press;
    // the tampered one is refused and named in the journal; each is moved on the stick to
    // installed/ or refused/, where the operator sees what became of it.
    let t_stick = Instant::now();
    plug(&mut qmp, "stick", &stick);
    con.wait_for(&["mounted at /media/stick"], Duration::from_secs(60));
    let installed_line =
        con.wait_for(&["inbox: /media/stick/new.bundle installed"], Duration::from_secs(120));
    assert!(installed_line.contains("moved to /media/stick/installed/new.bundle"), "{installed_line}");
    let installed_after = t_stick.elapsed();
    let refused_line =
        con.wait_for(&["inbox: /media/stick/tampered.bundle refused"], Duration::from_secs(120));
    assert!(refused_line.contains("moved to /media/stick/refused/tampered.bundle"), "{refused_line}");
    let (new_original, new_restored) = (scene_of(&new_spec, 0), scene_of(&new_spec, 1));
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &new_original,
        Duration::from_secs(30),
        "the new bundle's original scene once it is installed",
    );
    button.write_all(b"PRESS\n").unwrap();
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &new_restored,
        Duration::from_secs(2),
        "the new bundle's restoration after PRESS",
    );
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &new_original,
        Duration::from_secs(20),
        "the new bundle's original after the exposure timer",
    );
    let out = shell(
        &mut con,
        "ls /media/stick /media/stick/installed /media/stick/refused; cat /media/stick/refused/tampered.bundle.txt; \
         echo journal=$(journalctl -b -u restage-appliance --no-pager | grep -c 'tampered.bundle refused'); \
         restage-appliance status | grep -E '^playing:|refused'",
    );
    for want in [
        "/media/stick/installed: new.bundle".to_string(),
        "/media/stick/refused: tampered.bundle tampered.bundle.txt".into(),
        "journal=1".into(),
        format!("version {new_version}"),
    ] {
        assert!(out.contains(&want), "after the stick ({want:?}): {out}");
    }
    let shown_after = t_stick.elapsed();
    // A second stick while the first is in: refused by name, the first stays; pulling the
    // second out leaves the first mounted.
    let first = shell(&mut con, "findmnt -no SOURCE /media/stick");
    plug(&mut qmp, "second", &second);
    con.wait_for(
        &["not mounted, another stick is at /media/stick", "take that one out first"],
        Duration::from_secs(60),
    );
    unplug(&mut qmp, "second");
    std::thread::sleep(Duration::from_secs(2));
    let out = shell(&mut con, "findmnt -no SOURCE /media/stick; echo mounted=$?");
    assert!(
        out.contains(first.trim()) && out.contains("mounted=0"),
        "the first stick ({first}) after the second: {out}"
    );
    // Pulled out: unmounted at once, and the inbox holds nothing.
    unplug(&mut qmp, "stick");
    con.wait_for(&["unmounted from /media/stick"], Duration::from_secs(60));
    let out = shell(&mut con, "findmnt -n /media/stick; echo mounted=$?");
    assert!(
        out.contains("mounted=1"),
        "the stick's file system is still mounted after it was pulled out: {out}"
    );
    // A file system the stage does not take (squashfs here; NTFS likewise) is refused by name.
    plug(&mut qmp, "odd", &odd);
    con.wait_for(&["a squashfs file system; a stick must be FAT, exFAT or ext4"], Duration::from_secs(60));
    let out = shell(&mut con, "findmnt -n /media/stick; echo mounted=$?");
    assert!(out.contains("mounted=1"), "a squashfs stick was mounted: {out}");
    unplug(&mut qmp, "odd");
    eprintln!(
        "FIGURES (bundle inbox, emulated machine): stick plugged in to the new bundle installed {:.1} s (settling 4 s, verified, copied, verified again); to its showing and the tampered one refused {:.1} s",
        installed_after.as_secs_f64(),
        shown_after.as_secs_f64()
    );
    // The ledger as it stands: the update must keep every row. The last row may be the
    // exposure under way (the idle scene is light too), which grows until it ends: the rows
    // before it are compared.
    let ledger = shell(
        &mut con,
        "restage-appliance ledger export --csv > /tmp/l && n=$(( $(wc -l < /tmp/l) - 1 )) && echo $n $(head -n $n /tmp/l | md5sum)",
    );
    let (rows, sum) = ledger
        .split_once(' ')
        .map(|(r, s)| (r.parse::<usize>().unwrap(), s.split_whitespace().next().unwrap().to_string()))
        .unwrap_or_else(|| panic!("ledger export: {ledger}"));
    assert!(rows >= 2, "the ledger has no finished exposure row after a showing: {ledger}");

    // Updates from the stick: refused when unsigned or corrupt (nothing written), then one whose
    // appliance cannot start: on trial for one boot, it fails and the machine goes back to v1
    // by itself; then a good one, which becomes the machine's software.
    let m = shell(&mut con, "mount -o ro /dev/vdb /media/stick && echo mounted");
    assert!(m.contains("mounted"), "the stick: {m}");
    let t_update = Instant::now();
    let out = shell(&mut con, "restage-appliance update install /media/stick/unsigned; echo status=$?");
    assert!(out.contains("status=1"), "an update signed by a stranger was not refused: {out}");
    assert!(
        out.contains("not valid for any key in /etc/restage/update-trust"),
        "no message naming the trust folder: {out}"
    );
    let out = shell(&mut con, "restage-appliance update install /media/stick/corrupt; echo status=$?");
    assert!(out.contains("status=1"), "a corrupt update was not refused: {out}");
    assert!(
        out.contains("root.squashfs: its content is not what the signed manifest says"),
        "no message naming the corrupt file: {out}"
    );
    assert!(
        machine_report(&mut con).contains("entries=restage-a.conf."),
        "a refused update touched the boot entries"
    );
    let out =
        shell(&mut con, "restage-appliance update install --tries 1 /media/stick/broken; echo status=$?");
    assert!(
        out.contains("status=0") && out.contains(&format!("update {v1}.1 installed in slot b")),
        "the broken (but signed) update was not installed: {out}"
    );
    con.command("systemctl reboot");
    (guest, con, _) = restart(guest, con);
    con.wait_for(&["did not get ready on this slot: rebooting"], Duration::from_secs(300));
    (guest, con, qmp) = restart(guest, con);
    con.wait_for(&["automatic login"], Duration::from_secs(300));
    let report = machine_report(&mut con);
    for want in [
        format!("image=restage-{v1} "),
        "slot=a ".into(),
        "app=active".into(),
        "entries=restage-a.conf.restage-b+0-1.conf.".into(),
    ] {
        assert!(report.contains(&want), "after the broken update, not back on v1 ({want:?}): {report}");
    }
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &new_original,
        Duration::from_secs(60),
        "the new bundle's original scene on v1 after the rollback",
    );

    let m = shell(&mut con, "mount -o ro /dev/vdb /media/stick && echo mounted");
    assert!(m.contains("mounted"), "the stick after the rollback: {m}");
    let out = shell(&mut con, "restage-appliance update install /media/stick/good; echo status=$?");
    assert!(out.contains("status=0"), "the good update was not installed: {out}");
    let installed = Instant::now();
    con.command("systemctl reboot");
    (guest, con, qmp) = restart(guest, con);
    con.wait_for(&["automatic login"], Duration::from_secs(300));
    expect_heads(
        &mut qmp,
        &shots,
        None,
        &new_original,
        Duration::from_secs(60),
        "the new bundle's original scene on v2",
    );
    // Marked good once the appliance is ready (systemd-bless-boot renames the entry).
    let mut report = String::new();
    for _ in 0..30 {
        report = machine_report(&mut con);
        if report.contains("entries=restage-a.conf.restage-b.conf.") {
            break;
        }
        std::thread::sleep(Duration::from_secs(2));
    }
    for want in [
        format!("image=restage-{v1}.2 "),
        "slot=b ".into(),
        "root=squashfs /dev/vda3".into(),
        "app=active".into(),
        "entries=restage-a.conf.restage-b.conf.".into(),
    ] {
        assert!(report.contains(&want), "after the good update ({want:?}): {report}");
    }
    let after = shell(&mut con, &format!("restage-appliance ledger export --csv | head -n {rows} | md5sum"));
    assert!(
        after.starts_with(&sum),
        "the ledger's rows changed across the update: {sum} before, {after} after"
    );
    eprintln!(
        "FIGURES (image update, emulated machine): refusals, broken update and its rollback, good update {:.1} s in all; install to the new slot ready and marked good {:.1} s",
        t_update.elapsed().as_secs_f64(),
        installed.elapsed().as_secs_f64()
    );
    con.command("systemctl poweroff");
    wait_off(&mut guest, &mut con, "power off");
}

/// Waits (keeping the console's lines) until QEMU has ended: the guest's reset or power-off
/// ends it (`-no-reboot`); two minutes at most, as the watchdog's own timeout.
fn wait_off(guest: &mut qemu_common::Guest, con: &mut qemu_common::Console, what: &str) {
    let t = Instant::now();
    while guest.0.try_wait().unwrap().is_none() {
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "the machine did not {what} within 120 s; console:\n{}",
            con.seen.join("\n")
        );
        con.pump_until(Instant::now() + Duration::from_millis(200));
    }
    con.drain();
}

/// Scene `s` of the bundle `spec` on every head, as RGB8.
fn scene_of(spec: &ExampleSpec, s: usize) -> Vec<Vec<u8>> {
    (0..HEADS).map(|k| xrgb8888_to_rgb8(&example_frame(spec, s, k))).collect()
}

/// The operator's USB stick, a FAT file system written to `disk`: `new.bundle` (a newer
/// version of the test's bundle, dimmer pictures) and `tampered.bundle` (newer still, signed,
/// then one byte changed). Returns the new bundle's spec and version.
fn bundle_stick(work: &Path, disk: &Path) -> (ExampleSpec, u64) {
    std::fs::create_dir_all(work).unwrap();
    let new = ExampleSpec { version: spec().version + 1, peak_value: 170, ..spec() };
    let policy = qemu_common::policy(SHOWING_S);
    qemu_common::write_bundle(&work.join("new.bundle"), &new, &policy);
    let tampered = work.join("tampered.bundle");
    qemu_common::write_bundle(
        &tampered,
        &ExampleSpec { version: new.version + 1, peak_value: 120, ..spec() },
        &policy,
    );
    let mut bytes = std::fs::read(&tampered).unwrap();
    let at = bytes.len() / 2;
    bytes[at] ^= 0x01;
    std::fs::write(&tampered, bytes).unwrap();
    run(Command::new("mkfs.vfat").args(["-C", "-n", "STICK"]).arg(disk).arg("65536"));
    run(Command::new("mcopy").arg("-i").arg(disk).arg(work.join("new.bundle")).arg(&tampered).arg("::/"));
    let version = new.version;
    (new, version)
}

/// Plugs a USB stick whose disk is the file `disk` into the machine's xHCI controller, as
/// QMP device `id`.
fn plug(qmp: &mut qemu_common::Qmp, id: &str, disk: &Path) {
    qmp.execute(serde_json::json!({"execute": "blockdev-add", "arguments": {
        "driver": "raw", "node-name": id, "file": {"driver": "file", "filename": disk}}}));
    qmp.execute(serde_json::json!({"execute": "device_add", "arguments": {
        "driver": "usb-storage", "bus": "xhci.0", "drive": id, "id": id, "removable": true}}));
}

/// Pulls the stick `id` out.
fn unplug(qmp: &mut qemu_common::Qmp, id: &str) {
    qmp.execute(serde_json::json!({"execute": "device_del", "arguments": {"id": id}}));
}

/// Runs `cmd` in the service console's shell and returns its output (standard output and
/// error, lines joined by spaces) as one line; the command is wrapped so that its echo, which
/// the terminal prints first, cannot match.
fn shell(con: &mut qemu_common::Console, cmd: &str) -> String {
    static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    con.command(&format!("echo \"OUT{n}\"\"= $( ( {cmd} ) 2>&1 | tr '\\n' ' ')\""));
    let line = con.wait_for(&[&format!("OUT{n}= ")], Duration::from_secs(120));
    line.split_once(&format!("OUT{n}= ")).map(|(_, r)| r.to_string()).unwrap_or_default()
}

/// What the service console says about the machine, as `key=value` words.
fn machine_report(con: &mut qemu_common::Console) -> String {
    shell(
        con,
        "echo image=$(. /etc/os-release; echo $IMAGE_ID-$IMAGE_VERSION) \
         root=$(findmnt -no FSTYPE,SOURCE / | tr -s ' ') ro=$(findmnt -no OPTIONS / | cut -d, -f1) var=$(findmnt -no SOURCE /var) \
         app=$(systemctl is-active restage-appliance) journals=$(ls -d /var/log/journal/*/ | wc -l) \
         watchdog=$(cat /sys/class/watchdog/watchdog0/state) gettys=$(systemctl list-units --no-legend 'getty@*' 'autovt@*' | wc -l) \
         config=$(readlink /etc/restage) trust=$(ls /etc/restage/trust) \
         var_mib=$(df -m --output=size /var | tail -n1 | tr -d ' ') \
         slot=$(tr ' ' '\\n' < /proc/cmdline | sed -n 's/^restage.slot=//p') \
         entries=$(ls /efi/loader/entries | tr '\\n' .) end",
    )
}

/// The stick's contents (`/dev/vdb` in the guest), made from the image's own update folder
/// `v1` in `work`: `good` (v1's root, IMAGE_VERSION v1.2), `broken` (v1.1, whose appliance
/// program exits at once), `corrupt` (good with a byte changed after signing) and `unsigned`
/// (good signed by a key the machine does not trust). Written as an ext4 file system to `disk`.
fn update_disk(v1: &Path, work: &Path, disk: &Path) {
    let root = work.join("root");
    let stick = work.join("stick");
    std::fs::create_dir_all(work).unwrap();
    run(Command::new("unsquashfs")
        .args(["-q", "-no-progress", "-d"])
        .arg(&root)
        .arg(v1.join("root.squashfs")));
    let os_release = root.join("usr/lib/os-release");
    let text = std::fs::read_to_string(&os_release).unwrap();
    let v1_version = text.lines().find_map(|l| l.strip_prefix("IMAGE_VERSION=")).unwrap().to_string();
    let make = |name: &str, version: &str, key: &SigningKey| {
        let dir = stick.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            &os_release,
            text.replace(&format!("IMAGE_VERSION={v1_version}"), &format!("IMAGE_VERSION={version}")),
        )
        .unwrap();
        run(Command::new("mksquashfs").arg(&root).arg(dir.join("root.squashfs")).args([
            "-comp",
            "zstd",
            "-Xcompression-level",
            "3",
            "-noappend",
            "-quiet",
            "-no-progress",
        ]));
        for f in ["vmlinuz", "initrd"] {
            std::fs::copy(v1.join(f), dir.join(f)).unwrap();
        }
        sysupdate::sign(&dir, version, key).unwrap();
    };
    make("good", &format!("{v1_version}.2"), &update_key());
    make("unsigned", &format!("{v1_version}.2"), &signing_key_from_seed([10; 32]));
    let corrupt = stick.join("corrupt");
    std::fs::create_dir_all(&corrupt).unwrap();
    for f in ["root.squashfs", "vmlinuz", "initrd", sysupdate::MANIFEST, sysupdate::SIGNATURE] {
        std::fs::copy(stick.join("good").join(f), corrupt.join(f)).unwrap();
    }
    let mut bytes = std::fs::read(corrupt.join("root.squashfs")).unwrap();
    let at = bytes.len() / 2;
    bytes[at] ^= 0x40;
    std::fs::write(corrupt.join("root.squashfs"), bytes).unwrap();
    let appliance = root.join("usr/bin/restage-appliance");
    std::fs::remove_file(&appliance).unwrap();
    std::fs::write(&appliance, "#!/bin/sh\necho 'restage-appliance: a broken build' >&2\nexit 1\n").unwrap();
    run(Command::new("chmod").arg("755").arg(&appliance));
    make("broken", &format!("{v1_version}.1"), &update_key());
    run(Command::new("mkfs.ext4").args(["-q", "-F", "-L", "updates", "-d"]).arg(&stick).arg(disk).arg("1G"));
}

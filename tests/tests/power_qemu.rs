//! Power cuts on the emulated stage machine (issue 17). The ledger lives on a virtio disk
//! (ext4 on a raw image file, QEMU `cache=writeback`), and QEMU is killed with SIGKILL at
//! seeded random moments: while the appliance starts (ledger open and WAL recovery, bundle
//! verification, first light), idle (the original scene lit, which is charged too), showing,
//! fading. That is a power cut for the guest: what its kernel had not yet written to the
//! virtual disk (page cache, ext4 journal not yet committed) is gone, what it had written (QEMU
//! has passed it to the image file) stays. After every cut the test reads the ledger as the
//! next boot finds it (a copy of the image with its journal replayed by `e2fsck`, the files
//! taken out with `debugfs`), requires SQLite's integrity check to pass, and requires every lit
//! stretch seen so far, in every round, to be covered at every instant by exposure rows of at
//! least its lux. Then the machine boots again on the same disk.
//!
//! The lit stretches come from the output, not from the ledger: before each commit the KMS
//! output logs the wall-clock time (the ledger's clock) and a fingerprint of every head's
//! picture (`presenting`, debug level), and after the flips the wall-clock time again (`page
//! flip complete`). A picture counts as lit from its `presenting` to the completed flip of the
//! next one, or to the cut. The guest's wall clock at the cut is bounded above from a `clock`
//! round trip through the guest's init (its answer cannot be earlier than the question). A
//! picture's lux is the bundle's scene of that fingerprint (the shared crate's bound check on
//! its frames); a picture of no scene (a cross-fade frame, a mix in linear light) is given the
//! brightest scene's lux.
//!
//! `RESTAGE_POWER_CUTS` (default `DEFAULT_CUTS`) rounds, seed `RESTAGE_POWER_SEED`;
//! `RESTAGE_TEST_ONLY_LEDGER_SYNCHRONOUS_OFF=1` runs the guest's ledger with synchronous=OFF (a
//! debug build honours it; README: what the check then finds); `RESTAGE_POWER_VERBOSE=1`
//! echoes the console; `RESTAGE_SKIP_QEMU=1` skips the test. Needs the packages of
//! `kms_qemu.rs` and e2fsprogs (`mkfs.ext4`, `e2fsck`, `debugfs`).

mod qemu_common;

use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use qemu_common::{Boot, HEADS, MACHINE, field, spec, text_field};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use restage_appliance::ledger::{ExposureRow, Ledger};
use restage_appliance::output::kms::frame_fingerprint;
use restage_shared::bundle::example::{ExampleSpec, example_certificate, example_frame, example_info};
use restage_shared::light::{LightCertificate, LightModel, XrgbFrame, max_irradiance};

/// Rounds when `RESTAGE_POWER_CUTS` is not set: about 3 minutes on a 2-core machine.
const DEFAULT_CUTS: usize = 20;
const OBJECT: &str = "test-jar-1";
/// The exposure timer, seconds: short, so cuts land in showings and fades.
const SHOWING_S: u32 = 2;
const SYNC_OFF: &str = "RESTAGE_TEST_ONLY_LEDGER_SYNCHRONOUS_OFF";
const DISK_MB: u32 = 64;

/// The initramfs's payload (trust key, config) and the disk's first content (the bundle).
/// Showings of 2 s, the last second a cross-fade (each fade frame takes the emulated CPU about
/// half a second to mix, so a 0.3 s fade would show one frame for a moment).
/// Reservations of 2.5 s renewed 2 s before they run out: a ledger write every half second
/// while lit, so cuts land between, and during, writes; and 2 s of margin, as the emulated
/// CPU stalls the event loop for about half a second computing a cross-fade frame.
fn payload(dir: &Path, disk: &Path) {
    qemu_common::write_trust(&dir.join("trust"));
    std::fs::create_dir_all(disk).unwrap();
    qemu_common::write_bundle(&disk.join("active.bundle"), &spec(), &qemu_common::policy(SHOWING_S));
    let config = "trust_dir = \"/restage/trust\"\nstate_dir = \"/var/lib/restage\"\n\
                  [player]\nfade_ms = 1000\nfade_fps = 10\nmin_press_interval_ms = 100\n\
                  [ledger]\nreserve_ms = 2500\nrenew_ahead_ms = 2000\n\
                  [output]\nkind = \"kms\"\ncard = \"/dev/dri/card0\"\n\
                  connectors = [\"Virtual-1\", \"Virtual-2\", \"Virtual-3\"]\n\
                  [inputs.serial]\npath = \"/dev/ttyS1\"\nbaud = 115200\n";
    std::fs::write(dir.join("config.toml"), config).unwrap();
}

/// What a logged picture is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Picture {
    Dark,
    /// Every head shows scene `.0`'s frame.
    Scene(usize, f64),
    /// Frames of no single scene: a cross-fade (lux: the brightest scene's).
    Mix(f64),
}

impl Picture {
    fn lux(self) -> f64 {
        match self {
            Picture::Dark => 0.0,
            Picture::Scene(_, l) | Picture::Mix(l) => l,
        }
    }

    fn phase(self) -> &'static str {
        match self {
            Picture::Dark => "dark",
            Picture::Scene(0, _) => "idle (original)",
            Picture::Scene(..) => "showing",
            Picture::Mix(_) => "fading",
        }
    }
}

/// The bundle's pictures by fingerprint, and their lux.
struct Pictures {
    spec: ExampleSpec,
    light: LightModel,
    cert: LightCertificate,
    by_print: HashMap<String, (usize, usize)>,
    scene_lux: Vec<f64>,
}

impl Pictures {
    fn new(spec: &ExampleSpec) -> Pictures {
        let light = example_info(spec).light;
        let cert = example_certificate(spec);
        let mut by_print = HashMap::new();
        let mut scene_lux = Vec::new();
        for s in 0..spec.scenes {
            let frames: Vec<Vec<u8>> = (0..HEADS).map(|k| example_frame(spec, s, k)).collect();
            for (k, f) in frames.iter().enumerate() {
                by_print.insert(format!("{:08x}", frame_fingerprint(f)), (s, k));
            }
            let refs: Vec<XrgbFrame<'_>> = frames
                .iter()
                .map(|f| XrgbFrame { width: spec.width, height: spec.height, xrgb: f })
                .collect();
            scene_lux.push(max_irradiance(&light, &cert, &refs).unwrap().lux);
        }
        Pictures { spec: spec.clone(), light, cert, by_print, scene_lux }
    }

    /// The picture of a `presenting` line's `lit` and `frames` fields.
    fn picture(&self, lit: bool, prints: &str) -> Picture {
        if !lit {
            return Picture::Dark;
        }
        let known: Vec<Option<(usize, usize)>> =
            prints.split(',').map(|p| self.by_print.get(p).copied()).collect();
        let brightest = self.scene_lux.iter().copied().fold(0.0, f64::max);
        if known.len() != HEADS || known.iter().enumerate().any(|(k, x)| x.is_none_or(|(_, head)| head != k))
        {
            return Picture::Mix(brightest);
        }
        let scenes: Vec<usize> = known.iter().map(|x| x.unwrap().0).collect();
        if scenes.iter().all(|&s| s == scenes[0]) {
            return Picture::Scene(scenes[0], self.scene_lux[scenes[0]]);
        }
        // Heads of different scenes: the bound check on exactly those frames.
        let frames: Vec<Vec<u8>> =
            scenes.iter().enumerate().map(|(k, &s)| example_frame(&self.spec, s, k)).collect();
        let refs: Vec<XrgbFrame<'_>> = frames
            .iter()
            .map(|f| XrgbFrame { width: self.spec.width, height: self.spec.height, xrgb: f })
            .collect();
        Picture::Mix(max_irradiance(&self.light, &self.cert, &refs).unwrap().lux)
    }
}

/// A lit stretch, in the guest's wall-clock microseconds (the ledger's clock, in µs).
#[derive(Clone, Debug)]
struct Stretch {
    round: usize,
    from_us: i64,
    to_us: i64,
    picture: Picture,
}

/// The union of the spans of rows paying at least `lux`, sorted and disjoint, in µs.
fn paying(rows: &[ExposureRow], lux: f64) -> Vec<(i64, i64)> {
    let mut spans: Vec<(i64, i64)> = rows
        .iter()
        .filter(|r| r.lux >= lux * (1.0 - 1e-9))
        .map(|r| (r.start_ms * 1000, r.end_ms * 1000))
        .collect();
    spans.sort_unstable();
    let mut out: Vec<(i64, i64)> = Vec::new();
    for (s, e) in spans {
        match out.last_mut() {
            Some(last) if s <= last.1 => last.1 = last.1.max(e),
            _ => out.push((s, e)),
        }
    }
    out
}

/// Microseconds of `[from, to]` that no span covers.
fn uncovered(spans: &[(i64, i64)], from: i64, to: i64) -> i64 {
    let (mut gap, mut at) = (0, from);
    for &(s, e) in spans {
        if e < at {
            continue;
        }
        if s >= to || at >= to {
            break;
        }
        if s > at {
            gap += s - at;
        }
        at = at.max(e);
    }
    gap + (to - at).max(0)
}

/// The ledger as the next boot finds it.
struct LedgerView {
    rows: Vec<ExposureRow>,
    total_lxh: f64,
    open_reservations: u64,
    fsck_code: i32,
}

fn run(cmd: &mut Command) -> Result<std::process::Output, String> {
    cmd.output().map_err(|e| format!("{cmd:?}: {e}"))
}

/// Copies the disk image, replays its journal (`e2fsck -fy`, as mounting would, and a full
/// check: exit codes 4 and above are uncorrected errors), takes the ledger's files out with
/// `debugfs` and opens them with the appliance's own code (which recovers the WAL).
/// `Ok(None)`: no ledger on the disk yet.
fn read_ledger(disk: &Path, work: &Path) -> Result<Option<LedgerView>, String> {
    let img = work.join("check.img");
    let _ = std::fs::remove_file(&img);
    let cp = run(Command::new("cp").arg("--sparse=always").arg(disk).arg(&img))?;
    if !cp.status.success() {
        return Err(format!("cp: {}", String::from_utf8_lossy(&cp.stderr)));
    }
    let fsck = run(Command::new("e2fsck").arg("-fy").arg(&img))?;
    let fsck_code = fsck.status.code().unwrap_or(-1);
    let report = String::from_utf8_lossy(&fsck.stdout);
    // After a cut e2fsck replays the journal and corrects the superblock's free block and
    // inode counts (ext4 does not keep those exact on disk; mounting recounts them) and
    // finishes orphans (files truncated or deleted while open), as mounting does; anything
    // else is damage.
    let expected = |l: &str| {
        let l = l.trim();
        l.is_empty()
            || l.ends_with(": recovering journal")
            || l.starts_with("Pass ")
            || l.starts_with("Free blocks count wrong")
            || l.starts_with("Free inodes count wrong")
            || l.starts_with("Clearing orphaned inode")
            || l.starts_with("Truncating orphaned inode")
            || l == "Fix? yes"
            || l.ends_with("***** FILE SYSTEM WAS MODIFIED *****")
            || l.contains(" files (")
    };
    let damage: Vec<&str> = report.lines().filter(|l| !expected(l)).collect();
    if !(0..=1).contains(&fsck_code) || !damage.is_empty() {
        return Err(format!(
            "e2fsck exit {fsck_code}, file system damaged: {}{}",
            report,
            String::from_utf8_lossy(&fsck.stderr)
        ));
    }
    let dir = work.join("ledger");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let ls = run(Command::new("debugfs").args(["-R", "ls -p /"]).arg(&img))?;
    let listing = String::from_utf8_lossy(&ls.stdout).to_string();
    // `ls -p`: /inode/mode/uid/gid/name/size/ per entry.
    let present = |name: &str| listing.lines().any(|l| l.split('/').nth(5) == Some(name));
    if !present("ledger.sqlite") {
        return Ok(None);
    }
    for f in ["ledger.sqlite", "ledger.sqlite-wal"].into_iter().filter(|f| present(f)) {
        let out = dir.join(f);
        let dump =
            run(Command::new("debugfs").arg("-R").arg(format!("dump /{f} {}", out.display())).arg(&img))?;
        if !out.is_file() {
            return Err(format!("debugfs dump /{f}: {}", String::from_utf8_lossy(&dump.stderr)));
        }
    }
    let path = dir.join("ledger.sqlite");
    let ledger =
        Ledger::open(&path, restage_appliance::zone::LocalZone::utc()).map_err(|e| format!("open: {e}"))?;
    ledger.integrity_check().map_err(|e| e.to_string())?;
    let rows = ledger.exposure_rows(OBJECT).map_err(|e| e.to_string())?;
    let total_lxh = ledger.total(OBJECT).map_err(|e| e.to_string())?;
    let open_reservations = ledger.status(0).map_err(|e| e.to_string())?.open_reservations;
    Ok(Some(LedgerView { rows, total_lxh, open_reservations, fsck_code }))
}

/// A round's plan, drawn before it starts (so the draws do not depend on timing).
#[derive(Debug)]
struct Plan {
    /// Cut this long after the appliance starts (it opens the ledger, verifies the bundle,
    /// lights the original), else `after_light_ms` after first light.
    during_start_ms: Option<u64>,
    after_light_ms: u64,
    /// Button presses, ms after first light.
    presses_ms: Vec<u64>,
}

impl Plan {
    fn draw(rng: &mut ChaCha8Rng) -> Plan {
        let during_start_ms = rng.gen_bool(0.2).then(|| rng.gen_range(0..2500));
        let after_light_ms = rng.gen_range(0..7000);
        let mut presses_ms: Vec<u64> =
            (0..rng.gen_range(0..=3)).map(|_| rng.gen_range(0..after_light_ms.max(1))).collect();
        presses_ms.sort_unstable();
        Plan { during_start_ms, after_light_ms, presses_ms }
    }
}

fn tool_runs(tool: &str) -> bool {
    Command::new(tool).arg("-V").output().is_ok()
}

#[test]
fn power_cuts_at_random_moments_never_lose_paid_light() {
    let _one = MACHINE.lock().unwrap_or_else(|e| e.into_inner());
    if qemu_common::skipped("the emulated power-cut test") {
        return;
    }
    for tool in ["mkfs.ext4", "e2fsck", "debugfs"] {
        assert!(tool_runs(tool), "{tool} not found: install the apt package e2fsprogs");
    }
    let env_num =
        |k: &str, default: u64| std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(default);
    let cuts = env_num("RESTAGE_POWER_CUTS", DEFAULT_CUTS as u64) as usize;
    let seed = env_num("RESTAGE_POWER_SEED", 17);
    let sync_off = std::env::var(SYNC_OFF).is_ok_and(|v| v == "1");
    let echo = std::env::var("RESTAGE_POWER_VERBOSE").is_ok_and(|v| v == "1");
    let t0 = Instant::now();
    let us = |i: Instant| i.duration_since(t0).as_micros() as i64;

    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    payload(&d.join("payload"), &d.join("disk"));
    let vm = qemu_common::prepare(d, &d.join("payload"), Some("disk"));
    let disk = d.join("state.img");
    let mkfs = Command::new("mkfs.ext4")
        .args(["-q", "-F", "-b", "4096", "-E", "lazy_itable_init=0,lazy_journal_init=0", "-d"])
        .arg(d.join("disk"))
        .arg(&disk)
        .arg(format!("{DISK_MB}M"))
        .output()
        .unwrap();
    assert!(mkfs.status.success(), "mkfs.ext4: {}", String::from_utf8_lossy(&mkfs.stderr));
    let pictures = Pictures::new(&spec());
    let work = d.join("work");
    std::fs::create_dir_all(&work).unwrap();

    // The kernel hands parameters without a dot to init as environment variables.
    let append = format!(
        "fbcon=map:9 restage_disk=/dev/vda RESTAGE_LOG=info,restage_appliance::output::kms=debug{}",
        if sync_off { format!(" {SYNC_OFF}=1") } else { String::new() }
    );
    let drive = format!("file={},if=none,id=state,format=raw,cache=writeback", disk.display());
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut stretches: Vec<Stretch> = Vec::new();
    let mut problems: Vec<String> = Vec::new();
    let mut phases: BTreeMap<&str, usize> = BTreeMap::new();
    let mut fsck_codes: BTreeMap<i32, usize> = BTreeMap::new();
    let (mut presses_sent, mut presses_seen, mut fades_seen) = (0, 0, 0);
    let mut cut_mid_line = 0;
    let mut clock_slack_us: Vec<i64> = Vec::new();
    let mut last_kill_guest_us = i64::MIN;
    let mut last_view: Option<LedgerView> = None;
    let mut under_rounds = 0;
    let mut unpaid_lxh = 0.0;
    let mut rounds_done = 0;

    for round in 0..cuts {
        let r0 = Instant::now();
        let plan = Plan::draw(&mut rng);
        let button_path = d.join(format!("button{round}.sock"));
        let (mut guest, mut con) = qemu_common::boot(Boot {
            vm: &vm,
            append: append.clone(),
            button: button_path.clone(),
            qmp: None,
            args: vec!["-drive".into(), drive.clone(), "-device".into(), "virtio-blk-pci,drive=state".into()],
            echo,
        });
        let Some((started_at, _)) = con.wait_for_opt(&["appliance starting"], Duration::from_secs(180))
        else {
            problems.push(format!(
                "round {round}: the appliance did not start; console:\n{}",
                con.seen.join("\n")
            ));
            break;
        };
        // The guest's wall clock, asked as the appliance starts and again at first light.
        let mut pressed = 0;
        let mut pings = vec![Instant::now()];
        con.command("clock");
        con.wait_for_opt(&["GUEST: clock"], Duration::from_secs(30));
        let (kill_at, what) = if let Some(ms) = plan.during_start_ms {
            (started_at + Duration::from_millis(ms), format!("{ms} ms after start"))
        } else {
            // (It may have come while the clock was asked.)
            let first_light = match con.seen.iter().position(|l| l.contains("first light")) {
                Some(i) => Some(con.seen_at[i]),
                None => con.wait_for_opt(&["first light"], Duration::from_secs(90)).map(|(at, _)| at),
            };
            match first_light {
                Some(lit_at) => {
                    pings.push(Instant::now());
                    con.command("clock");
                    let mut button = UnixStream::connect(&button_path).ok();
                    for &p in &plan.presses_ms {
                        con.pump_until(lit_at + Duration::from_millis(p));
                        if let Some(b) = button.as_mut() {
                            pressed += usize::from(b.write_all(b"PRESS\n").is_ok());
                        }
                    }
                    (
                        lit_at + Duration::from_millis(plan.after_light_ms),
                        format!("{} ms after first light", plan.after_light_ms),
                    )
                }
                None => {
                    problems
                        .push(format!("round {round}: no first light; console:\n{}", con.seen.join("\n")));
                    (Instant::now(), "without first light".into())
                }
            }
        };
        con.pump_until(kill_at);
        // The power cut.
        guest.kill();
        let killed = Instant::now();
        con.drain();
        // A line the cut interrupted is left out: its last field may be cut. When it announced
        // a picture, that picture could show only from the announcement (written just before
        // the commit) to the cut, the time the rest of one line takes to leave the machine;
        // the picture before it is counted to the cut.
        cut_mid_line += usize::from(con.cut_short.is_some());

        // The guest's clock: offset = guest wall time - host time, at most what the clock
        // answers give (answered after the question was sent), at least what any line gives
        // (written before it arrived).
        let lines: Vec<(Instant, &str)> =
            con.seen_at.iter().copied().zip(con.seen.iter().map(String::as_str)).collect();
        let mut lo = i64::MIN;
        let mut answers = Vec::new();
        for &(at, line) in &lines {
            if let Some(u) = field(line, "unix_us") {
                lo = lo.max(u as i64 - us(at));
                if line.contains("GUEST: clock") {
                    answers.push(u as i64);
                }
            }
        }
        let Some(hi) = answers.iter().zip(&pings).map(|(&u, &p)| u - us(p)).next_back() else {
            problems.push(format!("round {round}: no answer to `clock`; console:\n{}", con.seen.join("\n")));
            break;
        };
        if lo > hi + 2000 {
            problems.push(format!("round {round}: the guest clock ran {} µs ahead of its bound", lo - hi));
        }
        clock_slack_us.push(hi - lo);
        let kill_guest_us = us(killed) + hi;

        // The pictures shown, from the output's lines.
        struct Shown {
            from: i64,
            to: Option<i64>,
            picture: Picture,
        }
        let mut shown: Vec<Shown> = Vec::new();
        for &(_, line) in &lines {
            if line.contains("kms: presenting") {
                let (Some(u), Some(lit), Some(prints)) =
                    (field(line, "unix_us"), text_field(line, "lit"), text_field(line, "frames"))
                else {
                    panic!("unreadable line: {line}")
                };
                shown.push(Shown {
                    from: u as i64,
                    to: None,
                    picture: pictures.picture(lit == "true", prints),
                });
            } else if line.contains("page flip complete") {
                let u = field(line, "unix_us").unwrap_or_else(|| panic!("no unix_us: {line}")) as i64;
                let n = shown.len();
                for s in shown.iter_mut().take(n.saturating_sub(1)).filter(|s| s.to.is_none()) {
                    s.to = Some(u);
                }
            }
        }
        if let Some(first) = shown.first() {
            assert!(
                first.from > last_kill_guest_us,
                "round {round}: the guest clock starts before the last round's cut; rows could not be told apart"
            );
        }
        last_kill_guest_us = kill_guest_us;
        presses_sent += pressed;
        let phase = shown.last().map_or("dark (before the output)", |s| s.picture.phase());
        *phases.entry(phase).or_default() += 1;
        presses_seen += lines.iter().filter(|(_, l)| l.contains(" press ") && l.contains("serial")).count();
        let fresh = stretches.len();
        for s in shown.iter().filter(|s| s.picture != Picture::Dark) {
            fades_seen += usize::from(matches!(s.picture, Picture::Mix(_)));
            stretches.push(Stretch {
                round,
                from_us: s.from,
                to_us: s.to.unwrap_or(kill_guest_us),
                picture: s.picture,
            });
        }
        drop(con);

        // The ledger the next boot finds, and every lit stretch so far against it.
        let view = match read_ledger(&disk, &work) {
            Ok(v) => v,
            Err(e) => {
                problems.push(format!("round {round}: ledger unreadable after the cut: {e}"));
                rounds_done += 1;
                break;
            }
        };
        let rows = view.as_ref().map(|v| v.rows.as_slice()).unwrap_or_default();
        let mut spans: HashMap<u64, Vec<(i64, i64)>> = HashMap::new();
        let mut lost_now = Vec::new();
        unpaid_lxh = 0.0;
        for (i, s) in stretches.iter().enumerate() {
            let lux = s.picture.lux();
            let sp = spans.entry(lux.to_bits()).or_insert_with(|| paying(rows, lux));
            let gap = uncovered(sp, s.from_us, s.to_us);
            unpaid_lxh += lux * gap as f64 / 3.6e9;
            if gap > 0 {
                lost_now.push(format!(
                    "{} stretch of round {} ({:?}, {} .. {} µs): {gap} µs unpaid",
                    if i >= fresh { "this round's" } else { "an earlier" },
                    s.round,
                    s.picture,
                    s.from_us,
                    s.to_us
                ));
            }
        }
        if let Some(v) = &view {
            *fsck_codes.entry(v.fsck_code).or_default() += 1;
        }
        eprintln!(
            "round {round}: cut {what} ({phase}), {pressed} presses, {} lit stretches; ledger {} rows, {:.5} lx·h, {} open; {:.1} s",
            stretches.len() - fresh,
            rows.len(),
            view.as_ref().map_or(0.0, |v| v.total_lxh),
            view.as_ref().map_or(0, |v| v.open_reservations),
            r0.elapsed().as_secs_f64()
        );
        if !lost_now.is_empty() {
            under_rounds += 1;
            let msg = format!(
                "round {round}: UNDER-COUNT: {} of {} lit stretches not paid in full, {unpaid_lxh:.5} lx·h unpaid; e.g. {}",
                lost_now.len(),
                stretches.len(),
                lost_now[..lost_now.len().min(2)].join("; ")
            );
            eprintln!("{msg}");
            problems.push(msg);
        }
        last_view = view;
        rounds_done += 1;
    }

    let observed_lxh: f64 =
        stretches.iter().map(|s| s.picture.lux() * (s.to_us - s.from_us) as f64).sum::<f64>() / 3.6e9;
    let ledger_lxh = last_view.as_ref().map_or(0.0, |v| v.total_lxh);
    let lit_cuts: usize = phases.iter().filter(|(p, _)| !p.starts_with("dark")).map(|(_, n)| n).sum();
    clock_slack_us.sort_unstable();
    eprintln!(
        "FIGURES power cuts ({}, seed {seed}, {}): {rounds_done} of {cuts} rounds, {lit_cuts} cuts while lit, phases {phases:?}; \
         {} lit stretches ({fades_seen} fade frames), presses {presses_sent} sent / {presses_seen} seen; \
         {cut_mid_line} cuts in the middle of a console line; \
         rounds with an under-count {under_rounds}, unpaid at the end {unpaid_lxh:.5} lx·h; ledger {ledger_lxh:.5} lx·h / observed {observed_lxh:.5} lx·h = {:.3}; \
         {} open reservations; e2fsck exit codes {fsck_codes:?}; guest clock bound slack median {} µs, max {} µs; \
         {:.1} s ({:.1} s a round)",
        if sync_off { "ledger synchronous=OFF" } else { "ledger synchronous=FULL" },
        qemu_common::accel(),
        stretches.len(),
        if observed_lxh > 0.0 { ledger_lxh / observed_lxh } else { f64::NAN },
        last_view.as_ref().map_or(0, |v| v.open_reservations),
        clock_slack_us.get(clock_slack_us.len() / 2).copied().unwrap_or(0),
        clock_slack_us.last().copied().unwrap_or(0),
        t0.elapsed().as_secs_f64(),
        t0.elapsed().as_secs_f64() / rounds_done.max(1) as f64,
    );
    assert!(problems.is_empty(), "{} problems:\n{}", problems.len(), problems.join("\n"));
    assert!(!stretches.is_empty(), "nothing was lit: the test exercised nothing");
    assert!(2 * lit_cuts >= cuts, "only {lit_cuts} of {cuts} cuts while lit");
}

//! The emulated stage machine shared by `kms_qemu.rs` and `power_qemu.rs`: QEMU (software
//! emulation) booting a stock Debian kernel with a three-output virtio-gpu, the initramfs of
//! `tests/qemu/prepare.sh` (the appliance and `tests/qemu/init`), the guest's console on
//! QEMU's standard input and output, its second serial port (the appliance's button box) on
//! a unix socket, and the bundle the guest plays.

#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use restage_shared::bundle::example::{ExampleSpec, example_certificate, example_frame, example_info};
use restage_shared::bundle::{BundleWriter, SceneKind};
use restage_shared::keys::{public_key_to_pem, signing_key_from_seed};
use restage_shared::policy::{ExposurePolicy, IdleMode};

pub const W: u32 = 640;
pub const H: u32 = 480;
pub const HEADS: usize = 3;
pub const PACKAGES: &str = "qemu-system-x86 busybox-static cpio kmod xz-utils";

/// The bundle's shape: three 640x480 projectors (a mode every virtio-gpu head offers), an
/// original scene and one restoration.
pub fn spec() -> ExampleSpec {
    ExampleSpec { projectors: HEADS, scenes: 2, width: W, height: H, step: 16, ..ExampleSpec::small() }
}

/// Scene ids in bundle order.
pub const SCENES: [(&str, SceneKind); 2] =
    [("original", SceneKind::Original), ("restored-1", SceneKind::Restoration)];

/// Writes the trust directory `dir` (the public key the bundles are signed with).
pub fn write_trust(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let key = signing_key_from_seed([7; 32]);
    std::fs::write(dir.join("test.pem"), public_key_to_pem(&key.verifying_key())).unwrap();
}

/// The emulated machines' policy: showings of `showing_s`, no cooldown, budgets that never
/// run out, idle on the original scene.
pub fn policy(showing_s: u32) -> ExposurePolicy {
    ExposurePolicy {
        max_showing_s: showing_s,
        cooldown_s: 0,
        daily_budget_lxh: 1e6,
        annual_budget_lxh: 1e7,
        warn_at: vec![0.75, 0.9],
        idle: IdleMode::Scene("original".into()),
    }
}

/// Writes a signed bundle of `spec` (the scenes of `SCENES`) with `policy` to `file`.
pub fn write_bundle(file: &Path, spec: &ExampleSpec, policy: &ExposurePolicy) {
    let key = signing_key_from_seed([7; 32]);
    let mut info = example_info(spec);
    info.policy = policy.clone();
    let mut w = BundleWriter::new(info, example_certificate(spec));
    for (s, (id, kind)) in SCENES.into_iter().enumerate() {
        let frames = (0..spec.projectors).map(|k| example_frame(spec, s, k)).collect();
        w.add_scene(id, id, kind, frames).unwrap();
    }
    w.write(&key, std::fs::File::create(file).unwrap()).unwrap();
}

/// True when `RESTAGE_SKIP_QEMU=1` asks to skip (said on stderr); otherwise checks that QEMU
/// is there, failing with the packages to install.
pub fn skipped(what: &str) -> bool {
    if std::env::var("RESTAGE_SKIP_QEMU").is_ok_and(|v| v == "1") {
        eprintln!("RESTAGE_SKIP_QEMU=1: {what} is skipped");
        return true;
    }
    let have_qemu =
        Command::new("qemu-system-x86_64").arg("--version").output().is_ok_and(|o| o.status.success());
    assert!(
        have_qemu,
        "qemu-system-x86_64 not found: install the apt packages {PACKAGES} (or set RESTAGE_SKIP_QEMU=1 to skip this test)"
    );
    false
}

/// Runs `tests/qemu/prepare.sh` for the appliance binary and `payload` (`variant` "disk"
/// adds the disk modules); returns the folder with `vmlinux` and `initrd.cpio`.
pub fn prepare(dir: &Path, payload: &Path, variant: Option<&str>) -> PathBuf {
    let t0 = Instant::now();
    let vm = dir.join("vm");
    let bin = restage_tests::appliance_bin();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("qemu/prepare.sh");
    let prep =
        Command::new("bash").arg(&script).arg(&vm).arg(bin).arg(payload).args(variant).output().unwrap();
    assert!(
        prep.status.success(),
        "{} failed (packages needed: {PACKAGES}):\n{}{}",
        script.display(),
        String::from_utf8_lossy(&prep.stdout),
        String::from_utf8_lossy(&prep.stderr)
    );
    eprintln!("{}prepared in {:.1} s", String::from_utf8_lossy(&prep.stdout), t0.elapsed().as_secs_f64());
    vm
}

/// How to start the machine.
pub struct Boot<'a> {
    pub vm: &'a Path,
    /// Kernel command line beyond `console=ttyS0 quiet loglevel=3` and the heads' modes.
    pub append: String,
    /// The guest's second serial port (the button box), a unix socket QEMU listens on.
    pub button: PathBuf,
    /// QMP's unix socket, if wanted.
    pub qmp: Option<PathBuf>,
    /// More QEMU arguments (disks).
    pub args: Vec<String>,
    /// Echo every console line on stderr (`guest| ...`).
    pub echo: bool,
}

/// Boots the machine: `-machine pc` (software emulation; `RESTAGE_QEMU_ACCEL=kvm` uses KVM
/// where /dev/kvm can run a guest), 512 MB, the virtio-gpu of `HEADS` outputs (`gpu0`, no
/// display), each head forced on at `W`x`H`.
pub fn boot(b: Boot<'_>) -> (Guest, Console) {
    let accel = accel();
    let video: Vec<String> = (1..=HEADS).map(|k| format!("video=Virtual-{k}:{W}x{H}@60e")).collect();
    let append = format!("console=ttyS0 quiet loglevel=3 {} {}", video.join(" "), b.append);
    let mut cmd = Command::new("qemu-system-x86_64");
    cmd.args(["-machine", "pc", "-accel", &accel, "-m", "512", "-nodefaults", "-no-reboot"])
        .args(["-device", "virtio-gpu-pci,max_outputs=3,id=gpu0", "-vga", "none", "-display", "none"])
        .arg("-kernel")
        .arg(b.vm.join("vmlinux"))
        .arg("-initrd")
        .arg(b.vm.join("initrd.cpio"))
        .args(["-append", &append, "-serial", "stdio"])
        .args(["-serial", &format!("unix:{},server=on,wait=off", b.button.display())]);
    if let Some(q) = &b.qmp {
        cmd.args(["-qmp", &format!("unix:{},server=on,wait=off", q.display())]);
    }
    cmd.args(&b.args);
    spawn(cmd, b.echo)
}

/// Starts QEMU as `cmd` says, its standard output being the guest's console (read by a thread
/// into the returned `Console`, each line echoed on stderr when `echo`).
pub fn spawn(mut cmd: Command, echo: bool) -> (Guest, Console) {
    let mut child = cmd
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("qemu-system-x86_64 starts");
    let stdin = child.stdin.take().unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        let mut r = BufReader::new(stdout);
        let mut buf = Vec::new();
        while r.read_until(b'\n', &mut buf).is_ok_and(|n| n > 0) {
            let at = Instant::now();
            let whole = buf.ends_with(b"\n");
            let text = String::from_utf8_lossy(&buf).replace('\r', "").trim_end().to_string();
            buf.clear();
            if tx.send((at, text, whole)).is_err() {
                return;
            }
        }
    });
    (Guest(child), Console { stdin, lines, seen: Vec::new(), seen_at: Vec::new(), cut_short: None, echo })
}

/// `tcg` (software emulation), or `RESTAGE_QEMU_ACCEL`.
pub fn accel() -> String {
    std::env::var("RESTAGE_QEMU_ACCEL").unwrap_or_else(|_| "tcg".into())
}

/// The QEMU process; killed (SIGKILL) when dropped.
pub struct Guest(pub Child);

impl Guest {
    /// SIGKILL to QEMU: the machine stops at once, as at a power cut.
    pub fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for Guest {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The guest's console: lines arrive on a channel with the moment they arrived, and are kept.
pub struct Console {
    stdin: ChildStdin,
    lines: mpsc::Receiver<(Instant, String, bool)>,
    pub seen: Vec<String>,
    /// When each line of `seen` arrived.
    pub seen_at: Vec<Instant>,
    /// The last line when QEMU stopped in the middle of it (a power cut while the guest was
    /// writing): its last field may be cut, so it is kept here and not in `seen`.
    pub cut_short: Option<String>,
    echo: bool,
}

impl Console {
    fn keep(&mut self, at: Instant, line: String, whole: bool) {
        if self.echo {
            eprintln!("guest| {line}{}", if whole { "" } else { " [cut short]" });
        }
        if !whole {
            self.cut_short = Some(line);
            return;
        }
        self.seen.push(line);
        self.seen_at.push(at);
    }

    /// Waits for a line containing every one of `parts`; returns it.
    pub fn wait_for(&mut self, parts: &[&str], timeout: Duration) -> String {
        self.wait_for_at(parts, timeout).1
    }

    /// Waits for a line containing every one of `parts`; returns when it arrived, and it.
    pub fn wait_for_at(&mut self, parts: &[&str], timeout: Duration) -> (Instant, String) {
        self.wait_for_opt(parts, timeout).unwrap_or_else(|| {
            panic!(
                "no console line with {parts:?} within {timeout:?} (or QEMU exited); console:\n{}",
                self.seen.join("\n")
            )
        })
    }

    /// Waits for a line containing every one of `parts`; `None` when the timeout passes or
    /// QEMU exits first.
    pub fn wait_for_opt(&mut self, parts: &[&str], timeout: Duration) -> Option<(Instant, String)> {
        let start = Instant::now();
        loop {
            let left = timeout.checked_sub(start.elapsed())?;
            match self.lines.recv_timeout(left) {
                Ok((at, line, whole)) => {
                    self.keep(at, line.clone(), whole);
                    if parts.iter().all(|p| line.contains(p)) {
                        return Some((at, line));
                    }
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => return None,
            }
        }
    }

    /// Keeps the lines that arrive until `until`.
    pub fn pump_until(&mut self, until: Instant) {
        while let Some(left) = until.checked_duration_since(Instant::now()) {
            match self.lines.recv_timeout(left) {
                Ok((at, line, whole)) => self.keep(at, line, whole),
                Err(mpsc::RecvTimeoutError::Timeout) => return,
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    std::thread::sleep(left);
                    return;
                }
            }
        }
    }

    /// After QEMU is gone: keeps every line it had written (until the pipe's end).
    pub fn drain(&mut self) {
        while let Ok((at, line, whole)) = self.lines.recv_timeout(Duration::from_secs(10)) {
            self.keep(at, line, whole);
        }
    }

    /// Sends a command line to the guest's init.
    pub fn command(&mut self, cmd: &str) {
        self.stdin.write_all(format!("{cmd}\n").as_bytes()).unwrap();
        self.stdin.flush().unwrap();
    }
}

/// Connects to the guest's button box port and waits until the appliance answers `PING`
/// (bytes sent before the guest opens the port are lost).
pub fn button(path: &Path) -> UnixStream {
    let mut button = UnixStream::connect(path).expect("serial socket");
    button.set_read_timeout(Some(Duration::from_millis(300))).unwrap();
    let start = Instant::now();
    let mut got = Vec::new();
    while !String::from_utf8_lossy(&got).contains("PONG") {
        assert!(start.elapsed() < Duration::from_secs(30), "no PONG from the appliance's serial input");
        button.write_all(b"PING\n").unwrap();
        let mut b = [0u8; 64];
        if let Ok(n) = button.read(&mut b) {
            got.extend_from_slice(&b[..n]);
        }
    }
    button
}

/// Seconds since midnight of a tracing line's timestamp (`2026-01-01T12:34:56.789012Z ...`).
pub fn stamp_s(line: &str) -> Option<f64> {
    let t = line.split_whitespace().next()?.split('T').nth(1)?.trim_end_matches('Z');
    let mut parts = t.split(':');
    let (h, m, s): (f64, f64, f64) =
        (parts.next()?.parse().ok()?, parts.next()?.parse().ok()?, parts.next()?.parse().ok()?);
    Some(h * 3600.0 + m * 60.0 + s)
}

/// The value of `key=NUMBER` in a tracing line (the whole key: `unix_us` is not found in
/// `commit_unix_us=`).
pub fn field(line: &str, key: &str) -> Option<u64> {
    let pat = format!("{key}=");
    let at =
        line.match_indices(&pat).map(|(i, _)| i).find(|&i| {
            !line[..i].chars().next_back().is_some_and(|c| c.is_ascii_alphanumeric() || c == '_')
        })? + pat.len();
    line[at..].split(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
}

/// The text of `key=VALUE` (up to the next space) in a tracing line.
pub fn text_field<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    let pat = format!(" {key}=");
    let at = line.find(&pat)? + pat.len();
    line[at..].split_whitespace().next()
}

/// One emulated machine at a time in a test binary (two software-emulated CPUs on a 2-core
/// machine would slow each other past a showing's length).
pub static MACHINE: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// QMP: one JSON command per line, skipping asynchronous events.
pub struct Qmp {
    stream: BufReader<UnixStream>,
}

impl Qmp {
    pub fn connect(path: &Path) -> Qmp {
        let start = Instant::now();
        let s = loop {
            match UnixStream::connect(path) {
                Ok(s) => break s,
                Err(e) if start.elapsed() > Duration::from_secs(20) => panic!("QMP {}: {e}", path.display()),
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        let mut q = Qmp { stream: BufReader::new(s) };
        q.read_reply(); // the greeting
        q.execute(serde_json::json!({"execute": "qmp_capabilities"}));
        q
    }

    fn read_reply(&mut self) -> serde_json::Value {
        loop {
            let mut line = String::new();
            self.stream.read_line(&mut line).expect("QMP answers");
            assert!(!line.is_empty(), "QMP closed");
            let v: serde_json::Value = serde_json::from_str(&line).expect("QMP speaks JSON");
            if v.get("event").is_none() {
                return v;
            }
        }
    }

    pub fn execute(&mut self, cmd: serde_json::Value) -> serde_json::Value {
        let s = self.stream.get_mut();
        s.write_all(format!("{cmd}\n").as_bytes()).unwrap();
        let v = self.read_reply();
        assert!(v.get("error").is_none(), "QMP {cmd}: {v}");
        v
    }

    /// Head `head`'s picture as RGB8.
    pub fn screendump(&mut self, dir: &Path, head: usize) -> (u32, u32, Vec<u8>) {
        let file = dir.join(format!("head{head}.png"));
        let _ = std::fs::remove_file(&file);
        self.execute(serde_json::json!({"execute": "screendump", "arguments": {
            "filename": file, "device": "gpu0", "head": head, "format": "png"}}));
        let img = image::open(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display())).to_rgb8();
        (img.width(), img.height(), img.into_raw())
    }
}

/// Checks that `heads` (all when `None`) show `want[k]`, polling until `timeout` (see
/// `these_heads_show`); panics naming `what` otherwise. With `RESTAGE_QEMU_SHOTS=DIR` the
/// last screendumps are kept as `DIR/<variant>-<n>-<what>-head<k>.png` (pass or fail), for
/// people to look at.
pub fn expect_heads(
    qmp: &mut Qmp,
    dir: &Path,
    heads: Option<&[usize]>,
    want: &[Vec<u8>],
    timeout: Duration,
    what: &str,
) {
    let all: Vec<usize> = (0..want.len()).collect();
    let heads = heads.unwrap_or(&all);
    let result = these_heads_show(qmp, dir, heads, want, timeout);
    if let Ok(keep) = std::env::var("RESTAGE_QEMU_SHOTS") {
        static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let variant = dir.file_name().and_then(|f| f.to_str()).unwrap_or("shots");
        let slug: String = what.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '-' }).collect();
        std::fs::create_dir_all(&keep).unwrap();
        for &k in heads {
            let to = Path::new(&keep).join(format!("{variant}-{n:02}-{slug}-head{k}.png"));
            let _ = std::fs::copy(dir.join(format!("head{k}.png")), to);
        }
    }
    if let Err(e) = result {
        panic!("{what}: {e}");
    }
}

/// Polls the heads in `heads` until each equals `want[k]` (RGB8, W x H) or the timeout
/// passes; returns the last mismatch.
pub fn these_heads_show(
    qmp: &mut Qmp,
    dir: &Path,
    heads: &[usize],
    want: &[Vec<u8>],
    timeout: Duration,
) -> Result<(), String> {
    let start = Instant::now();
    loop {
        let mut bad = None;
        for &k in heads {
            let want = &want[k];
            let (w, h, got) = qmp.screendump(dir, k);
            if (w, h) != (W, H) {
                bad = Some(format!("head {k} is {w}x{h}, not {W}x{H}"));
                break;
            }
            if got != *want {
                let diff = got.iter().zip(want).filter(|(a, b)| a != b).count();
                bad = Some(format!("head {k}: {diff} of {} bytes differ", want.len()));
                break;
            }
        }
        match bad {
            None => return Ok(()),
            Some(b) if start.elapsed() > timeout => return Err(b),
            Some(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}

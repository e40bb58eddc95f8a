//! The status page over real HTTP on loopback: routes, JSON round trip, a new snapshot seen
//! on the next request, limits; and the page rendered by headless Chromium (skipped with
//! `RESTAGE_SKIP_BROWSER=1`).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use restage_appliance::status::{self, Limits, Snapshot, StateKind};
use tokio::sync::watch;

/// A server on 127.0.0.1:0 on its own current-thread runtime (as on the appliance).
struct Server {
    addr: SocketAddr,
    tx: watch::Sender<Arc<Snapshot>>,
    _thread: std::thread::JoinHandle<()>,
}

fn start(snap: Snapshot, limits: Limits) -> Server {
    let (tx, rx) = watch::channel(Arc::new(snap));
    let (addr_tx, addr_rx) = std::sync::mpsc::channel();
    let thread = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        rt.block_on(async move {
            let listener = status::bind("127.0.0.1:0".parse().unwrap()).await.unwrap();
            addr_tx.send(listener.local_addr().unwrap()).unwrap();
            // Ends with the test process (the thread is detached).
            status::serve(listener, rx, limits).await;
        });
    });
    let addr = addr_rx.recv_timeout(Duration::from_secs(10)).expect("server did not start");
    Server { addr, tx, _thread: thread }
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(10)))
        .build()
        .into()
}

/// (status, content type, body)
fn get(addr: SocketAddr, path: &str) -> (u16, String, String) {
    let mut r = agent().get(format!("http://{addr}{path}")).call().unwrap();
    let ct = r.headers().get("content-type").map(|v| v.to_str().unwrap().to_string()).unwrap_or_default();
    (r.status().as_u16(), ct, r.body_mut().read_to_string().unwrap())
}

#[test]
fn serves_page_json_metrics_and_404() {
    let s = start(Snapshot::example(), Limits::default());

    let (code, ct, page) = get(s.addr, "/");
    assert_eq!((code, ct.as_str()), (200, "text/html; charset=utf-8"));
    assert!(page.contains("Europe/Berlin") && page.contains("retable-st-anne"), "{page}");

    let (code, ct, json) = get(s.addr, "/status.json");
    assert_eq!((code, ct.as_str()), (200, "application/json"));
    let back: Snapshot = serde_json::from_str(&json).unwrap();
    assert_eq!(back, Snapshot::example());
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["schema"], 1);
    assert_eq!(v["state"]["kind"], "showing");

    let (code, ct, metrics) = get(s.addr, "/metrics");
    assert_eq!((code, ct.as_str()), (200, "text/plain; version=0.0.4; charset=utf-8"));
    assert!(metrics.lines().any(|l| l == "restage_up 1"), "{metrics}");
    assert!(metrics.lines().any(|l| l == "restage_state{state=\"showing\"} 1"), "{metrics}");

    let (code, _, _) = get(s.addr, "/admin");
    assert_eq!(code, 404);
    let (code, _, _) = get(s.addr, "/status.json?x=1");
    assert_eq!(code, 200, "a query string does not change the route");

    let r = agent().post(format!("http://{}/", s.addr)).send("press").unwrap();
    assert_eq!(r.status().as_u16(), 405);
    assert_eq!(r.headers()["allow"], "GET, HEAD");
    let r = agent().head(format!("http://{}/", s.addr)).call().unwrap();
    assert_eq!(r.status().as_u16(), 200);
}

#[test]
fn a_new_snapshot_is_seen_on_the_next_request() {
    let s = start(Snapshot::example(), Limits::default());
    assert!(get(s.addr, "/metrics").2.contains("restage_state{state=\"showing\"} 1"));

    let mut next = Snapshot::example();
    next.state.kind = StateKind::BudgetExhausted;
    next.state.detail = Some("daily budget used up".into());
    s.tx.send_replace(Arc::new(next.clone()));

    let back: Snapshot = serde_json::from_str(&get(s.addr, "/status.json").2).unwrap();
    assert_eq!(back, next);
    assert!(get(s.addr, "/metrics").2.contains("restage_state{state=\"budget-exhausted\"} 1"));
    assert!(get(s.addr, "/").2.contains("daily budget used up"));
}

#[test]
fn a_silent_client_is_dropped_and_does_not_block_others() {
    let limits = Limits {
        max_connections: 2,
        header_read_timeout: Duration::from_millis(300),
        connection_timeout: Duration::from_secs(5),
        max_header_bytes: 8192,
    };
    let s = start(Snapshot::example(), limits);
    // Two clients that connect and say nothing hold both connection slots...
    let mut silent: Vec<TcpStream> = (0..2).map(|_| TcpStream::connect(s.addr).unwrap()).collect();
    let t0 = Instant::now();
    // ...until the header timeout closes them; then a real request is served.
    assert_eq!(get(s.addr, "/").0, 200);
    assert!(t0.elapsed() < Duration::from_secs(4), "waited {:?}", t0.elapsed());
    for c in &mut silent {
        c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut buf = Vec::new();
        // Closed by the server (EOF, possibly after a 408 it wrote) rather than held open.
        let _ = c.read_to_end(&mut buf);
        let text = String::from_utf8_lossy(&buf);
        assert!(buf.is_empty() || text.starts_with("HTTP/1.1 408"), "{text}");
    }
}

#[test]
fn an_oversized_request_head_is_refused() {
    let s = start(Snapshot::example(), Limits::default());
    let mut c = TcpStream::connect(s.addr).unwrap();
    c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let big = "x".repeat(64 * 1024);
    // The server may close before all of it is written; only its answer matters.
    let _ = write!(c, "GET / HTTP/1.1\r\nHost: a\r\nX-Big: {big}\r\n\r\n");
    let mut buf = Vec::new();
    let _ = c.read_to_end(&mut buf);
    let text = String::from_utf8_lossy(&buf);
    assert!(text.is_empty() || text.starts_with("HTTP/1.1 431"), "{text}");
    assert!(!text.contains("<html"), "served a page for a 64 KiB header");
}

/// Where the screenshot goes: `$CARGO_TARGET_DIR/tmp` (or the system's temp folder).
fn screenshot_path() -> PathBuf {
    let dir = std::env::var_os("CARGO_TARGET_TMPDIR")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("CARGO_TARGET_DIR").map(|d| PathBuf::from(d).join("tmp")))
        .unwrap_or_else(std::env::temp_dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir.join("status-page.png")
}

fn chromium() -> Option<&'static str> {
    ["chromium", "chromium-browser", "google-chrome"].into_iter().find(|b| {
        Command::new(b).arg("--version").stdout(Stdio::null()).stderr(Stdio::null()).status().is_ok()
    })
}

#[test]
fn headless_chromium_renders_the_page() {
    if std::env::var_os("RESTAGE_SKIP_BROWSER").is_some_and(|v| v == "1") {
        println!("skipped: RESTAGE_SKIP_BROWSER=1 (the status page is not rendered in a browser)");
        return;
    }
    let browser = chromium().expect(
        "no chromium: install Debian's package `chromium` (apt-get install -y chromium), \
         or set RESTAGE_SKIP_BROWSER=1 to skip this test",
    );
    let s = start(Snapshot::example(), Limits::default());
    let png_path = screenshot_path();
    let _ = std::fs::remove_file(&png_path);
    let profile = tempfile::tempdir().unwrap();
    let mut child = Command::new(browser)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run"])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--screenshot={}", png_path.display()))
        .arg("--window-size=1200,1600")
        .arg(format!("http://{}/", s.addr))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(90);
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("chromium took over 90 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut err = String::new();
    let _ = child.stderr.take().map(|mut e| e.read_to_string(&mut err));
    assert!(status.success() && png_path.exists(), "chromium failed ({status}): {err}");

    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png_path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (1200, 1600), "{}", png_path.display());
    let channels = info.color_type.samples();
    assert!(channels >= 3 && info.bit_depth == png::BitDepth::Eight, "{:?}", info.color_type);
    let colours: std::collections::HashSet<&[u8]> =
        buf[..info.buffer_size()].chunks_exact(channels).map(|p| &p[..3]).collect();
    assert!(colours.len() > 20, "only {} colours: a blank page?", colours.len());
    // The banner (showing: green #1e7d3a) is near the top.
    let row = 60 * info.line_size;
    let banner_green = buf[row..row + info.line_size]
        .chunks_exact(channels)
        .filter(|p| p[..3] == [0x1e, 0x7d, 0x3a])
        .count();
    assert!(banner_green > 500, "banner colour on {banner_green} pixels of row 60");
    println!("screenshot: {}", png_path.display());
}

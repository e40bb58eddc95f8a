//! The serial button box protocol over a real pseudo-terminal pair (the appliance opens the
//! slave through tokio-serial like a USB adapter): presses and releases arrive; garbage,
//! partial lines, overlong lines and a flood are survived, and the port keeps answering.

use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::sync::mpsc as std_mpsc;
use std::time::{Duration, Instant};

use nix::pty::openpty;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use restage_appliance::feedback::Availability;
use restage_appliance::input::{InputEvent, serial};
use tokio::sync::mpsc;

struct Box_ {
    master: std::fs::File,
    replies: std_mpsc::Receiver<u8>,
    events: mpsc::Receiver<InputEvent>,
    _keep: (std::os::fd::OwnedFd, std::thread::JoinHandle<()>),
}

impl Box_ {
    fn open() -> Box_ {
        let pty = openpty(None, None).unwrap();
        let path = nix::unistd::ttyname(pty.slave.as_fd()).unwrap();
        let (tx, events) = mpsc::channel(restage_appliance::input::CHANNEL_CAPACITY);
        let rt = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
            // The box's LED lines are not looked at here; they only interleave with PONGs.
            let (_publish, availability) = tokio::sync::watch::channel(Availability::Ready);
            rt.block_on(serial::run(path, 115_200, tx, availability));
        });
        let master = std::fs::File::from(pty.master);
        let mut reader = master.try_clone().unwrap();
        let (rtx, replies) = std_mpsc::channel();
        std::thread::spawn(move || {
            let mut b = [0u8; 256];
            while let Ok(n) = reader.read(&mut b) {
                if n == 0 {
                    break;
                }
                for &c in &b[..n] {
                    if rtx.send(c).is_err() {
                        return;
                    }
                }
            }
        });
        Box_ { master, replies, events, _keep: (pty.slave, rt) }
    }

    fn send(&mut self, bytes: &[u8]) {
        self.master.write_all(bytes).unwrap();
        self.master.flush().unwrap();
    }

    /// PING until PONG: the port is open (and raw) and the reader keeps up.
    fn ping(&mut self, timeout: Duration) {
        let start = Instant::now();
        let mut seen = Vec::new();
        while start.elapsed() < timeout {
            self.send(b"PING\n");
            let until = Instant::now() + Duration::from_millis(200);
            while let Ok(c) = self.replies.recv_timeout(until.saturating_duration_since(Instant::now())) {
                seen.push(c);
                if seen.windows(5).any(|w| w == b"PONG\n") {
                    // Drain whatever else arrived (extra PONGs).
                    std::thread::sleep(Duration::from_millis(50));
                    while self.replies.try_recv().is_ok() {}
                    return;
                }
            }
        }
        panic!("no PONG within {timeout:?}; got {:?}", String::from_utf8_lossy(&seen));
    }

    /// Events that arrive within `wait`: (presses, releases).
    fn drain(&mut self, wait: Duration) -> (usize, usize) {
        let (mut p, mut r) = (0, 0);
        let until = Instant::now() + wait;
        while Instant::now() < until {
            match self.events.try_recv() {
                Ok(InputEvent::Press { source }) => {
                    assert_eq!(source, "serial");
                    p += 1
                }
                Ok(InputEvent::Release { .. }) => r += 1,
                Ok(e) => panic!("unexpected {e:?}"),
                Err(_) => std::thread::sleep(Duration::from_millis(5)),
            }
        }
        (p, r)
    }
}

#[test]
fn protocol_over_a_pty_survives_garbage_partial_lines_and_floods() {
    let mut b = Box_::open();
    b.ping(Duration::from_secs(20));
    assert_eq!(b.drain(Duration::from_millis(50)), (0, 0));

    b.send(b"PRESS\nRELEASE\r\n");
    assert_eq!(b.drain(Duration::from_millis(300)), (1, 1));

    // A line split across writes, with a pause, is one press.
    b.send(b"PRE");
    std::thread::sleep(Duration::from_millis(100));
    b.send(b"SS\r\n");
    assert_eq!(b.drain(Duration::from_millis(300)), (1, 0));

    // Seeded garbage (no line ends inside) then a line end: nothing; then a press: one.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let garbage: Vec<u8> =
        (0..5000).map(|_| rng.r#gen::<u8>()).filter(|c| *c != b'\n' && *c != b'\r').collect();
    b.send(&garbage);
    b.send(b"\nPRESS\n");
    assert_eq!(b.drain(Duration::from_millis(300)), (1, 0));

    // Lower case and blanks are accepted; near-misses are not.
    b.send(b"  press \nPRESSS\nPRES\nXPRESS\n");
    assert_eq!(b.drain(Duration::from_millis(300)), (1, 0));

    // A flood of 100 000 presses while nobody reads the channel: bounded, not fatal.
    let flood = b"PRESS\n".repeat(100_000);
    b.send(&flood);
    b.ping(Duration::from_secs(30));
    let (p, _) = b.drain(Duration::from_millis(300));
    assert!((1..=restage_appliance::input::CHANNEL_CAPACITY).contains(&p), "{p} presses kept from the flood");

    // Still working afterwards.
    b.send(b"PRESS\n");
    assert_eq!(b.drain(Duration::from_millis(300)), (1, 0));
}

//! The serial box's LED lines over a real pseudo-terminal (opened by tokio-serial like a USB
//! adapter): the current state when the port opens, every change, `STATE?`; and a box that
//! never reads (the kernel's tty buffer full) still gets its presses through.

use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::sync::mpsc as std_mpsc;
use std::time::{Duration, Instant};

use nix::pty::openpty;
use restage_appliance::feedback::{Availability, publish};
use restage_appliance::input::{InputEvent, serial};
use tokio::sync::{mpsc, watch};

struct Pty {
    master: std::fs::File,
    publish: watch::Sender<Availability>,
    events: mpsc::Receiver<InputEvent>,
    _keep: (std::os::fd::OwnedFd, std::thread::JoinHandle<()>),
}

fn open(first: Availability) -> Pty {
    let pty = openpty(None, None).unwrap();
    let path = nix::unistd::ttyname(pty.slave.as_fd()).unwrap();
    let (tx, events) = mpsc::channel(restage_appliance::input::CHANNEL_CAPACITY);
    let (publish, availability) = watch::channel(first);
    let rt = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        rt.block_on(serial::run(path, 115_200, tx, availability));
    });
    Pty { master: std::fs::File::from(pty.master), publish, events, _keep: (pty.slave, rt) }
}

/// Reads the master on a thread, line by line.
fn lines(master: &std::fs::File) -> std_mpsc::Receiver<String> {
    let mut reader = master.try_clone().unwrap();
    let (tx, rx) = std_mpsc::channel();
    std::thread::spawn(move || {
        let mut line = Vec::new();
        let mut b = [0u8; 256];
        while let Ok(n) = reader.read(&mut b) {
            if n == 0 {
                return;
            }
            for &c in &b[..n] {
                if c == b'\n' {
                    if tx.send(String::from_utf8_lossy(&line).into_owned()).is_err() {
                        return;
                    }
                    line.clear();
                } else if c != b'\r' {
                    line.push(c);
                }
            }
        }
    });
    rx
}

fn next(rx: &std_mpsc::Receiver<String>) -> String {
    rx.recv_timeout(Duration::from_secs(20)).expect("a line from the appliance")
}

#[test]
fn led_lines_over_a_pty() {
    let mut p = open(Availability::Exhausted);
    let rx = lines(&p.master);
    // The port opens within a moment; the first thing the box hears is the state.
    assert_eq!(next(&rx), "LED EXHAUSTED");
    publish(&p.publish, Availability::Ready);
    assert_eq!(next(&rx), "LED READY");
    publish(&p.publish, Availability::Wait { until_mono_ms: 1 });
    assert_eq!(next(&rx), "LED WAIT");
    p.master.write_all(b"STATE?\r\nPING\n").unwrap();
    assert_eq!(next(&rx), "LED WAIT");
    assert_eq!(next(&rx), "PONG");
    p.master.write_all(b"PRESS\n").unwrap();
    let ev = p.events.blocking_recv();
    assert!(matches!(ev, Some(InputEvent::Press { source: "serial" })), "{ev:?}");
}

#[test]
fn a_box_that_never_reads_still_presses() {
    let mut p = open(Availability::Ready);
    // Nobody reads the master: thousands of LED lines fill the kernel's buffer.
    let start = Instant::now();
    let mut k = 0u64;
    while start.elapsed() < Duration::from_secs(2) {
        let a = if k.is_multiple_of(2) { Availability::Showing } else { Availability::Closed };
        publish(&p.publish, a);
        k += 1;
        std::thread::sleep(Duration::from_micros(200));
    }
    // Presses still arrive at once, each well under the writer's timeout.
    for n in 0..10u32 {
        p.master.write_all(b"PRESS\n").unwrap();
        let t = Instant::now();
        loop {
            match p.events.try_recv() {
                Ok(InputEvent::Press { .. }) => break,
                Ok(e) => panic!("unexpected {e:?}"),
                Err(_) if t.elapsed() > Duration::from_secs(5) => panic!("press {n} never arrived"),
                Err(_) => std::thread::sleep(Duration::from_millis(2)),
            }
        }
        assert!(t.elapsed() < serial::WRITE_TIMEOUT * 2, "press {n} took {:?}", t.elapsed());
        publish(&p.publish, if n.is_multiple_of(2) { Availability::Ready } else { Availability::OutOfOrder });
    }
}

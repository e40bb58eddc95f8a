//! PJLink client and controller against the simulated projector on loopback: warm-up,
//! cool-down, mute, authentication, classes, and the faults (silent, garbage, refused, lamp).
//! Every wait is bounded; the simulator's warm-up and cool-down are fractions of a second.

use std::sync::Arc;
use std::time::Duration;

use proptest::prelude::*;
use restage_appliance::clock::SystemTime;
use restage_appliance::pjlink::protocol::Command;
use restage_appliance::pjlink::sim::{self, Fault, SimConfig, SimProjector};
use restage_appliance::pjlink::{
    Class, ErrCode, Level, PjlinkControl, PjlinkError, PowerState, Projector, ProjectorSpec, ProjectorStatus,
    Timing, Want,
};
use tokio::time::Instant;

const LIMIT: Duration = Duration::from_secs(10);

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn timing() -> Timing {
    Timing {
        poll: ms(200),
        busy_poll: ms(40),
        timeout: ms(300),
        warmup_max: Duration::from_secs(5),
        cooldown_max: Duration::from_secs(5),
        retry_max: ms(400),
    }
}

fn spec(name: &str, address: String, password: Option<&str>) -> ProjectorSpec {
    ProjectorSpec { name: name.into(), address, password: password.map(str::to_string) }
}

fn control(specs: &[ProjectorSpec]) -> PjlinkControl {
    PjlinkControl::spawn(specs, timing(), Arc::new(SystemTime))
}

/// Asking must return at once (it only records the wish).
const ASKING: Duration = Duration::from_millis(100);

/// Waits (bounded) until projector `i`'s status satisfies `pred`; returns it.
async fn status_where(
    c: &PjlinkControl,
    i: usize,
    pred: impl Fn(&ProjectorStatus) -> bool,
) -> ProjectorStatus {
    let mut rx = c.subscribe().swap_remove(i);
    let waited = tokio::time::timeout(LIMIT, rx.wait_for(|s| pred(s))).await;
    match waited {
        Ok(Ok(s)) => s.clone(),
        _ => panic!("status never matched; last: {:?}", c.statuses()[i]),
    }
}

async fn sim_where(p: &SimProjector, pred: impl Fn(&SimProjector) -> bool) {
    let t0 = Instant::now();
    while !pred(p) {
        assert!(t0.elapsed() < LIMIT, "simulator never matched: {:?}", p.power());
        tokio::time::sleep(ms(5)).await;
    }
}

fn client(p: &SimProjector, password: Option<&str>) -> Projector {
    Projector::new(&p.address(), password, ms(500))
}

#[tokio::test]
async fn power_on_waits_for_warm_up() {
    let p = SimProjector::start(SimConfig { warmup: ms(400), ..SimConfig::default() }).await.unwrap();
    let c = control(&[spec("left", p.address(), None)]);
    let t0 = Instant::now();
    c.want(Want::On);
    assert!(t0.elapsed() < ASKING, "asking blocks");
    let warming = status_where(&c, 0, |s| s.power == Some(PowerState::Warming)).await;
    assert!(!warming.ready, "ready while warming: {warming:?}");
    assert!(c.wait_ready(LIMIT).await, "{:?}", c.statuses());
    assert!(t0.elapsed() >= ms(400), "ready before the warm-up ended: {:?}", t0.elapsed());
    assert_eq!(p.power(), PowerState::On);
    let ons = p.commands().iter().filter(|l| *l == "%1POWR 1").count();
    assert_eq!(ons, 1, "{:?}", p.commands());
    let s = &c.statuses()[0];
    assert!(s.reachable && s.settled() && s.last_error.is_none(), "{s:?}");
    assert!(s.last_poll_unix_ms.is_some_and(|t| t > 1_600_000_000_000));
}

#[tokio::test]
async fn no_power_on_is_sent_while_cooling_down() {
    let p = SimProjector::start(SimConfig { warmup: ms(50), cooldown: ms(500), ..SimConfig::default() })
        .await
        .unwrap();
    let c = control(&[spec("left", p.address(), None)]);
    c.want(Want::On);
    assert!(c.wait_ready(LIMIT).await);
    c.want(Want::Standby);
    sim_where(&p, |p| p.power() == PowerState::Cooling).await;
    let cooling_from = Instant::now();
    // The visitor comes back at once: on is wanted again during the cool-down.
    c.want(Want::On);
    let cooling = status_where(&c, 0, |s| s.power == Some(PowerState::Cooling)).await;
    assert!(!cooling.ready);
    assert!(c.wait_ready(LIMIT).await, "{:?}", c.statuses());
    assert!(cooling_from.elapsed() >= ms(450), "on before the cool-down ended: {:?}", cooling_from.elapsed());
    let received = p.received();
    assert!(
        !received.iter().any(|r| r.line == "%1POWR 1" && r.power == PowerState::Cooling),
        "power on sent while cooling: {received:?}"
    );
    assert_eq!(received.iter().filter(|r| r.line == "%1POWR 0").count(), 1, "{received:?}");
    assert_eq!(received.iter().filter(|r| r.line == "%1POWR 1").count(), 2, "{received:?}");
}

#[tokio::test]
async fn standby_while_warming_waits_for_on_then_switches_off() {
    let p = SimProjector::start(SimConfig { warmup: ms(300), cooldown: ms(100), ..SimConfig::default() })
        .await
        .unwrap();
    let c = control(&[spec("left", p.address(), None)]);
    c.want(Want::On);
    sim_where(&p, |p| p.power() == PowerState::Warming).await;
    c.want(Want::Standby);
    assert!(c.wait_settled(LIMIT).await, "{:?}", c.statuses());
    assert_eq!(p.power(), PowerState::Off);
    assert!(
        !p.received().iter().any(|r| r.line == "%1POWR 0" && r.power == PowerState::Warming),
        "standby sent while warming: {:?}",
        p.received()
    );
}

#[tokio::test]
async fn mute_and_unmute() {
    let p = SimProjector::start(SimConfig { power: PowerState::On, ..SimConfig::default() }).await.unwrap();
    let c = control(&[spec("left", p.address(), None)]);
    c.want(Want::Mute(true));
    assert!(c.wait_settled(LIMIT).await, "{:?}", c.statuses());
    assert!(p.mute().video && p.mute().audio);
    assert_eq!(c.statuses()[0].muted, Some(true));
    c.want(Want::Mute(false));
    assert!(c.wait_settled(LIMIT).await, "{:?}", c.statuses());
    assert!(!p.mute().video);
    assert_eq!(c.statuses()[0].muted, Some(false));
    let avmt: Vec<String> = p.commands().into_iter().filter(|l| l.starts_with("%1AVMT 3")).collect();
    assert_eq!(avmt, ["%1AVMT 31", "%1AVMT 30"]);
}

#[tokio::test]
async fn a_mute_wanted_while_off_is_applied_as_soon_as_it_is_on() {
    let p = SimProjector::start(SimConfig { warmup: ms(200), ..SimConfig::default() }).await.unwrap();
    let c = control(&[spec("left", p.address(), None)]);
    c.want(Want::Mute(true));
    c.want(Want::On);
    assert!(c.wait_ready(LIMIT).await, "{:?}", c.statuses());
    assert!(p.mute().video, "on but not muted");
    let s = &c.statuses()[0];
    assert_eq!((s.power, s.muted), (Some(PowerState::On), Some(true)));
    // The mute went out in the first exchange that found the projector on: no other poll
    // between the first `POWR ?` answered "on" and `AVMT 31`.
    let received = p.received();
    let first_on = received.iter().position(|r| r.line == "%1POWR ?" && r.power == PowerState::On).unwrap();
    let muted = received.iter().position(|r| r.line == "%1AVMT 31").unwrap();
    assert!(first_on < muted, "{received:?}");
    assert!(!received[first_on + 1..muted].iter().any(|r| r.line == "%1POWR ?"), "{received:?}");
    assert!(!received[..muted].iter().any(|r| r.line.starts_with("%1AVMT 3")), "{received:?}");
}

#[tokio::test]
async fn repeating_a_wish_costs_nothing() {
    let p = SimProjector::start(SimConfig { power: PowerState::On, ..SimConfig::default() }).await.unwrap();
    let c = PjlinkControl::spawn(
        &[spec("left", p.address(), None)],
        Timing { poll: Duration::from_secs(30), ..timing() },
        Arc::new(SystemTime),
    );
    c.want(Want::Mute(true));
    assert!(c.wait_settled(LIMIT).await);
    let n = p.connections();
    for _ in 0..50 {
        c.want(Want::Mute(true));
    }
    tokio::time::sleep(ms(200)).await;
    assert_eq!(p.connections(), n, "an unchanged wish woke the projector's task");
    c.want(Want::Mute(false));
    assert!(c.wait_settled(LIMIT).await);
    assert!(p.connections() > n);
}

#[tokio::test]
async fn wrong_password_gives_a_clear_auth_error() {
    let p = SimProjector::start(SimConfig {
        password: Some("JBMIAProjectorLink".into()),
        ..SimConfig::default()
    })
    .await
    .unwrap();
    assert_eq!(client(&p, Some("JBMIAProjectorLink")).power().await, Ok(PowerState::Off));
    let e = client(&p, Some("wrong")).power().await.unwrap_err();
    assert_eq!(e, PjlinkError::Auth { address: p.address() });
    assert!(e.to_string().contains("password refused"), "{e}");
    let e = client(&p, None).power().await.unwrap_err();
    assert!(matches!(e, PjlinkError::PasswordRequired { .. }), "{e}");
    // The right password authenticates a whole connection: several commands, one digest.
    let mut session = client(&p, Some("JBMIAProjectorLink")).connect().await.unwrap();
    assert_eq!(session.power().await, Ok(PowerState::Off));
    assert!(session.lamps().await.is_ok());

    let c = control(&[spec("left", p.address(), Some("wrong"))]);
    c.want(Want::On);
    let s = status_where(&c, 0, |s| s.failures >= 1).await;
    assert!(!s.reachable && !s.ready);
    assert!(s.last_error.as_deref().is_some_and(|e| e.contains("password refused")), "{s:?}");
    assert_eq!(p.power(), PowerState::Off);
}

#[tokio::test]
async fn class_one_and_class_two_both_work() {
    let one = SimProjector::start(SimConfig { name: "one".into(), ..SimConfig::default() }).await.unwrap();
    let two =
        SimProjector::start(SimConfig { class: Class::Two, name: "two".into(), ..SimConfig::default() })
            .await
            .unwrap();
    let info = client(&one, None).info().await.unwrap();
    assert_eq!((info.class, info.name.as_str(), info.serial_number), (Some(Class::One), "one", None));
    let info = client(&two, None).info().await.unwrap();
    assert_eq!(info.class, Some(Class::Two));
    assert_eq!(info.serial_number.as_deref(), Some("SIM0001"));
    assert_eq!(info.software_version.as_deref(), Some("1.0"));
    assert_eq!(client(&two, None).connect().await.unwrap().filter_hours().await, Ok(321));
    let e = client(&one, None).connect().await.unwrap().text(Command::Snum).await.unwrap_err();
    assert!(matches!(e, PjlinkError::Refused { code: ErrCode::Undefined, .. }), "{e}");
    assert!(two.commands().contains(&"%2SNUM ?".to_string()));

    let c = control(&[spec("one", one.address(), None), spec("two", two.address(), None)]);
    c.want(Want::On);
    assert!(c.wait_ready(LIMIT).await, "{:?}", c.statuses());
    let s = c.statuses();
    assert_eq!((s[0].class, s[1].class), (Some(Class::One), Some(Class::Two)));
}

#[tokio::test]
async fn a_silent_projector_times_out_without_blocking_the_others() {
    let silent =
        SimProjector::start(SimConfig { fault: Fault::Silent, ..SimConfig::default() }).await.unwrap();
    let good = SimProjector::start(SimConfig { warmup: ms(100), ..SimConfig::default() }).await.unwrap();
    let e = client(&silent, None).power().await.unwrap_err();
    assert!(matches!(e, PjlinkError::Timeout { .. }) && e.is_unreachable(), "{e}");

    // A long timeout: the good projector must be ready while the silent one is still awaited.
    let patient = Timing { timeout: Duration::from_secs(3), ..timing() };
    let specs = [spec("silent", silent.address(), None), spec("good", good.address(), None)];
    let c = PjlinkControl::spawn(&specs, patient, Arc::new(SystemTime));
    let t0 = Instant::now();
    c.want(Want::On);
    c.want(Want::Mute(true));
    assert!(t0.elapsed() < ASKING, "asking blocks");
    let s = status_where(&c, 1, |s| s.ready).await;
    assert_eq!(s.muted, Some(true));
    let silent_now = &c.statuses()[0];
    assert!(
        t0.elapsed() < Duration::from_secs(3) && silent_now.failures == 0,
        "the good projector waited for the silent one: {:?} {silent_now:?}",
        t0.elapsed()
    );
    let s = status_where(&c, 0, |s| s.failures >= 1).await;
    assert!(!s.reachable && !s.ready);
    assert!(s.last_error.as_deref().is_some_and(|e| e.contains("no answer within 3000 ms")), "{s:?}");
    assert!(!c.wait_ready(ms(100)).await);
    sim_where(&silent, |p| p.connections() >= 2).await; // retried
}

#[tokio::test]
async fn a_refused_connection_is_reported_unreachable() {
    let address = sim::closed_port().await.unwrap();
    let e = Projector::new(&address, None, ms(300)).power().await.unwrap_err();
    assert!(matches!(e, PjlinkError::Connect { .. }) && e.is_unreachable(), "{e}");
    let c = control(&[spec("gone", address.clone(), None)]);
    c.want(Want::On);
    let s = status_where(&c, 0, |s| s.failures >= 1).await;
    assert!(!s.reachable && s.last_error.as_deref().is_some_and(|e| e.contains("cannot connect")), "{s:?}");
    assert_eq!(s.address, address);
}

#[tokio::test]
async fn garbage_answers_are_reported() {
    for seed in 0..8 {
        let p = SimProjector::start(SimConfig { fault: Fault::Garbage, seed, ..SimConfig::default() })
            .await
            .unwrap();
        let e = client(&p, None).power().await.unwrap_err();
        assert!(matches!(e, PjlinkError::Garbage { .. } | PjlinkError::Overlong { .. }), "seed {seed}: {e}");
    }
    // A projector that greets properly, then answers garbage.
    let p = SimProjector::start(SimConfig::default()).await.unwrap();
    let c = control(&[spec("noisy", p.address(), None)]);
    assert!(status_where(&c, 0, |s| s.reachable).await.last_error.is_none());
    p.set_fault(Fault::Garbage);
    let s = status_where(&c, 0, |s| s.failures >= 1).await;
    let e = s.last_error.unwrap_or_default();
    assert!(e.contains("garbage") || e.contains("longer than"), "{e}");
    assert!(!s.reachable);
    // Recovers when the projector does.
    p.set_fault(Fault::None);
    let s = status_where(&c, 0, |s| s.reachable).await;
    assert_eq!((s.failures, s.last_error), (0, None));
}

#[tokio::test]
async fn a_lamp_error_is_reported_with_its_error() {
    let p = SimProjector::start(SimConfig { fault: Fault::LampError, ..SimConfig::default() }).await.unwrap();
    let errors = client(&p, None).error_status().await.unwrap();
    assert_eq!(errors.lamp, Level::Error);
    let c = control(&[spec("left", p.address(), None)]);
    c.want(Want::On);
    let s = status_where(&c, 0, |s| s.failures >= 1).await;
    assert_eq!(s.errors.map(|e| e.lamp), Some(Level::Error));
    let e = s.last_error.unwrap_or_default();
    assert!(e.contains("ERR4") && e.contains("lamp error"), "{e}");
    assert!(s.reachable && !s.ready);
    assert_eq!(s.power, Some(PowerState::Off));
    assert!(s.lamps.iter().all(|l| !l.on));
}

#[tokio::test]
async fn error_status_warnings_are_reported_while_working() {
    let p = SimProjector::start(SimConfig { power: PowerState::On, ..SimConfig::default() }).await.unwrap();
    p.set_error_status(restage_appliance::pjlink::ErrorStatus {
        filter: Level::Warning,
        ..Default::default()
    });
    let c = control(&[spec("left", p.address(), None)]);
    let s = status_where(&c, 0, |s| s.reachable).await;
    assert!(s.ready, "a warning does not stop the stage");
    assert_eq!(s.last_error.as_deref(), Some("projector reports filter warning"));
}

#[tokio::test]
async fn lamp_hours_are_parsed() {
    let p = SimProjector::start(SimConfig {
        power: PowerState::On,
        lamp_hours: vec![1500, 20],
        ..SimConfig::default()
    })
    .await
    .unwrap();
    let lamps = client(&p, None).lamps().await.unwrap();
    assert_eq!(lamps.iter().map(|l| (l.hours, l.on)).collect::<Vec<_>>(), [(1500, true), (20, true)]);
    let c = control(&[spec("left", p.address(), None)]);
    let s = status_where(&c, 0, |s| s.reachable).await;
    assert_eq!(s.lamp_hours, Some(1500));
    assert_eq!(s.lamps.len(), 2);
    // A lampless (laser) projector answers LAMP with ERR1: no hours, not an error.
    p.set_lamp_hours(Vec::new());
    let e = client(&p, None).lamps().await.unwrap_err();
    assert!(matches!(e, PjlinkError::Refused { code: ErrCode::Undefined, .. }));
    let s = status_where(&c, 0, |s| s.lamp_hours.is_none() && s.failures == 0).await;
    assert!(s.reachable && s.lamps.is_empty());
}

#[tokio::test]
async fn connections_closed_by_the_projector_between_polls_are_no_trouble() {
    let p =
        SimProjector::start(SimConfig { power: PowerState::On, idle_close: ms(30), ..SimConfig::default() })
            .await
            .unwrap();
    let c = control(&[spec("left", p.address(), None)]);
    let before = status_where(&c, 0, |s| s.reachable).await.last_poll_unix_ms;
    let s = status_where(&c, 0, |s| s.last_poll_unix_ms > before).await;
    assert!(s.reachable && s.failures == 0, "{s:?}");
    assert!(p.connections() >= 2);
}

#[tokio::test]
async fn dropping_the_controller_stops_polling() {
    let p = SimProjector::start(SimConfig::default()).await.unwrap();
    let c = control(&[spec("left", p.address(), None)]);
    status_where(&c, 0, |s| s.reachable).await;
    drop(c);
    tokio::time::sleep(ms(50)).await;
    let n = p.connections();
    tokio::time::sleep(ms(500)).await;
    assert_eq!(p.connections(), n);
}

/// A one-shot server that greets and then answers whatever `answer` holds.
async fn serve_bytes(greeting: Vec<u8>, answer: Vec<u8>) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap().to_string();
    tokio::spawn(async move {
        if let Ok((mut s, _)) = listener.accept().await {
            let _ = s.write_all(&greeting).await;
            let mut buf = [0u8; 64];
            let _ = s.read(&mut buf).await;
            let _ = s.write_all(&answer).await;
            let _ = s.read(&mut buf).await;
        }
    });
    address
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Whatever bytes a projector sends, every query ends in a value or a typed error.
    #[test]
    fn the_client_never_panics_on_arbitrary_answers(
        greeting in proptest::collection::vec(any::<u8>(), 0..300),
        answer in proptest::collection::vec(any::<u8>(), 0..300),
        framed in any::<bool>(),
    ) {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        rt.block_on(async {
            let greeting = if framed { b"PJLINK 0\r".to_vec() } else { greeting };
            let address = serve_bytes(greeting, answer).await;
            let r = Projector::new(&address, Some("pw"), ms(50)).poll().await;
            if let Err(e) = r {
                let _ = e.to_string();
            }
        });
    }
}

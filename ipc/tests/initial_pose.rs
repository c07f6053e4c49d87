//! The `initial_pose` service over real iceoryx2 shared memory, in-process: consumers publish
//! hints, the daemon's subscriber receives them. Each test works in its own random domain.
//!
//! Contents:
//! - round trip: a sender's hint reaches the daemon, with every field; several senders at once
//! - one-shot: `send_initial_pose` returns after the linger and the hint is still there
//! - refusals: an invalid hint is refused at send; one sent anyway is skipped and counted
//! - errors: no daemon (NotRunning), a second daemon on one domain (DomainInUse)
//! - settings: the service the daemon created keeps no history and allows 8 senders

use std::hash::BuildHasher;
use std::thread;
use std::time::{Duration, Instant};

use glint_ipc::iceoryx2::prelude::*;
use glint_ipc::{
    send_initial_pose, settings, Domain, Frame, InitialPose, InitialPoseCreateError,
    InitialPoseError, InitialPoseOpenError, InitialPosePublisher, InitialPoseSendError,
    InitialPoseSubscriber, Stream,
};

/// Generous: only reached when something is broken.
const PATIENCE: Duration = Duration::from_secs(5);

fn unique_domain(tag: &str) -> Domain {
    let random = std::collections::hash_map::RandomState::new().hash_one((
        std::process::id(),
        tag,
        Instant::now(),
    ));
    Domain::new(&format!("test-ip-{tag}-{random:016x}")).expect("valid test domain")
}

fn hint() -> InitialPose {
    InitialPose::new(
        1_700_000_000_123_456_789,
        [12.5, -3.25, 0.125],
        [0.0, 0.0, 0.6, 0.8],
        0.75,
    )
}

#[test]
fn a_senders_hint_reaches_the_daemon_with_every_field() {
    let domain = unique_domain("roundtrip");
    let daemon = InitialPoseSubscriber::create(&domain).expect("daemon side");
    let sender = InitialPosePublisher::open(&domain).expect("sender");
    assert_eq!(sender.send(&hint()).expect("send"), 1, "one daemon");
    assert_eq!(daemon.wait_next(PATIENCE).expect("wait"), Some(hint()));
    assert_eq!(daemon.try_next().expect("receive"), None);
    assert_eq!(daemon.rejected(), 0);
}

#[test]
fn several_senders_at_once_and_try_latest_keeps_the_newest() {
    let domain = unique_domain("many");
    let daemon = InitialPoseSubscriber::create(&domain).expect("daemon side");
    let senders: Vec<_> = (0..settings::INITIAL_POSE_MAX_PUBLISHERS)
        .map(|_| InitialPosePublisher::open(&domain).expect("sender"))
        .collect();
    match InitialPosePublisher::open(&domain) {
        Err(InitialPoseOpenError::TooManySenders { service }) => {
            assert_eq!(service, domain.service_name(Stream::InitialPose));
        }
        other => panic!("expected TooManySenders, got {other:?}"),
    }
    for (i, sender) in senders.iter().enumerate() {
        let h = InitialPose::on_floor(i as u64, i as f64, 0.0, 0.1, 1.0);
        sender.send(&h).expect("send");
    }
    let latest = daemon.try_latest().expect("receive").expect("a hint");
    assert_eq!(
        latest.timestamp_ns,
        settings::INITIAL_POSE_MAX_PUBLISHERS as u64 - 1
    );
}

#[test]
fn wait_next_wakes_on_a_hint_from_another_thread() {
    let domain = unique_domain("wake");
    let daemon = InitialPoseSubscriber::create(&domain).expect("daemon side");
    let d = domain.clone();
    let sender = thread::spawn(move || {
        let sender = InitialPosePublisher::open(&d).expect("sender");
        thread::sleep(Duration::from_millis(100));
        sender.send(&hint()).expect("send");
        sender
    });
    let start = Instant::now();
    assert_eq!(daemon.wait_next(PATIENCE).expect("wait"), Some(hint()));
    assert!(start.elapsed() < PATIENCE, "woke only at the timeout");
    drop(sender.join().expect("sender thread"));
}

#[test]
fn a_one_shot_senders_hint_survives_its_sender() {
    let domain = unique_domain("oneshot");
    let daemon = InitialPoseSubscriber::create(&domain).expect("daemon side");
    let d = domain.clone();
    let start = Instant::now();
    let sender = thread::spawn(move || send_initial_pose(&d, &hint()).expect("send"));
    // The daemon polls at its documented pace while the sender lingers.
    let mut got = None;
    while got.is_none() && start.elapsed() < PATIENCE {
        got = daemon.try_next().expect("receive");
        thread::sleep(settings::INITIAL_POSE_MAX_POLL_INTERVAL / 2);
    }
    assert_eq!(sender.join().expect("sender thread"), 1);
    assert!(start.elapsed() >= settings::INITIAL_POSE_SENDER_LINGER);
    assert_eq!(got, Some(hint()));
}

#[test]
fn invalid_hints_are_refused_at_send_and_nothing_is_sent() {
    let domain = unique_domain("refused");
    let daemon = InitialPoseSubscriber::create(&domain).expect("daemon side");
    let sender = InitialPosePublisher::open(&domain).expect("sender");
    let mut nan = hint();
    nan.position[0] = f64::NAN;
    assert!(matches!(
        sender.send(&nan),
        Err(InitialPoseSendError::Invalid(InitialPoseError::NonFinite {
            field: "position"
        }))
    ));
    let mut odom = hint();
    odom.frame = Frame::ODOM;
    assert!(matches!(
        sender.send(&odom),
        Err(InitialPoseSendError::Invalid(
            InitialPoseError::NotMapFrame { .. }
        ))
    ));
    // The one-shot refuses before opening anything: no daemon needed to say why.
    let nowhere = unique_domain("refused-nowhere");
    assert!(matches!(
        send_initial_pose(&nowhere, &nan),
        Err(glint_ipc::SendInitialPoseError::Send(
            InitialPoseSendError::Invalid(_)
        ))
    ));
    assert_eq!(daemon.try_next().expect("receive"), None);
    assert_eq!(daemon.rejected(), 0);
}

/// A sender in another language, bypassing the checks: raw bytes under the type name.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("glint::InitialPoseV1")]
struct RawHint {
    timestamp_ns: u64,
    values: [f64; 8],
    frame: u32,
    pad: u32,
}

#[test]
fn invalid_hints_that_arrive_anyway_are_skipped_and_counted() {
    let domain = unique_domain("skipped");
    let daemon = InitialPoseSubscriber::create(&domain).expect("daemon side");
    let node = NodeBuilder::new().create::<ipc::Service>().expect("node");
    let service = node
        .service_builder(&ServiceName::new(&domain.service_name(Stream::InitialPose)).unwrap())
        .publish_subscribe::<RawHint>()
        .open()
        .expect("open by type name and size alone");
    let publisher = service.publisher_builder().create().expect("publisher");
    let good = RawHint {
        timestamp_ns: 3,
        values: [1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.5],
        frame: 1,
        pad: 0,
    };
    let mut nan = good;
    nan.values[1] = f64::NAN;
    let mut odom = good;
    odom.frame = 0;
    for raw in [nan, odom, good] {
        publisher.send_copy(raw).expect("send");
    }
    let got = daemon.try_next().expect("receive").expect("the valid hint");
    assert_eq!(got.timestamp_ns, 3);
    assert_eq!(got.position, [1.0, 2.0, 0.0]);
    assert_eq!(got.orientation, [0.0, 0.0, 0.0, 1.0]);
    assert_eq!(got.position_sigma, 0.5);
    assert_eq!(daemon.rejected(), 2);
    assert_eq!(
        daemon.last_rejection(),
        Some(InitialPoseError::NotMapFrame { frame: Frame::ODOM })
    );
}

#[test]
fn opening_without_a_daemon_says_it_is_not_running() {
    let domain = unique_domain("absent");
    match InitialPosePublisher::open(&domain) {
        Err(e @ InitialPoseOpenError::NotRunning { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains(&domain.service_name(Stream::InitialPose))
                    && text.contains("is glintd running"),
                "{text}"
            );
        }
        other => panic!("expected NotRunning, got {other:?}"),
    }
    assert!(matches!(
        send_initial_pose(&domain, &hint()),
        Err(glint_ipc::SendInitialPoseError::Open(
            InitialPoseOpenError::NotRunning { .. }
        ))
    ));
}

#[test]
fn a_second_daemon_on_one_domain_is_refused() {
    let domain = unique_domain("twice");
    let _first = InitialPoseSubscriber::create(&domain).expect("daemon side");
    match InitialPoseSubscriber::create(&domain) {
        Err(InitialPoseCreateError::DomainInUse { domain: d, .. }) => {
            assert_eq!(d, domain.as_str());
        }
        other => panic!("expected DomainInUse, got {other:?}"),
    }
}

#[test]
fn the_daemon_creates_the_service_without_history_for_eight_senders() {
    let domain = unique_domain("settings");
    let _daemon = InitialPoseSubscriber::create(&domain).expect("daemon side");
    let node = NodeBuilder::new().create::<ipc::Service>().expect("node");
    let service = node
        .service_builder(&ServiceName::new(&domain.service_name(Stream::InitialPose)).unwrap())
        .publish_subscribe::<InitialPose>()
        .open()
        .expect("open");
    let config = service.static_config();
    assert_eq!(config.history_size(), 0);
    assert_eq!(config.max_publishers(), 8);
    assert_eq!(config.max_subscribers(), 1);
    assert!(config.has_safe_overflow());
    let details = config.message_type_details();
    assert_eq!(
        details.payload.type_name().to_string(),
        InitialPose::TYPE_NAME
    );
    assert_eq!(details.payload.size(), 80);
    assert_eq!(details.payload.alignment(), 8);
}

#[test]
fn ports_can_move_between_threads() {
    fn send_sync<T: Send + Sync>() {}
    fn send<T: Send>() {}
    // The daemon hands its subscriber to the localiser's thread, or shares it.
    send_sync::<InitialPoseSubscriber>();
    send::<InitialPosePublisher>();
}

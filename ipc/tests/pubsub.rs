//! Publish/subscribe over real iceoryx2 shared memory, in-process (plus one child process for the
//! crash case). Each test works in its own random domain, so tests run in parallel without
//! sharing a service, and drops its nodes before returning.
//!
//! Contents:
//! - round trips: every pose stream and the status stream, streams kept apart
//! - waiting: `wait_next` wakes on a publish from another thread, times out when idle
//! - history: a late subscriber gets the last pose
//! - overload: a subscriber that never reads does not slow the publisher
//! - errors: missing services, invalid domains, a second daemon on one domain, non-finite poses
//! - restarts: graceful and SIGKILL; subscribers keep receiving without reopening
//! - the wire: a consumer knowing only the README's type name and offsets reads a pose

use std::collections::hash_map::RandomState;
use std::hash::BuildHasher;
use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};
use std::thread;
use std::time::{Duration, Instant};

use glint_ipc::{
    Domain, DomainError, Frame, Pose, PosePublisher, PoseStream, PoseSubscriber, PublishError,
    PublisherError, Status, StatusFlags, StatusSubscriber, Stream, SubscribeError,
};

/// Generous: only reached when something is broken.
const PATIENCE: Duration = Duration::from_secs(5);

fn unique_domain(tag: &str) -> Domain {
    let random = RandomState::new().hash_one((std::process::id(), tag, Instant::now()));
    Domain::new(&format!("test-{tag}-{random:016x}")).expect("valid test domain")
}

fn pose(sequence: u64, frame: Frame) -> Pose {
    let mut p = Pose::new(sequence, 1_700_000_000_000_000_000 + sequence, frame);
    p.position = [1.5, -2.25, 0.125 * sequence as f64];
    p.orientation = [0.0, 0.0, 0.382_683_432_365_089_8, 0.923_879_532_511_286_7];
    p.linear_velocity = [0.8, 0.0, 0.0];
    p.angular_velocity = [0.0, 0.0, 0.1];
    for i in 0..6 {
        p.covariance[i * 6 + i] = 0.01 * (i + 1) as f64;
    }
    p.quality = 0.93;
    p.status = StatusFlags::TRACKING;
    p
}

fn publish(publisher: &PosePublisher, stream: PoseStream, p: &Pose) -> Result<(), PublishError> {
    match stream {
        PoseStream::Odom => publisher.publish_odom(p),
        PoseStream::Map => publisher.publish_map(p),
        PoseStream::Predicted => publisher.publish_predicted(p),
    }
}

#[test]
fn ports_can_move_between_threads() {
    fn send_sync<T: Send + Sync>() {}
    fn send<T: Send>() {}
    // The daemon shares one publisher between its odometry and back-end threads.
    send_sync::<PosePublisher>();
    send::<PoseSubscriber>();
    send::<StatusSubscriber>();
}

#[test]
fn every_pose_stream_round_trips_and_streams_stay_apart() {
    let domain = unique_domain("roundtrip");
    let publisher = PosePublisher::create(&domain).expect("publisher");
    let subscribers = PoseStream::ALL.map(|s| PoseSubscriber::open(&domain, s).expect("open"));

    for (i, stream) in PoseStream::ALL.into_iter().enumerate() {
        let mut sent = pose(10 + i as u64, Frame::MAP);
        if stream == PoseStream::Predicted {
            sent.status |= StatusFlags::PREDICTED;
        }
        publish(&publisher, stream, &sent).expect("publish");
        for (j, subscriber) in subscribers.iter().enumerate() {
            let got = subscriber.try_next().expect("receive");
            if i == j {
                assert_eq!(got, Some(sent), "{stream:?}");
            } else {
                assert_eq!(got, None, "{stream:?} leaked into {:?}", PoseStream::ALL[j]);
            }
        }
    }
}

#[test]
fn status_round_trips() {
    let domain = unique_domain("status");
    let publisher = PosePublisher::create(&domain).expect("publisher");
    let subscriber = StatusSubscriber::open(&domain).expect("open");
    let mut sent = Status::new(3, 1_700_000_000_000_000_000);
    sent.sweeps_processed = 1200;
    sent.sweeps_dropped = 2;
    sent.packets_received = 905_000;
    sent.packets_dropped = 7;
    sent.packets_malformed = 1;
    sent.sweep_rate_hz = 10.0;
    sent.packet_rate_hz = 754.0;
    sent.latency_median_ms = 21.5;
    sent.latency_p99_ms = 48.0;
    sent.flags = StatusFlags::TRACKING | StatusFlags::DEGENERATE;
    publisher.publish_status(&sent).expect("publish");
    assert_eq!(subscriber.wait_next(PATIENCE).expect("wait"), Some(sent));
    assert_eq!(subscriber.try_next().expect("receive"), None);
}

#[test]
fn wait_next_wakes_on_a_publish_from_another_thread() {
    let domain = unique_domain("wake");
    let publisher = PosePublisher::create(&domain).expect("publisher");
    let subscriber = PoseSubscriber::open(&domain, PoseStream::Odom).expect("open");
    let sent = pose(1, Frame::ODOM);
    // Also proves the publisher is `Send`: the daemon publishes from its pipeline threads.
    let sender = thread::spawn(move || {
        thread::sleep(Duration::from_millis(100));
        publisher.publish_odom(&sent).expect("publish");
        publisher
    });
    let start = Instant::now();
    let got = subscriber.wait_next(PATIENCE).expect("wait");
    assert_eq!(got, Some(sent));
    assert!(start.elapsed() < PATIENCE, "woke only at the timeout");
    drop(sender.join().expect("sender thread"));
}

#[test]
fn wait_next_times_out_with_none_when_nothing_is_published() {
    let domain = unique_domain("timeout");
    let _publisher = PosePublisher::create(&domain).expect("publisher");
    let subscriber = PoseSubscriber::open(&domain, PoseStream::Map).expect("open");
    let timeout = Duration::from_millis(50);
    let start = Instant::now();
    assert_eq!(subscriber.wait_next(timeout).expect("wait"), None);
    assert!(start.elapsed() >= timeout);
}

#[test]
fn late_subscriber_gets_the_last_pose() {
    let domain = unique_domain("history");
    let publisher = PosePublisher::create(&domain).expect("publisher");
    for seq in 1..=3 {
        publisher
            .publish_odom(&pose(seq, Frame::ODOM))
            .expect("publish");
    }
    let late = PoseSubscriber::open(&domain, PoseStream::Odom).expect("open");
    // No pose is flowing (say tracking is lost): the periodic update hands over the history
    // and wakes the waiting subscriber.
    publisher.update_connections().expect("update");
    assert_eq!(
        late.wait_next(PATIENCE).expect("wait"),
        Some(pose(3, Frame::ODOM))
    );
    assert_eq!(late.try_next().expect("receive"), None, "history is 1 deep");

    // With poses flowing, the next send delivers the history first.
    let later = PoseSubscriber::open(&domain, PoseStream::Odom).expect("open");
    publisher
        .publish_odom(&pose(4, Frame::ODOM))
        .expect("publish");
    let got: Vec<u64> = std::iter::from_fn(|| later.try_next().expect("receive"))
        .map(|p| p.sequence)
        .collect();
    assert_eq!(got, [3, 4]);
}

#[test]
fn a_subscriber_that_never_reads_does_not_block_the_publisher() {
    let domain = unique_domain("stalled");
    let publisher = PosePublisher::create(&domain).expect("publisher");
    // Opened (subscriber and listener) and then ignored while 1,000 poses go out.
    let stalled = PoseSubscriber::open(&domain, PoseStream::Odom).expect("open");
    let start = Instant::now();
    for seq in 1..=1000 {
        publisher
            .publish_odom(&pose(seq, Frame::ODOM))
            .expect("publish");
    }
    // A sanity bound, not a benchmark: blocking would hang, not take a little longer.
    assert!(
        start.elapsed() < Duration::from_secs(20),
        "{:?}",
        start.elapsed()
    );

    // The oldest were overwritten; what is left is the newest, in order, without gaps.
    let kept: Vec<u64> = std::iter::from_fn(|| stalled.try_next().expect("receive"))
        .map(|p| p.sequence)
        .collect();
    assert!(!kept.is_empty() && kept.len() <= glint_ipc::settings::SUBSCRIBER_BUFFER_SIZE);
    assert_eq!(kept.last(), Some(&1000));
    assert!(kept.windows(2).all(|w| w[1] == w[0] + 1), "{kept:?}");
}

#[test]
fn try_latest_skips_to_the_newest() {
    let domain = unique_domain("latest");
    let publisher = PosePublisher::create(&domain).expect("publisher");
    let subscriber = PoseSubscriber::open(&domain, PoseStream::Odom).expect("open");
    for seq in 1..=5 {
        publisher
            .publish_odom(&pose(seq, Frame::ODOM))
            .expect("publish");
    }
    let latest = subscriber
        .try_latest()
        .expect("receive")
        .map(|p| p.sequence);
    assert_eq!(latest, Some(5));
    assert_eq!(subscriber.try_next().expect("receive"), None);
}

#[test]
fn opening_a_service_nobody_created_says_the_daemon_is_not_running() {
    let domain = unique_domain("absent");
    match PoseSubscriber::open(&domain, PoseStream::Odom) {
        Err(SubscribeError::NotRunning { service }) => {
            assert_eq!(service, domain.service_name(PoseStream::Odom.into()));
        }
        other => panic!("expected NotRunning, got {other:?}"),
    }
    assert!(matches!(
        StatusSubscriber::open(&domain),
        Err(SubscribeError::NotRunning { .. })
    ));
}

#[test]
fn invalid_domains_are_refused_with_the_reason() {
    assert_eq!(Domain::new(""), Err(DomainError::Empty));
    assert!(matches!(
        Domain::new("agv/7"),
        Err(DomainError::InvalidCharacter { ch: '/', index: 3 })
    ));
    assert!(matches!(
        Domain::new("agv 7"),
        Err(DomainError::InvalidCharacter { ch: ' ', .. })
    ));
    assert!(matches!(
        Domain::new(&"a".repeat(Domain::MAX_LEN + 1)),
        Err(DomainError::TooLong { .. })
    ));
    assert!("agv-7_b".parse::<Domain>().is_ok());
}

#[test]
fn a_second_publisher_on_one_domain_is_refused() {
    let domain = unique_domain("twice");
    let _first = PosePublisher::create(&domain).expect("publisher");
    match PosePublisher::create(&domain) {
        Err(PublisherError::DomainInUse { domain: d, .. }) => assert_eq!(d, domain.as_str()),
        other => panic!("expected DomainInUse, got {other:?}"),
    }
}

#[test]
fn non_finite_poses_are_refused_and_not_sent() {
    let domain = unique_domain("nan");
    let publisher = PosePublisher::create(&domain).expect("publisher");
    let subscriber = PoseSubscriber::open(&domain, PoseStream::Map).expect("open");
    let mut bad = pose(1, Frame::MAP);
    bad.covariance[7] = f64::NAN;
    match publisher.publish_map(&bad) {
        Err(PublishError::NonFinite { stream, field }) => {
            assert_eq!(stream, Stream::Pose(PoseStream::Map));
            assert_eq!(field, "covariance");
        }
        other => panic!("expected NonFinite, got {other:?}"),
    }
    assert_eq!(subscriber.try_next().expect("receive"), None);
}

#[test]
fn subscriber_keeps_receiving_across_a_graceful_publisher_restart() {
    let domain = unique_domain("restart");
    let subscriber = {
        let publisher = PosePublisher::create(&domain).expect("publisher");
        let subscriber = PoseSubscriber::open(&domain, PoseStream::Odom).expect("open");
        publisher
            .publish_odom(&pose(1, Frame::ODOM))
            .expect("publish");
        assert_eq!(
            subscriber
                .wait_next(PATIENCE)
                .expect("wait")
                .map(|p| p.sequence),
            Some(1)
        );
        subscriber
    };
    let publisher = PosePublisher::create(&domain).expect("restarted publisher");
    publisher
        .publish_odom(&pose(2, Frame::ODOM))
        .expect("publish");
    assert_eq!(
        subscriber
            .wait_next(PATIENCE)
            .expect("wait")
            .map(|p| p.sequence),
        Some(2)
    );
}

/// Set in the child process of the crash test: the domain to publish in.
const CRASH_CHILD_ENV: &str = "GLINT_IPC_TEST_CRASH_CHILD_DOMAIN";

/// The child half of the SIGKILL test; returns at once unless started by it.
#[test]
fn crash_child() {
    let Ok(domain) = std::env::var(CRASH_CHILD_ENV) else {
        return;
    };
    let domain = Domain::new(&domain).expect("domain from the parent");
    let publisher = PosePublisher::create(&domain).expect("child publisher");
    let mut stdout = std::io::stdout();
    writeln!(stdout, "CHILD READY").expect("stdout");
    stdout.flush().expect("stdout");
    let mut lines = std::io::stdin().lock().lines();
    // One pose per line the parent sends; the parent SIGKILLs us eventually.
    while let Some(Ok(line)) = lines.next() {
        let seq = line.trim().parse().expect("sequence from the parent");
        publisher
            .publish_odom(&pose(seq, Frame::ODOM))
            .expect("publish");
        writeln!(stdout, "CHILD SENT {seq}").expect("stdout");
        stdout.flush().expect("stdout");
    }
}

#[test]
fn subscriber_keeps_receiving_after_the_publisher_is_killed_and_restarted() {
    let domain = unique_domain("sigkill");
    let mut child = Command::new(std::env::current_exe().expect("test binary"))
        .args(["--exact", "crash_child", "--nocapture", "--test-threads=1"])
        .env(CRASH_CHILD_ENV, domain.as_str())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn child");
    let mut to_child = child.stdin.take().expect("child stdin");
    let mut from_child = BufReader::new(child.stdout.take().expect("child stdout")).lines();
    let mut expect_line = |wanted: &str| {
        for line in from_child.by_ref() {
            if line.expect("child stdout").contains(wanted) {
                return;
            }
        }
        panic!("child exited before printing {wanted:?}");
    };

    expect_line("CHILD READY");
    let subscriber = PoseSubscriber::open(&domain, PoseStream::Odom).expect("open");
    writeln!(to_child, "1").expect("to child");
    expect_line("CHILD SENT 1");
    assert_eq!(
        subscriber
            .wait_next(PATIENCE)
            .expect("wait")
            .map(|p| p.sequence),
        Some(1)
    );

    child.kill().expect("SIGKILL the child");
    child.wait().expect("reap the child");

    // The dead publisher still holds the domain's only publisher slot until its node is cleaned
    // up, which creating the new publisher does.
    let publisher = PosePublisher::create(&domain).expect("publisher after the crash");
    publisher
        .publish_odom(&pose(2, Frame::ODOM))
        .expect("publish");
    assert_eq!(
        subscriber
            .wait_next(PATIENCE)
            .expect("wait")
            .map(|p| p.sequence),
        Some(2)
    );
}

/// A consumer that knows only what the README says: the type name, the size, and the offsets.
mod foreign_consumer {
    use super::*;
    use iceoryx2::prelude::*;

    /// 424 opaque bytes under Glint's type name, alignment 1 (allowed: an opener's alignment
    /// may be lower than the creator's).
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("glint::PoseV1")]
    struct RawPose {
        bytes: [u8; 424],
    }

    fn f64_at(bytes: &[u8], offset: usize) -> f64 {
        let mut b = [0; 8];
        b.copy_from_slice(&bytes[offset..offset + 8]);
        f64::from_ne_bytes(b)
    }

    fn u64_at(bytes: &[u8], offset: usize) -> u64 {
        let mut b = [0; 8];
        b.copy_from_slice(&bytes[offset..offset + 8]);
        u64::from_ne_bytes(b)
    }

    fn u32_at(bytes: &[u8], offset: usize) -> u32 {
        let mut b = [0; 4];
        b.copy_from_slice(&bytes[offset..offset + 4]);
        u32::from_ne_bytes(b)
    }

    #[test]
    fn a_plain_ipc_consumer_reads_the_documented_bytes() {
        let domain = unique_domain("foreign");
        let publisher = PosePublisher::create(&domain).expect("publisher");

        // Plain `ipc::Service`, as Python's `ServiceType.Ipc` and a C consumer use.
        let node = NodeBuilder::new().create::<ipc::Service>().expect("node");
        let name = domain.service_name(PoseStream::Map.into());
        let service = node
            .service_builder(&ServiceName::new(&name).expect("name"))
            .publish_subscribe::<RawPose>()
            .open()
            .expect("open by type name and size alone");
        let details = service.static_config().message_type_details();
        assert_eq!(details.payload.type_name().to_string(), Pose::TYPE_NAME);
        assert_eq!(details.payload.size(), 424);
        assert_eq!(details.payload.alignment(), 8, "the creator's alignment");
        assert_eq!(service.static_config().history_size(), 1);
        assert_eq!(service.static_config().subscriber_max_buffer_size(), 16);
        assert!(service.static_config().has_safe_overflow());
        let subscriber = service.subscriber_builder().create().expect("subscriber");

        let mut sent = pose(42, Frame::MAP);
        sent.status = StatusFlags::TRACKING | StatusFlags::LOOP_CLOSED;
        publisher.publish_map(&sent).expect("publish");
        let sample = subscriber.receive().expect("receive").expect("a sample");
        let b = &sample.payload().bytes;

        assert_eq!(u64_at(b, 0), 42);
        assert_eq!(u64_at(b, 8), sent.timestamp_ns);
        assert_eq!([f64_at(b, 16), f64_at(b, 24), f64_at(b, 32)], sent.position);
        assert_eq!(
            [f64_at(b, 40), f64_at(b, 48), f64_at(b, 56), f64_at(b, 64)],
            sent.orientation,
            "x, y, z, w"
        );
        assert_eq!(f64_at(b, 72), sent.linear_velocity[0]);
        assert_eq!(f64_at(b, 96 + 16), sent.angular_velocity[2]);
        assert_eq!(
            f64_at(b, 120 + 8 * 7),
            sent.covariance[7],
            "row-major [1][1]"
        );
        assert_eq!(f64_at(b, 120 + 8 * 35), sent.covariance[35]);
        assert_eq!(f32::from_bits(u32_at(b, 408)), sent.quality);
        assert_eq!(u32_at(b, 412), 1, "frame map");
        assert_eq!(u32_at(b, 416), 0b1_0010, "TRACKING | LOOP_CLOSED");
        assert_eq!(u32_at(b, 420), 0, "padding");
    }
}

//! The `sweep` service over real iceoryx2 shared memory, in process: a sweep published is read
//! back point for point with its header; a late subscriber gets the last sweep; a sweep larger
//! than the samples is refused; a subscriber that never reads does not stop the publisher.

use std::collections::hash_map::RandomState;
use std::hash::BuildHasher;
use std::time::Instant;

use glint_ipc::settings::{SWEEP_MAX_POINTS, SWEEP_SUBSCRIBER_BUFFER_SIZE};
use glint_ipc::{
    Domain, PointLabel, StatusFlags, SweepHeader, SweepPoint, SweepPublishError, SweepPublisher,
    SweepSubscriber,
};

fn unique_domain(tag: &str) -> Domain {
    let random = RandomState::new().hash_one((std::process::id(), tag, Instant::now()));
    Domain::new(&format!("test-{tag}-{random:016x}")).expect("valid test domain")
}

fn point(i: usize) -> SweepPoint {
    SweepPoint {
        position: [i as f32, -(i as f32) * 0.5, 0.25],
        intensity: if i.is_multiple_of(7) {
            f32::NAN
        } else {
            0.01 * i as f32
        },
        time_offset_ns: -(i as i32) * 1000,
        ring: (i % 16) as u16,
        reflectivity: (i % 256) as u8,
        label: if i.is_multiple_of(3) {
            PointLabel::EDGE
        } else {
            PointLabel::PLANE.with(PointLabel::INTENSITY)
        },
    }
}

fn header(t: u64) -> SweepHeader {
    SweepHeader {
        timestamp_ns: 1_700_000_000_000_000_000 + t,
        sensor_time_ns: t,
        flags: StatusFlags::TRACKING,
        ..SweepHeader::default()
    }
}

/// Copies the oldest unread sweep out.
fn next(sub: &SweepSubscriber) -> Option<(SweepHeader, Vec<SweepPoint>)> {
    sub.try_next(|h, p| (*h, p.to_vec())).expect("receive")
}

fn same(a: &SweepPoint, b: &SweepPoint) -> bool {
    a.position == b.position
        && a.intensity.to_bits() == b.intensity.to_bits()
        && (a.time_offset_ns, a.ring, a.reflectivity, a.label)
            == (b.time_offset_ns, b.ring, b.reflectivity, b.label)
}

#[test]
fn a_sweep_arrives_point_for_point() {
    let domain = unique_domain("sweep");
    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    let subscriber = SweepSubscriber::open(&domain).expect("subscriber");
    assert!(next(&subscriber).is_none());
    for (sweep, count) in [(0u64, 28_928usize), (1, 3), (2, 0)] {
        publisher
            .publish(header(sweep), count, point)
            .expect("publish");
        let (h, points) = next(&subscriber).expect("a sweep");
        assert_eq!(h.sequence, sweep);
        assert_eq!(h.point_count as usize, count);
        assert_eq!(h.timestamp_ns, header(sweep).timestamp_ns);
        assert_eq!(h.sensor_time_ns, sweep);
        assert_eq!(h.flags, StatusFlags::TRACKING);
        assert_eq!(points.len(), count);
        assert!(points.iter().enumerate().all(|(i, p)| same(p, &point(i))));
    }
    assert!(next(&subscriber).is_none());
}

#[test]
fn a_late_subscriber_gets_the_last_sweep_and_a_stalled_one_loses_the_oldest() {
    let domain = unique_domain("sweep-late");
    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    let stalled = SweepSubscriber::open(&domain).expect("subscriber");
    for t in 0..10 {
        publisher.publish(header(t), 100, point).expect("publish");
    }
    let late = SweepSubscriber::open(&domain).expect("late subscriber");
    publisher.update_connections().expect("connect");
    let (h, _) = next(&late).expect("the history");
    assert_eq!(h.sequence, 9);
    // The stalled subscriber kept the newest sweeps its buffer holds.
    let mut kept = Vec::new();
    while let Some((h, _)) = next(&stalled) {
        kept.push(h.sequence);
    }
    assert_eq!(kept.len(), SWEEP_SUBSCRIBER_BUFFER_SIZE, "{kept:?}");
    assert_eq!(*kept.last().unwrap(), 9, "{kept:?}");
}

#[test]
fn a_sweep_larger_than_the_samples_is_refused() {
    let domain = unique_domain("sweep-big");
    let mut publisher = SweepPublisher::create(&domain).expect("publisher");
    let err = publisher
        .publish(header(0), SWEEP_MAX_POINTS + 1, point)
        .unwrap_err();
    assert!(
        matches!(err, SweepPublishError::TooManyPoints { .. }),
        "{err}"
    );
    // Still usable, and the largest sweep fits.
    publisher
        .publish(header(1), SWEEP_MAX_POINTS, point)
        .expect("the largest sweep");
}

//! Publishes poses stamped with the wall clock at the moment of publishing, for measuring the
//! latency from publish to a consumer (`examples/glint_latency.c`; command in capi/README.md).
//!
//! `cargo run -p glint-capi --example latency_publisher -- DOMAIN COUNT RATE_HZ`
//!
//! It waits a second after creating the services so that a consumer started alongside it is
//! connected before the first pose, then publishes COUNT poses at RATE_HZ on `odom`.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use glint_ipc::{Domain, Frame, Pose, PosePublisher, StatusFlags};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [domain, count, rate] = args.as_slice() else {
        return Err("usage: latency_publisher DOMAIN COUNT RATE_HZ".into());
    };
    let publisher = PosePublisher::create(&Domain::new(domain)?)?;
    let count: u64 = count.parse()?;
    let period = Duration::from_secs_f64(1.0 / rate.parse::<f64>()?);
    std::thread::sleep(Duration::from_secs(1));
    let start = Instant::now();
    for sequence in 0..count {
        // Sleep to an absolute schedule so that a slow iteration does not shift the rest.
        let due = start + period.mul_f64(sequence as f64);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let now = SystemTime::now().duration_since(UNIX_EPOCH)?;
        let mut pose = Pose::new(sequence, u64::try_from(now.as_nanos())?, Frame::ODOM);
        pose.status = StatusFlags::TRACKING;
        publisher.publish_odom(&pose)?;
    }
    // Let the consumer drain before the services go away with this process.
    std::thread::sleep(Duration::from_millis(500));
    Ok(())
}

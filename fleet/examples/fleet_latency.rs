//! Measures the fleet link's added latency: the same odom poses received from the daemon's
//! shared memory and over Zenoh from `glintd bridge`, in one process, compared by sequence
//! number. Shared memory delivers in microseconds, so the difference is the bridge and the
//! network's time. Used by `scripts/fleet_bench.sh`.
//!
//!     fleet_latency DOMAIN ENDPOINT SITE ROBOT
//!
//! Runs until neither stream brought anything for 3 s after the first pose, then prints
//! `poses=… missing=… latency_median_ms=… latency_p99_ms=…`.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use glint_fleet::LinkConfig;
use glint_ipc::{Domain, Pose, PoseStream, PoseSubscriber};
use zenoh::handlers::FifoChannel;
use zenoh::Wait;

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [domain, endpoint, site, robot] = args.as_slice() else {
        return Err("usage: fleet_latency DOMAIN ENDPOINT SITE ROBOT".into());
    };
    let domain = Domain::new(domain)?;
    let link = LinkConfig {
        connect: vec![endpoint.clone()],
        insecure: true,
        ..LinkConfig::default()
    };
    let session = glint_fleet::open(&link)?;
    let fleet = session
        .declare_subscriber(format!("glint/{site}/{robot}/odom"))
        .with(FifoChannel::new(100_000))
        .wait()?;
    println!("subscribed");
    let shm = loop {
        match PoseSubscriber::open(&domain, PoseStream::Odom) {
            Ok(s) => break s,
            Err(_) => std::thread::sleep(Duration::from_millis(5)),
        }
    };
    let mut local: HashMap<u64, Instant> = HashMap::new();
    let mut remote: HashMap<u64, Instant> = HashMap::new();
    let mut last = None::<Instant>;
    while last.is_none_or(|t| t.elapsed() < Duration::from_secs(3)) {
        while let Some(p) = shm.try_next()? {
            local.insert(p.sequence, Instant::now());
            last = Some(Instant::now());
        }
        while let Ok(Some(sample)) = fleet.try_recv() {
            let pose = Pose::from_le_bytes(&sample.payload().to_bytes())?;
            remote.insert(pose.sequence, Instant::now());
            last = Some(Instant::now());
        }
        // Poll at 0.1 ms: the shared-memory side must be stamped on arrival.
        std::thread::sleep(Duration::from_micros(100));
    }
    let mut delays: Vec<f64> = remote
        .iter()
        .filter_map(|(seq, at)| {
            local
                .get(seq)
                .map(|t| at.saturating_duration_since(*t).as_secs_f64() * 1e3)
        })
        .collect();
    delays.sort_by(f64::total_cmp);
    let quantile = |q: f64| {
        delays
            .get(((delays.len() as f64 - 1.0) * q).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    println!(
        "poses={} missing={} latency_median_ms={:.3} latency_p99_ms={:.3}",
        delays.len(),
        local.len().saturating_sub(delays.len()),
        quantile(0.5),
        quantile(0.99)
    );
    Ok(())
}

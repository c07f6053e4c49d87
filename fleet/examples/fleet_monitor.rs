//! Fleet-side monitor in Rust: subscribes to every robot's poses and status on a site over
//! Zenoh and prints one line per sample. The payloads are the shared-memory layouts, read with
//! `glint_ipc`'s `from_le_bytes`; the attachment names the type.
//!
//!     cargo run -p glint-fleet --example fleet_monitor -- tcp/127.0.0.1:7447 [SITE] [COUNT]
//!
//! This example connects in plain TCP for brevity; a production monitor fills a
//! `glint_fleet::LinkConfig` with its `[tls]` settings instead (docs/fleet.md).

use glint_fleet::LinkConfig;
use glint_ipc::{Pose, Status};
use zenoh::Wait;

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let mut args = std::env::args().skip(1);
    let endpoint = args
        .next()
        .ok_or("usage: fleet_monitor ENDPOINT [SITE] [COUNT]")?;
    let site = args.next().unwrap_or_else(|| "site".into());
    let count: Option<u64> = args.next().map(|c| c.parse()).transpose()?;
    let link = LinkConfig {
        connect: vec![endpoint],
        insecure: true,
        ..LinkConfig::default()
    };
    let session = glint_fleet::open(&link)?;
    let subscriber = session
        .declare_subscriber(format!("glint/{site}/*/*"))
        .wait()?;
    let mut received = 0;
    while count.is_none_or(|c| received < c) {
        let sample = subscriber.recv()?;
        let key = sample.key_expr().as_str();
        let kind = sample
            .attachment()
            .and_then(|a| a.try_to_string().ok().map(|s| s.into_owned()))
            .unwrap_or_default();
        let bytes = sample.payload().to_bytes();
        if kind.contains("type=glint::PoseV1;") {
            let p = Pose::from_le_bytes(&bytes)?;
            let [x, y, z] = p.position;
            println!(
                "{key} #{} t={:.3} {} ({x:.3}, {y:.3}, {z:.3}) quality {:.2}",
                p.sequence,
                p.timestamp_ns as f64 * 1e-9,
                p.frame,
                p.quality
            );
        } else if kind.contains("type=glint::StatusV1;") {
            let s = Status::from_le_bytes(&bytes)?;
            println!(
                "{key} #{} sweeps {} dropped {} latency p99 {:.1} ms flags {:#x}",
                s.sequence, s.sweeps_processed, s.sweeps_dropped, s.latency_p99_ms, s.flags.0
            );
        } else {
            eprintln!("{key}: unknown payload {kind:?} ({} bytes)", bytes.len());
        }
        received += 1;
    }
    Ok(())
}

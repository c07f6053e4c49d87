//! `glintd echo`: subscribe to a running daemon's poses, status, sweeps or map updates and
//! print one line each.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use glint_ipc::{
    Domain, MapContent, MapUpdateSubscriber, PointLabel, PoseStream, PoseSubscriber,
    StatusSubscriber, SweepSubscriber,
};

/// Arguments of `glintd echo`.
#[derive(Args, Debug)]
pub struct EchoArgs {
    /// The stream: odom, map, predicted, status, sweep or map_update.
    #[arg(long, default_value = "odom")]
    pub stream: String,
    /// The daemon's domain (service-name prefix).
    #[arg(long, default_value = "default")]
    pub domain: String,
    /// Stop after this many messages.
    #[arg(long)]
    pub count: Option<u64>,
    /// Stop after this many seconds without waiting for more.
    #[arg(long)]
    pub timeout: Option<f64>,
    /// Keep trying for this many seconds while no daemon publishes in the domain (for consumers
    /// that start first).
    #[arg(long, default_value_t = 0.0)]
    pub wait: f64,
}

/// Opens with `open` until it succeeds or `wait` seconds have passed.
fn open_waiting<T, E>(wait: f64, mut open: impl FnMut() -> Result<T, E>) -> Result<T, E> {
    let until = Instant::now() + Duration::from_secs_f64(wait.max(0.0));
    loop {
        match open() {
            Ok(t) => return Ok(t),
            Err(e) if Instant::now() >= until => return Err(e),
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    }
}

/// Runs the command.
pub fn run(args: EchoArgs) -> Result<()> {
    let domain =
        Domain::new(&args.domain).with_context(|| format!("invalid --domain {:?}", args.domain))?;
    let deadline = args
        .timeout
        .map(|s| Instant::now() + Duration::from_secs_f64(s.max(0.0)));
    let remaining = || {
        deadline.map_or(Duration::from_millis(500), |d| {
            d.saturating_duration_since(Instant::now())
                .min(Duration::from_millis(500))
        })
    };
    let expired = || deadline.is_some_and(|d| Instant::now() >= d);
    let mut received = 0u64;
    let done = |n: u64| args.count.is_some_and(|c| n >= c);
    if args.stream == "status" {
        let sub = open_waiting(args.wait, || StatusSubscriber::open(&domain))
            .with_context(|| format!("no glintd publishing in domain {:?}", args.domain))?;
        while !done(received) && !expired() {
            if let Some(s) = sub.wait_next(remaining()).context("cannot receive")? {
                say!(
                    "status {} t={} sweeps={} dropped={} packets={} latency_p99={:.1}ms flags={}",
                    s.sequence,
                    s.timestamp_ns,
                    s.sweeps_processed,
                    s.sweeps_dropped,
                    s.packets_received,
                    s.latency_p99_ms,
                    s.flags
                );
                received += 1;
            }
        }
    } else if args.stream == "sweep" {
        let sub = open_waiting(args.wait, || SweepSubscriber::open(&domain))
            .with_context(|| format!("no glintd publishing sweeps in domain {:?}", args.domain))?;
        // The sweep service has no event service: poll at a tenth of a sweep period.
        while !done(received) && !expired() {
            let line = sub
                .try_next(|h, points| {
                    let labelled = |l| points.iter().filter(|p| p.label.contains(l)).count();
                    format!(
                        "sweep {} t={} points={} edges={} planes={} intensity={} flags={}",
                        h.sequence,
                        h.timestamp_ns,
                        h.point_count,
                        labelled(PointLabel::EDGE),
                        labelled(PointLabel::PLANE),
                        labelled(PointLabel::INTENSITY),
                        h.flags
                    )
                })
                .context("cannot receive")?;
            match line {
                Some(line) => {
                    say!("{line}");
                    received += 1;
                }
                None => std::thread::sleep(Duration::from_millis(10)),
            }
        }
    } else if args.stream == "map_update" {
        let sub = open_waiting(args.wait, || MapUpdateSubscriber::open(&domain))
            .with_context(|| format!("no glintd publishing its map in domain {:?}", args.domain))?;
        // No event service either: poll often enough for a new subscriber's paced map.
        while !done(received) && !expired() {
            match sub.try_next().context("cannot receive")? {
                Some(m) => {
                    let h = m.header;
                    let what = match &m.content {
                        MapContent::Cloud(points) => {
                            format!("cloud keyframe={} points={}", h.keyframe, points.len())
                        }
                        MapContent::KeyframePoses(poses) => format!("poses count={}", poses.len()),
                        MapContent::Edges(edges) => format!("edges count={}", edges.len()),
                        MapContent::Unreadable => format!("unreadable kind={}", h.kind),
                    };
                    say!(
                        "map_update {} t={} {what} part={}/{} keyframes={} map_id={} flags={}",
                        h.sequence,
                        h.sensor_time_ns,
                        h.part + 1,
                        h.parts,
                        h.keyframes,
                        h.map_id,
                        h.flags.0
                    );
                    received += 1;
                }
                None => std::thread::sleep(Duration::from_millis(10)),
            }
        }
    } else {
        let stream = match args.stream.as_str() {
            "odom" => PoseStream::Odom,
            "map" => PoseStream::Map,
            "predicted" => PoseStream::Predicted,
            other => {
                anyhow::bail!(
                    "unknown --stream {other:?}: odom, map, predicted, status, sweep or map_update"
                )
            }
        };
        let sub = open_waiting(args.wait, || PoseSubscriber::open(&domain, stream))
            .with_context(|| format!("no glintd publishing in domain {:?}", args.domain))?;
        while !done(received) && !expired() {
            if let Some(p) = sub.wait_next(remaining()).context("cannot receive")? {
                let [x, y, z] = p.position;
                let [qx, qy, qz, qw] = p.orientation;
                say!(
                    "{} {}.{:09} {x:.4} {y:.4} {z:.4} {qx:.6} {qy:.6} {qz:.6} {qw:.6} {}",
                    p.sequence,
                    p.timestamp_ns / 1_000_000_000,
                    p.timestamp_ns % 1_000_000_000,
                    p.status
                );
                received += 1;
            }
        }
    }
    if let Some(c) = args.count {
        anyhow::ensure!(
            received >= c,
            "received {received} of {c} messages before the timeout"
        );
    }
    Ok(())
}

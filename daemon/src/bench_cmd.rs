//! `glintd bench`: the odometry's compute time per sweep on one thread, without the pipeline's
//! threads, queues or publishing. Every sweep of a capture is decoded into memory first, then
//! calibration + features and registration run back to back on the calling thread, each stage
//! timed. Pin it to one core with `taskset -c N` for the one-core figure.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::odometry::{FrontEnd, Odometry, Stage};
use glint_core::scan::{Scan, ScanPoint};

use crate::capture::{self, SensorArgs};
use crate::config::DaemonConfig;
use crate::pipeline::{quantile, scan_points};

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// The capture to time (pcap or pcapng); make one with `glintd sim SCENARIO --out DIR`.
    pub capture: PathBuf,
    /// Geometry only.
    #[arg(long)]
    pub no_intensity: bool,
    /// Odometry parameters from a daemon configuration (as `glintd run --config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Run the whole capture this many times (the first run is also timed: its maps start empty
    /// just as a real start's do).
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    #[command(flatten)]
    pub sensor: SensorArgs,
}

/// One decoded sweep.
struct Input {
    points: Vec<ScanPoint>,
    rings: usize,
    reference_ns: u64,
}

/// Runs the command.
pub fn run(args: BenchArgs) -> Result<()> {
    let daemon = match &args.config {
        Some(path) => DaemonConfig::load(path)?,
        None => DaemonConfig::default(),
    };
    let config: OdometryConfig = if args.no_intensity {
        daemon.odometry.without_intensity()
    } else {
        daemon.odometry
    };
    let mut sweeps = Vec::new();
    capture::replay(&args.capture, &args.sensor, |sweep| {
        let Some(reference_ns) = sweep.points.last().map(|p| p.time_ns) else {
            return Ok(());
        };
        let mut points = Vec::new();
        scan_points(sweep, &mut points);
        let rings = points
            .iter()
            .map(|p| usize::from(p.ring) + 1)
            .max()
            .unwrap_or(16);
        sweeps.push(Input {
            points,
            rings,
            reference_ns,
        });
        Ok(())
    })?;
    if sweeps.is_empty() {
        bail!("{} holds no sweep", args.capture.display());
    }
    let mut front = Vec::new();
    let mut deskew = Vec::new();
    let mut align = Vec::new();
    let mut map = Vec::new();
    let mut total = Vec::new();
    let started = Instant::now();
    for _ in 0..args.repeat.max(1) {
        let mut front_end = FrontEnd::new(&config);
        let mut odometry = Odometry::new(&config);
        let mut features = SweepFeatures::default();
        for sweep in &sweeps {
            let t0 = Instant::now();
            front_end.process(
                &Scan {
                    points: &sweep.points,
                    rings: sweep.rings,
                    reference_ns: sweep.reference_ns,
                },
                &mut features,
            );
            let t1 = Instant::now();
            let mut last = t1;
            odometry.register(&features, |stage| {
                let now = Instant::now();
                let ms = (now - last).as_secs_f64() * 1e3;
                last = now;
                match stage {
                    Stage::Deskew => deskew.push(ms),
                    Stage::Align => align.push(ms),
                    Stage::MapUpdate => map.push(ms),
                }
            });
            front.push((t1 - t0).as_secs_f64() * 1e3);
            total.push((last - t0).as_secs_f64() * 1e3);
        }
    }
    let wall = started.elapsed().as_secs_f64();
    let line = |name: &str, v: &mut Vec<f64>| {
        if !v.is_empty() {
            say!(
                "  {name}: median {:.2} ms, p99 {:.2} ms",
                quantile(v, 0.5),
                quantile(v, 0.99)
            );
        }
    };
    say!(
        "{} sweeps × {} on one thread ({}): {:.1} sweeps/s",
        sweeps.len(),
        args.repeat.max(1),
        if config.solver.use_intensity {
            "with intensity"
        } else {
            "geometry only"
        },
        total.len() as f64 / wall
    );
    line("per sweep", &mut total);
    line("calibration + features", &mut front);
    line("deskew", &mut deskew);
    line("alignment", &mut align);
    line("map update", &mut map);
    Ok(())
}

//! `glintd bench`: the odometry's compute time per sweep on one thread, without the pipeline's
//! threads, queues or publishing. Each sweep of a capture is decoded (untimed), then calibration +
//! features and registration run back to back on the calling thread, each stage timed. Pin it to
//! one core with `taskset -c N` for the one-core figure. As in the daemon, a sweep's returns are
//! calibrated as they stream in, a packet's worth at a time; "after last packet" is the compute
//! from the last packet's returns to the pose (the rest of the calibration, the features, the
//! alignment). The map update follows the pose.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use clap::Args;
use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::front_end::FrontEnd;
use glint_core::localiser::{localisation_keyframes, Localiser};
use glint_core::odometry::Stage;
use glint_core::tracker::Tracker;

use crate::capture::{self, SensorArgs};
use crate::config::DaemonConfig;
use crate::pipeline::{quantile, scan_of};

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
    /// Localisation mode: the tracker localising in this saved site map, each keyframe located
    /// in the map on the same thread and timed apart (`--localize` is the same flag).
    #[arg(long, value_name = "MAP", visible_alias = "localize")]
    pub localise: Option<PathBuf>,
    /// Run the whole capture this many times, each from empty maps (as a real start), and time
    /// them all.
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    #[command(flatten)]
    pub sensor: SensorArgs,
}

/// Runs the command.
pub fn run(args: BenchArgs) -> Result<()> {
    let daemon = DaemonConfig::load_or_default(args.config.as_deref())?;
    let config: OdometryConfig = if args.no_intensity {
        daemon.odometry.without_intensity()
    } else {
        daemon.odometry
    };
    let mut streamed = Vec::new();
    let mut recalibrated = 0u64;
    // Feature sectors picked before the last packet, and the sectors there were.
    let mut picked_early = (0usize, 0usize);
    // Per sweep, the correspondences made before the last packet.
    let mut early_associated = Vec::new();
    let mut front = Vec::new();
    let mut deskew = Vec::new();
    let mut align = Vec::new();
    let mut map = Vec::new();
    let mut to_pose = Vec::new();
    let mut total = Vec::new();
    let mut sweeps = 0;
    let mut busy = Duration::ZERO;
    let site_map = args.localise.as_deref().map(glint_map::load).transpose()?;
    let mut locate = Vec::new();
    let mut verified = 0u64;
    for _ in 0..args.repeat.max(1) {
        let mut front_end = FrontEnd::new(&config);
        let mut localiser = site_map
            .clone()
            .map(|map| Localiser::new(map, &daemon.localiser, &daemon.backend.scan_context));
        let mut tracker = match &localiser {
            Some(_) => {
                Tracker::localising(&config, &localisation_keyframes(&daemon.backend.keyframes))
            }
            None => Tracker::new(&config, None),
        };
        let mut features = SweepFeatures::default();
        let mut early = SweepFeatures::default();
        let mut points = Vec::new();
        sweeps = 0;
        let report = capture::replay(&args.capture, &args.sensor, |sweep| {
            // Decoding is not timed: only what the odometry does with a decoded sweep.
            let Some(scan) = scan_of(sweep, &mut points) else {
                return Ok(());
            };
            // The returns stream in a packet's worth at a time, as the daemon calibrates them,
            // and the last packet's come with the closed sweep.
            let per_packet = scan
                .points
                .len()
                .div_ceil(sweep.packets_received.max(1) as usize);
            let last_packet = scan.points.len().saturating_sub(per_packet);
            let s0 = Instant::now();
            front_end.begin(scan.rings);
            let mut streamed_in = 0;
            let mut associated = 0;
            let sweep_start = scan.points.first().map_or(0, |p| p.time_ns);
            for chunk in scan.points[..last_packet].chunks(per_packet) {
                front_end.stream(chunk);
                streamed_in += chunk.len();
                // As the daemon's odometry thread does with each sector the front end picks.
                if front_end.sectors_picked() > associated {
                    associated = front_end.sectors_picked();
                    front_end.early_features(&scan.points[..streamed_in], &mut early);
                    tracker.associate_early(sweep_start, &early);
                }
            }
            early_associated.push(tracker.odometry().early_correspondences());
            let t0 = Instant::now();
            picked_early.0 += front_end.sectors_picked();
            picked_early.1 += config.features.sectors.max(1);
            front_end.process(&scan, &mut features);
            let t1 = Instant::now();
            recalibrated += u64::from(front_end.recalibrated() > 0);
            // The rest of the edges and planes, associated as the early ones were: part of the
            // alignment.
            front_end.features_from_start(scan.points, &features, &mut early);
            tracker.associate_early(sweep_start, &early);
            let rest_ms = t1.elapsed().as_secs_f64() * 1e3;
            let mut last = Instant::now();
            let tracked = tracker.track_pose(&features, None, |stage| {
                let now = Instant::now();
                let ms = (now - last).as_secs_f64() * 1e3;
                last = now;
                match stage {
                    Stage::Deskew => deskew.push(ms),
                    Stage::Align => align.push(ms + rest_ms),
                    Stage::MapUpdate => {}
                }
            });
            let posed = Instant::now();
            tracker.update_maps(&features);
            let grown = Instant::now();
            map.push((grown - posed).as_secs_f64() * 1e3);
            if let (Some(localiser), Some(keyframe)) = (localiser.as_mut(), &tracked.keyframe) {
                let started = Instant::now();
                let (correction, _) = localiser.answer(tracker.epoch(), keyframe);
                tracker.apply(&correction);
                locate.push(started.elapsed().as_secs_f64() * 1e3);
            }
            verified += u64::from(tracker.map_fix(&tracked.estimate).verified);
            streamed.push((t0 - s0).as_secs_f64() * 1e3);
            front.push((t1 - t0).as_secs_f64() * 1e3);
            to_pose.push((posed - t0).as_secs_f64() * 1e3);
            total.push((grown - s0).as_secs_f64() * 1e3);
            busy += grown - s0;
            sweeps += 1;
            Ok(())
        })?;
        if let Some(damage) = report.damage {
            say!("the capture is damaged ({damage}): timing the {sweeps} sweeps before it");
        }
    }
    if sweeps == 0 {
        bail!("{} holds no sweep", args.capture.display());
    }
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
        "{} sweeps × {} on one thread ({}): {:.1} sweeps/s of odometry compute",
        sweeps,
        args.repeat.max(1),
        if config.solver.use_intensity {
            "with intensity"
        } else {
            "geometry only"
        },
        total.len() as f64 / busy.as_secs_f64().max(1e-9)
    );
    line("per sweep", &mut total);
    line("after last packet", &mut to_pose);
    line("calibration as the returns stream in", &mut streamed);
    line("calibration + features after the last packet", &mut front);
    line("deskew", &mut deskew);
    line("alignment", &mut align);
    line("map update", &mut map);
    say!(
        "  {recalibrated} of {} sweeps had rings recalibrated at the close (a late return where a \
         streamed normal had looked)",
        total.len()
    );
    say!(
        "  {} of {} feature sectors picked before the last packet, median {} correspondences made \
         by then",
        picked_early.0,
        picked_early.1,
        {
            early_associated.sort_unstable();
            early_associated
                .get(early_associated.len() / 2)
                .copied()
                .unwrap_or(0)
        }
    );
    if site_map.is_some() {
        say!(
            "localisation (off the pose path, on its own thread in the daemon): {} keyframes located, {verified} sweeps verified in the map",
            locate.len()
        );
        line("locating a keyframe in the map", &mut locate);
    }
    Ok(())
}

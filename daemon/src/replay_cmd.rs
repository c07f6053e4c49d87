//! `glintd replay`: a capture through the pipeline (the threads `glintd run` uses) at any pace,
//! as fast as the machine allows by default, writing the
//! trajectory (one pose per sweep, stamped with the sweep's reference time) and the whole run's
//! map, and printing timing and — with ground truth — accuracy.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::Args;
use glint_core::metrics::{
    associate, ate_rmse, relative_errors, return_to_start, RETURN_MIN_TRAVEL_M, WAREHOUSE_LENGTHS,
};
use glint_core::trajectory::{parse_tum, StampedPose};
use nalgebra::Vector3;

use crate::capture::{describe_sources, SensorArgs};
use crate::config::DaemonConfig;
use crate::pipeline::{self, Input, Options, Pace, PublishOptions, SiteMapOptions};

/// Arguments of `glintd replay`.
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The capture (pcap or pcapng).
    pub capture: PathBuf,
    /// Where to write the trajectory (TUM: `t x y z qx qy qz qw`).
    #[arg(long)]
    pub trajectory: Option<PathBuf>,
    /// Also write the trajectory in KITTI format (12 numbers per line).
    #[arg(long)]
    pub kitti: Option<PathBuf>,
    /// Write the whole run's map (PCD, or PLY when the name ends in .ply), with calibrated
    /// intensity.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Geometry only: no intensity roughness in feature selection, no intensity residual.
    #[arg(long)]
    pub no_intensity: bool,
    /// Odometry only: no loop closure. By default the back end runs, and `--trajectory` holds
    /// every sweep's pose after the last optimisation.
    #[arg(long)]
    pub no_loop: bool,
    /// Also write the odometry's own poses (TUM), as published on `odom`.
    #[arg(long)]
    pub odom_trajectory: Option<PathBuf>,
    /// Ground truth (TUM) to evaluate against.
    #[arg(long)]
    pub groundtruth: Option<PathBuf>,
    /// Diagnostic: start every sweep's alignment from the ground truth and grow the map from it,
    /// and report how far alignment alone moves the pose off the truth (needs --groundtruth).
    #[arg(long)]
    pub seed_from_groundtruth: bool,
    /// Service-name prefix of the poses published over iceoryx2 (`glint/<domain>/odom`, …).
    #[arg(long, default_value = "default")]
    pub domain: String,
    /// Do not publish poses over iceoryx2.
    #[arg(long)]
    pub no_publish: bool,
    /// Voxel size of the exported map, m.
    #[arg(long, default_value_t = 0.1)]
    pub map_voxel: f32,
    /// Replay speed: `max` (as fast as the machine allows), `realtime`, or a factor of real
    /// time (`2`, `0.5`). The outputs are the same at any pace.
    #[arg(long, default_value = "max")]
    pub pace: Pace,
    /// Rate of the predicted pose stream, Hz (0: off).
    #[arg(long, default_value_t = 50.0)]
    pub predicted_rate: f64,
    /// Mapping: write the run's site map here at the end (any file name; `*.glintmap` by
    /// convention), in the map frame the trajectory is written in: the first `base_link` pose.
    /// With `--localise`: write the saved map extended by the places this run drove through
    /// that it does not cover, in its frame (the saved keyframes unchanged; it may be the
    /// same file).
    #[arg(long, value_name = "MAP")]
    pub save_map: Option<PathBuf>,
    /// Localisation: localise in this saved site map instead of mapping. `--trajectory` then
    /// holds the sensor's poses in the map frame for the sweeps whose pose is verified in it,
    /// and each (re)localisation prints a line with the sensor time it took.
    #[arg(long, value_name = "MAP", visible_alias = "localize")]
    pub localise: Option<PathBuf>,
    /// Localisation: where the robot's `base_link` is believed to be in the map, as
    /// `x,y,yaw` (m, m, rad), narrowing the first relocalisation to the keyframes near it.
    #[arg(
        long,
        value_name = "X,Y,YAW",
        value_delimiter = ',',
        allow_negative_numbers = true
    )]
    pub initial_pose: Option<Vec<f64>>,
    /// Take the odometry, back-end, pipeline and mounting parameters from a daemon
    /// configuration (as `glintd run --config`), so a capture replays with what the robot runs.
    /// `--no-intensity` and `--no-loop` still apply on top.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub sensor: SensorArgs,
}

fn read_tum(path: &std::path::Path) -> Result<Vec<StampedPose>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_tum(&text).with_context(|| path.display().to_string())
}

/// Runs the command.
pub fn run(args: ReplayArgs) -> Result<()> {
    let daemon = DaemonConfig::load_or_default(args.config.as_deref())?;
    let config = if args.no_intensity {
        daemon.odometry.clone().without_intensity()
    } else {
        daemon.odometry.clone()
    };
    let loop_closure = !args.no_loop && daemon.pipeline.loop_closure;
    let mode = if config.solver.use_intensity {
        "with intensity"
    } else {
        "geometry only"
    };
    let groundtruth = args.groundtruth.as_deref().map(read_tum).transpose()?;
    let known_poses = if args.seed_from_groundtruth {
        Some(
            groundtruth
                .clone()
                .context("--seed-from-groundtruth needs --groundtruth")?,
        )
    } else {
        None
    };
    if args.save_map.is_some() && args.localise.is_none() && !loop_closure {
        anyhow::bail!("--save-map needs the back end: leave out --no-loop");
    }
    let base_from_sensor = daemon.mounting.base_from_sensor();
    let localise = match &args.localise {
        Some(path) => Some(
            glint_map::load(path)
                .with_context(|| format!("cannot localise in {}", path.display()))?,
        ),
        None => None,
    };
    let hint = args
        .initial_pose
        .as_deref()
        .map(|p| crate::config::initial_pose(p, &base_from_sensor))
        .transpose()?;
    let stop = Arc::new(AtomicBool::new(false));
    crate::signals::stop_on_signals(&stop)?;
    let summary = pipeline::run(Options {
        site_map: SiteMapOptions {
            save: args.save_map.clone(),
            autosave: None,
            localise,
            hint,
            localiser: daemon.localiser.clone(),
        },
        input: Input::Capture {
            path: args.capture.clone(),
            ports: args.sensor.ports(),
            source: args.sensor.source,
            pace: args.pace,
        },
        stream: args.sensor.stream_config()?,
        odometry: config,
        queue: 2,
        odometry_thread: daemon.odometry_thread(),
        base_from_sensor,
        backend: loop_closure.then(|| daemon.backend.clone()),
        odom_trajectory: args.odom_trajectory.clone(),
        publish: (!args.no_publish).then(|| PublishOptions {
            domain: args.domain.clone(),
            predicted_rate_hz: args.predicted_rate,
            sweeps: true,
            map_updates: true,
        }),
        trajectory: args.trajectory.clone(),
        trajectory_max_bytes: None,
        kitti: args.kitti.clone(),
        map: args.map.clone().map(|p| (p, args.map_voxel)),
        keep_estimates: true,
        known_poses,
        stop,
        on_ready: None,
        on_alive: None,
        on_sweep: None,
    })?;
    let departures = &summary.departures;
    let timings = &summary.timings;
    let statuses = summary.statuses;
    if !departures.is_empty() {
        let n = departures.len() as f64;
        let mean = departures.iter().sum::<Vector3<f64>>() / n;
        let rms = (departures
            .iter()
            .map(|e| e.component_mul(e))
            .sum::<Vector3<f64>>()
            / n)
            .map(f64::sqrt);
        say!(
            "seeded from ground truth: alignment moves the pose off the truth by mean ({:.4}, {:.4}, {:.4}) m, rms ({:.4}, {:.4}, {:.4}) m (sensor x, y, z)",
            mean.x, mean.y, mean.z, rms.x, rms.y, rms.z
        );
    }
    if let Some(capture) = &summary.capture {
        // Said only when it matters: a capture of one sensor reports as it always has.
        let sources = &capture.sources;
        if sources.sources().len() > 1 || sources.stats().foreign() > 0 {
            let st = sources.stats();
            say!(
                "other sensors: {} data and {} position packets refused",
                st.foreign_data,
                st.foreign_position
            );
            for line in describe_sources(sources) {
                say!("{line}");
            }
        }
    }
    let n = timings.total.len();
    say!(
        "sweeps: {n} ({} initialising, {} tracking, {} degenerate, {} lost); {mode}",
        statuses.initialising,
        statuses.tracking,
        statuses.degenerate,
        statuses.lost,
    );
    for (name, v) in [
        ("per sweep", &timings.total),
        ("  calibration + features", &timings.front_end),
        ("  deskew", &timings.deskew),
        ("  alignment", &timings.align),
        ("  map update", &timings.map),
        (
            "latency (sweep received → pose published)",
            &timings.latency,
        ),
    ] {
        say!(
            "{name}: median {:.2} ms, p99 {:.2} ms",
            v.quantile(0.5),
            v.quantile(0.99)
        );
    }
    say!(
        "wall time {:.2} s: {:.1} sweeps/s (pace {:?})",
        summary.wall.as_secs_f64(),
        n as f64 / summary.wall.as_secs_f64().max(1e-9),
        args.pace
    );
    say!(
        "features per sweep (median): {} edges, {} planes, {} intensity points; {} solver steps",
        timings.edges.quantile(0.5),
        timings.planes.quantile(0.5),
        timings.intensity.quantile(0.5),
        timings.iterations.quantile(0.5)
    );
    say!(
        "degeneracy (smallest translational information per plane correspondence, 0–1/3): median {:.4}, min {:.4}",
        timings.degeneracy.quantile(0.5),
        timings.degeneracy.quantile(0.0)
    );
    let (edges, planes, cells) = summary.map_sizes;
    say!("local map: {edges} edge points, {planes} plane points, {cells} intensity cells");
    if let Some(slam) = &summary.slam {
        let st = &slam.stats;
        say!(
            "back end: {} keyframes; loops found {}, verified {}, accepted {}, rejected {}; {} keyframes released their points as redundant; {} tied to the floor",
            st.keyframes,
            st.loops_found,
            st.verified,
            st.accepted,
            st.rejected,
            st.released,
            st.on_floor
        );
        say!(
            "  per keyframe: descriptor median {:.2} ms, candidate search median {:.2} ms (p99 {:.2}); verification median {:.1} ms per candidate ({}); optimisation median {:.1} ms ({}, after loops and floor edges)",
            slam.descriptor_ms.quantile(0.5),
            slam.search_ms.quantile(0.5),
            slam.search_ms.quantile(0.99),
            slam.verify_ms.quantile(0.5),
            slam.verify_ms.len(),
            slam.optimize_ms.quantile(0.5),
            slam.optimize_ms.len()
        );
    }
    if let Some(groundtruth) = &groundtruth {
        let mut runs = vec![("odometry", &summary.estimates)];
        if let Some(slam) = &summary.slam {
            runs.push(("SLAM", &slam.trajectory));
        }
        for (name, estimates) in runs {
            let pairs = associate(estimates, groundtruth);
            anyhow::ensure!(
                pairs.len() >= 2,
                "fewer than 2 poses fall inside the ground truth's time span"
            );
            let prefix = if summary.slam.is_some() {
                format!("{name}: ")
            } else {
                String::new()
            };
            match relative_errors(&pairs, &WAREHOUSE_LENGTHS) {
                Some(r) => say!("{prefix}{r}"),
                None => say!("{prefix}drift: the run is shorter than 5 m"),
            }
            if let Some(a) = ate_rmse(&pairs) {
                say!("{prefix}{a}");
            }
            if let Some(r) = return_to_start(&pairs, RETURN_MIN_TRAVEL_M) {
                say!(
                    "{prefix}return to start: {:.3} m error where the truth comes back within {:.2} m of its start",
                    r.error,
                    r.distance_from_start
                );
            }
        }
    }
    if args.localise.is_some() {
        say!(
            "localisation: {} of {n} sweeps verified in the map; {} relocalisation(s), lost {} time(s)",
            summary.map_verified,
            summary.relocalisations.len(),
            summary.map_lost.len()
        );
        for r in &summary.relocalisations {
            say!(
                "relocalised at t = {:.3} s after {:.2} s of sensor data",
                r.time_ns as f64 * 1e-9,
                r.searched_s
            );
        }
        for t in &summary.map_lost {
            say!("lost in the map at t = {:.3} s", *t as f64 * 1e-9);
        }
    }
    if let Some(e) = &summary.site_map_extension {
        say!(
            "map extended: {} keyframe(s) added; of the run's {}, {} registered in the saved map and {} placed in it",
            e.added,
            e.run_keyframes,
            e.anchors,
            e.placed
        );
    }
    if let Some((path, bytes)) = &summary.site_map_saved {
        say!("site map written to {} ({bytes} bytes)", path.display());
    }
    if summary.sweeps_unpublished > 0 {
        say!(
            "sweep service: {} of {n} sweeps not published (its thread was busy; poses unaffected)",
            summary.sweeps_unpublished
        );
    }
    for e in &summary.output_errors {
        say!("output not written: {e}");
    }
    if let Some(damage) = summary.capture.and_then(|c| c.damage) {
        return Err(anyhow::Error::new(damage)
            .context("the capture is damaged; the sweeps before the damage were processed"));
    }
    anyhow::ensure!(
        summary.output_errors.is_empty(),
        "{} output file(s) could not be written",
        summary.output_errors.len()
    );
    Ok(())
}

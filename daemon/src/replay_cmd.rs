//! `glintd replay`: a capture through the odometry as fast as the machine allows, writing the
//! trajectory (one pose per sweep, stamped with the sweep's reference time) and the whole run's
//! map, and printing timing and — with ground truth — accuracy.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::metrics::{associate, ate_rmse, relative_errors, WAREHOUSE_LENGTHS};
use glint_core::odometry::{FrontEnd, Odometry, Stage, TrackingStatus};
use glint_core::scan::{Scan, ScanPoint};
use glint_core::trajectory::{interpolate, parse_tum, StampedPose};
use glint_core::world_map::WorldMap;
use glint_driver::Sweep;
use nalgebra::{Isometry3, Vector3};

use crate::capture::{replay, SensorArgs};
use crate::outputs::{write_map, TrajectoryWriter};
use crate::publish::PoseBus;
use glint_ipc::Status;

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
    /// Odometry only, no loop closure (the back end is not built yet, so this is the default
    /// behaviour for now).
    #[arg(long)]
    pub no_loop: bool,
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
    #[command(flatten)]
    pub sensor: SensorArgs,
}

fn read_tum(path: &std::path::Path) -> Result<Vec<StampedPose>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_tum(&text).with_context(|| path.display().to_string())
}

/// Converts a driver sweep to the odometry's input.
pub fn scan_points(sweep: &Sweep, out: &mut Vec<ScanPoint>) {
    out.clear();
    out.extend(sweep.points.iter().map(|p| ScanPoint {
        position: [p.x, p.y, p.z],
        time_ns: p.time_ns,
        reflectivity: p.reflectivity,
        ring: p.ring,
    }));
}

#[derive(Default)]
struct Timings {
    total: Vec<f64>,
    front_end: Vec<f64>,
    deskew: Vec<f64>,
    align: Vec<f64>,
    map: Vec<f64>,
    edges: Vec<f64>,
    planes: Vec<f64>,
    intensity: Vec<f64>,
    iterations: Vec<f64>,
    degeneracy: Vec<f64>,
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Runs the command.
pub fn run(args: ReplayArgs) -> Result<()> {
    let config = if args.no_intensity {
        OdometryConfig::geometry_only()
    } else {
        OdometryConfig::default()
    };
    let mut front_end = FrontEnd::new(&config);
    let mut odometry = Odometry::new(&config);
    let mut trajectory = args
        .trajectory
        .as_deref()
        .map(|p| TrajectoryWriter::create(p, false))
        .transpose()?;
    let mut kitti = args
        .kitti
        .as_deref()
        .map(|p| TrajectoryWriter::create(p, true))
        .transpose()?;
    let mut world = args.map.as_ref().map(|_| WorldMap::new(args.map_voxel));
    let mut estimates = Vec::new();
    let mut points = Vec::new();
    let mut features = SweepFeatures::default();
    let mut timings = Timings::default();
    let mut statuses = [0usize; 4];
    let mut bus = if args.no_publish {
        None
    } else {
        match PoseBus::create(&args.domain) {
            Ok(bus) => Some(bus),
            Err(e) => {
                tracing::warn!("poses will not be published: {e:#}");
                None
            }
        }
    };
    let groundtruth = args.groundtruth.as_deref().map(read_tum).transpose()?;
    let known_poses = if args.seed_from_groundtruth {
        Some(
            groundtruth
                .as_ref()
                .context("--seed-from-groundtruth needs --groundtruth")?,
        )
    } else {
        None
    };
    let mut origin: Option<Isometry3<f64>> = None;
    let mut departures: Vec<Vector3<f64>> = Vec::new();
    let report = replay(&args.capture, &args.sensor, |sweep| {
        let Some(reference_ns) = sweep.points.last().map(|p| p.time_ns) else {
            return Ok(());
        };
        let start = Instant::now();
        scan_points(sweep, &mut points);
        // 16 rings for the VLP-16 family, 32 for the HDL-32E: whatever the sweep holds.
        let rings = sweep
            .points
            .iter()
            .map(|p| usize::from(p.ring) + 1)
            .max()
            .unwrap_or(16);
        let scan = Scan {
            points: &points,
            rings,
            reference_ns,
        };
        front_end.process(&scan, &mut features);
        let after_front = Instant::now();
        let mut marks = [after_front; 3];
        // The map frame is the first sweep's sensor frame: ground truth is expressed in it.
        let known = known_poses
            .and_then(|gt| interpolate(gt, reference_ns))
            .map(|g| *origin.get_or_insert(g.inverse()) * g);
        let hook = |stage| {
            let i = match stage {
                Stage::Deskew => 0,
                Stage::Align => 1,
                Stage::MapUpdate => 2,
            };
            marks[i] = Instant::now();
        };
        let estimate = match known {
            Some(pose) => odometry.register_at_known_pose(&features, pose, hook),
            None => odometry.register(&features, hook),
        };
        if let Some(pose) = known {
            departures.push((estimate.pose.inverse() * pose).translation.vector);
        }
        let end = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        timings.total.push(ms(start, end));
        timings.front_end.push(ms(start, after_front));
        timings.deskew.push(ms(after_front, marks[0]));
        timings.align.push(ms(marks[0], marks[1]));
        timings.map.push(ms(marks[1], marks[2]));
        timings.edges.push(features.edges.len() as f64);
        timings.planes.push(features.planes.len() as f64);
        timings.intensity.push(features.intensity.len() as f64);
        if let Some(a) = &estimate.alignment {
            timings.iterations.push(a.iterations as f64);
            timings.degeneracy.push(a.degeneracy);
        }
        statuses[match estimate.status {
            TrackingStatus::Initialising => 0,
            TrackingStatus::Tracking => 1,
            TrackingStatus::Degenerate => 2,
            TrackingStatus::Lost => 3,
        }] += 1;
        if let Some(b) = bus.as_mut() {
            let features_used = estimate
                .alignment
                .as_ref()
                .map_or(0, |a| a.edges + a.planes);
            let offered = (features.edges.len() + features.planes.len()).max(1);
            b.publish(&estimate, features_used as f32 / offered as f32)?;
            if timings.total.len() % 10 == 0 {
                let mut status = Status::new(0, estimate.time_ns);
                status.sweeps_processed = timings.total.len() as u64;
                status.sweep_rate_hz = (1e3 / timings.total.last().copied().unwrap_or(1.0)) as f32;
                b.publish_status(status)?;
            }
        }
        let stamped = StampedPose {
            time_ns: estimate.time_ns,
            pose: estimate.pose,
        };
        if let Some(w) = trajectory.as_mut() {
            w.write(&stamped)?;
        }
        if let Some(w) = kitti.as_mut() {
            w.write(&stamped)?;
        }
        if let Some(map) = world.as_mut() {
            for (p, eta) in odometry.map_points(&features, &estimate.pose) {
                map.insert(&p, eta);
            }
        }
        estimates.push(stamped);
        Ok(())
    })?;
    if let Some(w) = trajectory {
        w.finish()?;
    }
    if let Some(w) = kitti {
        w.finish()?;
    }
    if let (Some(map), Some(path)) = (world, args.map.as_ref()) {
        write_map(path, &map.points())?;
    }

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
    let n = timings.total.len();
    say!(
        "sweeps: {n} ({} initialising, {} tracking, {} degenerate, {} lost){}",
        statuses[0],
        statuses[1],
        statuses[2],
        statuses[3],
        if args.no_intensity {
            "; geometry only"
        } else {
            "; with intensity"
        }
    );
    for (name, v) in [
        ("per sweep", &mut timings.total),
        ("  calibration + features", &mut timings.front_end),
        ("  deskew", &mut timings.deskew),
        ("  alignment", &mut timings.align),
        ("  map update", &mut timings.map),
    ] {
        say!(
            "{name}: median {:.2} ms, p99 {:.2} ms",
            percentile(v, 0.5),
            percentile(v, 0.99)
        );
    }
    say!(
        "features per sweep (median): {} edges, {} planes, {} intensity points; {} solver steps",
        percentile(&mut timings.edges, 0.5),
        percentile(&mut timings.planes, 0.5),
        percentile(&mut timings.intensity, 0.5),
        percentile(&mut timings.iterations, 0.5)
    );
    say!(
        "degeneracy (smallest translational information per plane correspondence, 0–1/3): median {:.4}, min {:.4}",
        percentile(&mut timings.degeneracy, 0.5),
        percentile(&mut timings.degeneracy, 0.0)
    );
    let (edges, planes, cells) = odometry.map_sizes();
    say!("local map: {edges} edge points, {planes} plane points, {cells} intensity cells");
    if let Some(gt_path) = &args.groundtruth {
        let text = std::fs::read_to_string(gt_path)
            .with_context(|| format!("cannot read {}", gt_path.display()))?;
        let groundtruth = parse_tum(&text).with_context(|| gt_path.display().to_string())?;
        let pairs = associate(&estimates, &groundtruth);
        anyhow::ensure!(
            pairs.len() >= 2,
            "fewer than 2 poses fall inside the ground truth's time span"
        );
        match relative_errors(&pairs, &WAREHOUSE_LENGTHS) {
            Some(r) => say!("{r}"),
            None => say!("drift: the run is shorter than 5 m"),
        }
        if let Some(a) = ate_rmse(&pairs) {
            say!("{a}");
        }
    }
    if let Some(damage) = report.damage {
        return Err(anyhow::Error::new(damage)
            .context("the capture is damaged; the sweeps before the damage were processed"));
    }
    Ok(())
}

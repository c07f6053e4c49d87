//! `glintd demo`: the whole chain on a built-in simulated warehouse, with no sensor and no
//! files needed — simulate a run to a capture, replay it through the driver and the odometry,
//! publish the poses over iceoryx2, write the trajectory and the map, and print accuracy against
//! the ground truth and the timing.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use glint_sim::{Scenario, SimConfig};

use crate::capture::SensorArgs;
use crate::pipeline::Pace;
use crate::replay_cmd::{self, ReplayArgs};

/// Arguments of `glintd demo`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Where to write the capture, ground truth, trajectory and map.
    #[arg(long, default_value = "glint-demo")]
    pub out: PathBuf,
    /// Simulated seconds (two laps of the warehouse loop take about 70 s).
    #[arg(long, default_value_t = 80.0)]
    pub seconds: f64,
    /// Warehouse layout seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Service-name prefix of the published poses.
    #[arg(long, default_value = "demo")]
    pub domain: String,
}

/// Runs the command.
pub fn run(args: DemoArgs) -> Result<()> {
    let config = SimConfig {
        scenario: Scenario::Warehouse,
        seed: args.seed,
        seconds: args.seconds,
        ..SimConfig::default()
    };
    say!(
        "simulating {:.0} s of a warehouse (seed {}) into {} …",
        args.seconds,
        args.seed,
        args.out.display()
    );
    let summary =
        glint_sim::simulate_to_dir(&config, &args.out).context("the simulation failed")?;
    say!("{}", summary.report().trim_end());
    say!(
        "to look at it, start this in another terminal (it waits for the daemon; the viewer program comes from pip install rerun-sdk==0.36.3): cargo run --release -p glint-view -- --domain {} --spawn",
        args.domain
    );
    say!(
        "replaying it through the pipeline (driver, front end, odometry, back end), publishing on iceoryx2 domain {:?} …",
        args.domain
    );
    replay_cmd::run(ReplayArgs {
        capture: args.out.join("scan.pcap"),
        trajectory: Some(args.out.join("trajectory.tum")),
        kitti: Some(args.out.join("trajectory_kitti.txt")),
        map: Some(args.out.join("map.pcd")),
        no_intensity: false,
        no_loop: false,
        odom_trajectory: Some(args.out.join("odometry.tum")),
        groundtruth: Some(args.out.join("groundtruth.tum")),
        seed_from_groundtruth: false,
        domain: args.domain.clone(),
        no_publish: false,
        map_voxel: 0.1,
        pace: Pace::Max,
        predicted_rate: 50.0,
        config: None,
        save_map: Some(args.out.join("site.glintmap")),
        localise: None,
        initial_pose: None,
        sensor: SensorArgs {
            model: None,
            calibration: None,
            data_port: 2368,
            position_port: 8308,
            cut_azimuth: 0.0,
            source: None,
        },
    })?;
    say!(
        "wrote {}/trajectory.tum (SLAM, TUM), trajectory_kitti.txt, odometry.tum, map.pcd, site.glintmap (localise in it with glintd replay CAPTURE --localise); compare with evo: evo_ape tum {0}/groundtruth.tum {0}/trajectory.tum -a",
        args.out.display()
    );
    Ok(())
}

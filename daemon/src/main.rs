//! `glintd`: Glint's daemon and command-line tool. Parses the command line, sets up logging,
//! runs the subcommand from the library (`lib.rs`), prints an error chain once and sets the
//! exit code.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use glintd::{
    bench_cmd, bridge_cmd, decode_cmd, echo_cmd, eval_cmd, info_cmd, initial_pose_cmd, map_cmd,
    posegraph_cmd, record_cmd, replay_cmd, run_cmd,
};
#[cfg(feature = "sim")]
use glintd::{demo_cmd, sim_cmd, soak_cmd};

/// Glint: intensity-assisted LiDAR localisation for VLP-16 AGVs.
#[derive(Parser, Debug)]
#[command(name = "glintd", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Parsed once at start: the size of the largest arguments (replay's) costs nothing worth a box.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand, Debug)]
enum Command {
    /// The live daemon: listen for the sensor, publish poses over iceoryx2 (see --config).
    Run(run_cmd::RunArgs),
    /// The whole chain on a built-in simulated warehouse: no sensor, no files, no flags needed.
    #[cfg(feature = "sim")]
    Demo(demo_cmd::DemoArgs),
    /// Print what a capture holds: model, return mode, packets, sweeps, rpm, time span, gaps.
    Info(info_cmd::InfoArgs),
    /// Decode every return of a capture to CSV (or PLY when the name ends in .ply).
    Decode(decode_cmd::DecodeArgs),
    /// Run a capture through the pipeline at any pace: trajectory, map, timing and accuracy.
    Replay(replay_cmd::ReplayArgs),
    /// Compare two TUM trajectories: relative drift and absolute trajectory error.
    Eval(eval_cmd::EvalArgs),
    /// Simulate a VLP-16 on a robot in a scenario: pcap, ground truth and scene description.
    #[cfg(feature = "sim")]
    Sim(sim_cmd::SimArgs),
    /// Hours of simulated sensor data through the whole pipeline without a restart, sampling
    /// memory, per-sweep cost and latency into a CSV (see scripts/soak.sh).
    #[cfg(feature = "sim")]
    Soak(soak_cmd::SoakArgs),
    /// Print the poses (or status) a running glintd publishes.
    Echo(echo_cmd::EchoArgs),
    /// Send a running glintd a hint of where the robot is in the site map: X Y YAW (m, m, rad).
    InitialPose(initial_pose_cmd::InitialPoseArgs),
    /// Capture the sensor's packets into a pcap for later replay.
    Record(record_cmd::RecordArgs),
    /// Optimise a g2o pose graph: initial and final cost, iterations, time.
    Posegraph(posegraph_cmd::PoseGraphArgs),
    /// Look into a saved site map: `info` (header, extent, size), `export` (a point cloud).
    Map(map_cmd::MapArgs),
    /// The fleet link: publish a running glintd's poses and status over Zenoh and serve its
    /// site maps (see docs/fleet.md).
    Bridge(bridge_cmd::BridgeArgs),
    /// Time the odometry per sweep on one thread (pin it with taskset for the one-core figure).
    Bench(bench_cmd::BenchArgs),
}

/// Logs go to journald when systemd connected stderr to the journal (it sets `JOURNAL_STREAM`),
/// human-readable to stderr otherwise. `GLINT_LOG` filters (`info`, `glintd=debug`, …).
fn init_logging(default_level: &str) {
    use tracing_subscriber::prelude::*;
    let filter = tracing_subscriber::EnvFilter::try_from_env("GLINT_LOG")
        .unwrap_or_else(|_| default_level.into());
    let journald = std::env::var_os("JOURNAL_STREAM").and_then(|_| tracing_journald::layer().ok());
    match journald {
        Some(layer) => tracing_subscriber::registry()
            .with(filter)
            .with(layer)
            .init(),
        None => tracing_subscriber::registry()
            .with(filter)
            .with(tracing_subscriber::fmt::layer().with_writer(std::io::stderr))
            .init(),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The daemon's modes report once a second; the tools only warn.
    let default_level = match cli.command {
        Command::Run(_) | Command::Record(_) => "info",
        // Zenoh's own info lines would drown the bridge's.
        Command::Bridge(_) => "warn,glintd=info",
        _ => "warn",
    };
    init_logging(default_level);
    // iceoryx2 logs on its own; only its errors matter here unless IOX2_LOG_LEVEL says more.
    glint_ipc::iceoryx2::prelude::set_log_level_from_env_or(
        glint_ipc::iceoryx2::prelude::LogLevel::Error,
    );
    let result = match cli.command {
        #[cfg(feature = "sim")]
        Command::Demo(args) => demo_cmd::run(args),
        Command::Run(args) => run_cmd::run(args),
        Command::Record(args) => record_cmd::run(args),
        Command::Echo(args) => echo_cmd::run(args),
        Command::InitialPose(args) => initial_pose_cmd::run(args),
        Command::Info(args) => info_cmd::run(args),
        Command::Decode(args) => decode_cmd::run(args),
        Command::Replay(args) => replay_cmd::run(args),
        Command::Eval(args) => eval_cmd::run(args),
        #[cfg(feature = "sim")]
        Command::Sim(args) => sim_cmd::run(args),
        #[cfg(feature = "sim")]
        Command::Soak(args) => soak_cmd::run(args),
        Command::Posegraph(args) => posegraph_cmd::run(args),
        Command::Bench(args) => bench_cmd::run(args),
        Command::Bridge(args) => bridge_cmd::run(args),
        Command::Map(args) => map_cmd::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("glintd: {e:#}");
            ExitCode::FAILURE
        }
    }
}

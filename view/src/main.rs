//! `glint-view`: a live view of one Glint domain in rerun. Subscribes to the daemon's
//! shared-memory services like any other consumer (`odom` and `map` poses, `status`, `sweep`)
//! and logs them to a rerun viewer on this machine (`--spawn`), on another (`--connect`), or to
//! a recording (`--save`). It never slows the daemon: its subscriber ports lose what it does not
//! read in time, and the daemon does not wait for them. `docs/viewer.md` describes what it shows.

mod blueprint;
mod colour;
mod scene;
mod sources;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::Parser;
use glint_ipc::Domain;

use crate::scene::Scene;
use crate::sources::Sources;

/// Look at what a glintd sees: poses, trajectories, the current sweep with its features, the map
/// around the robot, tracking state and latency, in rerun.
#[derive(Debug, Parser)]
#[command(name = "glint-view", version)]
struct Cli {
    /// The glintd domain to view (`[ipc] domain` in glintd.toml).
    #[arg(long, default_value = "default")]
    domain: String,
    /// Start a rerun viewer on this machine (`rerun` from `pip install rerun-sdk==0.36.3` on
    /// PATH) and stream to it.
    #[arg(long)]
    spawn: bool,
    /// Stream to a rerun viewer elsewhere, e.g. `rerun+http://laptop:9876/proxy` (what
    /// `rerun --serve-web` or `rerun` prints it listens on).
    #[arg(long, value_name = "URL")]
    connect: Option<String>,
    /// Also record everything to this `.rrd` file (open it later with `rerun FILE.rrd`).
    #[arg(long, value_name = "FILE.rrd")]
    save: Option<PathBuf>,
    /// Stop after this many seconds (default: until Ctrl-C or SIGTERM).
    #[arg(long, value_name = "S")]
    seconds: Option<f64>,
    /// Stop when no sweep or pose arrived for this many seconds after the first one (the end
    /// of a replay).
    #[arg(long, value_name = "S")]
    idle_exit: Option<f64>,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let domain = Domain::new(&cli.domain).with_context(|| format!("domain {:?}", cli.domain))?;
    if !cli.spawn && cli.connect.is_none() && cli.save.is_none() {
        bail!("nowhere to show the view: give --spawn, --connect URL or --save FILE.rrd");
    }
    let seconds = positive("--seconds", cli.seconds)?;
    let idle_exit = positive("--idle-exit", cli.idle_exit)?;

    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop)).context("signal handler")?;
    }

    let recording = open_recording(&cli)?;
    let mut scene = Scene::new(recording.clone())?;
    let mut sources = Sources::new(domain.clone());
    eprintln!("glint-view: viewing domain {:?}", domain.as_str());

    let started = Instant::now();
    let mut last_data: Option<Instant> = None;
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if seconds.is_some_and(|s| now.duration_since(started) >= s) {
            break;
        }
        if let (Some(idle), Some(last)) = (idle_exit, last_data) {
            if now.duration_since(last) >= idle {
                break;
            }
        }
        let received = sources.poll(&mut scene);
        if received > 0 {
            last_data = Some(now);
        } else {
            // The sweep service has no event service: poll it at ten times the sweep rate.
            std::thread::sleep(Duration::from_millis(10));
        }
        scene.refresh_if_due();
    }
    scene.finish();
    let counts = scene.counts();
    eprintln!(
        "glint-view: {} sweeps, {} odom and {} map poses, {} status and {} map_update messages logged",
        counts.sweeps, counts.odom, counts.map, counts.status, counts.map_updates
    );
    recording
        .flush_with_timeout(Duration::from_secs(10))
        .context("flushing the recording")?;
    Ok(())
}

/// A positive, finite number of seconds from a flag.
fn positive(flag: &str, value: Option<f64>) -> Result<Option<Duration>> {
    match value {
        None => Ok(None),
        Some(s) if s.is_finite() && s > 0.0 => Ok(Some(Duration::from_secs_f64(s))),
        Some(s) => bail!("{flag} must be a positive number of seconds, not {s}"),
    }
}

/// The recording stream with every sink the flags ask for.
fn open_recording(cli: &Cli) -> Result<rerun::RecordingStream> {
    let mut sinks: Vec<Box<dyn rerun::sink::LogSink>> = Vec::new();
    if cli.spawn {
        let spawned = rerun::spawn(&rerun::SpawnOptions::default())
            .context("starting the rerun viewer (is `rerun` from rerun-sdk==0.36.3 on PATH?)")?;
        let url = format!("rerun+http://127.0.0.1:{}/proxy", spawned.port);
        sinks.push(Box::new(grpc_sink(&url)?));
    }
    if let Some(url) = &cli.connect {
        sinks.push(Box::new(grpc_sink(url)?));
    }
    if let Some(path) = &cli.save {
        let sink = rerun::sink::FileSink::new(path)
            .with_context(|| format!("cannot record to {}", path.display()))?;
        sinks.push(Box::new(sink));
    }
    let recording = rerun::RecordingStreamBuilder::new("glint-view")
        .with_blueprint(blueprint::layout())
        .set_sinks(sinks)
        .context("opening the rerun recording")?;
    // The recording's only timeline is the sensor's: a recording scrubs like the run.
    recording.set_log_time_enabled(false);
    Ok(recording)
}

fn grpc_sink(url: &str) -> Result<rerun::sink::GrpcSink> {
    let uri = url
        .parse::<rerun::external::re_uri::ProxyUri>()
        .with_context(|| {
            format!("{url:?} is not a rerun viewer's address (rerun+http://HOST:PORT/proxy)")
        })?;
    Ok(rerun::sink::GrpcSink::new(uri))
}

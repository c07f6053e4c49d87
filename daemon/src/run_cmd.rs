//! `glintd run`: the live daemon. Reads the TOML configuration, listens for the sensor, runs the
//! pipeline, publishes on iceoryx2, streams the trajectory to its file, and talks to systemd:
//! READY once the sockets are bound and the services exist, WATCHDOG while every stage is alive,
//! STOPPING on the way out. SIGTERM or SIGINT drain the pipeline and write the outputs.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{anyhow, Result};
use clap::Args;
use sd_notify::NotifyState;

use crate::config::{DaemonConfig, SiteMapMode};
use crate::pipeline::{self, Input, Options, PublishOptions, SiteMapOptions};

/// Arguments of `glintd run`.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// The configuration (TOML; see systemd/glintd.toml). Without it, the defaults: listen on
    /// every interface at ports 2368 and 8308, publish on domain "default".
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override the configuration's `ipc.domain`.
    #[arg(long)]
    pub domain: Option<String>,
    /// Check the configuration and exit.
    #[arg(long)]
    pub check: bool,
}

/// Runs the command.
pub fn run(args: RunArgs) -> Result<()> {
    let mut config = match &args.config {
        Some(path) => DaemonConfig::load(path)?,
        None => DaemonConfig::parse("")?,
    };
    if let Some(domain) = args.domain {
        glint_ipc::Domain::new(&domain).map_err(|e| anyhow!("--domain {domain:?}: {e}"))?;
        config.ipc.domain = domain;
    }
    let stream = config.stream_config()?;
    let site = &config.site_map;
    let base_from_sensor = config.mounting.base_from_sensor();
    let mut site_map = SiteMapOptions {
        localiser: config.localiser.clone(),
        ..SiteMapOptions::default()
    };
    match (site.mode, &site.path) {
        (SiteMapMode::Mapping, Some(path)) => {
            site_map.save = Some(path.clone());
            site_map.autosave =
                (site.autosave_s > 0.0).then(|| Duration::from_secs_f64(site.autosave_s));
        }
        (SiteMapMode::Localisation, Some(path)) => {
            // A map that cannot be read is a configuration error: the robot must not drive on
            // poses in a frame of its own making.
            let map = glint_map::load(path).map_err(|e| anyhow!("site_map.path: {e}"))?;
            tracing::info!(
                path = %path.display(),
                keyframes = map.keyframes.len(),
                "localising in the saved site map"
            );
            site_map.localise = Some(map);
            site_map.save = site.extend_to.clone();
            site_map.hint = site
                .initial_pose
                .map(|p| crate::config::initial_pose(&p, &base_from_sensor))
                .transpose()?;
        }
        _ => {}
    }
    if args.check {
        say!("configuration ok");
        return Ok(());
    }
    let stop = Arc::new(AtomicBool::new(false));
    crate::signals::stop_on_signals(&stop)?;
    let mut watchdog_usec = 0;
    let watchdog = sd_notify::watchdog_enabled(false, &mut watchdog_usec);
    if watchdog {
        tracing::info!(
            "systemd watchdog every {:.1} s",
            Duration::from_micros(watchdog_usec).as_secs_f64()
        );
    }
    let summary = pipeline::run(Options {
        site_map,
        input: Input::Live {
            udp: config.udp_config(),
            source: config.sensor.source,
            silence: Duration::from_secs_f64(config.sensor.silence_timeout_s),
        },
        stream,
        odometry: config.odometry.clone(),
        queue: config.pipeline.queue_sweeps,
        odometry_thread: config.odometry_thread(),
        base_from_sensor,
        backend: config.pipeline.loop_closure.then(|| config.backend.clone()),
        odom_trajectory: config.output.odom_trajectory.clone(),
        publish: config.ipc.publish.then(|| PublishOptions {
            domain: config.ipc.domain.clone(),
            predicted_rate_hz: config.ipc.predicted_rate_hz,
            sweeps: config.ipc.sweeps,
            map_updates: config.ipc.map_updates,
        }),
        trajectory: config.output.trajectory.clone(),
        trajectory_max_bytes: Some(config.output.trajectory_max_bytes),
        kitti: None,
        map: config
            .output
            .map
            .clone()
            .map(|p| (p, config.output.map_voxel)),
        keep_estimates: false,
        known_poses: None,
        stop,
        on_ready: Some(Box::new(|| {
            tracing::info!("ready");
            // Outside systemd there is no socket to tell: not an error.
            let _ = sd_notify::notify(false, &[NotifyState::Ready]);
        })),
        on_alive: watchdog.then(|| {
            Box::new(|| {
                let _ = sd_notify::notify(false, &[NotifyState::Watchdog]);
            }) as Box<dyn FnMut()>
        }),
        on_sweep: None,
    });
    let _ = sd_notify::notify(false, &[NotifyState::Stopping]);
    let summary = summary?;
    let latency = &summary.timings.latency;
    tracing::info!(
        sweeps = summary.statuses.total(),
        dropped = summary.sweeps_dropped,
        sweeps_unpublished = summary.sweeps_unpublished,
        latency_median_ms = format_args!("{:.1}", latency.quantile(0.5)),
        latency_p99_ms = format_args!("{:.1}", latency.quantile(0.99)),
        loops_accepted = summary.slam.as_ref().map_or(0, |s| s.stats.accepted),
        "stopped"
    );
    anyhow::ensure!(
        summary.output_errors.is_empty(),
        "output files could not be written: {}",
        summary.output_errors.join("; ")
    );
    Ok(())
}

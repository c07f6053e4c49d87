//! `glintd bridge`: the robot's fleet link. A process of its own (its own systemd unit) that
//! subscribes to the daemon's shared-memory poses and status like any other consumer and
//! publishes them over Zenoh under `glint/<site>/<robot>/{odom,map,status}`, and serves the
//! robot's saved site maps to the fleet. The daemon never waits for it: the bridge reads with
//! its own subscriber ports, and each stream keeps only its latest payload while nobody on the
//! link listens (`glint_fleet::Forwarder`). It may start before the daemon and outlives the
//! daemon's restarts: until the services exist it retries, and a subscriber re-attaches by
//! itself when the daemon comes back. `docs/fleet.md` describes the link.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use glint_fleet::{FleetKeys, ForwardCounts, Forwarder, LinkConfig, MapServer, PayloadType};
use glint_ipc::{Domain, PoseStream, PoseSubscriber, StatusSubscriber};
use serde::Deserialize;

use crate::signals::stop_on_signals;

/// Arguments of `glintd bridge`. Flags override the file's settings; `--listen` and
/// `--connect` replace the file's lists.
#[derive(Args, Debug)]
pub struct BridgeArgs {
    /// The bridge's TOML configuration (see systemd/bridge.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The daemon's domain (service-name prefix) to read from.
    #[arg(long)]
    pub domain: Option<String>,
    /// The site's name: the second chunk of every key.
    #[arg(long)]
    pub site: Option<String>,
    /// The robot's name in the fleet (default: the host name).
    #[arg(long)]
    pub robot: Option<String>,
    /// An endpoint to listen on, in Zenoh's syntax (`tls/0.0.0.0:7447`); repeatable.
    #[arg(long)]
    pub listen: Vec<String>,
    /// A peer or router to connect to (`tls/fleet.example:7447`); repeatable.
    #[arg(long)]
    pub connect: Vec<String>,
    /// Allow plain TCP without TLS settings (logged as a warning).
    #[arg(long)]
    pub insecure: bool,
    /// A `.glintmap` to serve to the fleet under glint/<site>/maps/<file stem>; repeatable.
    #[arg(long = "serve-map")]
    pub serve_maps: Vec<PathBuf>,
}

/// Per-stream rate limits, Hz; 0 forwards every message.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RateConfig {
    /// Odometry poses.
    #[serde(default)]
    pub odom_hz: f64,
    /// Map poses.
    #[serde(default)]
    pub map_hz: f64,
    /// Status reports.
    #[serde(default)]
    pub status_hz: f64,
}

/// The bridge's configuration file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BridgeConfig {
    /// The daemon's domain (default `default`).
    #[serde(default)]
    pub domain: Option<String>,
    /// The site (default `site`).
    #[serde(default)]
    pub site: Option<String>,
    /// The robot (default: the host name).
    #[serde(default)]
    pub robot: Option<String>,
    /// Maps to serve.
    #[serde(default)]
    pub serve_maps: Vec<PathBuf>,
    /// Rate limits.
    #[serde(default)]
    pub rate: RateConfig,
    /// The Zenoh link: mode, endpoints, TLS, access control.
    #[serde(default)]
    pub link: LinkConfig,
}

impl BridgeConfig {
    /// Reads and checks the file at `path`.
    pub fn load(path: &std::path::Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let config: Self =
            toml::from_str(&text).with_context(|| format!("invalid {}", path.display()))?;
        for (name, hz) in [
            ("odom_hz", config.rate.odom_hz),
            ("map_hz", config.rate.map_hz),
            ("status_hz", config.rate.status_hz),
        ] {
            anyhow::ensure!(
                hz.is_finite() && hz >= 0.0,
                "{}: [rate] {name} must be 0 (every message) or a positive rate, got {hz}",
                path.display()
            );
        }
        Ok(config)
    }
}

/// The host name, the default robot name.
fn host_name() -> Result<String> {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .context("cannot read the host name; give --robot")?;
    Ok(name.trim().to_string())
}

/// Settings shared by the bridge and `glintd map fetch`: the file, then the flags.
pub struct LinkArgs<'a> {
    /// `--config`.
    pub config: &'a Option<PathBuf>,
    /// `--listen`.
    pub listen: &'a [String],
    /// `--connect`.
    pub connect: &'a [String],
    /// `--insecure`.
    pub insecure: bool,
}

impl LinkArgs<'_> {
    /// The configuration file (or the defaults) with the flags applied.
    pub fn resolve(&self) -> Result<BridgeConfig> {
        let mut config = match self.config {
            Some(path) => BridgeConfig::load(path)?,
            None => BridgeConfig::default(),
        };
        if !self.listen.is_empty() {
            config.link.listen = self.listen.to_vec();
        }
        if !self.connect.is_empty() {
            config.link.connect = self.connect.to_vec();
        }
        config.link.insecure |= self.insecure;
        if config.link.tls.is_some() && self.insecure {
            tracing::warn!("--insecure ignored: TLS is configured, so the link stays TLS only");
        } else if config.link.is_plain() && config.link.insecure {
            tracing::warn!(
                "the fleet link runs over plain TCP: poses and maps cross the network \
                 unencrypted and unauthenticated"
            );
        }
        Ok(config)
    }
}

/// Runs the command until SIGTERM or SIGINT.
pub fn run(args: BridgeArgs) -> Result<()> {
    let mut config = LinkArgs {
        config: &args.config,
        listen: &args.listen,
        connect: &args.connect,
        insecure: args.insecure,
    }
    .resolve()?;
    config.serve_maps.extend(args.serve_maps.iter().cloned());
    let domain_name = args
        .domain
        .or(config.domain.clone())
        .unwrap_or_else(|| "default".into());
    let domain =
        Domain::new(&domain_name).with_context(|| format!("invalid domain {domain_name:?}"))?;
    let site = args
        .site
        .or(config.site.clone())
        .unwrap_or_else(|| "site".into());
    let robot = match args.robot.or(config.robot.clone()) {
        Some(r) => r,
        None => host_name()?,
    };
    let keys = FleetKeys::new(&site, &robot)?;
    for map in &config.serve_maps {
        glint_map::info(map).with_context(|| format!("cannot serve {}", map.display()))?;
    }
    let stop = Arc::new(AtomicBool::new(false));
    stop_on_signals(&stop)?;

    let session = glint_fleet::open(&config.link).context("cannot open the fleet link")?;
    let maps = MapServer::serve(&session, &site, &config.serve_maps)?;
    let streams = [
        (Stream::Pose(PoseStream::Odom), "odom", config.rate.odom_hz),
        (Stream::Pose(PoseStream::Map), "map", config.rate.map_hz),
        (Stream::Status, "status", config.rate.status_hz),
    ];
    let mut workers = Vec::new();
    for (stream, name, hz) in streams {
        let payload = match stream {
            Stream::Pose(_) => PayloadType::Pose,
            Stream::Status => PayloadType::Status,
        };
        let forwarder = Forwarder::declare(&session, keys.stream(name), payload, hz)
            .map_err(|e| anyhow::anyhow!("cannot declare the {name} publisher: {e}"))?;
        let (domain, stop) = (domain.clone(), stop.clone());
        let worker = std::thread::Builder::new()
            .name(format!("bridge-{name}"))
            .spawn(move || forward(stream, &domain, forwarder, &stop))
            .context("cannot start a bridge thread")?;
        workers.push((name, worker));
    }
    tracing::info!(
        "bridge ready: domain {:?} → glint/{site}/{robot}/{{odom,map,status}}; serving {} map(s){}",
        domain.as_str(),
        maps.served().len(),
        maps.served()
            .iter()
            .map(|(key, path)| format!(" {key} ← {}", path.display()))
            .collect::<String>()
    );
    let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Ready]);
    let mut totals = Vec::new();
    for (name, worker) in workers {
        let counts = worker
            .join()
            .map_err(|_| anyhow::anyhow!("the {name} thread panicked"))?;
        totals.push((name, counts));
    }
    let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Stopping]);
    drop(maps);
    let _ = zenoh::Wait::wait(session.close());
    for (name, c) in totals {
        say!(
            "bridge {name}: sent {} dropped_unheard {} dropped_rate {} failed {}",
            c.sent,
            c.dropped_unheard,
            c.dropped_rate,
            c.failed
        );
    }
    Ok(())
}

/// Which shared-memory service a worker reads.
#[derive(Clone, Copy)]
enum Stream {
    Pose(PoseStream),
    Status,
}

/// A subscriber of either kind, read as payload bytes.
enum Source {
    Pose(PoseSubscriber),
    Status(StatusSubscriber),
}

impl Source {
    fn open(stream: Stream, domain: &Domain) -> Option<Self> {
        match stream {
            Stream::Pose(s) => PoseSubscriber::open(domain, s).ok().map(Self::Pose),
            Stream::Status => StatusSubscriber::open(domain).ok().map(Self::Status),
        }
    }

    /// The next payload's bytes within `timeout`; `Err` when the port failed.
    fn next(&self, timeout: Duration) -> Result<Option<Vec<u8>>, ()> {
        match self {
            Self::Pose(s) => s
                .wait_next(timeout)
                .map(|p| p.map(|p| p.to_le_bytes().to_vec()))
                .map_err(|_| ()),
            Self::Status(s) => s
                .wait_next(timeout)
                .map(|p| p.map(|p| p.to_le_bytes().to_vec()))
                .map_err(|_| ()),
        }
    }
}

/// How often a stream logs what it dropped (only when it dropped something).
const REPORT_EVERY: Duration = Duration::from_secs(60);

/// One stream: shared memory in, Zenoh out, until `stop`.
fn forward(
    stream: Stream,
    domain: &Domain,
    mut forwarder: Forwarder,
    stop: &AtomicBool,
) -> ForwardCounts {
    let mut source = None;
    let mut waiting_logged = false;
    let mut reported = (Instant::now(), ForwardCounts::default());
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        forwarder.flush(now);
        let Some(src) = source.as_ref() else {
            source = Source::open(stream, domain);
            match source {
                Some(_) => tracing::info!("{}: attached to the daemon", forwarder.key()),
                None if !waiting_logged => {
                    tracing::info!(
                        "{}: waiting for glintd to publish in domain {:?}",
                        forwarder.key(),
                        domain.as_str()
                    );
                    waiting_logged = true;
                }
                None => std::thread::sleep(Duration::from_millis(50)),
            }
            continue;
        };
        // A kept payload is retried often; otherwise wake only to notice `stop`.
        let timeout = if forwarder.has_pending() {
            Duration::from_millis(5)
        } else {
            Duration::from_millis(100)
        };
        match src.next(timeout) {
            Ok(Some(bytes)) => forwarder.offer(bytes, Instant::now()),
            Ok(None) => {}
            Err(()) => {
                tracing::warn!("{}: the subscriber failed; re-attaching", forwarder.key());
                source = None;
                waiting_logged = false;
            }
        }
        let counts = forwarder.counts();
        let dropped = |c: &ForwardCounts| c.dropped_unheard + c.dropped_rate + c.failed;
        if now.duration_since(reported.0) >= REPORT_EVERY && dropped(&counts) > dropped(&reported.1)
        {
            tracing::info!(
                "{}: sent {}, dropped {} while nobody listened, {} by the rate limit, {} failed",
                forwarder.key(),
                counts.sent,
                counts.dropped_unheard,
                counts.dropped_rate,
                counts.failed
            );
            reported = (now, counts);
        }
    }
    forwarder.counts()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_documented_bridge_configuration_is_accepted_by_zenoh() {
        let example = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../systemd/bridge.toml");
        let mut config = BridgeConfig::load(&example).unwrap();
        assert_eq!(config.site.as_deref(), Some("dc-berlin"));
        assert!(config.link.tls.as_ref().is_some_and(|t| t.mutual));
        // The certificates exist only on a robot: open the same settings on loopback TCP
        // (an endpoint given, so no multicast scouting) to let Zenoh check the rules.
        config.link.tls = None;
        config.link.insecure = true;
        config.link.connect.clear();
        config.link.listen = vec!["tcp/127.0.0.1:0".into()];
        let session = glint_fleet::open(&config.link).unwrap();
        zenoh::Wait::wait(session.close()).unwrap();
    }

    #[test]
    fn a_negative_rate_is_refused() {
        let dir = std::env::temp_dir().join(format!("glint-bridge-rate-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bridge.toml");
        std::fs::write(&path, "[rate]\nodom_hz = -1\n").unwrap();
        let error = format!("{:#}", BridgeConfig::load(&path).unwrap_err());
        assert!(error.contains("odom_hz"), "{error}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}

//! The real-time pipeline every mode runs: a receive thread (UDP sockets or a paced capture)
//! closes sweeps → a front-end thread calibrates them and selects features → an odometry thread
//! registers them → this (the calling) thread publishes poses on iceoryx2, writes the outputs and
//! reports health. Beside the odometry, a back-end thread takes its keyframes, closes loops and
//! hands back the `map ← odom` correction. Stages talk over bounded crossbeam channels; nothing
//! queues without bound.
//!
//! Live, the receive thread never waits: a sweep that finds the front end's queue full is
//! dropped whole and counted, and the stages behind it wait on each other. In a replay the reader
//! waits instead, so every sweep is processed in capture order and the outputs depend on the data
//! alone: the same capture and configuration give byte-identical trajectory files at any pace.
//! For that, a replay also runs the back end in lockstep: the odometry takes the answer to each
//! keyframe when it hands over the next one (waiting if need be), so a correction applies from a
//! sweep fixed by the data. Live, the odometry never waits for the back end; a correction applies
//! from whichever sweep follows its arrival.
//!
//! The calling thread owns the pose bus: every stream's sequence numbers live in it, so one
//! thread publishes everything and also runs the predicted stream's and the status report's
//! timers. Each stage beats a heartbeat while it works or idles; the systemd watchdog is fed only
//! while every heartbeat is fresh, so a stuck stage gets the daemon restarted.
//!
//! This file holds what a run is given and gives back, and `run`, which wires the stages; each
//! stage and concern has its own file: `receive`, `front_end`, `odometry`, `backend_link`,
//! `sink` (publishing and the outputs), `report` (figures and the once-a-second report) and
//! `health` (heartbeats).

mod backend_link;
mod front_end;
mod health;
mod map_updates;
mod odometry;
mod placement;
mod receive;
mod report;
mod sink;
mod sweeps;

use std::net::Ipv4Addr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use crossbeam_channel::{bounded, never, tick};
use glint_core::backend::config::BackEndConfig;
use glint_core::backend::keyframe::Keyframe;
use glint_core::backend::{BackEndStats, SiteMapHeader};
use glint_core::config::OdometryConfig;
use glint_core::extension::{ExtensionReport, MapExtension};
use glint_core::localiser::{localisation_keyframes, Localiser, LocaliserConfig};
use glint_core::odometry::TrackingStatus;
use glint_core::site_map::SiteMap;
use glint_core::tracker::{Correction, Tracker};
use glint_core::trajectory::StampedPose;
use glint_driver::udp::{Datagram, UdpConfig, UdpSource};
use glint_driver::{PcapSource, Ports, StreamConfig};
#[cfg(feature = "sim")]
use glint_sim::SimConfig;
use nalgebra::{Isometry3, Vector3};

use crate::capture::CaptureReport;
use crate::publish::PoseBus;
#[cfg(feature = "sim")]
use crate::simulated::SimulatedSensor;
use backend_link::{
    run_backend, run_localiser, BackEndLink, HintSource, Lockstep, MapSaver, BACK_END_QUEUE,
};
use front_end::{run_front_end, ToOdometry};
use health::Heartbeats;
use map_updates::{run_map_publisher, HeldMap, MapEvent, MapOutlet, MAP_EVENT_QUEUE};
use odometry::{run_odometry, Estimated, OdometryOutcome};
use receive::{read_payloads, receive_live, Arrival, ReceiveCounters, Returns, OPEN_RETURNS_QUEUE};
use sink::Sink;
use sweeps::{run_sweep_publisher, PublishedSweep, SweepOutlet};

pub use front_end::scan_of;
pub use placement::{Placed, ThreadPlacement};
pub use report::{quantile, Samples, SweepFigures, SweepWatcher, Timings};

/// How fast a capture is replayed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// As fast as the stages go.
    Max,
    /// This many times real time (1 = the sensor's own pace).
    Factor(f64),
}

impl std::str::FromStr for Pace {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "max" => Ok(Self::Max),
            "realtime" => Ok(Self::Factor(1.0)),
            _ => match s.parse::<f64>() {
                Ok(f) if f.is_finite() && f > 0.0 => Ok(Self::Factor(f)),
                _ => Err(format!(
                    "{s:?}: expected max, realtime or a positive speed factor such as 2 or 0.5"
                )),
            },
        }
    }
}

/// Where the packets come from.
#[derive(Debug, Clone)]
pub enum Input {
    /// A capture file, read at `pace`.
    Capture {
        /// The pcap or pcapng file.
        path: PathBuf,
        /// The ports to read.
        ports: Ports,
        /// Read only this sender's packets (None: the first to send valid data).
        source: Option<Ipv4Addr>,
        /// Replay speed.
        pace: Pace,
    },
    /// A simulated sensor run in process, as fast as the stages go: a run of any length
    /// without a capture file (`glintd soak`).
    #[cfg(feature = "sim")]
    Simulated {
        /// The simulation.
        config: SimConfig,
    },
    /// The sensor's UDP traffic.
    Live {
        /// Sockets.
        udp: UdpConfig,
        /// Decode only this sender's packets (None: the first to send valid data).
        source: Option<Ipv4Addr>,
        /// No data packet for this long: the sensor is silent.
        silence: Duration,
    },
}

/// What to publish over iceoryx2.
#[derive(Debug, Clone)]
pub struct PublishOptions {
    /// Service-name prefix.
    pub domain: String,
    /// Predicted stream rate, Hz (0: off).
    pub predicted_rate_hz: f64,
    /// Publish every sweep's returns on the `sweep` service too.
    pub sweeps: bool,
    /// Publish the map as keyframes on the `map_update` service (when the back end or the
    /// localiser runs).
    pub map_updates: bool,
}

/// Everything a run needs.
pub struct Options {
    /// The packets.
    pub input: Input,
    /// How to decode them.
    pub stream: StreamConfig,
    /// The algorithm.
    pub odometry: OdometryConfig,
    /// Sweeps that may wait between two stages.
    pub queue: usize,
    /// The odometry thread's core and priority.
    pub odometry_thread: ThreadPlacement,
    /// `base_link` ← sensor (the published poses are the base's).
    pub base_from_sensor: Isometry3<f64>,
    /// iceoryx2 publishing, if any.
    pub publish: Option<PublishOptions>,
    /// The sensor's trajectory (TUM), streamed.
    pub trajectory: Option<PathBuf>,
    /// Rotate the trajectory file at this size (live runs).
    pub trajectory_max_bytes: Option<u64>,
    /// The same in KITTI's format.
    pub kitti: Option<PathBuf>,
    /// The whole run's map and its voxel size.
    pub map: Option<(PathBuf, f32)>,
    /// Keep every pose and every sweep's timing for the report (replays; a live run keeps a
    /// bounded window).
    pub keep_estimates: bool,
    /// Loop closure and pose-graph optimisation (None: odometry only).
    pub backend: Option<BackEndConfig>,
    /// Saving the run's site map, or localising in a saved one.
    pub site_map: SiteMapOptions,
    /// The odometry's own poses (TUM), streamed, beside the corrected `trajectory`.
    pub odom_trajectory: Option<PathBuf>,
    /// Diagnostic: start each sweep's alignment from these poses (ground truth in the map
    /// frame's origin) and grow the map from them.
    pub known_poses: Option<Vec<StampedPose>>,
    /// Set (by a signal handler) to end the run: the reader stops, the stages drain, the
    /// outputs are written.
    pub stop: Arc<AtomicBool>,
    /// Called once the sockets are bound and the services exist (systemd's READY).
    pub on_ready: Option<Box<dyn FnOnce()>>,
    /// Called about once a second while every stage is alive (systemd's watchdog).
    pub on_alive: Option<Box<dyn FnMut()>>,
    /// Called with every published sweep's figures (`glintd soak`'s sampling).
    pub on_sweep: Option<SweepWatcher>,
}

/// The saved site map's part in a run (see `docs/localisation.md`).
#[derive(Default)]
pub struct SiteMapOptions {
    /// Mapping: write the run's map here at the end (needs the back end). Localising: write
    /// the saved map extended by what the run saw beyond it (see `glint_core::extension`).
    pub save: Option<PathBuf>,
    /// Mapping, live: also save it this often while running.
    pub autosave: Option<Duration>,
    /// Localisation: the saved map to localise in; the back end's place is taken by the
    /// localiser.
    pub localise: Option<SiteMap>,
    /// Localisation: where the sensor is believed to be in the map, narrowing the first
    /// relocalisation.
    pub hint: Option<Isometry3<f64>>,
    /// Localisation: the localiser's tuning.
    pub localiser: LocaliserConfig,
}

impl SiteMapOptions {
    fn mode(&self) -> SiteMapMode {
        match (&self.localise, &self.save) {
            (Some(_), _) => SiteMapMode::Localising,
            (None, Some(_)) => SiteMapMode::Mapping,
            (None, None) => SiteMapMode::Off,
        }
    }
}

/// What the run does with a site map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SiteMapMode {
    Off,
    Mapping,
    Localising,
}

/// A relocalisation: when the first verified pose came, and how much sensor data it took
/// since tracking began or was lost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Relocalisation {
    /// The first verified pose's time, ns.
    pub time_ns: u64,
    /// Sensor time spent relocalising, s.
    pub searched_s: f64,
}

/// What a run did.
#[derive(Debug, Default)]
pub struct Summary {
    /// Every pose (when `keep_estimates`).
    pub estimates: Vec<StampedPose>,
    /// Sweeps by status.
    pub statuses: StatusCounts,
    /// Timing and features.
    pub timings: Timings,
    /// Local map sizes at the end (edge points, plane points, intensity cells).
    pub map_sizes: (usize, usize, usize),
    /// Whole sweeps dropped because the front end was behind (live only).
    pub sweeps_dropped: u64,
    /// With known poses: how far alignment moved each off its known pose (sensor frame).
    pub departures: Vec<Vector3<f64>>,
    /// The capture's report (replays).
    pub capture: Option<CaptureReport>,
    /// Wall time of the whole run.
    pub wall: Duration,
    /// Output files that could not be written (the run went on publishing).
    pub output_errors: Vec<String>,
    /// The back end's report, when it ran.
    pub slam: Option<SlamSummary>,
    /// Localising: each (re)localisation.
    pub relocalisations: Vec<Relocalisation>,
    /// Localising: when tracking in the map was lost (ns).
    pub map_lost: Vec<u64>,
    /// Localising: sweeps whose map pose was verified.
    pub map_verified: u64,
    /// Mapping: the site map written at the end, and its size (bytes).
    pub site_map_saved: Option<(PathBuf, u64)>,
    /// Steps of the receive clock (host clock set, sensor reset) the stamps followed, and the
    /// last one's size, ns.
    pub clock_steps: (u64, i64),
    /// Localising with a map to save: what the run added to the saved map.
    pub site_map_extension: Option<ExtensionReport>,
    /// Sweeps whose returns were not published on the `sweep` service (its thread busy).
    pub sweeps_unpublished: u64,
}

/// Sweeps counted by their tracking status.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct StatusCounts {
    /// Before the first map, or restarting.
    pub initialising: u64,
    /// Tracked.
    pub tracking: u64,
    /// Tracked with too little structure in some direction.
    pub degenerate: u64,
    /// Not matched to the map.
    pub lost: u64,
}

impl StatusCounts {
    /// Counts one sweep of `status`.
    pub fn count(&mut self, status: TrackingStatus) {
        let counter = match status {
            TrackingStatus::Initialising => &mut self.initialising,
            TrackingStatus::Tracking => &mut self.tracking,
            TrackingStatus::Degenerate => &mut self.degenerate,
            TrackingStatus::Lost => &mut self.lost,
        };
        *counter += 1;
    }

    /// Every sweep counted.
    pub fn total(&self) -> u64 {
        self.initialising + self.tracking + self.degenerate + self.lost
    }
}

/// What the back end did.
#[derive(Debug, Default)]
pub struct SlamSummary {
    /// Keyframes, loops found, verified, accepted and rejected.
    pub stats: BackEndStats,
    /// Every sweep's pose after the last optimisation (when `keep_estimates`).
    pub trajectory: Vec<StampedPose>,
    /// Per keyframe: descriptor, candidate search, each verification, each optimisation (ms).
    pub descriptor_ms: Samples,
    /// See `descriptor_ms`.
    pub search_ms: Samples,
    /// See `descriptor_ms`.
    pub verify_ms: Samples,
    /// See `descriptor_ms`.
    pub optimize_ms: Samples,
    /// Keyframes the back end could not take in time (live only).
    pub keyframes_dropped: u64,
}

/// Runs the pipeline until the input ends or `options.stop` is set.
pub fn run(mut options: Options) -> Result<Summary> {
    let started = Instant::now();
    let queue = options.queue.max(1);
    let heartbeats = Arc::new(Heartbeats::new(
        started,
        options.backend.is_some() || options.site_map.localise.is_some(),
    ));
    let counters = Arc::new(ReceiveCounters::default());

    // The services first (a crashed daemon's leftovers are cleaned here), then the sockets:
    // READY means both exist.
    let mut bus = match &options.publish {
        Some(p) => Some(PoseBus::create(&p.domain)?),
        None => None,
    };

    let (sweep_tx, sweep_rx) = bounded::<Arrival>(queue);
    // Returns of the open sweep: a sweep's packets and then some, never waited for.
    let (returns_tx, returns_rx) = bounded::<Returns>(OPEN_RETURNS_QUEUE);
    let (feature_tx, feature_rx) = bounded::<ToOdometry>(queue);
    let (estimate_tx, estimate_rx) = bounded::<Estimated>(queue.max(4));

    let receiver = {
        let heartbeats = heartbeats.clone();
        let counters = counters.clone();
        let stop = options.stop.clone();
        let stream = options.stream.clone();
        match options.input.clone() {
            Input::Capture {
                path,
                ports,
                source,
                pace,
            } => spawn("glint-read", move || {
                let mut payloads = PcapSource::open(&path, ports)
                    .with_context(|| format!("cannot replay {}", path.display()))?;
                read_payloads(
                    &mut payloads,
                    &path.display().to_string(),
                    stream,
                    source,
                    pace,
                    &stop,
                    &sweep_tx,
                    &returns_tx,
                    &heartbeats,
                    &counters,
                )
                .map(Some)
            })?,
            #[cfg(feature = "sim")]
            Input::Simulated { config } => spawn("glint-read", move || {
                let mut payloads = SimulatedSensor::new(&config)?;
                read_payloads(
                    &mut payloads,
                    "the simulated sensor",
                    stream,
                    None,
                    Pace::Max,
                    &stop,
                    &sweep_tx,
                    &returns_tx,
                    &heartbeats,
                    &counters,
                )
                .map(Some)
            })?,
            Input::Live {
                udp,
                source: sensor,
                silence,
            } => {
                let (datagram_tx, datagram_rx) = bounded::<Datagram>(4096);
                let source = UdpSource::start(&udp, datagram_tx)
                    .with_context(|| format!("cannot listen for the sensor on {}", udp.bind))?;
                let ports = source.local_ports();
                tracing::info!(
                    data_port = ports.data,
                    position_port = ports.position,
                    receive_buffer = source.granted_buffer(),
                    "listening for the sensor"
                );
                spawn("glint-receive", move || {
                    receive_live(
                        source,
                        &udp.clock,
                        &datagram_rx,
                        stream,
                        sensor,
                        silence,
                        &stop,
                        &sweep_tx,
                        &returns_tx,
                        &heartbeats,
                        &counters,
                    )
                    .map(|()| None)
                })?
            }
        }
    };
    // Live, the threads off the pose's path yield to it (see `placement`); a replay's stages
    // wait on each other, and would only run slower.
    let live = matches!(options.input, Input::Live { .. });
    // The `sweep` service, on a thread of its own; one sweep may wait for it.
    let sweep_service = match &options.publish {
        Some(p) if p.sweeps => {
            let domain = glint_ipc::Domain::new(&p.domain)
                .map_err(|e| anyhow!("domain {:?}: {e}", p.domain))?;
            let (tx, rx) = bounded::<PublishedSweep>(1);
            let base_from_sensor = options.base_from_sensor;
            let handle = spawn("glint-sweeps", move || {
                if live {
                    placement::run_in_background("glint-sweeps");
                }
                run_sweep_publisher(&domain, base_from_sensor, &rx);
                Ok(())
            })?;
            Some((SweepOutlet::new(tx), handle))
        }
        _ => None,
    };
    let front_end = {
        let heartbeats = heartbeats.clone();
        let config = options.odometry.clone();
        let label_returns = sweep_service.is_some();
        spawn("glint-features", move || {
            run_front_end(
                &config,
                label_returns,
                &sweep_rx,
                &returns_rx,
                &feature_tx,
                &heartbeats,
            );
            Ok(())
        })?
    };
    let mode = options.site_map.mode();
    let saver = options.site_map.save.clone().map(|path| MapSaver {
        path,
        every: options.site_map.autosave,
        header: SiteMapHeader {
            created_ns: glint_driver::udp::host_now_ns(),
            sensor_model: "VLP-16".into(),
            base_from_sensor: options.base_from_sensor,
        },
        intensity: options.odometry.intensity_map.clone(),
    });
    // Everything but the sensor's own traffic is read at the stages' pace, every sweep.
    let lockstep = match options.input {
        Input::Live { .. } => Lockstep::Off,
        _ if mode == SiteMapMode::Localising => Lockstep::Immediate,
        _ => Lockstep::NextKeyframe,
    };
    let backend_config = options.backend.clone().unwrap_or_default();
    // The `map_update` service, on a thread of its own, fed by the back end (mapping) or
    // given the saved map (localising).
    let map_service = match &options.publish {
        Some(p)
            if p.map_updates
                && (options.backend.is_some() || options.site_map.localise.is_some()) =>
        {
            let domain = glint_ipc::Domain::new(&p.domain)
                .map_err(|e| anyhow!("domain {:?}: {e}", p.domain))?;
            let held = match &options.site_map.localise {
                Some(map) => HeldMap::saved(map),
                None => HeldMap::mapping(glint_driver::udp::host_now_ns()),
            };
            let (tx, rx) = bounded::<MapEvent>(MAP_EVENT_QUEUE);
            let handle = spawn("glint-map", move || {
                if live {
                    placement::run_in_background("glint-map");
                }
                run_map_publisher(&domain, held, &rx);
                Ok(())
            })?;
            Some((tx, handle))
        }
        _ => None,
    };
    let (keyframe_tx, keyframe_rx) = bounded::<(u64, Keyframe)>(BACK_END_QUEUE);
    let (reply_tx, reply_rx) = bounded::<Correction>(BACK_END_QUEUE);
    let link = BackEndLink::new(keyframe_tx, reply_rx, lockstep);
    let (link, backend, localiser) =
        match (options.site_map.localise.take(), options.backend.clone()) {
            (Some(map), _) => {
                let extension = options
                    .site_map
                    .save
                    .is_some()
                    .then(|| MapExtension::new(map.clone(), &backend_config));
                let mut localiser = Localiser::new(
                    map,
                    &options.site_map.localiser,
                    &backend_config.scan_context,
                );
                if let Some(hint) = options.site_map.hint {
                    localiser.hint(hint);
                }
                // Consumers may narrow the search at run time, where poses are published.
                let hints = match &options.publish {
                    Some(p) => {
                        let domain = glint_ipc::Domain::new(&p.domain)
                            .map_err(|e| anyhow!("domain {:?}: {e}", p.domain))?;
                        Some(HintSource {
                            subscriber: glint_ipc::InitialPoseSubscriber::create(&domain)
                                .context("cannot offer the initial-pose service")?,
                            base_from_sensor: options.base_from_sensor,
                        })
                    }
                    None => None,
                };
                let heartbeats = heartbeats.clone();
                let handle = spawn("glint-localiser", move || {
                    if live {
                        placement::run_in_background("glint-localiser");
                    }
                    Ok(run_localiser(
                        localiser,
                        hints,
                        extension,
                        &keyframe_rx,
                        &reply_tx,
                        &heartbeats,
                    ))
                })?;
                (Some(link), None, Some(handle))
            }
            (None, Some(config)) => {
                let heartbeats = heartbeats.clone();
                let saver = saver.clone();
                // The back end's world is the first sensor pose; the `map` stream's frame, its
                // `base_link` (see `Sink`).
                let outlet = map_service
                    .as_ref()
                    .map(|(tx, _)| MapOutlet::new(tx.clone(), options.base_from_sensor));
                let handle = spawn("glint-backend", move || {
                    if live {
                        placement::run_in_background("glint-backend");
                    }
                    Ok(run_backend(
                        &config,
                        saver.as_ref(),
                        outlet,
                        &keyframe_rx,
                        &reply_tx,
                        &heartbeats,
                    ))
                })?;
                (Some(link), Some(handle), None)
            }
            (None, None) => (None, None, None),
        };
    let odometry = {
        let heartbeats = heartbeats.clone();
        let config = options.odometry.clone();
        let known = options.known_poses.take();
        // With a back end, the exported map is rebuilt from its optimised keyframes instead.
        let map_voxel = options
            .map
            .as_ref()
            .filter(|_| backend.is_none())
            .map(|(_, v)| *v);
        let tracker = match mode {
            SiteMapMode::Localising => {
                Tracker::localising(&config, &localisation_keyframes(&backend_config.keyframes))
            }
            _ => Tracker::new(&config, link.is_some().then_some(&backend_config.keyframes)),
        };
        let placement = options.odometry_thread;
        spawn("glint-odometry", move || {
            placement.apply("glint-odometry");
            Ok(run_odometry(
                tracker,
                known,
                map_voxel,
                link,
                &feature_rx,
                &estimate_tx,
                &heartbeats,
            ))
        })?
    };
    if let Some(ready) = options.on_ready.take() {
        ready();
    }

    let mut sink = Sink::new(&options, mode)?;
    sink.on_sweep = options.on_sweep.take();
    let sweep_thread = sweep_service.map(|(outlet, handle)| {
        sink.sweep_outlet = Some(outlet);
        handle
    });
    let predicted_rate = options
        .publish
        .as_ref()
        .map_or(0.0, |p| p.predicted_rate_hz);
    let predicted_tick = if predicted_rate > 0.0 && bus.is_some() {
        tick(Duration::from_secs_f64(1.0 / predicted_rate))
    } else {
        never()
    };
    let report_tick = tick(Duration::from_secs(1));
    let mut on_alive = options.on_alive.take();
    loop {
        crossbeam_channel::select! {
            recv(estimate_rx) -> message => match message {
                Ok(e) => sink.take(e, bus.as_mut(), &counters),
                Err(_) => break,
            },
            recv(predicted_tick) -> _ => {
                if let Some(b) = bus.as_mut() {
                    sink.predict(b);
                }
            },
            recv(report_tick) -> _ => {
                sink.report(bus.as_mut(), &counters);
                if heartbeats.all_alive() {
                    if let Some(alive) = on_alive.as_mut() {
                        alive();
                    }
                }
            },
        }
    }

    let capture = join(receiver, "receive")?;
    join(front_end, "front end")?;
    let OdometryOutcome {
        world,
        map_sizes,
        keyframes_dropped,
    } = join(odometry, "odometry")?;
    let backend = backend.map(|b| join(b, "back end")).transpose()?;
    if let Some((events, handle)) = map_service {
        // The back end's copy is gone with it; this closes the service's input.
        drop(events);
        join(handle, "map service")?;
    }
    let extension = localiser
        .map(|l| join(l, "localiser"))
        .transpose()?
        .flatten();
    let mut summary = sink.finish(world, backend, extension, saver.as_ref(), &options)?;
    if let Some(handle) = sweep_thread {
        join(handle, "sweep service")?;
    }
    if let Some(slam) = summary.slam.as_mut() {
        slam.keyframes_dropped = keyframes_dropped;
    }
    summary.map_sizes = map_sizes;
    summary.capture = capture;
    summary.sweeps_dropped = counters.sweeps_dropped.load(Ordering::Relaxed);
    summary.clock_steps = (
        counters.clock_steps.load(Ordering::Relaxed),
        counters.last_clock_step_ns.load(Ordering::Relaxed),
    );
    summary.wall = started.elapsed();
    Ok(summary)
}

/// Starts a stage's thread, named for `top` and the logs.
fn spawn<T: Send + 'static>(
    name: &str,
    f: impl FnOnce() -> Result<T> + Send + 'static,
) -> Result<JoinHandle<Result<T>>> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .with_context(|| format!("cannot start thread {name}"))
}

/// Waits for a stage's thread; its result, or an error naming the stage if it panicked.
fn join<T>(handle: JoinHandle<Result<T>>, stage: &str) -> Result<T> {
    handle
        .join()
        .map_err(|_| anyhow!("the {stage} stage panicked"))?
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pace_parses() {
        assert_eq!("max".parse::<Pace>(), Ok(Pace::Max));
        assert_eq!("realtime".parse::<Pace>(), Ok(Pace::Factor(1.0)));
        assert_eq!("2.5".parse::<Pace>(), Ok(Pace::Factor(2.5)));
        assert!("0".parse::<Pace>().is_err());
        assert!("fast".parse::<Pace>().is_err());
        assert!("nan".parse::<Pace>().is_err());
    }
}

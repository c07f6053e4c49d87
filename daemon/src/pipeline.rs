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
//! The publishing thread owns the iceoryx2 ports (they are not `Send`), so it also runs the
//! predicted stream's and the status report's timers. Each stage beats a heartbeat while it works
//! or idles; the systemd watchdog is fed only while every heartbeat is fresh, so a stuck stage
//! gets the daemon restarted.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use crossbeam_channel::{bounded, never, tick, Receiver, RecvTimeoutError, Sender, TrySendError};
use glint_core::backend::config::BackEndConfig;
use glint_core::backend::keyframe::Keyframe;
use glint_core::backend::{BackEnd, BackEndStage, BackEndStats, SiteMapHeader};
use glint_core::config::{IntensityMapConfig, OdometryConfig};
use glint_core::features::SweepFeatures;
use glint_core::localiser::{localisation_keyframes, Localiser, LocaliserConfig, MapState};
use glint_core::odometry::{FrontEnd, OdometryEstimate, Stage, TrackingStatus};
use glint_core::scan::{Scan, ScanPoint};
use glint_core::se3::{base_covariance, exp, to_base};
use glint_core::site_map::SiteMap;
use glint_core::tracker::{Correction, MapFix, Tracker, TrackerEvent, RESUME_GAP_NS};
use glint_core::trajectory::{interpolate, StampedPose};
use glint_core::world_map::WorldMap;
use glint_driver::udp::{host_now_ns, Datagram, UdpConfig, UdpCounters, UdpSource};
use glint_driver::{PacketKind, Ports, SensorStream, StreamConfig, Sweep, SweepRecycler};
use glint_ipc::{Status, StatusFlags};
use nalgebra::{Isometry3, Vector3};

use crate::capture::{replay_stream, CaptureReport};
use crate::outputs::{write_map, TrajectoryWriter};
use crate::publish::{PoseBus, PoseSample};

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
        /// Replay speed.
        pace: Pace,
    },
    /// The sensor's UDP traffic.
    Live {
        /// Sockets.
        udp: UdpConfig,
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
}

/// The saved site map's part in a run (see `docs/localisation.md`).
#[derive(Default)]
pub struct SiteMapOptions {
    /// Mapping: write the run's map here at the end (needs the back end).
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

/// Per-sweep samples, bounded: past `CAPACITY` the oldest are overwritten, so a run of months
/// keeps the last few hours.
#[derive(Debug, Default, Clone)]
pub struct Samples {
    values: Vec<f64>,
    next: usize,
}

impl Samples {
    const CAPACITY: usize = 1 << 17;

    /// Adds one sample.
    pub fn push(&mut self, v: f64) {
        if self.values.len() < Self::CAPACITY {
            self.values.push(v);
        } else {
            self.values[self.next] = v;
            self.next = (self.next + 1) % Self::CAPACITY;
        }
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Whether none are held.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// The `q` quantile (0..=1) of the samples held, NaN when there are none.
    pub fn quantile(&self, q: f64) -> f64 {
        quantile(&mut self.values.clone(), q)
    }
}

pub use glint_core::tracker::quantile;

/// Per-stage timing (ms) and per-sweep feature figures.
#[derive(Debug, Default, Clone)]
pub struct Timings {
    /// Front end + odometry, per sweep.
    pub total: Samples,
    /// Calibration and features.
    pub front_end: Samples,
    /// Prediction and deskew.
    pub deskew: Samples,
    /// Scan-to-map alignment.
    pub align: Samples,
    /// Map update.
    pub map: Samples,
    /// Sweep closed (its last packet received) → pose published.
    pub latency: Samples,
    /// Edge features.
    pub edges: Samples,
    /// Plane features.
    pub planes: Samples,
    /// Intensity points.
    pub intensity: Samples,
    /// Solver steps.
    pub iterations: Samples,
    /// Degeneracy measure.
    pub degeneracy: Samples,
}

/// What a run did.
#[derive(Debug, Default)]
pub struct Summary {
    /// Every pose (when `keep_estimates`).
    pub estimates: Vec<StampedPose>,
    /// Sweeps by status: initialising, tracking, degenerate, lost.
    pub statuses: [u64; 4],
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

/// Counters the receive thread shares with the reporter.
#[derive(Debug, Default)]
struct ReceiveCounters {
    packets: AtomicU64,
    packets_missing: AtomicU64,
    malformed: AtomicU64,
    sweeps_dropped: AtomicU64,
    silent: AtomicBool,
}

impl ReceiveCounters {
    fn update(&self, stream: &SensorStream, udp: Option<&UdpCounters>) {
        let s = stream.stats();
        let (udp_dropped, wrong_length) = udp.map_or((0, 0), |u| {
            (
                u.dropped.load(Ordering::Relaxed),
                u.wrong_length.load(Ordering::Relaxed),
            )
        });
        self.packets
            .store(s.data_packets + s.position_packets, Ordering::Relaxed);
        self.packets_missing
            .store(s.packets_missing + udp_dropped, Ordering::Relaxed);
        self.malformed
            .store(s.truncated + s.malformed + wrong_length, Ordering::Relaxed);
    }
}

/// Liveness of the stages: the time (ms since the run started) each last showed progress.
struct Heartbeats {
    start: Instant,
    beats: [AtomicU64; 4],
    /// Which stages run (the back end is optional).
    active: [bool; 4],
}

impl Heartbeats {
    const RECEIVE: usize = 0;
    const FRONT_END: usize = 1;
    const ODOMETRY: usize = 2;
    const BACK_END: usize = 3;
    /// A stage silent for longer than this is stuck.
    const STALE: Duration = Duration::from_secs(3);

    fn beat(&self, stage: usize) {
        self.beats[stage].store(self.start.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    fn all_alive(&self) -> bool {
        let now = self.start.elapsed().as_millis() as u64;
        self.beats.iter().zip(self.active).all(|(b, active)| {
            !active
                || now.saturating_sub(b.load(Ordering::Relaxed)) < Self::STALE.as_millis() as u64
        })
    }
}

/// How long an idle stage waits before beating its heartbeat again.
const IDLE_BEAT: Duration = Duration::from_millis(200);

/// A closed sweep on its way to the front end.
struct Arrival {
    sweep: Sweep,
    recycler: Option<SweepRecycler>,
    /// When its last packet was received.
    received: Instant,
}

/// A sweep's features on their way to the odometry.
struct Featured {
    features: SweepFeatures,
    received: Instant,
    front_ms: f64,
}

/// A sweep's estimate on its way to the publisher.
struct Estimated {
    estimate: OdometryEstimate,
    quality: f32,
    received: Instant,
    /// front end, deskew, align, map update (ms).
    stage_ms: [f64; 4],
    counts: [usize; 3],
    departure: Option<Vector3<f64>>,
    /// `map ← odom` as of this sweep.
    map_from_odom: Isometry3<f64>,
    /// The correction changed with this sweep.
    loop_closed: bool,
    /// How far the map pose is to be trusted.
    map_fix: MapFix,
}

/// Runs the pipeline until the input ends or `options.stop` is set.
pub fn run(mut options: Options) -> Result<Summary> {
    let started = Instant::now();
    let queue = options.queue.max(1);
    let heartbeats = Arc::new(Heartbeats {
        start: started,
        beats: Default::default(),
        active: [
            true,
            true,
            true,
            options.backend.is_some() || options.site_map.localise.is_some(),
        ],
    });
    let counters = Arc::new(ReceiveCounters::default());

    // The services first (a crashed daemon's leftovers are cleaned here), then the sockets:
    // READY means both exist.
    let mut bus = match &options.publish {
        Some(p) => Some(PoseBus::create(&p.domain)?),
        None => None,
    };

    let (sweep_tx, sweep_rx) = bounded::<Arrival>(queue);
    let (feature_tx, feature_rx) = bounded::<Featured>(queue);
    let (estimate_tx, estimate_rx) = bounded::<Estimated>(queue.max(4));

    let receiver = {
        let heartbeats = heartbeats.clone();
        let counters = counters.clone();
        let stop = options.stop.clone();
        let stream = options.stream.clone();
        match options.input.clone() {
            Input::Capture { path, ports, pace } => spawn("glint-read", move || {
                read_capture(
                    &path,
                    ports,
                    stream,
                    pace,
                    &stop,
                    &sweep_tx,
                    &heartbeats,
                    &counters,
                )
                .map(Some)
            })?,
            Input::Live { udp, silence } => {
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
                        &datagram_rx,
                        stream,
                        silence,
                        &stop,
                        &sweep_tx,
                        &heartbeats,
                        &counters,
                    )
                    .map(|()| None)
                })?
            }
        }
    };
    let front_end = {
        let heartbeats = heartbeats.clone();
        let config = options.odometry.clone();
        spawn("glint-features", move || {
            run_front_end(&config, &sweep_rx, &feature_tx, &heartbeats);
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
    let lockstep = match options.input {
        Input::Capture { .. } if mode == SiteMapMode::Localising => Lockstep::Immediate,
        Input::Capture { .. } => Lockstep::NextKeyframe,
        Input::Live { .. } => Lockstep::Off,
    };
    let backend_config = options.backend.clone().unwrap_or_default();
    let (keyframe_tx, keyframe_rx) = bounded::<(u64, Keyframe)>(BACK_END_QUEUE);
    let (reply_tx, reply_rx) = bounded::<Correction>(BACK_END_QUEUE);
    let link = BackEndLink {
        keyframes: keyframe_tx,
        corrections: reply_rx,
        lockstep,
        pending: false,
        dropped: 0,
    };
    let (link, backend, localiser) =
        match (options.site_map.localise.take(), options.backend.clone()) {
            (Some(map), _) => {
                let mut localiser = Localiser::new(
                    map,
                    &options.site_map.localiser,
                    &backend_config.scan_context,
                );
                if let Some(hint) = options.site_map.hint {
                    localiser.hint(hint);
                }
                let heartbeats = heartbeats.clone();
                let handle = spawn("glint-localiser", move || {
                    run_localiser(localiser, &keyframe_rx, &reply_tx, &heartbeats);
                    Ok(())
                })?;
                (Some(link), None, Some(handle))
            }
            (None, Some(config)) => {
                let heartbeats = heartbeats.clone();
                let saver = saver.clone();
                let handle = spawn("glint-backend", move || {
                    Ok(run_backend(
                        &config,
                        saver.as_ref(),
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
        spawn("glint-odometry", move || {
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
    let (world, map_sizes, keyframes_dropped) = join(odometry, "odometry")?;
    let backend = backend.map(|b| join(b, "back end")).transpose()?;
    if let Some(l) = localiser {
        join(l, "localiser")?;
    }
    let mut summary = sink.finish(world, backend, saver.as_ref(), &options)?;
    if let Some(slam) = summary.slam.as_mut() {
        slam.keyframes_dropped = keyframes_dropped;
    }
    summary.map_sizes = map_sizes;
    summary.capture = capture;
    summary.sweeps_dropped = counters.sweeps_dropped.load(Ordering::Relaxed);
    summary.wall = started.elapsed();
    Ok(summary)
}

fn spawn<T: Send + 'static>(
    name: &str,
    f: impl FnOnce() -> Result<T> + Send + 'static,
) -> Result<JoinHandle<Result<T>>> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .with_context(|| format!("cannot start thread {name}"))
}

fn join<T>(handle: JoinHandle<Result<T>>, stage: &str) -> Result<T> {
    handle
        .join()
        .map_err(|_| anyhow!("the {stage} stage panicked"))?
}

/// The receive stage of a replay: reads the capture at `pace`, waiting for the front end
/// rather than dropping.
#[allow(clippy::too_many_arguments)]
fn read_capture(
    path: &std::path::Path,
    ports: Ports,
    stream: StreamConfig,
    pace: Pace,
    stop: &AtomicBool,
    out: &Sender<Arrival>,
    heartbeats: &Heartbeats,
    counters: &ReceiveCounters,
) -> Result<CaptureReport> {
    let mut clock: Option<(u64, Instant)> = None;
    let downstream_gone = std::cell::Cell::new(false);
    replay_stream(
        path,
        ports,
        stream,
        |record_ns, stream| {
            heartbeats.beat(Heartbeats::RECEIVE);
            if stop.load(Ordering::Relaxed) || downstream_gone.get() {
                return false;
            }
            if let Pace::Factor(f) = pace {
                let (t0, w0) = *clock.get_or_insert((record_ns, Instant::now()));
                let due =
                    w0 + Duration::from_secs_f64(record_ns.saturating_sub(t0) as f64 * 1e-9 / f);
                // Sleep in short steps so a stop request is seen promptly.
                while let Some(wait) = due.checked_duration_since(Instant::now()) {
                    if stop.load(Ordering::Relaxed) {
                        return false;
                    }
                    heartbeats.beat(Heartbeats::RECEIVE);
                    std::thread::sleep(wait.min(IDLE_BEAT));
                }
            }
            counters.update(stream, None);
            true
        },
        |sweep, stream| {
            let arrival = Arrival {
                sweep,
                recycler: stream.recycler(),
                received: Instant::now(),
            };
            // Blocking: a replay processes every sweep. Beat while waiting, so a slow stage
            // behind is not taken for a stuck reader.
            let mut pending = arrival;
            loop {
                match out.send_timeout(pending, IDLE_BEAT) {
                    Ok(()) => break,
                    Err(crossbeam_channel::SendTimeoutError::Timeout(a)) => {
                        heartbeats.beat(Heartbeats::RECEIVE);
                        pending = a;
                    }
                    Err(crossbeam_channel::SendTimeoutError::Disconnected(_)) => {
                        downstream_gone.set(true);
                        break;
                    }
                }
            }
            Ok(())
        },
    )
}

/// The receive stage live: datagrams from the socket threads into the stream; closed sweeps
/// offered to the front end without waiting.
#[allow(clippy::too_many_arguments)]
fn receive_live(
    source: UdpSource,
    datagrams: &Receiver<Datagram>,
    stream: StreamConfig,
    silence: Duration,
    stop: &AtomicBool,
    out: &Sender<Arrival>,
    heartbeats: &Heartbeats,
    counters: &ReceiveCounters,
) -> Result<()> {
    let udp = source.counters();
    let mut stream = SensorStream::new(stream);
    let mut last_data = Instant::now();
    let mut silent_since: Option<Instant> = None;
    let mut logged_errors = 0u64;
    let mut last_drop_log: Option<Instant> = None;
    while !stop.load(Ordering::Relaxed) {
        heartbeats.beat(Heartbeats::RECEIVE);
        let datagram = match datagrams.recv_timeout(Duration::from_millis(50)) {
            Ok(d) => Some(d),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        if let Some(d) = &datagram {
            let result = match d.kind {
                PacketKind::Data => {
                    last_data = Instant::now();
                    stream.push_data(d.payload(), d.receive_ns)
                }
                PacketKind::Position => stream.push_position(d.payload()),
            };
            if let Err(e) = result {
                // Garbage on the port or a damaged packet: counted by the stream, logged
                // sparingly (the first few, then every thousandth).
                logged_errors += 1;
                if logged_errors <= 5 || logged_errors.is_multiple_of(1000) {
                    tracing::warn!(count = logged_errors, "packet refused: {e}");
                }
            }
            counters.update(&stream, Some(&udp));
        }
        match (silent_since, last_data.elapsed() > silence) {
            (None, true) => {
                silent_since = Some(last_data);
                counters.silent.store(true, Ordering::Relaxed);
                tracing::warn!(
                    "no data from the sensor for {:.1} s (cable, power or network?)",
                    silence.as_secs_f64()
                );
            }
            (Some(since), false) => {
                silent_since = None;
                counters.silent.store(false, Ordering::Relaxed);
                tracing::info!(
                    "sensor data resumed after {:.1} s of silence",
                    since.elapsed().as_secs_f64()
                );
            }
            _ => {}
        }
        while let Some(sweep) = stream.take_sweep() {
            let behind = Duration::from_nanos(host_now_ns().saturating_sub(sweep.last_receive_ns));
            let arrival = Arrival {
                sweep,
                recycler: stream.recycler(),
                received: Instant::now()
                    .checked_sub(behind)
                    .unwrap_or_else(Instant::now),
            };
            match out.try_send(arrival) {
                Ok(()) => {}
                Err(TrySendError::Full(a)) => {
                    let dropped = counters.sweeps_dropped.fetch_add(1, Ordering::Relaxed) + 1;
                    if last_drop_log.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
                        tracing::warn!(dropped, "the pipeline is behind: sweep dropped");
                        last_drop_log = Some(Instant::now());
                    }
                    if let Some(r) = &a.recycler {
                        r.recycle(a.sweep);
                    }
                }
                Err(TrySendError::Disconnected(_)) => return Ok(()),
            }
        }
    }
    source.stop();
    Ok(())
}

/// Converts a driver sweep to the odometry's input, its points written into `out`; `None` for
/// an empty sweep. The reference time is the sweep's last return; the ring count is whatever
/// the sweep holds (16 for the VLP-16 family, 32 for the HDL-32E).
pub fn scan_of<'a>(sweep: &Sweep, out: &'a mut Vec<ScanPoint>) -> Option<Scan<'a>> {
    let reference_ns = sweep.points.last()?.time_ns;
    out.clear();
    out.extend(sweep.points.iter().map(|p| ScanPoint {
        position: [p.x, p.y, p.z],
        time_ns: p.time_ns,
        reflectivity: p.reflectivity,
        ring: p.ring,
    }));
    let rings = out
        .iter()
        .map(|p| usize::from(p.ring) + 1)
        .max()
        .unwrap_or(16);
    Some(Scan {
        points: out,
        rings,
        reference_ns,
    })
}

fn run_front_end(
    config: &OdometryConfig,
    input: &Receiver<Arrival>,
    output: &Sender<Featured>,
    heartbeats: &Heartbeats,
) {
    let mut front_end = FrontEnd::new(config);
    let mut points = Vec::new();
    let mut start = LeadingSweep::default();
    let mut process = |arrival: Arrival| -> Result<(), ()> {
        let begin = Instant::now();
        let scan = scan_of(&arrival.sweep, &mut points);
        if let Some(r) = &arrival.recycler {
            r.recycle(arrival.sweep);
        }
        let Some(scan) = scan else {
            return Ok(());
        };
        let mut features = SweepFeatures::default();
        front_end.process(&scan, &mut features);
        let message = Featured {
            features,
            received: arrival.received,
            front_ms: begin.elapsed().as_secs_f64() * 1e3,
        };
        send_beating(output, message, heartbeats, Heartbeats::FRONT_END)
    };
    while let Some(arrival) = recv_beating(input, heartbeats, Heartbeats::FRONT_END) {
        for a in start.admit(arrival).into_iter().flatten() {
            if process(a).is_err() {
                return;
            }
        }
    }
    if let Some(a) = start.finish() {
        // A stream of nothing but partial sweeps (a capture shorter than two rotations).
        let _ = process(a);
    }
}

/// Keeps a stream's partial first sweep out of the odometry when a whole one follows. The
/// sensor is mid-rotation when a capture or the daemon starts, so the first sweep may hold a
/// few degrees of the scene; the odometry would build its first map from that sliver, and with
/// the robot already moving (a restart while driving) the next sweeps would match too little of
/// it to see the motion (a simulated yard, seed 41: 85 plane matches, the first 0.35 m lost).
#[derive(Default)]
struct LeadingSweep {
    held: Option<Arrival>,
    decided: bool,
}

impl LeadingSweep {
    /// The sweeps to process now, in order.
    fn admit(&mut self, arrival: Arrival) -> [Option<Arrival>; 2] {
        if self.decided {
            return [Some(arrival), None];
        }
        match (self.held.take(), arrival.sweep.partial) {
            (None, true) => {
                self.held = Some(arrival);
                [None, None]
            }
            (Some(first), false) => {
                self.decided = true;
                tracing::info!(
                    returns = first.sweep.points.len(),
                    "the stream's first sweep covers part of a rotation: the odometry starts from the next"
                );
                if let Some(r) = &first.recycler {
                    r.recycle(first.sweep);
                }
                [Some(arrival), None]
            }
            (held, _) => {
                self.decided = true;
                [held, Some(arrival)]
            }
        }
    }

    /// A sweep still held at the end of the stream.
    fn finish(&mut self) -> Option<Arrival> {
        self.held.take()
    }
}

/// Receives, beating `stage`'s heartbeat while idle; None once the sender is gone.
fn recv_beating<T>(input: &Receiver<T>, heartbeats: &Heartbeats, stage: usize) -> Option<T> {
    loop {
        heartbeats.beat(stage);
        match input.recv_timeout(IDLE_BEAT) {
            Ok(message) => return Some(message),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => return None,
        }
    }
}

/// Sends, beating `stage`'s heartbeat while the next stage is busy.
fn send_beating<T>(
    out: &Sender<T>,
    mut message: T,
    heartbeats: &Heartbeats,
    stage: usize,
) -> Result<(), ()> {
    loop {
        match out.send_timeout(message, IDLE_BEAT) {
            Ok(()) => return Ok(()),
            Err(crossbeam_channel::SendTimeoutError::Timeout(m)) => {
                heartbeats.beat(stage);
                message = m;
            }
            Err(crossbeam_channel::SendTimeoutError::Disconnected(_)) => return Err(()),
        }
    }
}

/// Keyframes allowed to wait for the back end (live: more are dropped, counted).
const BACK_END_QUEUE: usize = 8;

/// How the odometry waits for the back end's (or the localiser's) answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Lockstep {
    /// Live: never; the newest answer applies from whichever sweep follows its arrival.
    Off,
    /// Replays: each keyframe's answer is awaited when the next keyframe is handed over, so a
    /// correction applies from a sweep fixed by the data while the back end works in parallel
    /// with the odometry for a keyframe interval (about 1 m of travel).
    NextKeyframe,
    /// Replays localising: each keyframe's answer is awaited at once, so a (re)localisation
    /// applies from the keyframe that made it.
    Immediate,
}

/// The odometry's end of the back end or the localiser.
struct BackEndLink {
    keyframes: Sender<(u64, Keyframe)>,
    corrections: Receiver<Correction>,
    lockstep: Lockstep,
    /// A keyframe was handed over and its answer not yet taken (`NextKeyframe`).
    pending: bool,
    dropped: u64,
}

impl BackEndLink {
    /// Hands a keyframe of odometry epoch `epoch` over. In lockstep, returns the answer due.
    fn offer(
        &mut self,
        epoch: u64,
        keyframe: Keyframe,
        heartbeats: &Heartbeats,
    ) -> Option<Correction> {
        match self.lockstep {
            Lockstep::NextKeyframe => {
                let mut answer = None;
                if self.pending {
                    answer = Some(recv_beating(
                        &self.corrections,
                        heartbeats,
                        Heartbeats::ODOMETRY,
                    )?);
                }
                self.pending = send_beating(
                    &self.keyframes,
                    (epoch, keyframe),
                    heartbeats,
                    Heartbeats::ODOMETRY,
                )
                .is_ok();
                answer
            }
            Lockstep::Immediate => {
                send_beating(
                    &self.keyframes,
                    (epoch, keyframe),
                    heartbeats,
                    Heartbeats::ODOMETRY,
                )
                .ok()?;
                recv_beating(&self.corrections, heartbeats, Heartbeats::ODOMETRY)
            }
            Lockstep::Off => {
                if let Err(TrySendError::Full(_)) = self.keyframes.try_send((epoch, keyframe)) {
                    self.dropped += 1;
                    tracing::warn!(
                        dropped = self.dropped,
                        "the back end is behind: keyframe dropped"
                    );
                }
                None
            }
        }
    }

    /// The answers sent since the last call, in order (live): each is applied, so a
    /// relocalisation's jump is not lost behind a later answer.
    fn arrived(&self) -> impl Iterator<Item = Correction> + '_ {
        self.corrections.try_iter()
    }
}

/// Writes the back end's site map (mapping).
#[derive(Clone)]
struct MapSaver {
    path: PathBuf,
    /// Live: also this often while running.
    every: Option<Duration>,
    header: SiteMapHeader,
    intensity: IntensityMapConfig,
}

impl MapSaver {
    /// Saves `backend`'s map crash-safely; its size in bytes.
    fn save(&self, backend: &BackEnd) -> Result<u64> {
        let site_from_world = backend.site_from_world(&self.header.base_from_sensor);
        let map = backend.site_map(&site_from_world, &self.intensity, self.header.clone());
        let report = glint_map::save(&self.path, &map)
            .with_context(|| format!("cannot save the site map {}", self.path.display()))?;
        Ok(report.bytes)
    }
}

fn run_localiser(
    mut localiser: Localiser,
    input: &Receiver<(u64, Keyframe)>,
    output: &Sender<Correction>,
    heartbeats: &Heartbeats,
) {
    while let Some((epoch, keyframe)) = recv_beating(input, heartbeats, Heartbeats::BACK_END) {
        let (answer, outcome) = localiser.answer(epoch, &keyframe);
        tracing::debug!(
            epoch,
            state = ?outcome.state,
            verifications = outcome.verifications,
            "keyframe located"
        );
        match outcome.state {
            MapState::Lost => {
                tracing::warn!("the scan no longer fits the saved map: lost, relocalising");
            }
            MapState::Tracking if outcome.relocalised => {
                tracing::info!(epoch, "relocalised in the saved map");
            }
            _ => {}
        }
        if output.send(answer).is_err() {
            break;
        }
    }
}

fn run_backend(
    config: &BackEndConfig,
    saver: Option<&MapSaver>,
    input: &Receiver<(u64, Keyframe)>,
    output: &Sender<Correction>,
    heartbeats: &Heartbeats,
) -> (BackEnd, SlamSummary) {
    let mut backend = BackEnd::new(config);
    let mut report = SlamSummary::default();
    let mut saved = Instant::now();
    while let Some((_, keyframe)) = recv_beating(input, heartbeats, Heartbeats::BACK_END) {
        let mut last = Instant::now();
        let outcome = backend.add_keyframe(keyframe, |stage| {
            let now = Instant::now();
            let ms = (now - last).as_secs_f64() * 1e3;
            last = now;
            heartbeats.beat(Heartbeats::BACK_END);
            match stage {
                BackEndStage::Descriptor => report.descriptor_ms.push(ms),
                BackEndStage::Search => report.search_ms.push(ms),
                BackEndStage::Verify => report.verify_ms.push(ms),
                BackEndStage::Optimize => report.optimize_ms.push(ms),
            }
        });
        if let Some(l) = &outcome.accepted {
            tracing::info!(
                keyframe = l.query,
                closes_on = l.candidate,
                similarity = l.similarity,
                "loop closed"
            );
        }
        if output.send(Correction::slam(backend.correction())).is_err() {
            break;
        }
        // Periodic saves happen here, between keyframes, off the pose path: the odometry never
        // waits for the back end live.
        if let Some(s) = saver.filter(|s| s.every.is_some_and(|e| saved.elapsed() >= e)) {
            heartbeats.beat(Heartbeats::BACK_END);
            match s.save(&backend) {
                Ok(bytes) => tracing::info!(path = %s.path.display(), bytes, "site map saved"),
                Err(e) => tracing::error!("{e:#}"),
            }
            saved = Instant::now();
        }
    }
    // Floor edges since the last optimisation: into the final trajectory too.
    let start = Instant::now();
    if backend.finish().is_some() {
        report.optimize_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    report.stats = backend.stats();
    (backend, report)
}

fn run_odometry(
    mut tracker: Tracker,
    known: Option<Vec<StampedPose>>,
    map_voxel: Option<f32>,
    mut backend: Option<BackEndLink>,
    input: &Receiver<Featured>,
    output: &Sender<Estimated>,
    heartbeats: &Heartbeats,
) -> (Option<WorldMap>, (usize, usize, usize), u64) {
    let mut world = map_voxel.map(WorldMap::new);
    while let Some(featured) = recv_beating(input, heartbeats, Heartbeats::ODOMETRY) {
        let features = &featured.features;
        let start = Instant::now();
        let mut marks = [start; 3];
        let hook = |stage| {
            let i = match stage {
                Stage::Deskew => 0,
                Stage::Align => 1,
                Stage::MapUpdate => 2,
            };
            marks[i] = Instant::now();
        };
        let known_pose = known
            .as_deref()
            .and_then(|gt| interpolate(gt, features.reference_ns));
        let tracked = tracker.track(features, known_pose, hook);
        match tracked.event {
            Some(TrackerEvent::Resumed { quality, cost }) => {
                tracing::info!(quality, cost, "tracking resumed after a gap in the data");
            }
            Some(TrackerEvent::Restarted { epoch }) => tracing::warn!(
                epoch,
                "sweeps stopped matching the odometry's map (moved, or blinded): \
                 odometry restarted, relocalising"
            ),
            Some(TrackerEvent::LostAfterGap { quality, cost }) => tracing::warn!(
                quality,
                cost,
                "after a gap in the data the scan does not match the map: lost \
                 (trying each sweep from the last good pose)"
            ),
            None => {}
        }
        let estimate = tracked.estimate;
        tracing::debug!(
            quality = tracked.quality,
            cost = tracked.cost,
            "sweep registered"
        );
        if let Some(map) = world.as_mut() {
            if estimate.status != TrackingStatus::Lost {
                for (p, eta) in tracker.map_points(features, &estimate.pose) {
                    map.insert(&p, eta);
                }
            }
        }
        let previous_correction = tracker.correction();
        if let Some(link) = backend.as_mut() {
            if let Some(keyframe) = tracked.keyframe {
                if let Some(c) = link.offer(tracker.epoch(), keyframe, heartbeats) {
                    tracker.apply(&c);
                }
            }
            if link.lockstep == Lockstep::Off {
                for c in link.arrived() {
                    tracker.apply(&c);
                }
            }
        }
        let map_fix = tracker.map_fix(&estimate);
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        let message = Estimated {
            map_from_odom: tracker.correction(),
            loop_closed: tracker.correction() != previous_correction,
            map_fix,
            quality: tracked.quality,
            received: featured.received,
            stage_ms: [
                featured.front_ms,
                ms(start, marks[0]),
                ms(marks[0], marks[1]),
                ms(marks[1], marks[2]),
            ],
            counts: [
                features.edges.len(),
                features.planes.len(),
                features.intensity.len(),
            ],
            departure: tracked.departure,
            estimate,
        };
        if send_beating(output, message, heartbeats, Heartbeats::ODOMETRY).is_err() {
            break;
        }
    }
    let dropped = backend.map_or(0, |l| l.dropped);
    (world, tracker.odometry().map_sizes(), dropped)
}

/// The publishing end: poses, predictions, status, trajectory files and the report.
struct Sink {
    base_from_sensor: Isometry3<f64>,
    /// The published `map` frame from the odometry's corrected world: the mounting (the map
    /// frame is the first `base_link` pose) unless localising, where the world is the saved
    /// map's frame already.
    site_from_world: Isometry3<f64>,
    /// The trajectory files' frame from the same: the map frame with a site map; without,
    /// none (the files are in the world itself, the first sensor pose's frame).
    trajectory_from_world: Option<Isometry3<f64>>,
    mode: SiteMapMode,
    /// Localising: since when (sensor time) the map pose has not been verified.
    searching_since: Option<u64>,
    /// Localising: the localiser's state at the last sweep.
    last_map_state: Option<MapState>,
    /// Written as the poses come (map frame), unless `final_trajectory`.
    trajectory: Option<TrajectoryWriter>,
    kitti: Option<TrajectoryWriter>,
    odom_trajectory: Option<TrajectoryWriter>,
    /// With a back end in a replay, `trajectory` and `kitti` hold the final optimised poses,
    /// written at the end.
    final_trajectory: bool,
    keep_estimates: bool,
    summary: Summary,
    /// The latest base pose and when its sweep was received.
    latest: Option<(PoseSample, Instant)>,
    /// Sweep period measured from consecutive poses, ns.
    period_ns: u64,
    // The reporting window.
    window_start: Instant,
    window_sweeps: u64,
    window_packets: u64,
    window_latency: Vec<f64>,
    sweeps: u64,
}

impl Sink {
    fn new(options: &Options, mode: SiteMapMode) -> Result<Self> {
        let trajectory = options
            .trajectory
            .as_deref()
            .map(|p| TrajectoryWriter::create(p, false, options.trajectory_max_bytes))
            .transpose()?;
        let kitti = options
            .kitti
            .as_deref()
            .map(|p| TrajectoryWriter::create(p, true, None))
            .transpose()?;
        let odom_trajectory = options
            .odom_trajectory
            .as_deref()
            .map(|p| TrajectoryWriter::create(p, false, options.trajectory_max_bytes))
            .transpose()?;
        let site_from_world = match mode {
            SiteMapMode::Localising => Isometry3::identity(),
            _ => options.base_from_sensor,
        };
        Ok(Self {
            base_from_sensor: options.base_from_sensor,
            site_from_world,
            trajectory_from_world: (mode != SiteMapMode::Off).then_some(site_from_world),
            mode,
            searching_since: None,
            last_map_state: None,
            trajectory,
            kitti,
            odom_trajectory,
            final_trajectory: options.backend.is_some()
                && mode != SiteMapMode::Localising
                && options.keep_estimates,
            keep_estimates: options.keep_estimates,
            summary: Summary::default(),
            latest: None,
            period_ns: 100_000_000,
            window_start: Instant::now(),
            window_sweeps: 0,
            window_packets: 0,
            window_latency: Vec::new(),
            sweeps: 0,
        })
    }

    fn take(&mut self, e: Estimated, bus: Option<&mut PoseBus>, counters: &ReceiveCounters) {
        let estimate = &e.estimate;
        let mut flags = match estimate.status {
            TrackingStatus::Initialising => StatusFlags::INITIALISING,
            TrackingStatus::Tracking => StatusFlags::TRACKING,
            TrackingStatus::Degenerate => StatusFlags::TRACKING.with(StatusFlags::DEGENERATE),
            TrackingStatus::Lost => StatusFlags::LOST,
        };
        if counters.silent.load(Ordering::Relaxed) {
            flags = flags.with(StatusFlags::SENSOR_SILENT);
        }
        let (pose, twist) = to_base(&self.base_from_sensor, &estimate.pose, &estimate.velocity);
        if let Some((last, _)) = self.latest {
            let dt = estimate.time_ns.saturating_sub(last.time_ns);
            if dt > 0 && dt < RESUME_GAP_NS {
                self.period_ns = dt;
            }
        }
        // The published frames are the odometry's world turned by the mounting (odom), and by
        // the back end's correction as well (map).
        let covariance = |frame_from_world: &Isometry3<f64>, base: &Isometry3<f64>| {
            estimate
                .alignment
                .as_ref()
                .map(|a| base_covariance(&a.covariance, frame_from_world, &estimate.pose, base))
        };
        let sample = PoseSample {
            time_ns: estimate.time_ns,
            pose,
            velocity: twist,
            flags,
            quality: e.quality,
            covariance: covariance(&self.base_from_sensor, &pose),
        };
        let map_pose = e.map_from_odom * estimate.pose;
        let site_pose = self.site_from_world * map_pose;
        let map_base = site_pose * self.base_from_sensor.inverse();
        let map_flags = self.map_flags(flags, &e, estimate.time_ns);
        let map_sample = PoseSample {
            pose: map_base,
            flags: map_flags,
            covariance: covariance(&(self.site_from_world * e.map_from_odom), &map_base),
            ..sample
        };
        if let Some(b) = bus {
            if let Err(err) = b.publish(&sample, &map_sample) {
                tracing::warn!("{err:#}");
            }
        }
        let latency = e.received.elapsed().as_secs_f64() * 1e3;
        self.latest = Some((sample, e.received));
        self.sweeps += 1;
        self.window_sweeps += 1;
        self.window_latency.push(latency);

        let stamped = StampedPose {
            time_ns: estimate.time_ns,
            pose: estimate.pose,
        };
        let corrected = StampedPose {
            time_ns: estimate.time_ns,
            pose: self
                .trajectory_from_world
                .map_or(map_pose, |t| t * map_pose),
        };
        // With a final trajectory, the corrected files are written at the end instead;
        // localising, they hold only poses verified in the map.
        let corrected_now =
            !self.final_trajectory && (self.mode != SiteMapMode::Localising || e.map_fix.verified);
        let streamed: [(&str, &mut Option<TrajectoryWriter>, &StampedPose, bool); 3] = [
            (
                "trajectory",
                &mut self.trajectory,
                &corrected,
                corrected_now,
            ),
            (
                "KITTI trajectory",
                &mut self.kitti,
                &corrected,
                corrected_now,
            ),
            (
                "odometry trajectory",
                &mut self.odom_trajectory,
                &stamped,
                true,
            ),
        ];
        for (name, writer, pose, now) in streamed {
            if !now {
                continue;
            }
            if let Some(w) = writer.as_mut() {
                if let Err(err) = w.write(pose) {
                    // A full disk must not stop the poses: stop writing this file, say so once.
                    tracing::error!("{name} no longer written: {err:#}");
                    self.summary.output_errors.push(format!("{err:#}"));
                    *writer = None;
                }
            }
        }
        let s = &mut self.summary;
        s.statuses[match estimate.status {
            TrackingStatus::Initialising => 0,
            TrackingStatus::Tracking => 1,
            TrackingStatus::Degenerate => 2,
            TrackingStatus::Lost => 3,
        }] += 1;
        let t = &mut s.timings;
        let [front, deskew, align, map] = e.stage_ms;
        t.total.push(front + deskew + align + map);
        t.front_end.push(front);
        t.deskew.push(deskew);
        t.align.push(align);
        t.map.push(map);
        t.latency.push(latency);
        t.edges.push(e.counts[0] as f64);
        t.planes.push(e.counts[1] as f64);
        t.intensity.push(e.counts[2] as f64);
        if let Some(a) = &estimate.alignment {
            t.iterations.push(a.iterations as f64);
            t.degeneracy.push(a.degeneracy);
        }
        if let Some(d) = e.departure {
            s.departures.push(d);
        }
        if self.keep_estimates {
            s.estimates.push(stamped);
        }
    }

    /// The `map` pose's flags. Off and mapping, the odometry's, with `LOOP_CLOSED` when the
    /// correction changed. Localising, the odometry's only when the pose is verified in the saved
    /// map (`LOOP_CLOSED` on the first after a relocalisation); otherwise `RELOCALISING`, with
    /// `LOST` when tracking in the map was just lost, never `TRACKING`.
    fn map_flags(&mut self, flags: StatusFlags, e: &Estimated, time_ns: u64) -> StatusFlags {
        if self.mode != SiteMapMode::Localising {
            return if e.loop_closed {
                flags.with(StatusFlags::LOOP_CLOSED)
            } else {
                flags
            };
        }
        let fix = e.map_fix;
        if fix.state == MapState::Lost && self.last_map_state != Some(MapState::Lost) {
            self.summary.map_lost.push(time_ns);
        }
        self.last_map_state = Some(fix.state);
        if fix.verified {
            self.summary.map_verified += 1;
            let since = self.searching_since.take();
            if fix.relocalised {
                let searched_s = since.map_or(0.0, |t| time_ns.saturating_sub(t) as f64 * 1e-9);
                self.summary.relocalisations.push(Relocalisation {
                    time_ns,
                    searched_s,
                });
                return flags.with(StatusFlags::LOOP_CLOSED);
            }
            return flags;
        }
        self.searching_since.get_or_insert(time_ns);
        let unverified = flags
            .without(StatusFlags::TRACKING)
            .without(StatusFlags::DEGENERATE)
            .with(StatusFlags::RELOCALISING);
        if fix.state == MapState::Lost {
            unverified.with(StatusFlags::LOST)
        } else {
            unverified
        }
    }

    /// Publishes the predicted pose: the latest estimate carried forward at its velocity to
    /// now, never more than one sweep period past it (after that the sensor is late and a
    /// prediction would be a guess).
    fn predict(&mut self, bus: &mut PoseBus) {
        let Some((last, received)) = self.latest else {
            return;
        };
        let ahead = received.elapsed().as_nanos() as u64;
        if ahead > self.period_ns {
            return;
        }
        let dt = ahead as f64 * 1e-9;
        let sample = PoseSample {
            time_ns: last.time_ns + ahead,
            pose: last.pose * exp(&(last.velocity * dt)),
            flags: last.flags.with(StatusFlags::PREDICTED),
            quality: 0.0,
            ..last
        };
        if let Err(err) = bus.publish_predicted(&sample) {
            tracing::warn!("{err:#}");
        }
    }

    /// Once a second: the status message, one log line, flushed trajectory files.
    fn report(&mut self, bus: Option<&mut PoseBus>, counters: &ReceiveCounters) {
        let seconds = self.window_start.elapsed().as_secs_f64().max(1e-3);
        let packets = counters.packets.load(Ordering::Relaxed);
        let silent = counters.silent.load(Ordering::Relaxed);
        let sweep_rate = self.window_sweeps as f64 / seconds;
        let packet_rate = packets.saturating_sub(self.window_packets) as f64 / seconds;
        let median = quantile(&mut self.window_latency, 0.5);
        let p99 = quantile(&mut self.window_latency, 0.99);
        let dropped = counters.sweeps_dropped.load(Ordering::Relaxed);
        let mut flags = self
            .latest
            .map_or(StatusFlags::INITIALISING, |(last, _)| last.flags);
        if self.mode == SiteMapMode::Localising && self.last_map_state != Some(MapState::Tracking) {
            // The status speaks for the `map` stream too: not yet (or no longer) in the map.
            flags = flags.with(StatusFlags::RELOCALISING);
        }
        if silent {
            flags = flags.with(StatusFlags::SENSOR_SILENT);
        }
        if let Some(b) = bus {
            let mut status = Status::new(0, glint_driver::udp::host_now_ns());
            status.sweeps_processed = self.sweeps;
            status.sweeps_dropped = dropped;
            status.packets_received = packets;
            status.packets_dropped = counters.packets_missing.load(Ordering::Relaxed);
            status.packets_malformed = counters.malformed.load(Ordering::Relaxed);
            status.sweep_rate_hz = sweep_rate as f32;
            status.packet_rate_hz = packet_rate as f32;
            status.latency_median_ms = if median.is_finite() {
                median as f32
            } else {
                0.0
            };
            status.latency_p99_ms = if p99.is_finite() { p99 as f32 } else { 0.0 };
            status.flags = flags;
            if let Err(err) = b.publish_status(status) {
                tracing::warn!("{err:#}");
            }
        }
        if self.window_sweeps > 0 || silent {
            tracing::info!(
                sweeps = self.sweeps,
                rate_hz = format_args!("{sweep_rate:.1}"),
                latency_median_ms = format_args!("{median:.1}"),
                latency_p99_ms = format_args!("{p99:.1}"),
                dropped,
                silent,
                "pipeline"
            );
        }
        for writer in [
            &mut self.trajectory,
            &mut self.kitti,
            &mut self.odom_trajectory,
        ] {
            if let Some(w) = writer.as_mut() {
                if let Err(err) = w.flush() {
                    tracing::error!("{err:#}");
                    self.summary.output_errors.push(format!("{err:#}"));
                    *writer = None;
                }
            }
        }
        self.window_start = Instant::now();
        self.window_sweeps = 0;
        self.window_packets = packets;
        self.window_latency.clear();
    }

    fn finish(
        mut self,
        world: Option<WorldMap>,
        backend: Option<(BackEnd, SlamSummary)>,
        saver: Option<&MapSaver>,
        options: &Options,
    ) -> Result<Summary> {
        let mut world = world;
        if let Some((backend, mut report)) = backend {
            if let Some(saver) = saver {
                // The trajectory written at the end is in the saved map's (levelled) frame.
                self.trajectory_from_world = Some(backend.site_from_world(&self.base_from_sensor));
                match saver.save(&backend) {
                    Ok(bytes) => self.summary.site_map_saved = Some((saver.path.clone(), bytes)),
                    Err(err) => self.summary.output_errors.push(format!("{err:#}")),
                }
            }
            if self.keep_estimates {
                report.trajectory = backend.trajectory(&self.summary.estimates);
            }
            if self.final_trajectory {
                for writer in [self.trajectory.as_mut(), self.kitti.as_mut()]
                    .into_iter()
                    .flatten()
                {
                    for pose in &report.trajectory {
                        let pose = StampedPose {
                            time_ns: pose.time_ns,
                            pose: self
                                .trajectory_from_world
                                .map_or(pose.pose, |t| t * pose.pose),
                        };
                        if let Err(err) = writer.write(&pose) {
                            self.summary.output_errors.push(format!("{err:#}"));
                            break;
                        }
                    }
                }
            }
            // The map from the keyframes at their optimised poses: consistent after loops,
            // where one grown sweep by sweep from odometry poses would hold both sides of the
            // drift.
            if let Some((_, voxel)) = options.map.as_ref() {
                let mut map = WorldMap::new(*voxel);
                for (keyframe, pose) in backend.keyframes().iter().zip(backend.keyframe_poses()) {
                    let pose = pose.cast::<f32>();
                    for point in &keyframe.cloud {
                        let p = pose * nalgebra::Point3::from(point.position);
                        map.insert(&p.coords, point.eta);
                    }
                }
                world = Some(map);
            }
            self.summary.slam = Some(report);
        }
        for writer in [
            self.trajectory.take(),
            self.kitti.take(),
            self.odom_trajectory.take(),
        ]
        .into_iter()
        .flatten()
        {
            if let Err(err) = writer.finish() {
                self.summary.output_errors.push(format!("{err:#}"));
            }
        }
        if let (Some(map), Some((path, _))) = (world, options.map.as_ref()) {
            if let Err(err) = write_map(path, &map.points()) {
                self.summary.output_errors.push(format!("{err:#}"));
            }
        }
        Ok(self.summary)
    }
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

    #[test]
    fn a_partial_first_sweep_is_left_out_when_a_whole_one_follows() {
        let arrival = |index: u64, partial: bool| Arrival {
            sweep: Sweep {
                index,
                partial,
                ..Sweep::default()
            },
            recycler: None,
            received: Instant::now(),
        };
        let indices = |v: [Option<Arrival>; 2]| {
            v.iter()
                .flatten()
                .map(|a| a.sweep.index)
                .collect::<Vec<_>>()
        };

        // A capture started mid-rotation: its sliver is dropped, the rest pass, partial or not.
        let mut start = LeadingSweep::default();
        assert!(indices(start.admit(arrival(0, true))).is_empty());
        assert_eq!(indices(start.admit(arrival(1, false))), [1]);
        assert_eq!(indices(start.admit(arrival(2, false))), [2]);
        assert_eq!(indices(start.admit(arrival(3, true))), [3]);
        assert!(start.finish().is_none());

        // Started at the cut: nothing held.
        let mut start = LeadingSweep::default();
        assert_eq!(indices(start.admit(arrival(0, false))), [0]);
        assert!(start.finish().is_none());

        // Nothing but partial sweeps (a capture of about one rotation): all of them.
        let mut start = LeadingSweep::default();
        assert!(indices(start.admit(arrival(0, true))).is_empty());
        assert_eq!(indices(start.admit(arrival(1, true))), [0, 1]);
        let mut start = LeadingSweep::default();
        assert!(indices(start.admit(arrival(0, true))).is_empty());
        assert_eq!(start.finish().map(|a| a.sweep.index), Some(0));
    }

    #[test]
    fn samples_stay_bounded() {
        let mut s = Samples::default();
        for i in 0..(Samples::CAPACITY + 10) {
            s.push(i as f64);
        }
        assert_eq!(s.len(), Samples::CAPACITY);
        // The ten oldest were overwritten.
        assert_eq!(s.quantile(0.0), 10.0);
    }
}

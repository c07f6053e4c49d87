//! `glintd soak`: hours of sensor data through the whole pipeline without a restart, from a
//! simulated sensor run in process (no capture file), at the stages' own pace, in SLAM or
//! localisation mode, sampling memory, per-sweep cost and latency at a fixed wall interval into
//! a CSV. `scripts/soak.sh` runs it in both modes and plots the samples.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::Args;
use glint_core::odometry::TrackingStatus;
use glint_driver::StreamConfig;
use glint_sim::{Scenario, SimConfig};

use crate::config::DaemonConfig;
use crate::pipeline::{
    self, quantile, Input, Options, PublishOptions, SiteMapOptions, SweepFigures,
};

/// Arguments of `glintd soak`.
#[derive(Args, Debug)]
pub struct SoakArgs {
    /// The simulated scenario: warehouse, corridor or yard (the robot loops its route).
    #[arg(long, default_value = "warehouse")]
    pub scenario: String,
    /// Scenario seed (layout, sensor unit, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Sweeps to feed.
    #[arg(long, default_value_t = 200_000)]
    pub sweeps: u64,
    /// Localise in this saved site map (of the same scenario and seed) instead of mapping.
    #[arg(long, value_name = "MAP", visible_alias = "localize")]
    pub localise: Option<PathBuf>,
    /// Wall seconds between two samples.
    #[arg(long, default_value_t = 60.0)]
    pub every: f64,
    /// Write the samples here (CSV, one row per sample, flushed as it is taken).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// The daemon configuration whose odometry, back-end and localiser parameters to run.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Service-name prefix of the poses published over iceoryx2.
    #[arg(long, default_value = "soak")]
    pub domain: String,
    /// Do not publish poses over iceoryx2.
    #[arg(long)]
    pub no_publish: bool,
}

/// The CSV's header; [`Sample::row`] writes its columns in this order.
pub const CSV_HEADER: &str = "wall_s,sensor_s,sweeps,distance_m,rss_mib,cpu_ms_per_sweep,compute_median_ms,compute_p99_ms,latency_median_ms,latency_p99_ms,lost,verified";

/// One sampling interval.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Since the run started, s.
    pub wall_s: f64,
    /// Sensor time since the first sweep, s.
    pub sensor_s: f64,
    /// Sweeps published so far.
    pub sweeps: u64,
    /// Path the base drove so far (odometry), m.
    pub distance_m: f64,
    /// Resident memory now, MiB.
    pub rss_mib: f64,
    /// CPU time of every pipeline thread but the simulated sensor's, per sweep of the
    /// interval, ms: the cost of a sweep, whatever else runs on the machine.
    pub cpu_ms_per_sweep: f64,
    /// Front end + odometry per sweep in the interval (wall), ms.
    pub compute_median_ms: f64,
    /// See `compute_median_ms`.
    pub compute_p99_ms: f64,
    /// Sweep closed → pose published in the interval, ms.
    pub latency_median_ms: f64,
    /// See `latency_median_ms`.
    pub latency_p99_ms: f64,
    /// Sweeps of the interval the odometry lost.
    pub lost: u64,
    /// Sweeps of the interval whose `map` pose was verified (all of them when mapping).
    pub verified: u64,
}

impl Sample {
    /// The CSV row (see [`CSV_HEADER`]).
    pub fn row(&self) -> String {
        format!(
            "{:.1},{:.1},{},{:.1},{:.2},{:.3},{:.3},{:.3},{:.3},{:.3},{},{}",
            self.wall_s,
            self.sensor_s,
            self.sweeps,
            self.distance_m,
            self.rss_mib,
            self.cpu_ms_per_sweep,
            self.compute_median_ms,
            self.compute_p99_ms,
            self.latency_median_ms,
            self.latency_p99_ms,
            self.lost,
            self.verified
        )
    }
}

/// A memory figure of this process from `/proc/self/status` (`VmRSS`: resident now, `VmHWM`:
/// peak resident), MiB.
fn memory_mib(key: &str) -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kib: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib / 1024.0)
}

/// Resident memory of this process, MiB.
fn rss_mib() -> Option<f64> {
    memory_mib("VmRSS")
}

/// CPU time (user + system) from a `/proc` `stat` file, s.
fn stat_cpu_s(stat: &str) -> Option<f64> {
    // /proc reports CPU times in USER_HZ ticks, which Linux fixes at 100 for user space.
    const TICKS_PER_S: f64 = 100.0;
    // `pid (comm) state …`: the name may hold spaces, so split after its closing bracket. After
    // it, field 3 (state) comes first: utime and stime are fields 14 and 15.
    let (_, rest) = stat.rsplit_once(')')?;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) as f64 / TICKS_PER_S)
}

/// CPU time of this process, its ended threads included, s.
fn process_cpu_s() -> Option<f64> {
    stat_cpu_s(&std::fs::read_to_string("/proc/self/stat").ok()?)
}

/// CPU time of this process's thread named `name`, if it runs, s.
fn thread_cpu_s(name: &str) -> Option<f64> {
    for task in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
        let comm = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
        if comm.trim_end() == name {
            return stat_cpu_s(&std::fs::read_to_string(task.path().join("stat")).ok()?);
        }
    }
    None
}

/// CPU time of every thread but the simulated sensor's, s. The sensor's thread ends before the
/// others drain; its time as last seen stays subtracted.
struct PipelineCpu {
    reader_s: f64,
}

impl PipelineCpu {
    fn now(&mut self) -> f64 {
        if let Some(r) = thread_cpu_s(READER_THREAD) {
            self.reader_s = r;
        }
        process_cpu_s().unwrap_or(f64::NAN) - self.reader_s
    }
}

/// Gathers each sweep's figures into one [`Sample`] per interval.
struct Sampler {
    every: Duration,
    started: Instant,
    window_start: Instant,
    first_time_ns: Option<u64>,
    sweeps: u64,
    distance_m: f64,
    last_position: Option<[f64; 3]>,
    cpu: PipelineCpu,
    cpu_at_window_start: f64,
    compute_ms: Vec<f64>,
    latency_ms: Vec<f64>,
    lost: u64,
    verified: u64,
}

impl Sampler {
    fn new(every: Duration) -> Self {
        let now = Instant::now();
        let mut cpu = PipelineCpu { reader_s: 0.0 };
        Self {
            every,
            started: now,
            window_start: now,
            first_time_ns: None,
            sweeps: 0,
            distance_m: 0.0,
            last_position: None,
            cpu_at_window_start: cpu.now(),
            cpu,
            compute_ms: Vec::new(),
            latency_ms: Vec::new(),
            lost: 0,
            verified: 0,
        }
    }

    /// Takes one sweep; a sample when the interval is over.
    fn take(&mut self, s: &SweepFigures) -> Option<Sample> {
        let first = *self.first_time_ns.get_or_insert(s.time_ns);
        self.sweeps += 1;
        if let Some(last) = self.last_position {
            let step: f64 = (0..3).map(|i| (s.odom_position[i] - last[i]).powi(2)).sum();
            self.distance_m += step.sqrt();
        }
        self.last_position = Some(s.odom_position);
        self.compute_ms.push(s.compute_ms);
        self.latency_ms.push(s.latency_ms);
        self.lost += u64::from(s.status == TrackingStatus::Lost);
        self.verified += u64::from(s.verified);
        if self.window_start.elapsed() < self.every {
            return None;
        }
        let cpu = self.cpu.now();
        let in_window = self.compute_ms.len() as f64;
        let sample = Sample {
            wall_s: self.started.elapsed().as_secs_f64(),
            sensor_s: s.time_ns.saturating_sub(first) as f64 * 1e-9,
            sweeps: self.sweeps,
            distance_m: self.distance_m,
            rss_mib: rss_mib().unwrap_or(f64::NAN),
            cpu_ms_per_sweep: (cpu - self.cpu_at_window_start) * 1e3 / in_window,
            compute_median_ms: quantile(&mut self.compute_ms, 0.5),
            compute_p99_ms: quantile(&mut self.compute_ms, 0.99),
            latency_median_ms: quantile(&mut self.latency_ms, 0.5),
            latency_p99_ms: quantile(&mut self.latency_ms, 0.99),
            lost: self.lost,
            verified: self.verified,
        };
        self.window_start = Instant::now();
        self.cpu_at_window_start = cpu;
        self.compute_ms.clear();
        self.latency_ms.clear();
        self.lost = 0;
        self.verified = 0;
        Some(sample)
    }
}

/// The simulated sensor's thread, left out of the per-sweep CPU time.
const READER_THREAD: &str = "glint-read";

/// Runs the command.
pub fn run(args: SoakArgs) -> Result<()> {
    if !(args.every.is_finite() && args.every > 0.0) {
        bail!("--every must be a positive number of seconds");
    }
    if args.sweeps == 0 {
        bail!("--sweeps must be at least 1");
    }
    let scenario: Scenario = args.scenario.parse().map_err(|e| anyhow::anyhow!("{e}"))?;
    let daemon = DaemonConfig::load_or_default(args.config.as_deref())?;
    let sim = SimConfig {
        scenario,
        seed: args.seed,
        ..SimConfig::default()
    };
    // The last sweep is closed by the first packet past it: a little more than the sweeps.
    let sim = SimConfig {
        seconds: (args.sweeps as f64 + 0.5) * 60.0 / sim.rpm,
        ..sim
    };
    let localise = match &args.localise {
        Some(path) => Some(
            glint_map::load(path)
                .with_context(|| format!("cannot localise in {}", path.display()))?,
        ),
        None => None,
    };
    let mode = if localise.is_some() {
        "localisation"
    } else {
        "SLAM"
    };
    let mut csv = match &args.csv {
        Some(path) => {
            let mut f = BufWriter::new(
                File::create(path).with_context(|| format!("cannot create {}", path.display()))?,
            );
            writeln!(f, "{CSV_HEADER}")?;
            f.flush()?;
            Some((f, path.clone()))
        }
        None => None,
    };
    say!(
        "soak: {} sweeps ({:.1} h of sensor time) of the simulated {scenario} (seed {}) in {mode} mode, a sample every {} s",
        args.sweeps,
        sim.seconds / 3600.0,
        args.seed,
        args.every
    );
    say!("{CSV_HEADER}");
    let mut sampler = Sampler::new(Duration::from_secs_f64(args.every));
    let mut csv_error: Option<String> = None;
    let on_sweep = move |s: &SweepFigures| {
        let Some(sample) = sampler.take(s) else {
            return;
        };
        let row = sample.row();
        say!("{row}");
        if let Some((f, path)) = csv.as_mut() {
            if let Err(e) = writeln!(f, "{row}").and_then(|()| f.flush()) {
                if csv_error.is_none() {
                    tracing::error!("cannot write {}: {e}", path.display());
                    csv_error = Some(e.to_string());
                }
            }
        }
    };
    let stop = Arc::new(AtomicBool::new(false));
    crate::signals::stop_on_signals(&stop)?;
    let base_from_sensor = daemon.mounting.base_from_sensor();
    let summary = pipeline::run(Options {
        input: Input::Simulated { config: sim },
        stream: StreamConfig::default(),
        odometry: daemon.odometry.clone(),
        queue: 2,
        odometry_thread: daemon.odometry_thread(),
        base_from_sensor,
        publish: (!args.no_publish).then(|| PublishOptions {
            domain: args.domain.clone(),
            predicted_rate_hz: 0.0,
            sweeps: true,
            map_updates: true,
        }),
        trajectory: None,
        trajectory_max_bytes: None,
        kitti: None,
        map: None,
        keep_estimates: false,
        backend: localise.is_none().then(|| daemon.backend.clone()),
        site_map: SiteMapOptions {
            save: None,
            autosave: None,
            localise,
            hint: None,
            localiser: daemon.localiser.clone(),
        },
        odom_trajectory: None,
        known_poses: None,
        stop,
        on_ready: None,
        on_alive: None,
        on_sweep: Some(Box::new(on_sweep)),
    })?;
    let statuses = summary.statuses;
    say!(
        "soak done: {} sweeps in {:.0} s ({} initialising, {} tracking, {} degenerate, {} lost); peak RSS {:.1} MiB",
        statuses.total(),
        summary.wall.as_secs_f64(),
        statuses.initialising,
        statuses.tracking,
        statuses.degenerate,
        statuses.lost,
        peak_rss_mib().unwrap_or(f64::NAN)
    );
    if let Some(slam) = &summary.slam {
        let s = &slam.stats;
        say!(
            "back end: {} keyframes, {} loops accepted, {} rejected",
            s.keyframes,
            s.accepted,
            s.rejected
        );
    }
    if !summary.relocalisations.is_empty() || !summary.map_lost.is_empty() {
        say!(
            "localisation: {} sweeps verified in the map, {} relocalisations, lost {} times",
            summary.map_verified,
            summary.relocalisations.len(),
            summary.map_lost.len()
        );
    }
    Ok(())
}

/// Peak resident memory of this process, MiB.
fn peak_rss_mib() -> Option<f64> {
    memory_mib("VmHWM")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_has_memory_and_cpu_time() {
        assert!(rss_mib().is_some_and(|m| m > 0.0));
        assert!(peak_rss_mib().is_some_and(|m| m >= rss_mib().unwrap() * 0.5));
        let spinner = std::thread::Builder::new()
            .name("glint-spin-test".into())
            .spawn(|| {
                // Spin until the thread itself has used 60 ms of CPU (however busy the machine
                // is), within a generous bound for a broken reader.
                let spin = Instant::now();
                let mut x = 0u64;
                while spin.elapsed() < Duration::from_secs(20)
                    && thread_cpu_s("glint-spin-test").is_none_or(|t| t < 0.06)
                {
                    for _ in 0..100_000 {
                        x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
                    }
                }
                std::hint::black_box(x);
                thread_cpu_s("glint-spin-test")
            })
            .unwrap();
        let mine = spinner.join().unwrap();
        let all = process_cpu_s().unwrap();
        assert!(
            mine.is_some_and(|t| t >= 0.05 && t <= all + 0.01),
            "{mine:?} of {all}"
        );
        assert_eq!(
            thread_cpu_s("glint-spin-test"),
            None,
            "the thread has ended"
        );
        assert!(all >= 0.05, "{all} s of CPU after spinning 0.1 s");
    }

    #[test]
    fn a_sample_per_interval_with_its_sweeps() {
        let mut sampler = Sampler::new(Duration::ZERO);
        let sweep = |i: u64, status| SweepFigures {
            time_ns: 1_000_000_000 + i * 100_000_000,
            compute_ms: i as f64,
            latency_ms: 2.0 * i as f64,
            status,
            verified: status != TrackingStatus::Lost,
            odom_position: [i as f64, 0.0, 0.0],
        };
        let first = sampler.take(&sweep(0, TrackingStatus::Tracking)).unwrap();
        assert_eq!(first.sweeps, 1);
        let second = sampler.take(&sweep(3, TrackingStatus::Lost)).unwrap();
        assert_eq!(second.sweeps, 2);
        assert!((second.sensor_s - 0.3).abs() < 1e-9);
        assert!((second.distance_m - 3.0).abs() < 1e-9);
        assert_eq!((second.lost, second.verified), (1, 0));
        assert_eq!(second.compute_median_ms, 3.0);
        assert_eq!(second.latency_p99_ms, 6.0);
        assert_eq!(
            second.row().split(',').count(),
            CSV_HEADER.split(',').count()
        );
    }
}

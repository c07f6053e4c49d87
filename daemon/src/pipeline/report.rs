//! What the pipeline measures and tells while it runs: per-sweep samples, bounded so a run of
//! months keeps the last few hours, the per-stage timings a run's summary holds, and the
//! once-a-second report (the status message on the bus and one log line).

use std::sync::atomic::Ordering;
use std::time::Instant;

use glint_core::odometry::TrackingStatus;
use glint_ipc::{Status, StatusFlags};

use super::receive::ReceiveCounters;
use crate::publish::PoseBus;

pub use glint_core::tracker::quantile;

/// Per-sweep samples, bounded: past the limit the oldest are overwritten, so a run of months
/// keeps only the latest (a few hours by default; [`Samples::LIVE`] in a live run).
#[derive(Debug, Clone)]
pub struct Samples {
    values: Vec<f64>,
    next: usize,
    limit: usize,
}

impl Default for Samples {
    fn default() -> Self {
        Self::bounded(Self::CAPACITY)
    }
}

impl Samples {
    const CAPACITY: usize = 1 << 17;
    /// A live run's window: about half an hour at 10 Hz. Its memory (11 figures a sweep) is
    /// reached within that half hour and stays flat however long the run.
    pub const LIVE: usize = 1 << 14;

    /// Keeping the latest `limit` samples (at least one).
    pub fn bounded(limit: usize) -> Self {
        Self {
            values: Vec::new(),
            next: 0,
            limit: limit.max(1),
        }
    }

    /// Adds one sample.
    pub fn push(&mut self, v: f64) {
        if self.values.len() < self.limit {
            self.values.push(v);
        } else {
            self.values[self.next] = v;
            self.next = (self.next + 1) % self.limit;
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

impl Timings {
    /// Each figure keeping its latest `limit` samples.
    pub fn bounded(limit: usize) -> Self {
        let s = || Samples::bounded(limit);
        Self {
            total: s(),
            front_end: s(),
            deskew: s(),
            align: s(),
            map: s(),
            latency: s(),
            edges: s(),
            planes: s(),
            intensity: s(),
            iterations: s(),
            degeneracy: s(),
        }
    }
}

/// One published sweep's figures, for a caller watching a long run (`Options::on_sweep`).
#[derive(Debug, Clone, Copy)]
pub struct SweepFigures {
    /// The sweep's sensor time, ns.
    pub time_ns: u64,
    /// Front end and odometry, ms.
    pub compute_ms: f64,
    /// Sweep closed (its last packet received) → pose published, ms.
    pub latency_ms: f64,
    /// The odometry's status.
    pub status: TrackingStatus,
    /// The published `map` pose is verified in the map (always, unless localising).
    pub verified: bool,
    /// The published `odom` position of the base, m.
    pub odom_position: [f64; 3],
}

/// What watches every published sweep's figures.
pub type SweepWatcher = Box<dyn FnMut(&SweepFigures)>;

/// The once-a-second report's window: what happened since the last report.
pub(super) struct ReportWindow {
    start: Instant,
    sweeps: u64,
    /// The receive stage's packet count when the window started.
    packets: u64,
    /// Each sweep's latency (ms).
    latency: Vec<f64>,
}

impl ReportWindow {
    pub(super) fn new() -> Self {
        Self {
            start: Instant::now(),
            sweeps: 0,
            packets: 0,
            latency: Vec::new(),
        }
    }

    /// A sweep's pose was published `latency_ms` after its last packet arrived.
    pub(super) fn add_sweep(&mut self, latency_ms: f64) {
        self.sweeps += 1;
        self.latency.push(latency_ms);
    }

    /// Publishes the status message (with `flags`; `sweeps` processed in the whole run) and logs
    /// one line, then starts the next window.
    pub(super) fn report(
        &mut self,
        bus: Option<&mut PoseBus>,
        counters: &ReceiveCounters,
        sweeps: u64,
        flags: StatusFlags,
        silent: bool,
    ) {
        let seconds = self.start.elapsed().as_secs_f64().max(1e-3);
        let packets = counters.packets.load(Ordering::Relaxed);
        let sweep_rate = self.sweeps as f64 / seconds;
        let packet_rate = packets.saturating_sub(self.packets) as f64 / seconds;
        let median = quantile(&mut self.latency, 0.5);
        let p99 = quantile(&mut self.latency, 0.99);
        let dropped = counters.sweeps_dropped.load(Ordering::Relaxed);
        let foreign = counters.foreign.load(Ordering::Relaxed);
        if let Some(b) = bus {
            let mut status = Status::new(0, glint_driver::udp::host_now_ns());
            status.sweeps_processed = sweeps;
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
        if self.sweeps > 0 || silent {
            tracing::info!(
                sweeps,
                rate_hz = format_args!("{sweep_rate:.1}"),
                latency_median_ms = format_args!("{median:.1}"),
                latency_p99_ms = format_args!("{p99:.1}"),
                dropped,
                silent,
                foreign,
                "pipeline"
            );
        }
        self.start = Instant::now();
        self.sweeps = 0;
        self.packets = packets;
        self.latency.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_stay_bounded() {
        let mut s = Samples::default();
        for i in 0..(Samples::CAPACITY + 10) {
            s.push(i as f64);
        }
        assert_eq!(s.len(), Samples::CAPACITY);
        let mut live = Samples::bounded(Samples::LIVE);
        for i in 0..(3 * Samples::LIVE) {
            live.push(i as f64);
        }
        assert_eq!(live.len(), Samples::LIVE);
        assert_eq!(live.quantile(0.0), (2 * Samples::LIVE) as f64);
        // The ten oldest were overwritten.
        assert_eq!(s.quantile(0.0), 10.0);
    }
}

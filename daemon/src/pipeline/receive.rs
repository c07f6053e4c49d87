//! The receive stage: packets from a capture (paced, waiting for the front end so a replay
//! processes every sweep) or from the sensor's sockets (never waiting: a sweep that finds the
//! front end's queue full is dropped whole and counted), closed into sweeps for the front end.
//! Either way only one sensor's packets are decoded; another's are refused and counted. The
//! open sweep's returns are also offered to the front end as they arrive ([`OpenReturns`]), so
//! it can calibrate them before the sweep closes; that stream never waits and is never needed:
//! what it misses the front end does from the closed sweep.

use std::net::{IpAddr, Ipv4Addr};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::Result;
use crossbeam_channel::{Receiver, RecvTimeoutError, SendTimeoutError, Sender, TrySendError};
use glint_core::scan::ScanPoint;
use glint_driver::udp::{Datagram, ReceiveClock, UdpCounters, UdpSource};
use glint_driver::{
    PacketKind, SensorStream, SourceFilter, StreamConfig, StreamError, Sweep, SweepRecycler,
    Verdict,
};

use super::front_end::scan_point;
use super::health::{Heartbeats, Stage, IDLE_BEAT};
use super::Pace;
use crate::capture::{foreign_active, replay_payloads, CaptureReport, ForeignLog, PayloadSource};

/// Counters the receive thread shares with the reporter.
#[derive(Debug, Default)]
pub(super) struct ReceiveCounters {
    pub(super) packets: AtomicU64,
    pub(super) packets_missing: AtomicU64,
    pub(super) malformed: AtomicU64,
    pub(super) sweeps_dropped: AtomicU64,
    pub(super) silent: AtomicBool,
    /// Packets refused as another sensor's.
    pub(super) foreign: AtomicU64,
    /// Another sensor's packets arrived lately.
    pub(super) foreign_active: AtomicBool,
    /// Steps of the receive-time anchor (host clock steps, sensor resets) ...
    pub(super) clock_steps: AtomicU64,
    /// ... and the last one's size, ns.
    pub(super) last_clock_step_ns: AtomicI64,
}

impl ReceiveCounters {
    fn update_sources(&self, filter: &SourceFilter, now_ns: u64) {
        self.foreign
            .store(filter.stats().foreign(), Ordering::Relaxed);
        self.foreign_active
            .store(foreign_active(filter, now_ns), Ordering::Relaxed);
    }

    fn update(&self, stream: &SensorStream, udp: Option<&UdpCounters>) {
        let s = stream.stats();
        if s.clock.resyncs > self.clock_steps.load(Ordering::Relaxed) {
            // Stamps follow the new clock from this packet; motion stays on sensor time.
            tracing::warn!(
                step_s = s.clock.last_step_ns as f64 * 1e-9,
                "the receive clock stepped (host clock set, or the sensor reset): stamps follow it"
            );
            self.clock_steps.store(s.clock.resyncs, Ordering::Relaxed);
            self.last_clock_step_ns
                .store(s.clock.last_step_ns, Ordering::Relaxed);
        }
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

/// The most batches of open-sweep returns queued for the front end: two sweeps' packets at
/// 10 Hz (76 a sweep), so a front end busy with one sweep still finds the next one's whole.
pub(super) const OPEN_RETURNS_QUEUE: usize = 160;

/// Returns of the sweep still open, on their way to the front end.
pub(super) struct Returns {
    /// The open sweep's index ([`Sweep::index`]).
    pub(super) sweep: u64,
    /// How many of its returns came before these.
    pub(super) offset: usize,
    pub(super) points: Vec<ScanPoint>,
}

/// Offers the open sweep's new returns to the front end after each packet, without waiting:
/// a full queue ends the offers for that sweep (the front end then calibrates it whole).
pub(super) struct OpenReturns<'a> {
    out: &'a Sender<Returns>,
    /// The sweep being offered and how many of its returns went.
    sent: Option<(u64, usize)>,
}

impl<'a> OpenReturns<'a> {
    pub(super) fn new(out: &'a Sender<Returns>) -> Self {
        Self { out, sent: None }
    }

    /// Offers what the stream's open sweep gained since the last offer.
    fn offer(&mut self, stream: &SensorStream) {
        let Some((sweep, points)) = stream.open_sweep() else {
            return;
        };
        let offset = match self.sent {
            Some((s, n)) if s == sweep => n,
            _ => 0,
        };
        if offset >= points.len() {
            return;
        }
        let returns = Returns {
            sweep,
            offset,
            points: points[offset..].iter().map(scan_point).collect(),
        };
        self.sent = Some(match self.out.try_send(returns) {
            Ok(()) => (sweep, points.len()),
            // Nothing more of this sweep: the front end could not use it after a gap.
            Err(_) => (sweep, usize::MAX),
        });
    }
}

/// A closed sweep on its way to the front end.
pub(super) struct Arrival {
    pub(super) sweep: Sweep,
    pub(super) recycler: Option<SweepRecycler>,
    /// When its last packet was received.
    pub(super) received: Instant,
}

/// The receive stage of a replay: reads the capture (`label` in errors) at `pace`, waiting for
/// the front end rather than dropping.
#[allow(clippy::too_many_arguments)]
pub(super) fn read_payloads(
    payloads: &mut impl PayloadSource,
    label: &str,
    stream: StreamConfig,
    source: Option<Ipv4Addr>,
    pace: Pace,
    stop: &AtomicBool,
    out: &Sender<Arrival>,
    returns: &Sender<Returns>,
    heartbeats: &Heartbeats,
    counters: &ReceiveCounters,
) -> Result<CaptureReport> {
    let mut clock: Option<(u64, Instant)> = None;
    let mut open = OpenReturns::new(returns);
    let downstream_gone = std::cell::Cell::new(false);
    replay_payloads(
        payloads,
        label,
        stream,
        source,
        |record_ns, stream, filter| {
            heartbeats.beat(Stage::Receive);
            if stop.load(Ordering::Relaxed) || downstream_gone.get() {
                return false;
            }
            // What the previous packet added, before waiting for this one's time.
            open.offer(stream);
            if let Pace::Factor(f) = pace {
                let (t0, w0) = *clock.get_or_insert((record_ns, Instant::now()));
                let due =
                    w0 + Duration::from_secs_f64(record_ns.saturating_sub(t0) as f64 * 1e-9 / f);
                // Sleep in short steps so a stop request is seen promptly.
                while let Some(wait) = due.checked_duration_since(Instant::now()) {
                    if stop.load(Ordering::Relaxed) {
                        return false;
                    }
                    heartbeats.beat(Stage::Receive);
                    std::thread::sleep(wait.min(IDLE_BEAT));
                }
            }
            counters.update(stream, None);
            counters.update_sources(filter, record_ns);
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
                    Err(SendTimeoutError::Timeout(a)) => {
                        heartbeats.beat(Stage::Receive);
                        pending = a;
                    }
                    Err(SendTimeoutError::Disconnected(_)) => {
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
pub(super) fn receive_live(
    source: UdpSource,
    clock: &ReceiveClock,
    datagrams: &Receiver<Datagram>,
    stream: StreamConfig,
    sensor: Option<Ipv4Addr>,
    silence: Duration,
    stop: &AtomicBool,
    out: &Sender<Arrival>,
    returns: &Sender<Returns>,
    heartbeats: &Heartbeats,
    counters: &ReceiveCounters,
) -> Result<()> {
    let udp = source.counters();
    let mut open = OpenReturns::new(returns);
    let mut stream = SensorStream::new(stream);
    let mut filter = SourceFilter::new(sensor.map(IpAddr::V4));
    let mut foreign_log = ForeignLog::default();
    let mut last_data = Instant::now();
    let mut silent_since: Option<Instant> = None;
    let mut logged_errors = 0u64;
    let mut last_drop_log: Option<Instant> = None;
    while !stop.load(Ordering::Relaxed) {
        heartbeats.beat(Stage::Receive);
        let datagram = match datagrams.recv_timeout(Duration::from_millis(50)) {
            Ok(d) => Some(d),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        if let Some(d) = &datagram {
            let verdict = filter.judge(d.kind, d.source, d.payload(), d.receive_ns);
            // Garbage on the port or a damaged packet: counted by the stream, logged sparingly
            // (the first few, then every thousandth).
            let mut refused = |e: StreamError| {
                logged_errors += 1;
                if logged_errors <= 5 || logged_errors.is_multiple_of(1000) {
                    tracing::warn!(count = logged_errors, "packet refused: {e}");
                }
            };
            while let Some(held) = filter.take_released() {
                if let Err(e) = stream.push_position(held.payload()) {
                    refused(e);
                }
            }
            let result = match (verdict, d.kind) {
                (Verdict::Accept, PacketKind::Data) => {
                    last_data = Instant::now();
                    stream.push_data(d.payload(), d.receive_ns)
                }
                (Verdict::Accept, PacketKind::Position) => stream.push_position(d.payload()),
                (Verdict::Foreign, _) => {
                    foreign_log.note(&filter, d.source, d.receive_ns);
                    Ok(())
                }
                (Verdict::Held, _) => Ok(()),
            };
            if let Err(e) = result {
                refused(e);
            }
            counters.update(&stream, Some(&udp));
        }
        counters.update_sources(&filter, clock.now_ns());
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
            let behind = Duration::from_nanos(clock.now_ns().saturating_sub(sweep.last_receive_ns));
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
        if datagram.is_some() {
            open.offer(&stream);
        }
    }
    source.stop();
    Ok(())
}

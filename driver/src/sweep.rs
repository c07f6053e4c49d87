//! Sweeps: one rotation of returns, cut where the firing azimuth crosses a configurable angle.
//!
//! A sweep records when it starts and ends, the packets it got and the ones missing (counted
//! from the device-time step between packets, never papered over), and whether it is partial
//! (the stream started or stopped inside it, or the sensor fell silent). Point buffers come
//! from a pool the consumer returns them to, so steady state does not allocate.

use std::collections::VecDeque;

use crossbeam_channel::{Receiver, Sender};

use crate::decode::{Decoder, Firing, Point};

use crate::wire::{DataPacket, AZIMUTH_LIMIT};

/// One rotation of returns.
#[derive(Debug, Clone, Default)]
pub struct Sweep {
    /// Sweep number in the stream, from 0.
    pub index: u64,
    /// Returns in firing order.
    pub points: Vec<Point>,
    /// Time of the first firing, ns since the epoch.
    pub start_ns: u64,
    /// Time of the last return, ns since the epoch (of the last firing sequence's first laser
    /// when that sequence had no return): within one sequence (55 µs) of the last firing.
    pub end_ns: u64,
    /// Data packets that contributed returns (a packet straddling the cut counts in both
    /// sweeps).
    pub packets_received: u32,
    /// Packets the device-time steps say were sent inside the sweep but never arrived.
    pub packets_missing: u32,
    /// The stream started or stopped inside this sweep, or the sensor fell silent: it does not
    /// cover a whole rotation.
    pub partial: bool,
    /// Receive time of the last packet, ns (pcap record time in replay, host clock live).
    pub last_receive_ns: u64,
    /// Point times are sensor times ([`crate::clock`]): adding this turns one into a stamp, as
    /// the clock stood at the sweep's last packet, ns.
    pub stamp_offset_ns: i64,
}

impl Sweep {
    /// The stamp of a sensor time of this sweep's (see [`Self::stamp_offset_ns`]), ns.
    pub fn stamp(&self, sensor_ns: u64) -> u64 {
        crate::clock::stamp(sensor_ns, self.stamp_offset_ns)
    }

    /// Packets expected: received plus missing.
    pub fn packets_expected(&self) -> u32 {
        self.packets_received + self.packets_missing
    }

    /// Rotation rate implied by the sweep's duration, rpm (meaningful for whole sweeps).
    pub fn rpm(&self) -> Option<f64> {
        let span = self.end_ns.checked_sub(self.start_ns)?;
        (span > 0).then(|| 60e9 / span as f64)
    }
}

/// How sweeps are cut.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepConfig {
    /// Azimuth at which a new sweep starts, rad, clockwise as the sensor counts (0 = +x).
    pub cut_azimuth: f64,
    /// Points reserved per sweep buffer (grown on demand, then reused).
    pub capacity: usize,
}

impl Default for SweepConfig {
    fn default() -> Self {
        // 300 rpm in dual-return mode: 2 × 2 × ~28,800 returns.
        Self {
            cut_azimuth: 0.0,
            capacity: 120_000,
        }
    }
}

/// A sweep open for longer than this (slower than 300 rpm, or not spinning) is closed as
/// partial so buffers stay bounded.
const MAX_SWEEP_NS: u64 = 250_000_000;
/// Buffers kept for reuse.
const POOL_SIZE: usize = 16;
const CENTIDEG_PER_RAD: f32 = 18_000.0 / std::f32::consts::PI;

/// Assembles decoded packets into sweeps.
#[derive(Debug)]
pub struct SweepAssembler {
    decoder: Decoder,
    /// Points of the open sweep (decoded straight into it).
    points: Vec<Point>,
    cutter: Cutter,
    ready: VecDeque<Sweep>,
    pool_tx: Sender<Vec<Point>>,
    pool: Receiver<Vec<Point>>,
}

impl SweepAssembler {
    /// An assembler for packets decoded by `decoder`.
    pub fn new(decoder: Decoder, config: SweepConfig) -> Self {
        let (pool_tx, pool) = crossbeam_channel::bounded(POOL_SIZE);
        let cut = (config.cut_azimuth.to_degrees() * 100.0).rem_euclid(f64::from(AZIMUTH_LIMIT));
        Self {
            decoder,
            points: Vec::with_capacity(config.capacity),
            cutter: Cutter {
                cut: cut as f32,
                capacity: config.capacity,
                current: Sweep::default(),
                open: false,
                last_relative: 0.0,
                started_at_cut: false,
                next_index: 0,
                last_packet_ns: None,
                missing: 0,
                receive_ns: 0,
                stamp_offset_ns: 0,
                counted: true,
            },
            ready: VecDeque::with_capacity(4),
            pool_tx,
            pool,
        }
    }

    /// The decoder in use.
    pub fn decoder(&self) -> &Decoder {
        &self.decoder
    }

    /// Where consumers return a sweep's point buffer when done with it (from any thread).
    /// Buffers beyond the pool's size are dropped.
    pub fn recycler(&self) -> SweepRecycler {
        SweepRecycler(self.pool_tx.clone())
    }

    /// Adds one checked data packet whose first firing is at `packet_time_ns`, received at
    /// `receive_ns`, with stamps equal to times. Sweeps it completes are then available from
    /// [`Self::take_sweep`].
    pub fn push<T: AsRef<[u8]>>(
        &mut self,
        packet: &DataPacket<T>,
        packet_time_ns: u64,
        receive_ns: u64,
    ) {
        self.push_stamped(packet, packet_time_ns, receive_ns, 0);
    }

    /// [`Self::push`] for a packet whose first firing is at sensor time `packet_time_ns` and
    /// whose stamps are sensor times plus `stamp_offset_ns` ([`crate::clock::PacketTime`]).
    pub fn push_stamped<T: AsRef<[u8]>>(
        &mut self,
        packet: &DataPacket<T>,
        packet_time_ns: u64,
        receive_ns: u64,
        stamp_offset_ns: i64,
    ) {
        let mode = packet
            .return_mode()
            .unwrap_or(crate::wire::ReturnMode::Strongest);
        let packet_ns = self.decoder.timing().packet_ns(mode);
        let mut tail = Tail {
            ready: &mut self.ready,
            pool: &self.pool,
        };
        let c = &mut self.cutter;
        c.missing = 0;
        if let Some(last) = c.last_packet_ns {
            let step = packet_time_ns.saturating_sub(last);
            if step > MAX_SWEEP_NS {
                // Silence: whatever was open is cut off.
                c.close(&mut self.points, false, &mut tail);
            } else {
                // Steps are whole packets (±1 µs counter rounding).
                c.missing = ((step + packet_ns / 2) / packet_ns).saturating_sub(1) as u32;
            }
        }
        c.last_packet_ns = Some(packet_time_ns);
        c.receive_ns = receive_ns;
        c.stamp_offset_ns = stamp_offset_ns;
        c.counted = false;
        self.decoder
            .decode_firings(packet, packet_time_ns, &mut self.points, |out, f| {
                c.firing(out, f, &mut tail)
            });
    }

    /// The oldest completed sweep not yet taken.
    pub fn take_sweep(&mut self) -> Option<Sweep> {
        self.ready.pop_front()
    }

    /// The sweep still open: its index and its returns so far (the start of what
    /// [`Self::take_sweep`] will hand over for it), for consumers that work as it streams in.
    pub fn open_sweep(&self) -> Option<(u64, &[Point])> {
        self.cutter
            .open
            .then_some((self.cutter.current.index, self.points.as_slice()))
    }

    /// Closes the open sweep at the end of the stream (it is partial unless it happens to end
    /// exactly at the cut); take it with [`Self::take_sweep`].
    pub fn finish(&mut self) {
        let mut tail = Tail {
            ready: &mut self.ready,
            pool: &self.pool,
        };
        self.cutter.close(&mut self.points, false, &mut tail);
    }
}

/// Returns sweep buffers to their assembler's pool.
#[derive(Debug, Clone)]
pub struct SweepRecycler(Sender<Vec<Point>>);

impl SweepRecycler {
    /// Gives a finished sweep's buffer back. Never blocks.
    pub fn recycle(&self, sweep: Sweep) {
        let mut points = sweep.points;
        points.clear();
        let _ = self.0.try_send(points);
    }
}

/// Where closed sweeps go and fresh buffers come from.
struct Tail<'a> {
    ready: &'a mut VecDeque<Sweep>,
    pool: &'a Receiver<Vec<Point>>,
}

/// The open sweep's bookkeeping (its points live in the assembler's vector).
#[derive(Debug)]
struct Cutter {
    cut: f32,
    capacity: usize,
    current: Sweep,
    open: bool,
    /// Relative azimuth (from the cut) of the last return or firing.
    last_relative: f32,
    started_at_cut: bool,
    next_index: u64,
    last_packet_ns: Option<u64>,
    /// Packets missing before the packet being decoded, its receive time, and whether it has
    /// been counted in the open sweep.
    missing: u32,
    receive_ns: u64,
    /// The packet's stamp offset ([`Sweep::stamp_offset_ns`]).
    stamp_offset_ns: i64,
    counted: bool,
}

impl Cutter {
    fn relative(&self, azimuth_centideg: f32) -> f32 {
        crate::decode::wrap_azimuth(azimuth_centideg - self.cut)
    }

    /// Whether a return at `relative`, `time_ns` belongs to a new sweep: `Some(true)` after a
    /// wrap through the cut, `Some(false)` when the open sweep has lasted too long.
    fn cut_before(&self, relative: f32, time_ns: u64) -> Option<bool> {
        if !self.open {
            return None;
        }
        // A wrap is a drop of more than half a turn; smaller backward steps are jitter.
        let half_turn = f32::from(AZIMUTH_LIMIT / 2);
        if relative + half_turn < self.last_relative {
            Some(true)
        } else if time_ns.saturating_sub(self.current.start_ns) > MAX_SWEEP_NS {
            Some(false)
        } else {
            None
        }
    }

    /// Accounts for a return (or an empty firing) in the open sweep, opening one if needed.
    fn extend(&mut self, relative: f32, time_ns: u64) {
        if !self.open {
            self.open = true;
            self.current.start_ns = time_ns;
            self.current.index = self.next_index;
            self.next_index += 1;
            // A stream that starts within a firing or two of the cut starts a whole sweep.
            if !self.started_at_cut {
                self.started_at_cut = relative < 100.0;
            }
        }
        if !self.counted {
            self.current.packets_received += 1;
            self.current.packets_missing += self.missing;
            self.counted = true;
        }
        self.current.end_ns = self.current.end_ns.max(time_ns);
        self.current.last_receive_ns = self.current.last_receive_ns.max(self.receive_ns);
        self.current.stamp_offset_ns = self.stamp_offset_ns;
        self.last_relative = relative;
    }

    fn firing(&mut self, out: &mut Vec<Point>, f: Firing, tail: &mut Tail<'_>) {
        let Some(last) = out.get(f.first_point..).and_then(<[Point]>::last).copied() else {
            let relative = self.relative(f.azimuth_centideg);
            if let Some(at_cut) = self.cut_before(relative, f.time_ns) {
                self.close(out, at_cut, tail);
            }
            self.extend(relative, f.time_ns);
            return;
        };
        // Azimuths rise through a firing, so the cut falls inside it only if its last return
        // is past the cut; otherwise the whole firing is accounted for at once.
        let last_relative = self.relative(last.azimuth * CENTIDEG_PER_RAD);
        if self.open && self.cut_before(last_relative, last.time_ns).is_none() {
            self.extend(last_relative, last.time_ns);
            return;
        }
        // Cut per return, not per firing: a sequence straddling the cut has its later lasers
        // past it, and each sweep must hold exactly one turn of azimuths.
        let mut i = f.first_point;
        while i < out.len() {
            let p = out[i];
            let relative = self.relative(p.azimuth * CENTIDEG_PER_RAD);
            if let Some(at_cut) = self.cut_before(relative, p.time_ns) {
                let mut next = tail
                    .pool
                    .try_recv()
                    .unwrap_or_else(|_| Vec::with_capacity(self.capacity));
                next.extend_from_slice(&out[i..]);
                out.truncate(i);
                std::mem::swap(out, &mut next);
                self.finish_sweep(next, at_cut, tail);
                i = 0;
                // The packet that starts the new sweep counts in it too.
                self.counted = false;
                self.missing = 0;
            }
            self.extend(relative, p.time_ns);
            i += 1;
        }
    }

    /// Closes the open sweep with every point in `out`, leaving `out` empty for the next.
    fn close(&mut self, out: &mut Vec<Point>, at_cut: bool, tail: &mut Tail<'_>) {
        if !self.open {
            return;
        }
        let mut next = tail
            .pool
            .try_recv()
            .unwrap_or_else(|_| Vec::with_capacity(self.capacity));
        std::mem::swap(out, &mut next);
        self.finish_sweep(next, at_cut, tail);
    }

    fn finish_sweep(&mut self, points: Vec<Point>, at_cut: bool, tail: &mut Tail<'_>) {
        self.open = false;
        let mut done = std::mem::take(&mut self.current);
        done.points = points;
        done.partial = !(self.started_at_cut && at_cut);
        // The next sweep starts at the cut only if this one ended there.
        self.started_at_cut = at_cut;
        tail.ready.push_back(done);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Model;
    use crate::wire::{ReturnMode, BLOCKS_PER_PACKET, BLOCK_FLAG, DATA_PAYLOAD_LEN};

    /// Packets of a VLP-16 turning at `rpm`, starting at azimuth `az0` (centideg).
    fn packets(n: usize, rpm: f64, az0: f64, skip: &[usize]) -> Vec<(Vec<u8>, u64)> {
        let block_ns = 110_592.0;
        let centideg_per_ns = rpm / 60.0 * 36000.0 / 1e9;
        let mut out = Vec::new();
        for i in 0..n {
            if skip.contains(&i) {
                continue;
            }
            let mut buf = vec![0u8; DATA_PAYLOAD_LEN];
            let mut p = DataPacket::new_unchecked(&mut buf[..]);
            let t0 = i as f64 * 12.0 * block_ns;
            for b in 0..BLOCKS_PER_PACKET {
                let az = (az0 + (t0 + b as f64 * block_ns) * centideg_per_ns).rem_euclid(36000.0);
                p.set_block_flag(b, BLOCK_FLAG);
                p.set_azimuth(b, az as u16 % 36000);
                for r in 0..32 {
                    p.set_record(b, r, 3000, 20);
                }
            }
            p.set_timestamp_us((t0 / 1000.0) as u32);
            p.set_return_mode(ReturnMode::Strongest);
            out.push((buf, t0 as u64));
        }
        out
    }

    fn run(pk: &[(Vec<u8>, u64)], cut_deg: f64) -> Vec<Sweep> {
        let config = SweepConfig {
            cut_azimuth: cut_deg.to_radians(),
            capacity: 1000,
        };
        let mut a = SweepAssembler::new(Decoder::for_model(Model::Vlp16), config);
        let mut sweeps = Vec::new();
        for (buf, t) in pk {
            a.push(&DataPacket::new_checked(&buf[..]).unwrap(), *t, *t);
            sweeps.extend(std::iter::from_fn(|| a.take_sweep()));
        }
        a.finish();
        sweeps.extend(a.take_sweep());
        sweeps
    }

    #[test]
    fn cuts_whole_rotations_at_any_spin_rate() {
        for rpm in [300.0, 600.0, 1200.0] {
            let per_rev = (60.0 / rpm) / 1.327104e-3;
            let n = (per_rev * 3.5) as usize;
            let sweeps = run(&packets(n, rpm, 18_000.0, &[]), 0.0);
            assert_eq!(sweeps.len(), 4, "rpm {rpm}");
            assert!(sweeps[0].partial && sweeps[3].partial);
            for s in &sweeps[1..3] {
                assert!(!s.partial);
                assert_eq!(s.packets_missing, 0);
                assert!((s.rpm().unwrap() - rpm).abs() / rpm < 0.01, "{:?}", s.rpm());
                // Every point's azimuth lies in one turn from the cut: increasing, unwrapped.
                let first = s.points[0].azimuth;
                assert!(!(0.01..=6.27).contains(&first));
                assert!((s.packets_received as f64 - per_rev).abs() <= 2.0);
            }
        }
    }

    #[test]
    fn gaps_are_counted_not_hidden() {
        let sweeps = run(&packets(200, 600.0, 100.0, &[90, 91, 92, 100]), 0.0);
        let s = &sweeps[1];
        assert_eq!(s.packets_missing, 4);
        assert!(!s.partial);
        assert_eq!(sweeps.iter().map(|s| s.packets_missing).sum::<u32>(), 4);
    }

    #[test]
    fn configurable_cut() {
        let sweeps = run(&packets(200, 600.0, 0.0, &[]), 90.0);
        let s = &sweeps[1];
        let first = s.points[0].azimuth.to_degrees();
        assert!((first - 90.0).abs() < 0.5, "{first}");
    }

    #[test]
    fn silence_closes_the_sweep_as_partial() {
        let mut pk = packets(40, 600.0, 0.0, &[]);
        let later = packets(40, 600.0, 0.0, &[]);
        for (buf, t) in later {
            pk.push((buf, t + 5_000_000_000));
        }
        let sweeps = run(&pk, 0.0);
        assert!(sweeps.len() >= 2);
        assert!(sweeps.iter().all(|s| s.partial));
    }

    #[test]
    fn the_open_sweep_is_the_start_of_the_sweep_it_becomes() {
        let config = SweepConfig {
            cut_azimuth: 0.0,
            capacity: 1000,
        };
        let mut a = SweepAssembler::new(Decoder::for_model(Model::Vlp16), config);
        assert!(a.open_sweep().is_none());
        // Per sweep index: the returns seen open after each packet.
        let mut seen: Vec<(u64, Vec<Point>)> = Vec::new();
        let mut closed = Vec::new();
        for (buf, t) in packets(250, 600.0, 30_000.0, &[]) {
            a.push(&DataPacket::new_checked(&buf[..]).unwrap(), t, t);
            closed.extend(std::iter::from_fn(|| a.take_sweep()));
            let (index, points) = a.open_sweep().expect("a sweep is open");
            match seen.last_mut() {
                Some((i, p)) if *i == index => {
                    assert!(points.starts_with(p), "an open sweep only grows");
                    *p = points.to_vec();
                }
                _ => seen.push((index, points.to_vec())),
            }
        }
        assert!(closed.len() >= 2);
        for sweep in &closed {
            let (_, open) = seen.iter().find(|(i, _)| *i == sweep.index).unwrap();
            assert!(!open.is_empty() && open.len() < sweep.points.len());
            assert!(sweep.points.starts_with(open));
        }
    }

    #[test]
    fn recycled_buffers_are_reused() {
        let pk = packets(300, 600.0, 0.0, &[]);
        let config = SweepConfig {
            cut_azimuth: 0.0,
            capacity: 10,
        };
        let mut a = SweepAssembler::new(Decoder::for_model(Model::Vlp16), config);
        let recycler = a.recycler();
        let mut capacities = Vec::new();
        for (buf, t) in &pk {
            a.push(&DataPacket::new_checked(&buf[..]).unwrap(), *t, *t);
            if let Some(s) = a.take_sweep() {
                capacities.push(s.points.capacity());
                recycler.recycle(s);
            }
        }
        // After the first sweeps grew their buffers, later sweeps reuse them at full size.
        assert!(capacities[2] >= 28_000, "{capacities:?}");
    }
}

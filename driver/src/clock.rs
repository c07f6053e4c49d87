//! The time base: turns the sensor's µs-past-the-hour counter into u64 ns since the Unix epoch.
//!
//! Relative times always come from the counter. The absolute anchor comes from the position
//! packet's `$GPRMC` date and hour while the PPS is locked; otherwise from each packet's receive
//! time (the pcap record time in replay, the host clock live), with the counter aligned to it by
//! a tracked offset, because a sensor without GPS counts freely from power-on. Nothing here reads
//! the wall clock, so a replay gives the same times on every run.
//!
//! Each packet gets two times ([`PacketTime`]): its **stamp**, on the anchor's clock as it is now
//! (it follows a host clock step or a first GPS fix within a packet), and its **sensor time**, the
//! counter on one continuous timeline anchored once, at the first packet (and again only when
//! the counter itself restarts). Motion is computed on sensor time, so a host clock that steps
//! under a running daemon (NTP or PTP correcting a wrong boot clock) never looks like motion, a
//! gap or time running backwards; stamps are what consumers fuse with their other host-stamped
//! data.

use crate::nmea::{parse_rmc, NS_PER_S};
use crate::wire::{PositionPacket, PpsStatus};

/// Length of the counter's cycle: one hour in µs.
pub const HOUR_US: u64 = 3_600_000_000;
const HOUR_NS: u64 = HOUR_US * 1000;
/// A counter step backwards larger than this (but smaller than half an hour) is a jump, not
/// the reordering of two packets: the counter was reset or the sensor rebooted.
const REORDER_TOLERANCE_US: u64 = 100_000;
/// The receive-time offset is the smallest (receive − counter) over a window, because network
/// and capture delays only add. Windows this long let it follow clock drift.
const OFFSET_WINDOW_NS: u64 = 10 * NS_PER_S;
/// A receive-time offset that moves by more than this is a re-synchronisation (reported).
const RESYNC_THRESHOLD_NS: u64 = NS_PER_S;
/// The applied offset moves toward the estimate by at most 1/100 of the device time elapsed:
/// fast enough to shed a first packet's delay within a second, slow enough (13 µs per packet)
/// that firings of consecutive packets (20 µs apart at the seam) never swap order.
const OFFSET_SLEW_DIVISOR: i128 = 100;
/// Counter advances longer than this (10 s) are checked against the receive time.
const JUMP_CHECK_US: u64 = 10_000_000;

/// Where absolute time currently comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeSource {
    /// No packet yet.
    None,
    /// Receive times, aligned by a tracked offset.
    ReceiveTime,
    /// GPS date and hour from `$GPRMC` with PPS locked.
    Gps,
}

/// Counts of clock events, for reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClockStats {
    /// Counter wraps at the top of the hour.
    pub hour_wraps: u64,
    /// Backward jumps of the counter beyond packet reordering (resets, reboots).
    pub backward_jumps: u64,
    /// Forward jumps of the counter by far more than the receive time advanced.
    pub forward_jumps: u64,
    /// Packets whose counter was slightly behind the previous one (reordered on the network).
    pub reordered: u64,
    /// Times the receive-time offset had to be re-established.
    pub resyncs: u64,
    /// How far the receive-time anchor stepped at the last re-establishment (the host clock
    /// stepped, or the sensor was reset): positive forward, ns.
    pub last_step_ns: i64,
    /// Position packets whose `$GPRMC` was read while the PPS was locked.
    pub gps_fixes: u64,
}

/// A packet's two times (see the module docs), ns since the Unix epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PacketTime {
    /// On the continuous timeline anchored at the first packet: for differences.
    pub sensor_ns: u64,
    /// On the anchor's clock as it is now: for stamps.
    pub stamp_ns: u64,
}

impl PacketTime {
    /// `stamp − sensor`: what turns a sensor time of this packet's into a stamp, ns.
    pub fn stamp_offset_ns(&self) -> i64 {
        (i128::from(self.stamp_ns) - i128::from(self.sensor_ns)) as i64
    }
}

/// The stamp of sensor time `sensor_ns`, given `stamp − sensor` at its packet
/// ([`PacketTime::stamp_offset_ns`]).
pub fn stamp(sensor_ns: u64, stamp_offset_ns: i64) -> u64 {
    (i128::from(sensor_ns) + i128::from(stamp_offset_ns)).max(0) as u64
}

/// Converts device counters to Unix ns. See the module docs.
#[derive(Debug, Clone)]
pub struct Clock {
    /// Counter of the last data packet and how many hours it has wrapped since the first.
    last_counter: Option<u32>,
    last_receive_ns: u64,
    hours: u64,
    /// Receive-time offset: Unix ns − unwrapped counter ns, minimum over this and the previous
    /// window.
    offset: Option<i128>,
    /// Device time at which the applied offset was last updated, ns.
    offset_device_ns: i128,
    window_min: i128,
    previous_window_min: i128,
    window_start_ns: u64,
    /// GPS anchor: Unix ns − unwrapped counter ns, from the last fix.
    gps_offset: Option<i128>,
    /// Sensor time − unwrapped counter ns: the anchor at the first packet (or at the first
    /// after the counter restarted).
    timeline: Option<i128>,
    stats: ClockStats,
}

impl Default for Clock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock {
    /// A clock with no anchor yet.
    pub fn new() -> Self {
        Self {
            last_counter: None,
            last_receive_ns: 0,
            hours: 0,
            offset: None,
            offset_device_ns: 0,
            window_min: i128::MAX,
            previous_window_min: i128::MAX,
            window_start_ns: 0,
            gps_offset: None,
            timeline: None,
            stats: ClockStats::default(),
        }
    }

    /// Event counts so far.
    pub fn stats(&self) -> ClockStats {
        self.stats
    }

    /// The current source of absolute time.
    pub fn source(&self) -> TimeSource {
        if self.gps_offset.is_some() {
            TimeSource::Gps
        } else if self.offset.is_some() {
            TimeSource::ReceiveTime
        } else {
            TimeSource::None
        }
    }

    /// Takes the GPS anchor from a position packet when its PPS is locked and its `$GPRMC` is
    /// valid. Returns whether it did.
    pub fn observe_position<T: AsRef<[u8]>>(&mut self, packet: &PositionPacket<T>) -> bool {
        if packet.pps_status() != PpsStatus::Locked {
            return false;
        }
        let Some(fix) = parse_rmc(packet.nmea()).filter(|f| f.valid) else {
            return false;
        };
        let counter = packet.timestamp_us();
        // The fix is the last whole second; the counter is µs past the hour it belongs to. The
        // hour start is the fix time minus the counter, rounded to a whole hour (the two differ
        // by at most a second, so rounding is exact even across the top of the hour).
        let approx = fix.unix_ns as i128 - i128::from(counter) * 1000;
        let hour = (approx + (HOUR_NS as i128) / 2).div_euclid(HOUR_NS as i128);
        if hour < 0 {
            return false;
        }
        // Anchor to the unwrapped counter, not to this fix's hour: times must stay right for as
        // long as the counter runs, fix or no fix (a PPS can drop for hours).
        let hours = match self.last_counter {
            None => {
                self.last_counter = Some(counter);
                self.hours
            }
            Some(last) => {
                let delta = i64::from(counter) - i64::from(last);
                let half = (HOUR_US / 2) as i64;
                if delta < -half {
                    self.hours + 1
                } else if delta > half {
                    self.hours.saturating_sub(1)
                } else {
                    self.hours
                }
            }
        };
        self.gps_offset =
            Some(i128::from(hour as u64 * HOUR_NS) - i128::from(hours) * HOUR_NS as i128);
        self.stats.gps_fixes += 1;
        true
    }

    /// The stamp of the counter value `counter_us` (a data packet's timestamp), received at
    /// `receive_ns`: [`Self::packet_times`]' `stamp_ns`.
    pub fn packet_time(&mut self, counter_us: u32, receive_ns: u64) -> u64 {
        self.packet_times(counter_us, receive_ns).stamp_ns
    }

    /// The stamp and the sensor time of the counter value `counter_us` (a data packet's
    /// timestamp), received at `receive_ns`.
    pub fn packet_times(&mut self, counter_us: u32, receive_ns: u64) -> PacketTime {
        let unwrapped_us = self.unwrap(counter_us, receive_ns);
        let device_ns = i128::from(unwrapped_us) * 1000;
        self.track_offset(device_ns, receive_ns);
        let anchor = match self.gps_offset {
            Some(gps) => gps,
            None => self.offset.expect("track_offset sets it"),
        };
        let timeline = *self.timeline.get_or_insert(anchor);
        PacketTime {
            sensor_ns: (device_ns + timeline).max(0) as u64,
            stamp_ns: (device_ns + anchor).max(0) as u64,
        }
    }

    /// Unwraps the counter across hour wraps and counts jumps. Returns µs since the hour before
    /// the first packet. Whether the counter wrapped or jumped is told apart by the receive
    /// time: across a wrap both advance alike; after a reset they disagree.
    fn unwrap(&mut self, counter: u32, receive_ns: u64) -> u64 {
        let Some(last) = self.last_counter else {
            self.last_counter = Some(counter);
            self.last_receive_ns = receive_ns;
            return u64::from(counter);
        };
        let forward = (i64::from(counter) - i64::from(last)).rem_euclid(HOUR_US as i64) as u64;
        if forward <= HOUR_US / 2 {
            let elapsed_ns = receive_ns.saturating_sub(self.last_receive_ns);
            let disagreement = (forward * 1000).abs_diff(elapsed_ns);
            if forward > JUMP_CHECK_US && disagreement > RESYNC_THRESHOLD_NS {
                if counter < last {
                    self.stats.backward_jumps += 1;
                } else {
                    self.stats.forward_jumps += 1;
                }
                // The counter restarted: neither anchor holds until re-established, and the
                // timeline starts again from the new anchor.
                self.offset = None;
                self.gps_offset = None;
                self.timeline = None;
            } else if counter < last {
                self.hours += 1;
                self.stats.hour_wraps += 1;
            }
        } else {
            let back = HOUR_US - forward;
            if back <= REORDER_TOLERANCE_US {
                // A late packet: it belongs before the last one, in the previous hour if the
                // last one had just wrapped.
                self.stats.reordered += 1;
                let hours = if counter > last {
                    self.hours.saturating_sub(1)
                } else {
                    self.hours
                };
                return hours * HOUR_US + u64::from(counter);
            }
            // The counter went back: a reset. Keep counting from here; the offset tracking
            // (or the next GPS fix) re-establishes the anchor.
            self.stats.backward_jumps += 1;
            self.offset = None;
            self.gps_offset = None;
            self.timeline = None;
        }
        self.last_counter = Some(counter);
        self.last_receive_ns = receive_ns;
        self.hours * HOUR_US + u64::from(counter)
    }

    fn track_offset(&mut self, device_ns: i128, receive_ns: u64) {
        let sample = i128::from(receive_ns) - device_ns;
        let Some(applied) = self.offset else {
            self.restart_offset(sample, device_ns, receive_ns);
            return;
        };
        if (sample - applied).unsigned_abs() > u128::from(RESYNC_THRESHOLD_NS) {
            // Delays do not last a second: the clocks moved apart (host clock step, sensor
            // reset). Start over from this packet.
            self.stats.resyncs += 1;
            self.stats.last_step_ns =
                (sample - applied).clamp(i128::from(i64::MIN), i128::from(i64::MAX)) as i64;
            self.restart_offset(sample, device_ns, receive_ns);
            return;
        }
        if receive_ns.saturating_sub(self.window_start_ns) >= OFFSET_WINDOW_NS {
            self.previous_window_min = self.window_min;
            self.window_min = sample;
            self.window_start_ns = receive_ns;
        } else {
            self.window_min = self.window_min.min(sample);
        }
        let target = self.window_min.min(self.previous_window_min);
        // Slew, never step: a step would move this packet's firings before the last packet's.
        let elapsed = (device_ns - self.offset_device_ns).max(0);
        let slew = elapsed / OFFSET_SLEW_DIVISOR;
        self.offset = Some(applied + (target - applied).clamp(-slew, slew));
        self.offset_device_ns = self.offset_device_ns.max(device_ns);
    }

    fn restart_offset(&mut self, sample: i128, device_ns: i128, receive_ns: u64) {
        self.offset = Some(sample);
        self.offset_device_ns = device_ns;
        self.window_min = sample;
        self.previous_window_min = sample;
        self.window_start_ns = receive_ns;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nmea::format_rmc;
    use crate::wire::POSITION_PAYLOAD_LEN;

    #[test]
    fn receive_time_aligns_a_free_running_counter() {
        let mut c = Clock::new();
        // Counter at 1234.5 s past some arbitrary power-on; host says 1_700_000_000 s.
        let base_recv = 1_700_000_000 * NS_PER_S;
        let t0 = c.packet_time(1_234_500_000, base_recv + 300_000);
        assert_eq!(t0, base_recv + 300_000);
        // Later packets arrive with only 100 µs delay: the offset slews to them (1 % of the
        // elapsed time), so times stay in order and converge.
        let mut last = t0;
        for i in 1..2000u64 {
            let counter = 1_234_500_000 + (i * 1327) as u32;
            let t = c.packet_time(counter, base_recv + i * 1_327_000 + 100_000);
            assert!(t > last + 1_300_000, "packet {i}: {t} after {last}");
            last = t;
        }
        assert_eq!(last, base_recv + 1999 * 1_327_000 + 100_000);
        assert_eq!(c.source(), TimeSource::ReceiveTime);
    }

    #[test]
    fn a_host_clock_step_moves_the_stamps_at_once_and_never_the_sensor_time() {
        for step_s in [2i64, -2, 3600, -3600] {
            let mut c = Clock::new();
            let base = 1_700_000_000 * NS_PER_S;
            let receive = |i: u64, stepped: bool| {
                let t = (base + i * 1_327_000 + 100_000) as i64;
                (if stepped {
                    t + step_s * NS_PER_S as i64
                } else {
                    t
                }) as u64
            };
            let counter = |i: u64| (600_000_000 + i * 1327) as u32;
            let mut last: Option<PacketTime> = None;
            for i in 0..4000u64 {
                let stepped = i >= 2000;
                let t = c.packet_times(counter(i), receive(i, stepped));
                if let Some(last) = last {
                    // Sensor time advances by the counter, step or no step.
                    assert_eq!(
                        t.sensor_ns - last.sensor_ns,
                        1_327_000,
                        "{step_s} s, packet {i}"
                    );
                }
                if i == 2000 {
                    assert_eq!(
                        c.stats().last_step_ns,
                        step_s * NS_PER_S as i64,
                        "{step_s} s"
                    );
                }
                if stepped {
                    // The stamp follows the new clock from the first packet after the step.
                    let error = t.stamp_ns as i64 - receive(i, true) as i64;
                    assert!(error.abs() <= 100_000, "{step_s} s, packet {i}: {error} ns");
                }
                last = Some(t);
            }
            assert_eq!(c.stats().resyncs, 1, "{step_s} s");
        }
    }

    #[test]
    fn hour_wrap_keeps_time_monotonic() {
        let mut c = Clock::new();
        let r = 1_000 * NS_PER_S;
        let a = c.packet_time((HOUR_US - 1000) as u32, r);
        let b = c.packet_time(327, r + 1_327_000);
        assert_eq!(b - a, 1_327_000);
        assert_eq!(c.stats().hour_wraps, 1);
        // A packet from just before the wrap, arriving late, stays in the old hour.
        let late = c.packet_time((HOUR_US - 500) as u32, r + 1_400_000);
        assert_eq!(late - a, 500_000);
        assert_eq!(c.stats().reordered, 1);
    }

    #[test]
    fn backward_jump_is_reported_and_resynchronised() {
        let mut c = Clock::new();
        let r = 1_000 * NS_PER_S;
        c.packet_time(2_000_000_000, r);
        let t = c.packet_time(5_000, r + 2_000_000);
        assert_eq!(c.stats().backward_jumps, 1);
        assert_eq!(t, r + 2_000_000);
    }

    #[test]
    fn gps_anchor_gives_the_hour() {
        let mut c = Clock::new();
        let mut buf = [0u8; POSITION_PAYLOAD_LEN];
        let mut p = PositionPacket::new_unchecked(&mut buf[..]);
        // 2026-11-23 10:59:59 UTC, counter 59 min 59.4 s past the hour.
        let fix = (20_780 * 86_400 + 10 * 3600 + 59 * 60 + 59) * NS_PER_S;
        p.set_pps_status(PpsStatus::Locked);
        p.set_nmea(format_rmc(fix).as_bytes());
        p.set_timestamp_us(3_599_400_000);
        assert!(c.observe_position(&PositionPacket::new_unchecked(&buf[..])));
        // A data packet after the wrap belongs to 11:00.
        let t = c.packet_time(20_000, fix + 700_000_000);
        assert_eq!(t, (20_780 * 86_400 + 11 * 3600) * NS_PER_S + 20_000_000);
        // One from before the wrap, arriving 70 ms late, to 10:59.
        let t = c.packet_time(3_599_950_000, fix + 710_000_000);
        assert_eq!(
            t,
            (20_780 * 86_400 + 10 * 3600) * NS_PER_S + 3_599_950_000_000
        );
        assert_eq!(c.source(), TimeSource::Gps);
    }

    #[test]
    fn gps_time_stays_right_long_after_the_last_fix() {
        // One fix at 10:10, then the PPS drops: two hours of packets (one per second) must keep
        // their time across both hour wraps. (Anchoring to the fix's own hour put every packet
        // from 10:40 on an hour early.)
        let mut c = Clock::new();
        let mut buf = [0u8; POSITION_PAYLOAD_LEN];
        let mut p = PositionPacket::new_unchecked(&mut buf[..]);
        let day = 20_780 * 86_400 * NS_PER_S;
        let fix = day + (10 * 3600 + 10 * 60) * NS_PER_S;
        p.set_pps_status(PpsStatus::Locked);
        p.set_nmea(format_rmc(fix).as_bytes());
        p.set_timestamp_us(600_000_000);
        assert!(c.observe_position(&PositionPacket::new_unchecked(&buf[..])));
        for s in 0..7200u64 {
            let counter = ((600 + s) % 3600) * 1_000_000;
            let t = c.packet_time(counter as u32, fix + s * NS_PER_S);
            assert_eq!(t, fix + s * NS_PER_S, "{s} s after the fix");
        }
        assert_eq!(c.stats().hour_wraps, 2);
    }

    #[test]
    fn unlocked_pps_is_ignored() {
        let mut c = Clock::new();
        let mut buf = [0u8; POSITION_PAYLOAD_LEN];
        let mut p = PositionPacket::new_unchecked(&mut buf[..]);
        p.set_nmea(format_rmc(1_000 * NS_PER_S).as_bytes());
        p.set_pps_status(PpsStatus::Synchronizing);
        assert!(!c.observe_position(&PositionPacket::new_unchecked(&buf[..])));
    }
}

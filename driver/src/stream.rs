//! A sensor's packet stream turned into sweeps: validation, model detection, the time base and
//! sweep assembly wired together, with counters for everything dropped.
//!
//! Until the model is decided, data packets are held (a handful of ms of data); position packets
//! go straight to the clock. A model named in the configuration decides at the first packet.

use crate::clock::{Clock, ClockStats};
use crate::model::{Detection, DetectionError, LaserTable, Model, ModelDetector};
use crate::sweep::{Sweep, SweepAssembler, SweepConfig, SweepRecycler};
use crate::wire::{
    DataPacket, PacketError, PositionPacket, ReturnMode, AZIMUTH_LIMIT, BLOCKS_PER_PACKET,
    DATA_PAYLOAD_LEN,
};

const FULL_TURN: u16 = AZIMUTH_LIMIT;
use crate::decode::Point;
use crate::Decoder;
use thiserror::Error;

/// What the stream needs to know up front.
#[derive(Debug, Clone, Default)]
pub struct StreamConfig {
    /// A model named by the user: always wins over detection.
    pub model: Option<Model>,
    /// A laser table from a calibration file, replacing the model's factory table.
    pub calibration: Option<LaserTable>,
    /// Sweep cutting.
    pub sweep: SweepConfig,
}

/// Why the stream cannot go on, or why one packet was dropped.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum StreamError {
    /// One packet was invalid: it is counted and dropped; the stream goes on.
    #[error("dropped packet: {0}")]
    Packet(#[from] PacketError),
    /// The model cannot be decided: the stream cannot be decoded.
    #[error(transparent)]
    Detection(#[from] DetectionError),
    /// The calibration table does not fit the model.
    #[error("the calibration file has {table} lasers but the {model} has {expected}")]
    CalibrationMismatch {
        model: Model,
        table: usize,
        expected: usize,
    },
}

impl StreamError {
    /// Whether the stream can go on after this error.
    pub fn is_recoverable(&self) -> bool {
        matches!(self, StreamError::Packet(_))
    }
}

/// Counters of a stream.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StreamStats {
    /// Valid data packets.
    pub data_packets: u64,
    /// Valid position packets.
    pub position_packets: u64,
    /// Packets dropped because they were cut short.
    pub truncated: u64,
    /// Packets dropped because their bytes were wrong.
    pub malformed: u64,
    /// Data packets with a block azimuth of exactly 36000 (a full turn), read as 0.
    pub full_turn_azimuths: u64,
    /// Data packets whose product-id byte differs from the first one's.
    pub product_id_changes: u64,
    /// Sweeps emitted, of which partial.
    pub sweeps: u64,
    /// See `sweeps`.
    pub partial_sweeps: u64,
    /// Packets missing inside sweeps (from device-time gaps).
    pub packets_missing: u64,
    /// Returns emitted.
    pub points: u64,
    /// Return mode of the last data packet.
    pub return_mode: Option<ReturnMode>,
    /// Time of the first and last firing decoded, ns.
    pub first_ns: Option<u64>,
    /// See `first_ns`.
    pub last_ns: u64,
    /// Clock events.
    pub clock: ClockStats,
    /// Azimuth advance over consecutive packets, hundredths of a degree, and the time it took,
    /// ns: the spin rate without needing a whole sweep.
    pub azimuth_advance_centideg: f64,
    /// See `azimuth_advance_centideg`.
    pub azimuth_advance_ns: u64,
}

impl StreamStats {
    /// Spin rate measured from the azimuth advance, rpm.
    pub fn rpm(&self) -> Option<f64> {
        (self.azimuth_advance_ns > 0).then(|| {
            self.azimuth_advance_centideg / 36_000.0 / (self.azimuth_advance_ns as f64 * 1e-9)
                * 60.0
        })
    }
}

/// Data packets held while the model is being detected (~21 ms at 10 Hz).
const HOLD_PACKETS: usize = 16;

/// From UDP payloads to sweeps. See the module docs.
#[derive(Debug)]
pub struct SensorStream {
    config: StreamConfig,
    detector: ModelDetector,
    detection: Option<Detection>,
    held: Vec<([u8; DATA_PAYLOAD_LEN], u64)>,
    clock: Clock,
    assembler: Option<SweepAssembler>,
    first_product_id: Option<u8>,
    last_packet: Option<(u64, u16)>,
    stats: StreamStats,
}

impl SensorStream {
    /// A stream with nothing received yet.
    pub fn new(config: StreamConfig) -> Self {
        Self {
            config,
            detector: ModelDetector::new(),
            detection: None,
            held: Vec::with_capacity(HOLD_PACKETS),
            clock: Clock::new(),
            assembler: None,
            first_product_id: None,
            last_packet: None,
            stats: StreamStats::default(),
        }
    }

    /// The model decision, once made.
    pub fn detection(&self) -> Option<&Detection> {
        self.detection.as_ref()
    }

    /// Counters so far.
    pub fn stats(&self) -> StreamStats {
        let mut s = self.stats;
        s.clock = self.clock.stats();
        s
    }

    /// The clock, for its source and stats.
    pub fn clock(&self) -> &Clock {
        &self.clock
    }

    /// Where to return finished sweeps' buffers (once the model is decided).
    pub fn recycler(&self) -> Option<SweepRecycler> {
        self.assembler.as_ref().map(SweepAssembler::recycler)
    }

    /// Handles a data-port payload received at `receive_ns`. A `Packet` error means this
    /// packet was dropped (and counted); any other error means the stream cannot be decoded.
    pub fn push_data(&mut self, payload: &[u8], receive_ns: u64) -> Result<(), StreamError> {
        let packet = match DataPacket::new_checked(payload) {
            Ok(p) => p,
            Err(PacketError::AzimuthOutOfRange {
                value: FULL_TURN, ..
            }) => {
                // Real VLP-16 firmware writes 36000 for a full turn (seen in the 20 Hz capture in
                // shared/data, between 35920 and 80): it means 0. Anything above is corrupt.
                let mut fixed = [0u8; DATA_PAYLOAD_LEN];
                fixed.copy_from_slice(payload);
                let mut view = DataPacket::new_unchecked(&mut fixed[..]);
                for block in 0..BLOCKS_PER_PACKET {
                    if view.azimuth(block) == FULL_TURN {
                        view.set_azimuth(block, 0);
                    }
                }
                self.stats.full_turn_azimuths += 1;
                let fixed =
                    DataPacket::new_checked(&fixed[..]).inspect_err(|e| self.count_drop(e))?;
                return self.push_checked(fixed, receive_ns);
            }
            Err(e) => {
                self.count_drop(&e);
                return Err(e.into());
            }
        };
        self.push_checked(packet, receive_ns)
    }

    fn push_checked(
        &mut self,
        packet: DataPacket<&[u8]>,
        receive_ns: u64,
    ) -> Result<(), StreamError> {
        self.stats.data_packets += 1;
        let id = packet.product_id();
        match self.first_product_id {
            None => self.first_product_id = Some(id),
            Some(first) if first != id => self.stats.product_id_changes += 1,
            _ => {}
        }
        if self.assembler.is_some() {
            self.decode(&packet, receive_ns);
            return Ok(());
        }
        self.detector.observe(&packet);
        let mut copy = [0u8; DATA_PAYLOAD_LEN];
        copy.copy_from_slice(packet.as_bytes());
        self.held.push((copy, receive_ns));
        if self.config.model.is_some()
            || self.detector.is_settled()
            || self.held.len() >= HOLD_PACKETS
        {
            self.decide()?;
        }
        Ok(())
    }

    /// Handles a position-port payload.
    pub fn push_position(&mut self, payload: &[u8]) -> Result<(), StreamError> {
        let packet = PositionPacket::new_checked(payload).inspect_err(|e| self.count_drop(e))?;
        self.stats.position_packets += 1;
        self.clock.observe_position(&packet);
        Ok(())
    }

    /// Ends the stream: decides the model with what was seen, flushes held packets and closes
    /// the open sweep.
    pub fn finish(&mut self) -> Result<(), StreamError> {
        if self.assembler.is_none() && !self.held.is_empty() {
            self.decide()?;
        }
        if let Some(a) = self.assembler.as_mut() {
            a.finish();
        }
        Ok(())
    }

    /// The sweep still open, see [`SweepAssembler::open_sweep`].
    pub fn open_sweep(&self) -> Option<(u64, &[Point])> {
        self.assembler.as_ref()?.open_sweep()
    }

    /// The oldest completed sweep not yet taken.
    pub fn take_sweep(&mut self) -> Option<Sweep> {
        let sweep = self.assembler.as_mut()?.take_sweep()?;
        self.stats.sweeps += 1;
        self.stats.partial_sweeps += u64::from(sweep.partial);
        self.stats.packets_missing += u64::from(sweep.packets_missing);
        self.stats.points += sweep.points.len() as u64;
        Some(sweep)
    }

    fn count_drop(&mut self, e: &PacketError) {
        match e {
            PacketError::Truncated { .. } => self.stats.truncated += 1,
            _ => self.stats.malformed += 1,
        }
    }

    fn decide(&mut self) -> Result<(), StreamError> {
        let detection = match self.detector.decide(self.config.model) {
            Ok(d) => d,
            Err(e) => {
                // Undecodable: drop what was held (the error is reported for every packet that
                // follows, and the buffer must not grow on a live stream).
                self.held.clear();
                return Err(e.into());
            }
        };
        let model = detection.model;
        let table = match &self.config.calibration {
            Some(table) if table.len() != model.timing().lasers => {
                return Err(StreamError::CalibrationMismatch {
                    model,
                    table: table.len(),
                    expected: model.timing().lasers,
                })
            }
            Some(table) => table.clone(),
            None => model.laser_table(),
        };
        self.detection = Some(detection);
        self.assembler = Some(SweepAssembler::new(
            Decoder::new(model, &table),
            self.config.sweep,
        ));
        let held = std::mem::take(&mut self.held);
        for (bytes, receive_ns) in &held {
            self.decode(&DataPacket::new_unchecked(&bytes[..]), *receive_ns);
        }
        Ok(())
    }

    fn decode(&mut self, packet: &DataPacket<&[u8]>, receive_ns: u64) {
        let times = self.clock.packet_times(packet.timestamp_us(), receive_ns);
        // Sweeps are assembled on sensor time: cuts, durations and point times never see a
        // host clock step; each sweep carries what turns its times into stamps.
        let time = times.sensor_ns;
        self.stats.return_mode = packet.return_mode().ok();
        self.stats.first_ns.get_or_insert(time);
        let assembler = self.assembler.as_mut().expect("decided before decoding");
        let packet_ns = assembler
            .decoder()
            .timing()
            .packet_ns(self.stats.return_mode.unwrap_or(ReturnMode::Strongest));
        self.stats.last_ns = self.stats.last_ns.max(time + packet_ns);
        let azimuth = packet.azimuth(0);
        if let Some((last_time, last_azimuth)) = self.last_packet {
            // Only adjacent packets measure the rate; across a gap the azimuth may have wrapped.
            let dt = time.saturating_sub(last_time);
            if dt > 0 && dt < packet_ns * 3 / 2 {
                let step = (i32::from(azimuth) - i32::from(last_azimuth)).rem_euclid(36_000);
                self.stats.azimuth_advance_centideg += f64::from(step);
                self.stats.azimuth_advance_ns += dt;
            }
        }
        self.last_packet = Some((time, azimuth));
        assembler.push_stamped(packet, time, receive_ns, times.stamp_offset_ns());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{BLOCK_FLAG, DATA_PAYLOAD_LEN};

    /// Packets whose device time advances 80 µs per block: no known sensor.
    fn odd_packet(i: u32) -> [u8; DATA_PAYLOAD_LEN] {
        let mut buf = [0u8; DATA_PAYLOAD_LEN];
        let mut p = DataPacket::new_unchecked(&mut buf[..]);
        for b in 0..BLOCKS_PER_PACKET {
            p.set_block_flag(b, BLOCK_FLAG);
            p.set_azimuth(b, ((i * 480 + b as u32 * 40) % 36_000) as u16);
        }
        p.set_timestamp_us(i * 960);
        p.set_return_mode(ReturnMode::Strongest);
        p.set_product_id(0x99);
        buf
    }

    #[test]
    fn an_undecodable_stream_is_an_error_that_holds_no_memory() {
        let mut stream = SensorStream::new(StreamConfig::default());
        let mut errors = 0;
        for i in 0..200 {
            if let Err(e) = stream.push_data(&odd_packet(i), u64::from(i) * 960_000) {
                assert!(!e.is_recoverable(), "{e}");
                errors += 1;
            }
            assert!(stream.held.len() <= HOLD_PACKETS);
        }
        assert!(errors > 150);
        assert!(stream.detection().is_none());
    }

    #[test]
    fn a_configured_model_decides_at_the_first_packet() {
        let config = StreamConfig {
            model: Some(Model::Vlp16),
            ..StreamConfig::default()
        };
        let mut stream = SensorStream::new(config);
        stream.push_data(&odd_packet(0), 0).unwrap();
        assert_eq!(stream.detection().unwrap().model, Model::Vlp16);
    }
}

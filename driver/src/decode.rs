//! From a checked data packet and its absolute time to points: per-return firing time, precise
//! azimuth, ring and laser index, reflectivity, return kind and REP-103 coordinates.
//!
//! Conventions (stated once for Glint): times are u64 ns since the Unix epoch; the sensor frame
//! is REP-103 (x forward = azimuth 0, y left, z up, right-handed); azimuths are in radians,
//! measured clockwise seen from above as the sensor reports them, in [0, 2π); distances in m.
//! `x = R cos ω cos α`, `y = −R cos ω sin α`, `z = R sin ω + vertical offset`.
//!
//! Speed comes from lookup tables built once per decoder: sin/cos per 0.01° of azimuth (the
//! sensor's resolution) refined by a first-order correction for the fractional part, and each
//! laser's elevation terms and time offsets.

use crate::model::{firings_blocks, FiringTiming, LaserTable, Model};
use crate::wire::{
    DataPacket, ReturnMode, AZIMUTH_LIMIT, BLOCKS_PER_PACKET, DISTANCE_UNIT_M, RECORDS_PER_BLOCK,
};

/// Which return of a firing a point is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ReturnKind {
    /// The strongest return (single-return strongest mode, or the strongest of a dual pair).
    #[default]
    Strongest,
    /// The last return.
    Last,
    /// Dual mode where the last and the strongest return are the same echo.
    Both,
}

impl ReturnKind {
    /// The name used in decoded output files.
    pub fn name(self) -> &'static str {
        match self {
            ReturnKind::Strongest => "strongest",
            ReturnKind::Last => "last",
            ReturnKind::Both => "both",
        }
    }
}

/// One return of one laser firing.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Point {
    /// Firing time, ns since the Unix epoch.
    pub time_ns: u64,
    /// REP-103 coordinates in the sensor frame, m.
    pub x: f32,
    /// See `x`.
    pub y: f32,
    /// See `x`.
    pub z: f32,
    /// Measured range, m.
    pub range: f32,
    /// Precise azimuth of the firing (interpolated per laser), rad, clockwise, in [0, 2π).
    pub azimuth: f32,
    /// Calibrated reflectivity: 0–100 diffuse, 101–255 retro-reflective.
    pub reflectivity: u8,
    /// Elevation order, 0 = lowest beam.
    pub ring: u8,
    /// Laser index in firing order.
    pub laser: u8,
    /// Which return it is.
    pub return_kind: ReturnKind,
}

/// One firing sequence: all lasers fired at one azimuth. Its returns are the output vector's
/// elements from `first_point` on.
#[derive(Debug, Clone, Copy)]
pub struct Firing {
    /// Azimuth of the sequence's first laser, hundredths of a degree in [0, 36000).
    pub azimuth_centideg: f32,
    /// Time of the sequence's first laser, ns since the epoch.
    pub time_ns: u64,
    /// Index in the output of the sequence's first return.
    pub first_point: usize,
}

#[derive(Debug, Clone, Copy)]
struct LaserTerms {
    cos_elevation: f32,
    sin_elevation: f32,
    vertical_offset: f32,
    horizontal_offset: f32,
    distance_correction: f32,
    /// Azimuth correction in hundredths of a degree, and its sine and cosine.
    azimuth_correction: f32,
    sin_correction: f32,
    cos_correction: f32,
    /// Firing time after the sequence's first laser, ns (and as f32 for the azimuth advance).
    offset_ns: u64,
    offset_ns_f32: f32,
    ring: u8,
}

/// A firing sequence: azimuth of its first laser (hundredths of a degree), azimuth advance per
/// ns, time of its first laser, that azimuth's (sin, cos) and the rotation from one laser to the
/// next.
#[derive(Debug, Clone, Copy)]
struct Sequence {
    azimuth: f32,
    rate: f32,
    time_ns: u64,
    trig: (f32, f32),
    step_trig: (f32, f32),
}

/// A laser's firing within a sequence: its azimuth (hundredths of a degree, before calibration),
/// that azimuth's (sin, cos), and its time.
#[derive(Debug, Clone, Copy)]
struct LaserFiring {
    azimuth: f32,
    trig: (f32, f32),
    time_ns: u64,
}

const TRIG_STEPS: usize = AZIMUTH_LIMIT as usize;
const CENTIDEG_TO_RAD: f32 = std::f32::consts::PI / 18_000.0;
/// An azimuth step between blocks above this (10°) is not rotation: a corrupt or stitched
/// packet. The decoder then falls back to the previous step.
const MAX_BLOCK_STEP_CENTIDEG: f32 = 1000.0;

/// Decodes data packets of one model with one laser table.
#[derive(Debug, Clone)]
pub struct Decoder {
    model: Model,
    timing: FiringTiming,
    lasers: Vec<LaserTerms>,
    /// Whether any laser has an azimuth, horizontal-offset or distance correction.
    corrected: bool,
    /// (sin, cos) per hundredth of a degree, interleaved so a lookup touches one cache line;
    /// shared by every decoder.
    trig: &'static [[f32; 2]],
}

impl Decoder {
    /// A decoder for `model` using `table` (the model's factory table or a calibration file).
    ///
    /// # Panics
    /// If the table's laser count is not the model's.
    pub fn new(model: Model, table: &LaserTable) -> Self {
        let timing = model.timing();
        assert_eq!(
            table.len(),
            timing.lasers,
            "laser table does not fit {model}"
        );
        let lasers = table
            .lasers()
            .iter()
            .zip(table.rings())
            .enumerate()
            .map(|(i, (l, &ring))| LaserTerms {
                offset_ns: i as u64 * timing.laser_ns,
                offset_ns_f32: (i as u64 * timing.laser_ns) as f32,
                cos_elevation: l.elevation.cos() as f32,
                sin_elevation: l.elevation.sin() as f32,
                vertical_offset: l.vertical_offset as f32,
                horizontal_offset: l.horizontal_offset as f32,
                distance_correction: l.distance_correction as f32,
                azimuth_correction: l.azimuth_correction.to_degrees() as f32 * 100.0,
                sin_correction: l.azimuth_correction.sin() as f32,
                cos_correction: l.azimuth_correction.cos() as f32,
                ring,
            })
            .collect();
        let trig = trig_table();
        let corrected = table.lasers().iter().any(|l| {
            l.azimuth_correction != 0.0
                || l.horizontal_offset != 0.0
                || l.distance_correction != 0.0
        });
        Self {
            model,
            timing,
            lasers,
            corrected,
            trig,
        }
    }

    /// A decoder with the model's factory table.
    pub fn for_model(model: Model) -> Self {
        Self::new(model, &model.laser_table())
    }

    /// The model decoded.
    pub fn model(&self) -> Model {
        self.model
    }

    /// The model's firing timing.
    pub fn timing(&self) -> FiringTiming {
        self.timing
    }

    /// Appends the returns of every firing sequence of `packet` to `out` in time order, calling
    /// `on_firing` after each sequence with `out` (which it may swap for another vector: later
    /// returns go to whatever `out` then is). `packet_time_ns` is the absolute time of the
    /// packet's first firing (see [`crate::clock`]). In dual-return mode a sequence carries both
    /// returns of each laser. The packet must be checked.
    pub fn decode_firings<T: AsRef<[u8]>>(
        &self,
        packet: &DataPacket<T>,
        packet_time_ns: u64,
        out: &mut Vec<Point>,
        mut on_firing: impl FnMut(&mut Vec<Point>, Firing),
    ) {
        let mode = packet.return_mode().unwrap_or(ReturnMode::Strongest);
        let dual = mode == ReturnMode::Dual;
        let stride = if dual { 2 } else { 1 };
        let firings = firings_blocks(mode);
        let single_kind = if mode == ReturnMode::Last {
            ReturnKind::Last
        } else {
            ReturnKind::Strongest
        };
        let seq_per_block = self.timing.sequences_per_block;
        let lasers = self.timing.lasers;

        let az_of = |k: usize| f32::from(packet.azimuth(k * stride));
        let step_of = |k: usize| wrap_step(az_of(k + 1) - az_of(k));
        let mut previous_step = if firings > 1 { step_of(0) } else { 0.0 };
        for k in 0..firings {
            let step = if k + 1 < firings {
                step_of(k)
            } else {
                previous_step
            };
            let step = if step > MAX_BLOCK_STEP_CENTIDEG {
                previous_step
            } else {
                step
            };
            previous_step = step;
            // Azimuth advance per ns over this block.
            let rate = step / self.timing.block_ns() as f32;
            let block_time = packet_time_ns + k as u64 * self.timing.block_ns();
            for seq in 0..seq_per_block {
                let seq_offset_ns = seq as u64 * self.timing.sequence_ns;
                let seq_azimuth = az_of(k) + rate * seq_offset_ns as f32;
                let seq_time = block_time + seq_offset_ns;
                let seq_trig = self.sin_cos(wrap_azimuth(seq_azimuth));
                // Each laser fires one interpolation step after the previous: rotate (sin, cos)
                // by that step (below 0.02° at 1200 rpm; third order is exact to 1e-12).
                let step = rate * self.timing.laser_ns as f32 * CENTIDEG_TO_RAD;
                let step_trig = (step - step * step * step / 6.0, 1.0 - 0.5 * step * step);
                let first_point = out.len();
                let sequence = Sequence {
                    azimuth: seq_azimuth,
                    rate,
                    time_ns: seq_time,
                    trig: seq_trig,
                    step_trig,
                };
                let range = seq * lasers * 3..(seq + 1) * lasers * 3;
                if dual {
                    let last = &packet.block_records(2 * k)[range.clone()];
                    let strongest = &packet.block_records(2 * k + 1)[range];
                    self.decode_sequence(last, None, ReturnKind::Last, &sequence, out);
                    let pair = Some((last, first_point));
                    self.decode_sequence(strongest, pair, ReturnKind::Strongest, &sequence, out);
                } else {
                    let records = &packet.block_records(k)[range];
                    self.decode_sequence(records, None, single_kind, &sequence, out);
                }
                on_firing(
                    out,
                    Firing {
                        azimuth_centideg: wrap_azimuth(seq_azimuth),
                        time_ns: seq_time,
                        first_point,
                    },
                );
            }
        }
    }

    /// Decodes one firing sequence's records. In dual mode `same_as` holds the last-return
    /// block's records and where their points start in `out`: a strongest return equal to the
    /// last one is the same echo, and that point is marked `Both` instead.
    #[inline(always)]
    fn decode_sequence(
        &self,
        records: &[u8],
        same_as: Option<(&[u8], usize)>,
        kind: ReturnKind,
        seq: &Sequence,
        out: &mut Vec<Point>,
    ) {
        if self.corrected {
            self.decode_sequence_with::<true>(records, same_as, kind, seq, out);
        } else {
            self.decode_sequence_with::<false>(records, same_as, kind, seq, out);
        }
    }

    #[inline(always)]
    fn decode_sequence_with<const CORRECTED: bool>(
        &self,
        records: &[u8],
        same_as: Option<(&[u8], usize)>,
        kind: ReturnKind,
        seq: &Sequence,
        out: &mut Vec<Point>,
    ) {
        out.reserve(self.lasers.len());
        let (mut sin_a, mut cos_a) = seq.trig;
        for (laser, (record, terms)) in records.chunks_exact(3).zip(&self.lasers).enumerate() {
            let trig = (sin_a, cos_a);
            (sin_a, cos_a) = (
                sin_a * seq.step_trig.1 + cos_a * seq.step_trig.0,
                cos_a * seq.step_trig.1 - sin_a * seq.step_trig.0,
            );
            let raw = u16::from_le_bytes([record[0], record[1]]);
            if raw == 0 {
                continue;
            }
            if let Some((last, from)) = same_as {
                if last.get(3 * laser..3 * laser + 3) == Some(record) {
                    if let Some(p) = out[from..].iter_mut().find(|p| p.laser == laser as u8) {
                        p.return_kind = ReturnKind::Both;
                    }
                    continue;
                }
            }
            let firing = LaserFiring {
                azimuth: seq.azimuth + seq.rate * terms.offset_ns_f32,
                trig,
                time_ns: seq.time_ns + terms.offset_ns,
            };
            out.push(self.point::<CORRECTED>(terms, laser, raw, record[2], firing, kind));
        }
    }

    /// Appends every return of `packet` to `out`.
    pub fn decode_into<T: AsRef<[u8]>>(
        &self,
        packet: &DataPacket<T>,
        packet_time_ns: u64,
        out: &mut Vec<Point>,
    ) {
        out.reserve(BLOCKS_PER_PACKET * RECORDS_PER_BLOCK);
        self.decode_firings(packet, packet_time_ns, out, |_, _| {});
    }

    /// One return. `CORRECTED` is false for tables without azimuth, horizontal or distance
    /// corrections (every factory table), which skips their arithmetic.
    #[inline(always)]
    fn point<const CORRECTED: bool>(
        &self,
        terms: &LaserTerms,
        laser: usize,
        raw: u16,
        reflectivity: u8,
        firing: LaserFiring,
        return_kind: ReturnKind,
    ) -> Point {
        let mut range = f32::from(raw) * DISTANCE_UNIT_M as f32;
        let (mut sin_a, mut cos_a) = firing.trig;
        let mut azimuth = firing.azimuth;
        let horizontal;
        let (x, y);
        if CORRECTED {
            range += terms.distance_correction;
            azimuth -= terms.azimuth_correction;
            // sin(a − k), cos(a − k) with k the laser's azimuth correction.
            (sin_a, cos_a) = (
                sin_a * terms.cos_correction - cos_a * terms.sin_correction,
                cos_a * terms.cos_correction + sin_a * terms.sin_correction,
            );
            horizontal = range * terms.cos_elevation;
            // The horizontal offset moves the beam's origin sideways (the manual's frame, as the
            // ROS driver applies it), which in REP-103 reads as below.
            x = horizontal * cos_a + terms.horizontal_offset * sin_a;
            y = -horizontal * sin_a + terms.horizontal_offset * cos_a;
        } else {
            horizontal = range * terms.cos_elevation;
            x = horizontal * cos_a;
            y = -horizontal * sin_a;
        }
        let z = range * terms.sin_elevation + terms.vertical_offset;
        Point {
            time_ns: firing.time_ns,
            x,
            y,
            z,
            range,
            azimuth: wrap_azimuth(azimuth) * CENTIDEG_TO_RAD,
            reflectivity,
            ring: terms.ring,
            laser: laser as u8,
            return_kind,
        }
    }

    /// sin and cos of an azimuth in [0, 36000) hundredths of a degree: the table at the whole
    /// hundredth, rotated by the fraction (first order; the error is below 2e-8).
    #[inline]
    fn sin_cos(&self, centideg: f32) -> (f32, f32) {
        let i = (centideg as usize).min(TRIG_STEPS - 1);
        let d = (centideg - i as f32) * CENTIDEG_TO_RAD;
        let [s, c] = self.trig[i];
        (s + c * d, c - s * d)
    }
}

/// The (sin, cos) table, built on first use and shared: it depends on nothing but the azimuth
/// resolution.
fn trig_table() -> &'static [[f32; 2]] {
    static TABLE: std::sync::OnceLock<Vec<[f32; 2]>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        (0..TRIG_STEPS)
            .map(|i| {
                let a = (i as f64 / 100.0).to_radians();
                [a.sin() as f32, a.cos() as f32]
            })
            .collect()
    })
}

/// Azimuth difference in hundredths of a degree, taken forward across the 35999→0 wrap.
#[inline]
fn wrap_step(step: f32) -> f32 {
    if step < 0.0 {
        step + AZIMUTH_LIMIT as f32
    } else {
        step
    }
}

/// An azimuth in hundredths of a degree, wrapped into [0, 36000). Inputs are within a turn of
/// that range (a block azimuth plus an interpolation step or a calibration correction), so a
/// conditional add or subtract does what `rem_euclid` (an `fmodf` call) would, several times
/// faster in the per-point loop.
#[inline]
pub(crate) fn wrap_azimuth(a: f32) -> f32 {
    let limit = AZIMUTH_LIMIT as f32;
    let w = if a >= limit {
        a - limit
    } else if a < 0.0 {
        a + limit
    } else {
        a
    };
    // Guards the input contract (and NaN) without a panic: anything else maps into range.
    if (0.0..limit).contains(&w) {
        w
    } else {
        a.rem_euclid(limit).min(limit - 0.01).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::BLOCK_FLAG;
    use crate::wire::DATA_PAYLOAD_LEN;

    fn packet(mode: ReturnMode, az0: u16, step: u16) -> [u8; DATA_PAYLOAD_LEN] {
        let mut buf = [0u8; DATA_PAYLOAD_LEN];
        let mut p = DataPacket::new_unchecked(&mut buf[..]);
        for b in 0..BLOCKS_PER_PACKET {
            let k = if mode == ReturnMode::Dual { b / 2 } else { b } as u16;
            p.set_block_flag(b, BLOCK_FLAG);
            p.set_azimuth(b, (az0 + k * step) % 36000);
            for r in 0..32 {
                p.set_record(b, r, 5000, 40);
            }
        }
        p.set_return_mode(mode);
        p.set_product_id(0x22);
        buf
    }

    #[test]
    fn laser_zero_at_ten_metres_matches_the_reference_decoder() {
        // vlp16.md: velodyne-decoder puts a 10 m return of laser 0 at z = −2.5770 m.
        let mut buf = packet(ReturnMode::Strongest, 0, 40);
        DataPacket::new_unchecked(&mut buf[..]).set_record(0, 0, 5000, 10);
        let d = Decoder::for_model(Model::Vlp16);
        let mut pts = Vec::new();
        d.decode_into(&DataPacket::new_checked(&buf[..]).unwrap(), 0, &mut pts);
        let p = pts[0];
        assert!((p.z - -2.5770).abs() < 5e-5, "{}", p.z);
        assert!((p.x - 10.0 * (15f32).to_radians().cos()).abs() < 1e-4);
        assert!(p.y.abs() < 1e-6);
        assert_eq!((p.ring, p.laser, p.time_ns), (0, 0, 0));
    }

    #[test]
    fn timing_and_azimuth_interpolation() {
        let buf = packet(ReturnMode::Strongest, 35_980, 40);
        let d = Decoder::for_model(Model::Vlp16);
        let mut pts = Vec::new();
        d.decode_into(&DataPacket::new_checked(&buf[..]).unwrap(), 1_000, &mut pts);
        assert_eq!(pts.len(), 384);
        // Block 1, record 16 + 5: 110.592 + 55.296 + 5 × 2.304 µs.
        let p = pts[32 + 16 + 5];
        assert_eq!(p.time_ns, 1_000 + 110_592 + 55_296 + 5 * 2_304);
        // Azimuth: block 1 is at 20 centideg (after the wrap); + half a step + 5 lasers.
        let expected = 20.0 + 20.0 + 40.0 * (5.0 * 2.304 / 110.592);
        assert!((p.azimuth.to_degrees() * 100.0 - expected).abs() < 1e-3);
        // Azimuths are increasing through the packet (across the wrap, unwrapped).
        let mut last = -1.0f32;
        for p in &pts {
            let mut a = p.azimuth.to_degrees();
            if a > 300.0 {
                a -= 360.0;
            }
            assert!(a > last, "{a} after {last}");
            last = a;
        }
    }

    #[test]
    fn dual_return_pairs_share_time_and_merge_identical_echoes() {
        let mut buf = packet(ReturnMode::Dual, 100, 40);
        {
            let mut p = DataPacket::new_unchecked(&mut buf[..]);
            // Block 1 (strongest of pair 0): laser 3 differs from block 0 (last).
            p.set_record(1, 3, 2500, 90);
        }
        let d = Decoder::for_model(Model::Vlp16);
        let mut pts = Vec::new();
        d.decode_into(&DataPacket::new_checked(&buf[..]).unwrap(), 0, &mut pts);
        // 6 pairs × 32 records; identical pairs merge to one point, except laser 3 seq 0 of pair 0.
        assert_eq!(pts.len(), 6 * 32 + 1);
        let l3: Vec<_> = pts
            .iter()
            .filter(|p| p.laser == 3 && p.time_ns == 3 * 2304)
            .collect();
        assert_eq!(l3.len(), 2);
        assert_eq!(l3[0].return_kind, ReturnKind::Last);
        assert_eq!(l3[1].return_kind, ReturnKind::Strongest);
        assert!(
            pts.iter()
                .filter(|p| p.return_kind == ReturnKind::Both)
                .count()
                == 6 * 32 - 1
        );
        // Pair 1 starts one block (110.592 µs) later.
        assert!(pts.iter().any(|p| p.time_ns == 110_592));
    }

    #[test]
    fn calibration_rotation_is_applied_exactly() {
        let mut lasers = Model::Vlp16.laser_table().lasers().to_vec();
        lasers[3].azimuth_correction = 0.1; // rad, larger than any real correction
        let table = LaserTable::new(lasers).unwrap();
        let buf = packet(ReturnMode::Strongest, 9_000, 40);
        let mut pts = Vec::new();
        Decoder::new(Model::Vlp16, &table).decode_into(
            &DataPacket::new_checked(&buf[..]).unwrap(),
            0,
            &mut pts,
        );
        let p = pts[3];
        let expected = (90.0f64 + 40.0 / 100.0 * 3.0 * 2.304 / 110.592).to_radians() - 0.1;
        assert!((f64::from(p.azimuth) - expected).abs() < 1e-6);
        let horizontal = f64::from(p.range) * 3f64.to_radians().cos();
        assert!((f64::from(p.x) - horizontal * expected.cos()).abs() < 1e-5);
        assert!((f64::from(p.y) + horizontal * expected.sin()).abs() < 1e-5);
    }

    #[test]
    fn trig_refinement_is_accurate() {
        let d = Decoder::for_model(Model::Vlp16);
        for a in [0.0f32, 0.37, 1234.5, 17_999.99, 35_999.9] {
            let (s, c) = d.sin_cos(a);
            let r = (f64::from(a) / 100.0).to_radians();
            assert!((f64::from(s) - r.sin()).abs() < 1e-6);
            assert!((f64::from(c) - r.cos()).abs() < 1e-6);
        }
    }
}

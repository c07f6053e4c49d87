//! Sensor models: their laser tables and firing timing (from the Velodyne manuals), and model
//! detection that checks the product-id byte against the packets' own timing.
//!
//! The product-id byte is a hint, not a fact: devices in the field send wrong bytes (the real
//! captures in `shared/data` are VLP-16s whose byte says HDL-32E). A model named by the user
//! always wins; otherwise the device-time step per packet decides the packet family, and within
//! the 16-laser family (where timing cannot tell a VLP-16 from a Puck Hi-Res) the byte decides.

use std::fmt;

use thiserror::Error;

use crate::wire::{DataPacket, ReturnMode, BLOCKS_PER_PACKET};

/// A supported sensor model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Model {
    /// Velodyne VLP-16 (Puck), product id 0x22.
    Vlp16,
    /// Velodyne Puck Hi-Res, product id 0x24: VLP-16 timing, narrower fan.
    PuckHiRes,
    /// Velodyne HDL-32E, product id 0x21.
    Hdl32e,
}

/// Packet layout and timing family: what the packets themselves reveal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Family {
    /// 16 lasers, two firing sequences per block, 110.592 µs per block (VLP-16, Puck Hi-Res).
    Sixteen,
    /// 32 lasers, one firing per block, 46.08 µs per block (HDL-32E).
    ThirtyTwo,
    /// 32 lasers, one firing per block, 55.296 µs per block (VLP-32C). Recognised so that it
    /// is reported by name; not decoded.
    Vlp32c,
}

impl Family {
    /// Duration of one data block in ns, from the manuals.
    pub fn block_ns(self) -> u64 {
        match self {
            Family::Sixteen => 110_592,
            Family::ThirtyTwo => 46_080,
            Family::Vlp32c => 55_296,
        }
    }

    /// A name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Family::Sixteen => "16-laser (VLP-16 / Puck Hi-Res timing)",
            Family::ThirtyTwo => "HDL-32E timing",
            Family::Vlp32c => "VLP-32C timing",
        }
    }
}

/// Unknown model name given by the user.
#[derive(Debug, Error)]
#[error("unknown sensor model {0:?}: expected vlp16, puck-hires or hdl32e")]
pub struct UnknownModel(pub String);

impl std::str::FromStr for Model {
    type Err = UnknownModel;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().replace(['_', ' '], "-").as_str() {
            "vlp16" | "vlp-16" | "puck" => Ok(Model::Vlp16),
            "puck-hires" | "puck-hi-res" | "vlp16-hires" | "hi-res" => Ok(Model::PuckHiRes),
            "hdl32e" | "hdl-32e" | "hdl32" => Ok(Model::Hdl32e),
            _ => Err(UnknownModel(s.to_string())),
        }
    }
}

impl fmt::Display for Model {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// VLP-16 elevation per laser index (firing order), degrees. Manual 63-9243, table 9-1.
const VLP16_ELEVATION_DEG: [f64; 16] = [
    -15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0,
];
/// VLP-16 vertical offset of each beam's origin, mm. Manual 63-9243, table 9-1.
const VLP16_VERTICAL_OFFSET_MM: [f64; 16] = [
    11.2, -0.7, 9.7, -2.2, 8.1, -3.7, 6.6, -5.1, 5.1, -6.6, 3.7, -8.1, 2.2, -9.7, 0.7, -11.2,
];
/// Puck Hi-Res elevation per laser index, degrees (published in 2/3° steps).
const PUCK_HIRES_ELEVATION_DEG: [f64; 16] = [
    -10.0, 0.67, -8.67, 2.0, -7.33, 3.33, -6.0, 4.67, -4.67, 6.0, -3.33, 7.33, -2.0, 8.67, -0.67,
    10.0,
];
/// Radius (mm) from the spin axis to the Puck's beam-steering mirror: the vertical offsets of
/// the VLP-16 table are this times tan(−ω). Used to derive the Hi-Res offsets, which the
/// manual does not tabulate.
const PUCK_OFFSET_RADIUS_MM: f64 = 41.91;
/// HDL-32E elevation per laser index, degrees. HDL-32E manual, appendix.
const HDL32E_ELEVATION_DEG: [f64; 32] = [
    -30.67, -9.33, -29.33, -8.00, -28.00, -6.67, -26.67, -5.33, -25.33, -4.00, -24.00, -2.67,
    -22.67, -1.33, -21.33, 0.00, -20.00, 1.33, -18.67, 2.67, -17.33, 4.00, -16.00, 5.33, -14.67,
    6.67, -13.33, 8.00, -12.00, 9.33, -10.67, 10.67,
];

impl Model {
    /// Every supported model.
    pub const ALL: [Model; 3] = [Model::Vlp16, Model::PuckHiRes, Model::Hdl32e];

    /// The product-id byte the model's firmware sends.
    pub fn product_id(self) -> u8 {
        match self {
            Model::Vlp16 => 0x22,
            Model::PuckHiRes => 0x24,
            Model::Hdl32e => 0x21,
        }
    }

    /// What a product-id byte claims, if it names a supported model.
    pub fn from_product_id(byte: u8) -> Option<Model> {
        Model::ALL.into_iter().find(|m| m.product_id() == byte)
    }

    /// The model's packet family.
    pub fn family(self) -> Family {
        match self {
            Model::Vlp16 | Model::PuckHiRes => Family::Sixteen,
            Model::Hdl32e => Family::ThirtyTwo,
        }
    }

    /// A display name.
    pub fn name(self) -> &'static str {
        match self {
            Model::Vlp16 => "VLP-16",
            Model::PuckHiRes => "Puck Hi-Res",
            Model::Hdl32e => "HDL-32E",
        }
    }

    /// The command-line spelling.
    pub fn cli_name(self) -> &'static str {
        match self {
            Model::Vlp16 => "vlp16",
            Model::PuckHiRes => "puck-hires",
            Model::Hdl32e => "hdl32e",
        }
    }

    /// Firing timing of the model.
    pub fn timing(self) -> FiringTiming {
        match self.family() {
            Family::Sixteen => FiringTiming {
                lasers: 16,
                sequences_per_block: 2,
                sequence_ns: 55_296,
                laser_ns: 2_304,
            },
            // HDL-32E: one firing of all 32 lasers per block, 1.152 µs apart, every 46.08 µs.
            Family::ThirtyTwo | Family::Vlp32c => FiringTiming {
                lasers: 32,
                sequences_per_block: 1,
                sequence_ns: 46_080,
                laser_ns: 1_152,
            },
        }
    }

    /// The factory laser table.
    pub fn laser_table(self) -> LaserTable {
        let lasers: Vec<Laser> = match self {
            Model::Vlp16 => VLP16_ELEVATION_DEG
                .iter()
                .zip(VLP16_VERTICAL_OFFSET_MM)
                .map(|(&el, off)| Laser::new(el.to_radians(), off * 1e-3))
                .collect(),
            Model::PuckHiRes => PUCK_HIRES_ELEVATION_DEG
                .iter()
                .map(|&el| {
                    let offset_mm = PUCK_OFFSET_RADIUS_MM * (-el.to_radians()).tan();
                    Laser::new(el.to_radians(), offset_mm * 1e-3)
                })
                .collect(),
            Model::Hdl32e => HDL32E_ELEVATION_DEG
                .iter()
                .map(|&el| Laser::new(el.to_radians(), 0.0))
                .collect(),
        };
        LaserTable::new(lasers).expect("factory tables are valid")
    }
}

/// Firing timing of one model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FiringTiming {
    /// Lasers per firing sequence.
    pub lasers: usize,
    /// Firing sequences per data block (2 for the 16-laser family).
    pub sequences_per_block: usize,
    /// Duration of one firing sequence, ns.
    pub sequence_ns: u64,
    /// Interval between consecutive lasers of a sequence, ns.
    pub laser_ns: u64,
}

impl FiringTiming {
    /// Duration of one data block, ns.
    pub fn block_ns(&self) -> u64 {
        self.sequence_ns * self.sequences_per_block as u64
    }

    /// Duration a whole packet covers, ns (dual-return packets hold half as many firings).
    pub fn packet_ns(&self, mode: ReturnMode) -> u64 {
        self.block_ns() * firings_blocks(mode) as u64
    }
}

/// Distinct firing blocks (times) in a packet of the given return mode.
pub fn firings_blocks(mode: ReturnMode) -> usize {
    match mode {
        ReturnMode::Dual => BLOCKS_PER_PACKET / 2,
        _ => BLOCKS_PER_PACKET,
    }
}

/// One laser's geometry. Angles in radians, lengths in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Laser {
    /// Elevation ω of the beam above the sensor's xy plane.
    pub elevation: f64,
    /// Height of the beam's origin above the sensor origin, added to z.
    pub vertical_offset: f64,
    /// Azimuth correction subtracted from the measured azimuth (calibration `rot_correction`).
    pub azimuth_correction: f64,
    /// Horizontal offset of the beam's origin (calibration `horiz_offset_correction`).
    pub horizontal_offset: f64,
    /// Added to every measured distance (calibration `dist_correction`).
    pub distance_correction: f64,
}

impl Laser {
    /// A laser with elevation and vertical offset only.
    pub fn new(elevation: f64, vertical_offset: f64) -> Self {
        Self {
            elevation,
            vertical_offset,
            azimuth_correction: 0.0,
            horizontal_offset: 0.0,
            distance_correction: 0.0,
        }
    }
}

/// Problems with a laser table.
#[derive(Debug, Error, PartialEq)]
pub enum LaserTableError {
    /// Not 16 or 32 lasers.
    #[error("a laser table has 16 or 32 lasers, this one has {0}")]
    WrongCount(usize),
    /// A value that is not finite or out of any sensor's range.
    #[error("laser {laser}: {what} = {value} is not plausible")]
    Implausible {
        laser: usize,
        what: &'static str,
        value: f64,
    },
}

/// Per-laser geometry in firing order, with each laser's ring (0 = lowest elevation).
#[derive(Debug, Clone, PartialEq)]
pub struct LaserTable {
    lasers: Vec<Laser>,
    rings: Vec<u8>,
}

impl LaserTable {
    /// Builds a table and numbers the rings by elevation.
    pub fn new(lasers: Vec<Laser>) -> Result<Self, LaserTableError> {
        if lasers.len() != 16 && lasers.len() != 32 {
            return Err(LaserTableError::WrongCount(lasers.len()));
        }
        for (i, l) in lasers.iter().enumerate() {
            let checks = [
                ("elevation", l.elevation, std::f64::consts::FRAC_PI_2),
                ("vertical_offset", l.vertical_offset, 1.0),
                (
                    "azimuth_correction",
                    l.azimuth_correction,
                    std::f64::consts::PI,
                ),
                ("horizontal_offset", l.horizontal_offset, 1.0),
                ("distance_correction", l.distance_correction, 10.0),
            ];
            for (what, value, limit) in checks {
                if !value.is_finite() || value.abs() > limit {
                    return Err(LaserTableError::Implausible {
                        laser: i,
                        what,
                        value,
                    });
                }
            }
        }
        let mut order: Vec<usize> = (0..lasers.len()).collect();
        order.sort_by(|&a, &b| lasers[a].elevation.total_cmp(&lasers[b].elevation));
        let mut rings = vec![0u8; lasers.len()];
        for (ring, &laser) in order.iter().enumerate() {
            rings[laser] = ring as u8;
        }
        Ok(Self { lasers, rings })
    }

    /// Lasers in firing order.
    pub fn lasers(&self) -> &[Laser] {
        &self.lasers
    }

    /// Ring (elevation order, 0 = lowest) of each laser index.
    pub fn rings(&self) -> &[u8] {
        &self.rings
    }

    /// Number of lasers.
    pub fn len(&self) -> usize {
        self.lasers.len()
    }

    /// Never true for a constructed table.
    pub fn is_empty(&self) -> bool {
        self.lasers.is_empty()
    }
}

/// How the product-id byte relates to the decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ByteVerdict {
    /// The byte names the decided model.
    Agrees,
    /// The byte names a supported model the packets contradict.
    Contradicted(Model),
    /// The byte names no supported model.
    Unknown,
}

/// Where the model came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelSource {
    /// Named by the user (command line or config): always wins.
    Configured,
    /// Decided by the packets' timing (and the byte within the 16-laser family).
    Timing,
    /// Only one data packet, or no adjacent pair: the byte alone, which named a model.
    ByteOnly,
}

/// The outcome of model detection, with the evidence for reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// The model packets are decoded with.
    pub model: Model,
    /// Where the decision came from.
    pub source: ModelSource,
    /// The product-id byte seen.
    pub product_id: u8,
    /// How the byte relates to the decision.
    pub byte: ByteVerdict,
    /// The family the timing indicates, when measured.
    pub timing_family: Option<Family>,
    /// Measured device time per firing block, µs, when measured.
    pub measured_block_us: Option<f64>,
}

impl Detection {
    /// A model named by the user.
    pub fn configured(model: Model, product_id: u8) -> Self {
        Self {
            model,
            source: ModelSource::Configured,
            product_id,
            byte: verdict(model, product_id),
            timing_family: None,
            measured_block_us: None,
        }
    }

    /// A one-line human description, saying what the byte says and what the timing says.
    pub fn describe(&self) -> String {
        let byte = match Model::from_product_id(self.product_id) {
            Some(m) => format!("{:#04x} ({})", self.product_id, m.name()),
            None => format!("{:#04x} (unknown)", self.product_id),
        };
        let timing = match (self.timing_family, self.measured_block_us) {
            (Some(f), Some(us)) => format!("{} ({us:.3} µs per block)", f.name()),
            _ => "not measured".to_string(),
        };
        let how = match self.source {
            ModelSource::Configured => "configured",
            ModelSource::Timing => "detected",
            ModelSource::ByteOnly => "from the product-id byte only",
        };
        let note = match self.byte {
            ByteVerdict::Agrees => String::new(),
            ByteVerdict::Contradicted(m) => {
                format!("; the product-id byte claims {} but is overruled", m.name())
            }
            ByteVerdict::Unknown => "; the product-id byte names no supported model".into(),
        };
        format!(
            "{} ({how}); product-id byte {byte}; timing says {timing}{note}",
            self.model.name()
        )
    }
}

fn verdict(model: Model, byte: u8) -> ByteVerdict {
    match Model::from_product_id(byte) {
        Some(m) if m == model => ByteVerdict::Agrees,
        Some(m) => ByteVerdict::Contradicted(m),
        None => ByteVerdict::Unknown,
    }
}

/// Detection failed.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DetectionError {
    /// The timing matches a family Glint does not decode.
    #[error("the packets' timing is a {} ({block_us:.3} µs per block), which Glint does not decode; product-id byte {product_id:#04x}", family.name())]
    UnsupportedFamily {
        family: Family,
        block_us: f64,
        product_id: u8,
    },
    /// The timing matches no known family.
    #[error("device time advances {block_us:.3} µs per firing block, which matches no known sensor; product-id byte {product_id:#04x}")]
    UnknownTiming { block_us: f64, product_id: u8 },
    /// No timing evidence and the byte names no supported model.
    #[error("cannot tell the sensor model: no two consecutive data packets and product-id byte {0:#04x} names no supported model; name the model with --model")]
    Undecidable(u8),
    /// No data packet at all.
    #[error("no data packets to detect the sensor model from")]
    NoData,
}

/// Collects timing evidence from data packets and decides the model.
///
/// Evidence: the device-time step between consecutive packets, divided by the firing blocks a
/// packet holds, is the block duration — 110.592 µs for the 16-laser family, 46.08 µs for the
/// HDL-32E. Lost packets only lengthen a step, so the smallest step seen over several pairs is
/// an adjacent pair's.
#[derive(Debug, Clone, Default)]
pub struct ModelDetector {
    last: Option<(u32, u16)>,
    min_block_us: Option<f64>,
    pairs: usize,
    product_id: Option<u8>,
    product_id_mixed: bool,
}

/// Pairs of consecutive packets after which the timing evidence is considered settled.
pub const DETECTION_PAIRS: usize = 8;

impl ModelDetector {
    /// A detector with no evidence.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one checked data packet.
    pub fn observe<T: AsRef<[u8]>>(&mut self, packet: &DataPacket<T>) {
        let id = packet.product_id();
        match self.product_id {
            None => self.product_id = Some(id),
            Some(seen) if seen != id => self.product_id_mixed = true,
            _ => {}
        }
        let mode = match packet.return_mode() {
            Ok(m) => m,
            Err(_) => return,
        };
        let ts = packet.timestamp_us();
        let az = packet.azimuth(0);
        if let Some((last_ts, last_az)) = self.last {
            let step = ts.wrapping_sub(last_ts);
            // Steps over 10 ms are gaps or hour wraps, not evidence; equal azimuths mean a
            // repeated packet.
            if step > 0 && step < 10_000 && az != last_az {
                let block_us = step as f64 / firings_blocks(mode) as f64;
                self.min_block_us = Some(self.min_block_us.map_or(block_us, |m| m.min(block_us)));
                self.pairs += 1;
            }
        }
        self.last = Some((ts, az));
    }

    /// Whether enough evidence is in to decide without waiting for more.
    pub fn is_settled(&self) -> bool {
        self.pairs >= DETECTION_PAIRS
    }

    /// Whether different packets carried different product-id bytes.
    pub fn product_id_mixed(&self) -> bool {
        self.product_id_mixed
    }

    /// Decides with the evidence so far. `configured` (from the user) always wins.
    pub fn decide(&self, configured: Option<Model>) -> Result<Detection, DetectionError> {
        let product_id = self.product_id.ok_or(DetectionError::NoData)?;
        let timing = self.min_block_us.map(|us| (us, family_of_block(us)));
        if let Some(model) = configured {
            let mut d = Detection::configured(model, product_id);
            if let Some((us, fam)) = timing {
                d.measured_block_us = Some(us);
                d.timing_family = fam;
            }
            return Ok(d);
        }
        let byte_model = Model::from_product_id(product_id);
        let (block_us, family) = match timing {
            Some((us, Some(f))) => (us, f),
            Some((us, None)) => {
                return Err(DetectionError::UnknownTiming {
                    block_us: us,
                    product_id,
                })
            }
            None => {
                let model = byte_model.ok_or(DetectionError::Undecidable(product_id))?;
                return Ok(Detection {
                    model,
                    source: ModelSource::ByteOnly,
                    product_id,
                    byte: ByteVerdict::Agrees,
                    timing_family: None,
                    measured_block_us: None,
                });
            }
        };
        let model = match family {
            Family::Sixteen => match byte_model {
                Some(Model::PuckHiRes) => Model::PuckHiRes,
                // The byte cannot tell within the family when it names another family or
                // nothing: the VLP-16 is the family's common member.
                _ => Model::Vlp16,
            },
            Family::ThirtyTwo => Model::Hdl32e,
            Family::Vlp32c => {
                return Err(DetectionError::UnsupportedFamily {
                    family,
                    block_us,
                    product_id,
                })
            }
        };
        Ok(Detection {
            model,
            source: ModelSource::Timing,
            product_id,
            byte: verdict(model, product_id),
            timing_family: Some(family),
            measured_block_us: Some(block_us),
        })
    }
}

/// The family whose block duration is within 3 % of the measured one.
fn family_of_block(block_us: f64) -> Option<Family> {
    [Family::Sixteen, Family::ThirtyTwo, Family::Vlp32c]
        .into_iter()
        .find(|f| ((block_us * 1e3) / f.block_ns() as f64 - 1.0).abs() < 0.03)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vlp16_rings_follow_elevation() {
        let t = Model::Vlp16.laser_table();
        // Laser 0 is -15° (ring 0), laser 1 is +1° (ring 8), laser 15 is +15° (ring 15).
        assert_eq!(t.rings()[0], 0);
        assert_eq!(t.rings()[1], 8);
        assert_eq!(t.rings()[14], 7);
        assert_eq!(t.rings()[15], 15);
    }

    #[test]
    fn vlp16_offsets_match_the_mirror_geometry() {
        // The manual's offsets are 41.91 mm × tan(−ω) rounded to 0.1 mm.
        for l in Model::Vlp16.laser_table().lasers() {
            let derived = PUCK_OFFSET_RADIUS_MM * 1e-3 * (-l.elevation).tan();
            assert!((derived - l.vertical_offset).abs() < 0.06e-3, "{l:?}");
        }
    }

    #[test]
    fn timing_constants() {
        let t = Model::Vlp16.timing();
        assert_eq!(t.block_ns(), 110_592);
        assert_eq!(t.packet_ns(ReturnMode::Strongest), 1_327_104);
        assert_eq!(t.packet_ns(ReturnMode::Dual), 663_552);
        assert_eq!(Model::Hdl32e.timing().packet_ns(ReturnMode::Last), 552_960);
    }

    #[test]
    fn model_names_parse() {
        assert_eq!("vlp16".parse::<Model>().unwrap(), Model::Vlp16);
        assert_eq!("puck-hires".parse::<Model>().unwrap(), Model::PuckHiRes);
        assert_eq!("HDL32E".parse::<Model>().unwrap(), Model::Hdl32e);
        assert!("vlp32".parse::<Model>().is_err());
    }

    #[test]
    fn family_tolerance() {
        assert_eq!(family_of_block(1327.0 / 12.0), Some(Family::Sixteen));
        assert_eq!(family_of_block(553.0 / 12.0), Some(Family::ThirtyTwo));
        assert_eq!(family_of_block(55.3), Some(Family::Vlp32c));
        assert_eq!(family_of_block(80.0), None);
    }
}

//! What to simulate: the scenario, the seed and the sensor's settings, validated once into a
//! [`SimConfig`], and the start-time parser for `--start-time`.
//!
//! Every random choice derives from the seed through separate ChaCha streams (layout, noise,
//! packet loss, vibration), so changing the noise settings never moves a rack. The variations
//! of one scene (another route, another sensor unit, changed goods, a kidnap) draw from streams
//! of their own seeds, so none of them moves anything else.

use std::fmt;
use std::str::FromStr;

use glint_driver::nmea::days_from_civil;
use glint_driver::wire::ReturnMode;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

const NS_PER_S: u64 = 1_000_000_000;

/// The kinds of place the simulator builds. The seed varies the layout, never the kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Scenario {
    /// Racks and aisles, pillars, walls, floor markings; two laps of a loop around a rack block.
    Warehouse,
    /// A long, geometrically degenerate corridor whose only axial cues are reflectivity patterns.
    Corridor,
    /// An outdoor yard with facades, poles, parked boxes and a larger loop.
    Yard,
}

impl Scenario {
    /// Every scenario.
    pub const ALL: [Scenario; 3] = [Scenario::Warehouse, Scenario::Corridor, Scenario::Yard];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Warehouse => "warehouse",
            Scenario::Corridor => "corridor",
            Scenario::Yard => "yard",
        }
    }
}

impl fmt::Display for Scenario {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A scenario name that is none of the known ones.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[error("unknown scenario {0:?}: expected warehouse, corridor or yard")]
pub struct UnknownScenario(pub String);

impl FromStr for Scenario {
    type Err = UnknownScenario;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Scenario::ALL
            .into_iter()
            .find(|sc| sc.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| UnknownScenario(s.to_string()))
    }
}

/// Why a configuration cannot be simulated.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ConfigError {
    /// The duration is zero, negative, not finite or longer than a day.
    #[error("the duration must be a positive number of seconds up to 86400, got {0}")]
    Seconds(f64),
    /// The rotation rate is outside what the sensor supports.
    #[error("the rotation rate must be between 300 and 1200 rpm, got {0}")]
    Rpm(f64),
    /// The range noise is negative, not finite or absurdly large.
    #[error("the range noise sigma must be between 0 and 1 m, got {0}")]
    RangeNoise(f64),
    /// The reflectivity noise is negative, not finite or absurdly large.
    #[error("the reflectivity noise sigma must be between 0 and 50 counts, got {0}")]
    ReflectivityNoise(f64),
    /// The per-laser gain bias is outside ±20 %.
    #[error("the per-laser gain bias must be between 0 and 0.2, got {0}")]
    GainBias(f64),
    /// The packet-loss probability is not in [0, 1).
    #[error("the packet-loss probability must be in [0, 1), got {0}")]
    PacketLoss(f64),
    /// The start time is outside what a `$GPRMC` two-digit year can say (1980–2079), or the
    /// run would end after it.
    #[error(
        "the start time must lie between 1980 and 2079 (the range of a $GPRMC date), got {0} ns"
    )]
    StartTime(u64),
    /// The start fraction is not in [0, 1).
    #[error("the start fraction must be in [0, 1) of the lap, got {0}")]
    StartFraction(f64),
    /// The kidnap time is not inside the run with room for one more sweep after it.
    #[error(
        "the kidnap time must be after the start and at least {KIDNAP_MARGIN_S} s before the \
         end of the {seconds} s run, got {time} s"
    )]
    KidnapTime {
        /// The requested time, s after the start.
        time: f64,
        /// The run's duration, s.
        seconds: f64,
    },
    /// The changed fraction is not in [0, 1].
    #[error("the fraction of movable objects to change must be in [0, 1], got {0}")]
    Change(f64),
    /// More movers than the scenes are built for.
    #[error("the number of movers must be at most {MAX_MOVERS}, got {0}")]
    Movers(usize),
}

/// Room a kidnap needs before the end of the run, s: the sweep it lands in must end before the
/// run does (a sweep lasts at most 0.2 s, at 300 rpm).
pub const KIDNAP_MARGIN_S: f64 = 0.25;
/// The most movers `--movers` may ask for.
pub const MAX_MOVERS: usize = 16;

/// Everything that defines a run. Two runs with equal configs produce identical bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Which kind of place.
    pub scenario: Scenario,
    /// Varies the layout, the sensor's start angle, gains, noise and loss.
    pub seed: u64,
    /// Simulated duration, s. Trajectories loop until it is reached.
    pub seconds: f64,
    /// Rotor speed, revolutions per minute (300–1200).
    pub rpm: f64,
    /// Strongest, last or dual return.
    pub return_mode: ReturnMode,
    /// Gaussian range noise σ, m (applied when `noise` is on).
    pub range_noise_m: f64,
    /// Gaussian reflectivity noise σ, counts (applied when `noise` is on).
    pub reflectivity_noise: f64,
    /// Spread of the per-laser gain bias: gains are drawn uniformly in 1 ± this. It is a
    /// property of the unit, not noise, so `noise = false` keeps it; set 0 to remove it.
    pub laser_gain_bias: f64,
    /// Master switch for random range and reflectivity noise.
    pub noise: bool,
    /// Probability that a data packet is lost (never sent, never written).
    pub packet_loss: f64,
    /// Time of the first firing, ns since the Unix epoch; `None` derives it from the seed.
    pub start_time_ns: Option<u64>,
    /// Another closed route through the same layout, chosen from this seed; `None` drives the
    /// scenario's own route.
    pub path_seed: Option<u64>,
    /// Drive the route in the opposite direction.
    pub reverse: bool,
    /// Where on the route the run starts, as a fraction of the lap length in [0, 1).
    pub start_fraction: f64,
    /// Teleport the robot this many seconds after the start (at the end of the sweep in
    /// progress) to a place on the route at least [`KIDNAP_MIN_DISTANCE_M`] away.
    pub kidnap_s: Option<f64>,
    /// The sensor unit (per-laser gains, start angle, noise) from this seed instead of `seed`.
    pub unit_seed: Option<u64>,
    /// Fraction of the movable objects (goods, pallets, parked vehicles) removed or shifted.
    pub change: f64,
    /// Decides which movable objects change and how.
    pub change_seed: u64,
    /// How many moving occluders (pedestrians, forklifts, cars); `None` keeps the scenario's.
    pub movers: Option<usize>,
}

/// The shortest straight-line jump of a kidnap, m.
pub const KIDNAP_MIN_DISTANCE_M: f64 = 10.0;

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            scenario: Scenario::Warehouse,
            seed: 1,
            seconds: 60.0,
            rpm: 600.0,
            return_mode: ReturnMode::Strongest,
            range_noise_m: 0.015,
            reflectivity_noise: 1.0,
            laser_gain_bias: 0.03,
            noise: true,
            packet_loss: 0.0,
            start_time_ns: None,
            path_seed: None,
            reverse: false,
            start_fraction: 0.0,
            kidnap_s: None,
            unit_seed: None,
            change: 0.0,
            change_seed: 1,
            movers: None,
        }
    }
}

/// 1980-01-01T00:00:00Z and 2080-01-01T00:00:00Z: the years a `$GPRMC` date can name as
/// Glint's NMEA reader interprets them.
const EARLIEST_START_S: u64 = 315_532_800;
const LATEST_END_S: u64 = 3_471_292_800;
/// 2020-01-01T00:00:00Z: seeded start times fall in the five years after it.
const SEEDED_EPOCH_S: u64 = 1_577_836_800;
const SEEDED_SPAN_S: u64 = 5 * 365 * 86_400;

impl SimConfig {
    /// Checks every field; the simulator only runs validated configs.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !(self.seconds.is_finite() && self.seconds > 0.0 && self.seconds <= 86_400.0) {
            return Err(ConfigError::Seconds(self.seconds));
        }
        if !(300.0..=1200.0).contains(&self.rpm) {
            return Err(ConfigError::Rpm(self.rpm));
        }
        if !(0.0..=1.0).contains(&self.range_noise_m) {
            return Err(ConfigError::RangeNoise(self.range_noise_m));
        }
        if !(0.0..=50.0).contains(&self.reflectivity_noise) {
            return Err(ConfigError::ReflectivityNoise(self.reflectivity_noise));
        }
        if !(0.0..=0.2).contains(&self.laser_gain_bias) {
            return Err(ConfigError::GainBias(self.laser_gain_bias));
        }
        if !(0.0..1.0).contains(&self.packet_loss) {
            return Err(ConfigError::PacketLoss(self.packet_loss));
        }
        let start = self.start_time_ns();
        let end = start.saturating_add((self.seconds * 1e9) as u64 + NS_PER_S);
        if start < EARLIEST_START_S * NS_PER_S || end >= LATEST_END_S * NS_PER_S {
            return Err(ConfigError::StartTime(start));
        }
        if !(0.0..1.0).contains(&self.start_fraction) {
            return Err(ConfigError::StartFraction(self.start_fraction));
        }
        if let Some(time) = self.kidnap_s {
            if !(time > 0.0 && time + KIDNAP_MARGIN_S <= self.seconds) {
                return Err(ConfigError::KidnapTime {
                    time,
                    seconds: self.seconds,
                });
            }
        }
        if !(0.0..=1.0).contains(&self.change) {
            return Err(ConfigError::Change(self.change));
        }
        if let Some(n) = self.movers.filter(|&n| n > MAX_MOVERS) {
            return Err(ConfigError::Movers(n));
        }
        Ok(())
    }

    /// The seed of the sensor unit: `unit_seed`, else `seed`.
    pub fn sensor_unit_seed(&self) -> u64 {
        self.unit_seed.unwrap_or(self.seed)
    }

    /// Whether the run departs from the scenario's own route, unit or contents.
    pub fn is_variant(&self) -> bool {
        self.path_seed.is_some()
            || self.reverse
            || self.start_fraction != 0.0
            || self.kidnap_s.is_some()
            || self.unit_seed.is_some()
            || self.change > 0.0
            || self.movers.is_some()
    }

    /// The time of the first firing: the configured one, or one derived from the seed (a
    /// moment in 2020–2024 with a sub-second part, so runs do not start on whole seconds).
    pub fn start_time_ns(&self) -> u64 {
        self.start_time_ns.unwrap_or_else(|| {
            let mut rng = seeded_rng(self.seed, Stream::StartTime);
            let secs = SEEDED_EPOCH_S + rand::Rng::random_range(&mut rng, 0..SEEDED_SPAN_S);
            let frac = rand::Rng::random_range(&mut rng, 0..NS_PER_S);
            secs * NS_PER_S + frac
        })
    }

    /// The duration in ns.
    pub fn duration_ns(&self) -> u64 {
        (self.seconds * 1e9).round() as u64
    }
}

/// Independent random streams derived from one seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stream {
    Layout = 1,
    StartTime = 2,
    SensorUnit = 3,
    Noise = 4,
    Loss = 5,
    Vibration = 6,
    Path = 7,
    Change = 8,
    Kidnap = 9,
    Movers = 10,
}

/// A ChaCha generator for one purpose of one seed.
pub(crate) fn seeded_rng(seed: u64, stream: Stream) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream as u64);
    rng
}

/// Why a `--start-time` value was not understood.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[error(
    "cannot read start time {0:?}: give Unix seconds (e.g. 1700000000.5) or RFC 3339 \
     (e.g. 2024-05-01T12:00:00Z or 2024-05-01T14:00:00.25+02:00)"
)]
pub struct StartTimeError(pub String);

/// Reads a start time given either as Unix seconds (integer or decimal) or as an RFC 3339
/// timestamp with `Z` or a numeric offset. Returns ns since the Unix epoch.
pub fn parse_start_time(text: &str) -> Result<u64, StartTimeError> {
    let err = || StartTimeError(text.to_string());
    let s = text.trim();
    if s.is_empty() {
        return Err(err());
    }
    if s.bytes().all(|b| b.is_ascii_digit() || b == b'.') {
        return parse_decimal_seconds(s).ok_or_else(err);
    }
    parse_rfc3339(s).ok_or_else(err)
}

/// Whole and fractional seconds to ns without going through f64 (which would lose the ns).
fn parse_decimal_seconds(s: &str) -> Option<u64> {
    let (whole, frac) = s.split_once('.').unwrap_or((s, ""));
    if whole.is_empty() || frac.len() > 9 || frac.contains('.') {
        return None;
    }
    let whole: u64 = whole.parse().ok()?;
    let mut frac_ns = 0u64;
    for (i, b) in frac.bytes().enumerate() {
        frac_ns += u64::from(b - b'0') * 10u64.pow(8 - i as u32);
    }
    whole.checked_mul(NS_PER_S)?.checked_add(frac_ns)
}

fn parse_rfc3339(s: &str) -> Option<u64> {
    let b = s.as_bytes();
    if b.len() < 20 || b[4] != b'-' || b[7] != b'-' || !matches!(b[10], b'T' | b't' | b' ') {
        return None;
    }
    if b[13] != b':' || b[16] != b':' {
        return None;
    }
    let num = |r: std::ops::Range<usize>| -> Option<u32> {
        let part = s.get(r)?;
        part.bytes()
            .all(|c| c.is_ascii_digit())
            .then(|| part.parse().ok())?
    };
    let (year, month, day) = (num(0..4)?, num(5..7)?, num(8..10)?);
    let (hour, minute, second) = (num(11..13)?, num(14..16)?, num(17..19)?);
    if !(1..=12).contains(&month) || !(1..=days_in_month(year, month)).contains(&day) {
        return None;
    }
    if hour > 23 || minute > 59 || second > 59 {
        return None;
    }
    let mut rest = &s[19..];
    let mut frac_ns = 0u64;
    if let Some(r) = rest.strip_prefix('.') {
        let digits = r.bytes().take_while(u8::is_ascii_digit).count();
        if digits == 0 || digits > 9 {
            return None;
        }
        frac_ns = parse_decimal_seconds(&format!("0.{}", &r[..digits]))?;
        rest = &r[digits..];
    }
    let offset_s: i64 = match rest {
        "Z" | "z" => 0,
        _ => {
            let ob = rest.as_bytes();
            if ob.len() != 6 || ob[3] != b':' || !matches!(ob[0], b'+' | b'-') {
                return None;
            }
            let oh: i64 = rest[1..3].parse().ok()?;
            let om: i64 = rest[4..6].parse().ok()?;
            if oh > 23 || om > 59 {
                return None;
            }
            let sign = if ob[0] == b'-' { -1 } else { 1 };
            sign * (oh * 3600 + om * 60)
        }
    };
    let days = days_from_civil(i64::from(year), month, day);
    let secs = days * 86_400 + i64::from(hour) * 3600 + i64::from(minute) * 60 + i64::from(second)
        - offset_s;
    let secs = u64::try_from(secs).ok()?;
    secs.checked_mul(NS_PER_S)?.checked_add(frac_ns)
}

fn days_in_month(year: u32, month: u32) -> u32 {
    match month {
        4 | 6 | 9 | 11 => 30,
        2 if (year.is_multiple_of(4) && !year.is_multiple_of(100)) || year.is_multiple_of(400) => {
            29
        }
        2 => 28,
        _ => 31,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scenario_names_round_trip_and_unknown_names_are_refused() {
        for s in Scenario::ALL {
            assert_eq!(s.name().parse::<Scenario>().unwrap(), s);
        }
        assert_eq!(
            "  Corridor ".parse::<Scenario>().unwrap(),
            Scenario::Corridor
        );
        assert_eq!(
            "office".parse::<Scenario>().unwrap_err(),
            UnknownScenario("office".into())
        );
    }

    #[test]
    fn invalid_durations_and_settings_are_refused() {
        let ok = SimConfig::default();
        assert_eq!(ok.validate(), Ok(()));
        for secs in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e6] {
            let c = SimConfig {
                seconds: secs,
                ..ok.clone()
            };
            assert!(
                matches!(c.validate(), Err(ConfigError::Seconds(_))),
                "{secs}"
            );
        }
        assert!(matches!(
            SimConfig {
                rpm: 200.0,
                ..ok.clone()
            }
            .validate(),
            Err(ConfigError::Rpm(_))
        ));
        assert!(matches!(
            SimConfig {
                rpm: 1300.0,
                ..ok.clone()
            }
            .validate(),
            Err(ConfigError::Rpm(_))
        ));
        assert!(matches!(
            SimConfig {
                packet_loss: 1.0,
                ..ok.clone()
            }
            .validate(),
            Err(ConfigError::PacketLoss(_))
        ));
        assert!(matches!(
            SimConfig {
                range_noise_m: -0.1,
                ..ok.clone()
            }
            .validate(),
            Err(ConfigError::RangeNoise(_))
        ));
        assert!(matches!(
            SimConfig {
                start_time_ns: Some(0),
                ..ok
            }
            .validate(),
            Err(ConfigError::StartTime(0))
        ));
    }

    #[test]
    fn invalid_variations_of_a_run_are_refused() {
        let ok = SimConfig {
            seconds: 10.0,
            path_seed: Some(3),
            reverse: true,
            start_fraction: 0.5,
            kidnap_s: Some(9.75),
            unit_seed: Some(2),
            change: 1.0,
            movers: Some(MAX_MOVERS),
            ..SimConfig::default()
        };
        assert_eq!(ok.validate(), Ok(()));
        for f in [1.0, -0.1, f64::NAN] {
            let c = SimConfig {
                start_fraction: f,
                ..ok.clone()
            };
            assert!(
                matches!(c.validate(), Err(ConfigError::StartFraction(_))),
                "{f}"
            );
        }
        for t in [0.0, -2.0, 9.8, 10.0, f64::NAN, f64::INFINITY] {
            let c = SimConfig {
                kidnap_s: Some(t),
                ..ok.clone()
            };
            assert!(
                matches!(c.validate(), Err(ConfigError::KidnapTime { .. })),
                "{t}"
            );
        }
        for f in [1.01, -0.5, f64::NAN] {
            let c = SimConfig {
                change: f,
                ..ok.clone()
            };
            assert!(matches!(c.validate(), Err(ConfigError::Change(_))), "{f}");
        }
        let c = SimConfig {
            movers: Some(MAX_MOVERS + 1),
            ..ok
        };
        assert_eq!(c.validate(), Err(ConfigError::Movers(MAX_MOVERS + 1)));
        assert!(!SimConfig::default().is_variant());
    }

    #[test]
    fn seeded_start_times_are_fixed_by_the_seed_and_not_whole_seconds() {
        let a = SimConfig {
            seed: 7,
            ..SimConfig::default()
        };
        assert_eq!(a.start_time_ns(), a.clone().start_time_ns());
        let b = SimConfig {
            seed: 8,
            ..SimConfig::default()
        };
        assert_ne!(a.start_time_ns(), b.start_time_ns());
        let t = a.start_time_ns();
        assert!(
            (SEEDED_EPOCH_S * NS_PER_S..(SEEDED_EPOCH_S + SEEDED_SPAN_S + 1) * NS_PER_S)
                .contains(&t)
        );
        let explicit = SimConfig {
            start_time_ns: Some(42 * NS_PER_S),
            ..a
        };
        assert_eq!(explicit.start_time_ns(), 42 * NS_PER_S);
    }

    #[test]
    fn start_times_parse_as_unix_seconds_or_rfc3339() {
        assert_eq!(
            parse_start_time("1700000000").unwrap(),
            1_700_000_000 * NS_PER_S
        );
        assert_eq!(
            parse_start_time("1700000000.25").unwrap(),
            1_700_000_000_250_000_000
        );
        assert_eq!(
            parse_start_time("1700000000.000000001").unwrap(),
            1_700_000_000_000_000_001
        );
        // 2023-11-14T22:13:20Z is Unix 1_700_000_000.
        assert_eq!(
            parse_start_time("2023-11-14T22:13:20Z").unwrap(),
            1_700_000_000 * NS_PER_S
        );
        assert_eq!(
            parse_start_time("2023-11-15T00:13:20.5+02:00").unwrap(),
            1_700_000_000_500_000_000
        );
        assert_eq!(
            parse_start_time("2023-11-14T21:13:20-01:00").unwrap(),
            1_700_000_000 * NS_PER_S
        );
        for bad in [
            "",
            "yesterday",
            "-5",
            "1.2.3",
            "2023-02-30T00:00:00Z",
            "2023-11-14T25:00:00Z",
            "2023-11-14T22:13:20",
        ] {
            assert!(parse_start_time(bad).is_err(), "{bad}");
        }
    }
}

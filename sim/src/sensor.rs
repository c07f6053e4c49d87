//! The virtual VLP-16: its own laser and timing tables, written from the manual (63-9243) and
//! deliberately not taken from the decoder, so that each checks the other; the beam (origin,
//! direction, footprint); echoes, detection and the reflectivity model; return selection.
//!
//! Model, stated once:
//! - Laser `l` with elevation ω at rotor azimuth α (clockwise seen from above, 0 = +x) points
//!   along (cos ω cos α, −cos ω sin α, sin ω) from (0, 0, 41.91 mm × tan(−ω)) in the sensor
//!   frame; the measured distance is along that ray from that origin.
//! - A ray may produce up to three echoes: a surface with coverage c < 1 (fence, foliage) or a
//!   pole narrower than the beam footprint returns a fraction c of the remaining energy and
//!   lets the rest through.
//! - Diffuse echo: reported reflectivity round(100·ρ·cos α·gain_l·c + N(0, σ_r)), clamped to
//!   0..=100 (the sensor compensates range, not incidence). Retro-reflective echo:
//!   round(value·(0.85 + 0.15·cos α) + N(0, 2σ_r)), clamped to 101..=255.
//! - Detection: a diffuse echo is reported only if ρ·cos α·c·(100 m / R)² ≥ 0.25, i.e. a white
//!   wall is seen to 100 m, a 10 % one to 63 m, grazing floor returns fade with range. Retro
//!   echoes are always detected. Nothing beyond 100 m or nearer than 0.5 m.
//! - Strongest = the echo with the largest expected reflectivity; last = the farthest. Dual:
//!   the last, and the strongest, or the second strongest when the strongest is the last.
//! - Range: true range + N(0, σ), rounded to 2 mm.

use glint_driver::wire::ReturnMode;
use nalgebra::Vector3;
use rand::Rng;
use rand_distr::StandardNormal;

use crate::config::{seeded_rng, SimConfig, Stream};
use crate::scene::{Reflect, Scene};

type V3 = Vector3<f64>;

/// Lasers per firing sequence.
pub const LASERS: usize = 16;
/// Time between consecutive lasers of a sequence, ns (manual: 2.304 µs).
pub const LASER_INTERVAL_NS: u64 = 2_304;
/// One firing sequence of all 16 lasers plus recharge, ns (manual: 55.296 µs).
pub const SEQUENCE_NS: u64 = 55_296;
/// Firing sequences per data block.
pub const SEQUENCES_PER_BLOCK: usize = 2;
/// One data block, ns.
pub const BLOCK_NS: u64 = SEQUENCES_PER_BLOCK as u64 * SEQUENCE_NS;
/// Elevation of each laser index in firing order, degrees (manual table 9-1).
pub const ELEVATION_DEG: [f64; LASERS] = [
    -15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0,
];
/// Distance from the spin axis to the beam-steering optics: each beam's origin sits
/// `BEAM_ORIGIN_RADIUS_M × tan(−ω)` above the sensor origin (the manual's per-laser offsets,
/// 11.2 mm at −15°, are this rounded).
pub const BEAM_ORIGIN_RADIUS_M: f64 = 0.041_91;
/// Distance unit on the wire, m.
pub const DISTANCE_UNIT_M: f64 = 0.002;
/// Farthest reported return, m.
pub const MAX_RANGE_M: f64 = 100.0;
/// Nearest reported return, m (the window in front of the optics; not in the manual).
pub const MIN_RANGE_M: f64 = 0.5;
/// Product id of a VLP-16.
pub const PRODUCT_ID: u8 = 0x22;
/// Echoes followed through partial surfaces per ray.
pub const MAX_ECHOES: usize = 3;
/// Width of the beam at the window, m, and its divergence, rad (VLP-16 datasheet: 12.7 mm,
/// 3 mrad horizontally): the footprint a thin pole is compared with.
pub const BEAM_EXIT_WIDTH_M: f64 = 0.0127;
/// See [`BEAM_EXIT_WIDTH_M`].
pub const BEAM_DIVERGENCE_RAD: f64 = 0.003;
/// Detection threshold on ρ·cos α·coverage·(100 m / R)².
pub const DETECTION_THRESHOLD: f64 = 0.25;

/// Time of record `record` (0..32) of firing block `block` after the packet's first firing, ns.
pub const fn record_offset_ns(block: usize, record: usize) -> u64 {
    block as u64 * BLOCK_NS
        + (record / LASERS) as u64 * SEQUENCE_NS
        + (record % LASERS) as u64 * LASER_INTERVAL_NS
}

/// Height of laser `laser`'s beam origin above the sensor origin, m.
pub fn vertical_offset_m(laser: usize) -> f64 {
    BEAM_ORIGIN_RADIUS_M * (-ELEVATION_DEG[laser].to_radians()).tan()
}

/// Unit direction of laser `laser` at azimuth `azimuth` (rad, clockwise from +x), sensor frame.
pub fn beam_direction(laser: usize, azimuth: f64) -> [f64; 3] {
    let w = ELEVATION_DEG[laser].to_radians();
    [w.cos() * azimuth.cos(), -w.cos() * azimuth.sin(), w.sin()]
}

/// One echo of a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Echo {
    /// True distance from the beam origin, m.
    pub range: f64,
    /// Object hit (see [`Scene::cast`]).
    pub id: u32,
    /// cos of the incidence angle.
    pub cos_incidence: f64,
    /// The surface's reflectivity there.
    pub reflect: Reflect,
    /// Fraction of the beam's energy this echo carries.
    pub weight: f64,
    /// The model's reflectivity before noise and rounding (what "strongest" compares).
    pub strength: f64,
    /// Whether the detection model reports it.
    pub detected: bool,
}

/// Which echoes a firing reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    /// No detected echo.
    Nothing,
    /// One echo (single-return modes, or dual with one echo): index into the echoes.
    One(usize),
    /// Dual return with two different echoes: (last, strongest-or-second).
    Two {
        /// The last (farthest) echo.
        last: usize,
        /// The strongest, or the second strongest if the strongest is the last.
        strong: usize,
    },
}

/// The unit's fixed properties (gains, start angle) and the run's settings.
#[derive(Debug, Clone)]
pub struct Vlp16 {
    rpm: f64,
    return_mode: ReturnMode,
    start_azimuth: f64,
    gains: [f64; LASERS],
    range_sigma: f64,
    reflectivity_sigma: f64,
    cos_el: [f64; LASERS],
    sin_el: [f64; LASERS],
    offset: [f64; LASERS],
}

impl Vlp16 {
    /// The unit for a run: gains and start angle from the unit seed (the run's seed unless
    /// another unit is asked for); noise per the config.
    pub fn new(config: &SimConfig) -> Vlp16 {
        let mut rng = seeded_rng(config.sensor_unit_seed(), Stream::SensorUnit);
        let start_azimuth = rng.random_range(0.0..std::f64::consts::TAU);
        let mut gains = [1.0; LASERS];
        if config.laser_gain_bias > 0.0 {
            for g in &mut gains {
                *g = 1.0 + rng.random_range(-config.laser_gain_bias..=config.laser_gain_bias);
            }
        }
        let mut cos_el = [0.0; LASERS];
        let mut sin_el = [0.0; LASERS];
        let mut offset = [0.0; LASERS];
        for l in 0..LASERS {
            let w = ELEVATION_DEG[l].to_radians();
            cos_el[l] = w.cos();
            sin_el[l] = w.sin();
            offset[l] = vertical_offset_m(l);
        }
        Vlp16 {
            rpm: config.rpm,
            return_mode: config.return_mode,
            start_azimuth,
            gains,
            range_sigma: if config.noise {
                config.range_noise_m
            } else {
                0.0
            },
            reflectivity_sigma: if config.noise {
                config.reflectivity_noise
            } else {
                0.0
            },
            cos_el,
            sin_el,
            offset,
        }
    }

    /// Rotor speed, rpm.
    pub fn rpm(&self) -> f64 {
        self.rpm
    }

    /// The return mode.
    pub fn return_mode(&self) -> ReturnMode {
        self.return_mode
    }

    /// Per-laser reflectivity gain (1 ± the configured bias).
    pub fn laser_gains(&self) -> [f64; LASERS] {
        self.gains
    }

    /// Rotor azimuth at the first firing, rad clockwise from +x.
    pub fn start_azimuth(&self) -> f64 {
        self.start_azimuth
    }

    /// Range noise σ in effect, m.
    pub fn range_sigma(&self) -> f64 {
        self.range_sigma
    }

    /// Reflectivity noise σ in effect, counts.
    pub fn reflectivity_sigma(&self) -> f64 {
        self.reflectivity_sigma
    }

    /// Rotor angular speed, rad/s.
    pub fn angular_speed(&self) -> f64 {
        self.rpm / 60.0 * std::f64::consts::TAU
    }

    /// Unwrapped rotor azimuth at `t` s after the first firing, rad (clockwise from +x).
    #[inline]
    pub fn azimuth_unwrapped(&self, t: f64) -> f64 {
        self.start_azimuth + self.angular_speed() * t
    }

    /// The block azimuth field for a block whose first firing is at `t`: hundredths of a
    /// degree, rounded, modulo 36000.
    pub fn azimuth_field(&self, t: f64) -> u16 {
        let deg = self.azimuth_unwrapped(t).to_degrees().rem_euclid(360.0);
        ((deg * 100.0).round() as u64 % 36_000) as u16
    }

    /// Beam origin and direction of `laser` at azimuth `azimuth`, sensor frame.
    #[inline]
    pub fn beam(&self, laser: usize, azimuth: f64) -> (V3, V3) {
        let (s, c) = azimuth.sin_cos();
        self.beam_sin_cos(laser, s, c)
    }

    /// [`Vlp16::beam`] from the azimuth's sine and cosine.
    #[inline]
    pub fn beam_sin_cos(&self, laser: usize, sin_azimuth: f64, cos_azimuth: f64) -> (V3, V3) {
        (
            V3::new(0.0, 0.0, self.offset[laser]),
            V3::new(
                self.cos_el[laser] * cos_azimuth,
                -self.cos_el[laser] * sin_azimuth,
                self.sin_el[laser],
            ),
        )
    }

    /// Follows the ray `origin + t·dir` (scene frame) through partial surfaces, writing up to
    /// [`MAX_ECHOES`] echoes for `laser` at time `time_s`. Returns how many.
    #[inline]
    pub fn echoes(
        &self,
        scene: &Scene,
        laser: usize,
        origin: [f64; 3],
        dir: [f64; 3],
        time_s: f64,
        out: &mut [Echo; MAX_ECHOES],
    ) -> usize {
        let mut exclude = [u32::MAX; MAX_ECHOES];
        let mut remaining = 1.0;
        let mut t_min = MIN_RANGE_M;
        let mut n = 0;
        while n < MAX_ECHOES {
            let Some(hit) = scene.cast(origin, dir, t_min, MAX_RANGE_M, time_s, &exclude[..n])
            else {
                break;
            };
            let s = scene.sample(&hit, origin, dir, time_s);
            let mut coverage = s.coverage;
            if let Some(r) = s.pole_radius {
                coverage *= (2.0 * r / (BEAM_EXIT_WIDTH_M + BEAM_DIVERGENCE_RAD * hit.t)).min(1.0);
            }
            let weight = remaining * coverage;
            let (strength, detected) = match s.reflect {
                Reflect::Diffuse(rho) => {
                    let e = rho * s.cos_incidence * weight;
                    let power = e * (MAX_RANGE_M / hit.t).powi(2);
                    (100.0 * e * self.gains[laser], power >= DETECTION_THRESHOLD)
                }
                Reflect::Retro(value) => (retro_mean(value, s.cos_incidence), true),
            };
            out[n] = Echo {
                range: hit.t,
                id: hit.id,
                cos_incidence: s.cos_incidence,
                reflect: s.reflect,
                weight,
                strength,
                detected,
            };
            exclude[n] = hit.id;
            n += 1;
            remaining *= 1.0 - coverage;
            if remaining < 0.05 {
                break;
            }
            t_min = hit.t;
        }
        n
    }

    /// Which echoes the return mode reports.
    pub fn select(&self, echoes: &[Echo]) -> Selection {
        let detected = || echoes.iter().enumerate().filter(|(_, e)| e.detected);
        let Some(last) = detected()
            .max_by(|a, b| a.1.range.total_cmp(&b.1.range))
            .map(|(i, _)| i)
        else {
            return Selection::Nothing;
        };
        let strongest_except = |skip: Option<usize>| {
            detected()
                .filter(|(i, _)| Some(*i) != skip)
                .max_by(|a, b| {
                    a.1.strength
                        .total_cmp(&b.1.strength)
                        .then(b.1.range.total_cmp(&a.1.range))
                })
                .map(|(i, _)| i)
        };
        let strongest = strongest_except(None).unwrap_or(last);
        match self.return_mode {
            ReturnMode::Strongest => Selection::One(strongest),
            ReturnMode::Last => Selection::One(last),
            ReturnMode::Dual => {
                let strong = if strongest == last {
                    strongest_except(Some(last))
                } else {
                    Some(strongest)
                };
                match strong {
                    Some(strong) => Selection::Two { last, strong },
                    None => Selection::One(last),
                }
            }
        }
    }

    /// What the sensor reports for an echo: distance in 2 mm units (never 0 for a detected
    /// echo) and reflectivity.
    pub fn measure(&self, echo: &Echo, rng: &mut impl Rng) -> (u16, u8) {
        let mut range = echo.range;
        if self.range_sigma > 0.0 {
            range += self.range_sigma * rng.sample::<f64, _>(StandardNormal);
        }
        let units =
            round_positive((range / DISTANCE_UNIT_M).clamp(1.0, f64::from(u16::MAX))) as u16;
        let reflectivity = match echo.reflect {
            Reflect::Diffuse(_) => {
                let noise = if self.reflectivity_sigma > 0.0 {
                    self.reflectivity_sigma * rng.sample::<f64, _>(StandardNormal)
                } else {
                    0.0
                };
                round_positive((echo.strength + noise).clamp(0.0, 100.0)) as u8
            }
            Reflect::Retro(_) => {
                let noise = if self.reflectivity_sigma > 0.0 {
                    2.0 * self.reflectivity_sigma * rng.sample::<f64, _>(StandardNormal)
                } else {
                    0.0
                };
                round_positive((echo.strength + noise).clamp(101.0, 255.0)) as u8
            }
        };
        (units, reflectivity)
    }
}

/// Rounds a non-negative value half away from zero, as `f64::round` does there, without the
/// library call `round` compiles to on baseline x86-64.
#[inline]
fn round_positive(x: f64) -> u64 {
    (x + 0.5) as u64
}

/// Mean reported value of retro-reflective sheeting of nominal `value` at incidence cos α:
/// weakly angle dependent.
pub fn retro_mean(value: u8, cos_incidence: f64) -> f64 {
    f64::from(value) * (0.85 + 0.15 * cos_incidence)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Material, Pattern, SceneBuilder, Shape};

    #[test]
    fn tables_follow_the_manual() {
        // Offsets: 11.2 mm at −15°, −0.7 mm at +1° (manual table 9-1, rounded to 0.1 mm).
        let manual_mm = [
            11.2, -0.7, 9.7, -2.2, 8.1, -3.7, 6.6, -5.1, 5.1, -6.6, 3.7, -8.1, 2.2, -9.7, 0.7,
            -11.2,
        ];
        for (l, mm) in manual_mm.iter().enumerate() {
            assert!(
                (vertical_offset_m(l) * 1000.0 - mm).abs() < 0.06,
                "laser {l}"
            );
        }
        // Record 31 of block 11: the last firing of a packet.
        assert_eq!(record_offset_ns(11, 31), 11 * 110_592 + 55_296 + 15 * 2_304);
        assert_eq!(record_offset_ns(1, 21), 110_592 + 55_296 + 5 * 2_304);
        let d = beam_direction(0, std::f64::consts::FRAC_PI_2);
        // Azimuth 90° clockwise from +x is −y (to the right).
        assert!(d[0].abs() < 1e-12 && d[1] < 0.0 && d[2] < 0.0);
    }

    #[test]
    fn azimuth_field_rounds_and_wraps() {
        let c = SimConfig {
            seed: 5,
            ..SimConfig::default()
        };
        let s = Vlp16::new(&c);
        let t_wrap = (std::f64::consts::TAU - s.start_azimuth()) / s.angular_speed();
        assert_eq!(s.azimuth_field(t_wrap), 0);
        assert_eq!(
            s.azimuth_field(t_wrap - 1e-6),
            0,
            "35999.996 rounds to 36000 → 0"
        );
        assert_eq!(
            s.azimuth_field(t_wrap + 0.01),
            3600,
            "0.1 turn (10 ms at 600 rpm) later is 36°"
        );
    }

    fn plane_scene(coverage: f64) -> Scene {
        let mut b = SceneBuilder::new();
        let fence = b
            .material(Material::diffuse("fence", 0.5).with_coverage(coverage))
            .unwrap();
        let wall = b.material(Material::diffuse("wall", 0.8)).unwrap();
        let retro = b
            .material(Material::new("retro", Pattern::Retro { value: 200 }))
            .unwrap();
        b.add(
            Shape::wall([5.0, 5.0], [5.0, -5.0], -5.0, 5.0),
            fence,
            "fence",
        )
        .unwrap();
        b.add(
            Shape::wall([10.0, 5.0], [10.0, -5.0], -5.0, 5.0),
            wall,
            "wall",
        )
        .unwrap();
        b.add(
            Shape::wall([3.0, 0.5], [3.0, 0.4], -0.1, 0.1),
            retro,
            "marker",
        )
        .unwrap();
        b.build()
    }

    #[test]
    fn partial_surfaces_give_two_echoes_and_dual_reports_both() {
        let scene = plane_scene(0.3);
        let config = SimConfig {
            return_mode: ReturnMode::Dual,
            noise: false,
            laser_gain_bias: 0.0,
            ..SimConfig::default()
        };
        let s = Vlp16::new(&config);
        let mut out = [Echo {
            range: 0.0,
            id: 0,
            cos_incidence: 0.0,
            reflect: Reflect::Diffuse(0.0),
            weight: 0.0,
            strength: 0.0,
            detected: false,
        }; MAX_ECHOES];
        let n = s.echoes(&scene, 1, [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], 0.0, &mut out);
        assert_eq!(n, 2);
        assert!((out[0].range - 5.0).abs() < 1e-12 && (out[1].range - 10.0).abs() < 1e-12);
        assert!((out[0].strength - 15.0).abs() < 1e-9, "0.5 × 0.3 × 100");
        assert!((out[1].strength - 56.0).abs() < 1e-9, "0.8 × 0.7 × 100");
        // The wall behind is both the last and the strongest: dual reports it and the fence.
        assert_eq!(s.select(&out[..n]), Selection::Two { last: 1, strong: 0 });
        let strongest = Vlp16::new(&SimConfig {
            return_mode: ReturnMode::Strongest,
            ..config.clone()
        });
        assert_eq!(strongest.select(&out[..n]), Selection::One(1));
        let last = Vlp16::new(&SimConfig {
            return_mode: ReturnMode::Last,
            ..config
        });
        assert_eq!(last.select(&out[..n]), Selection::One(1));
        // Through the retro marker: strongest is the marker, last the wall.
        let n = s.echoes(&scene, 1, [0.0, 0.45, 0.0], [1.0, 0.0, 0.0], 0.0, &mut out);
        assert_eq!(n, 1, "the marker is opaque");
        assert_eq!(out[0].reflect, Reflect::Retro(200));
        let (units, refl) = s.measure(&out[0], &mut seeded_rng(1, Stream::Noise));
        assert_eq!((units, refl), (1500, 200));
    }

    #[test]
    fn dark_grazing_returns_fade_with_range() {
        let mut b = SceneBuilder::new();
        let floor = b.material(Material::diffuse("floor", 0.3)).unwrap();
        b.add(
            Shape::horizontal(-200.0, -200.0, 200.0, 200.0, 0.0),
            floor,
            "floor",
        )
        .unwrap();
        let scene = b.build();
        let s = Vlp16::new(&SimConfig::default());
        let mut out = [Echo {
            range: 0.0,
            id: 0,
            cos_incidence: 0.0,
            reflect: Reflect::Diffuse(0.0),
            weight: 0.0,
            strength: 0.0,
            detected: false,
        }; MAX_ECHOES];
        let o = [0.0, 0.0, 0.8];
        let detected = |laser: usize, out: &mut [Echo; MAX_ECHOES]| {
            let (_, d) = s.beam(laser, 0.0);
            let n = s.echoes(&scene, laser, o, d.into(), 0.0, out);
            n == 1 && out[0].detected
        };
        // −15° reaches the floor at 3 m: seen. −1° at 46 m with cos α = 0.017: lost.
        assert!(detected(0, &mut out));
        assert!(!detected(14, &mut out));
    }
}

//! The simulator's packets, decoded by the driver, reproduce the simulator's own hit points:
//! same laser and ring, firing time within the µs truncation of the packet timestamp, position
//! within the 2 mm quantisation and the 0.01° rounding of the block azimuth (noise off), and
//! residuals with the configured σ (noise on). The decoder's tables and the simulator's are
//! written separately, so this checks both. Also: dual return, the hour wrap of the µs
//! counter, and the sweep cut against the ground-truth sweep ends.

mod common;

use std::collections::HashMap;

use glint_driver::sweep::{SweepAssembler, SweepConfig};
use glint_driver::wire::DataPacket;
use glint_driver::{Decoder, Model, Point, ReturnKind};
use glint_sim::{ReturnMode, Scenario, SimConfig, Simulation, TruthKind, TruthReturn};

/// Half the 0.01° resolution of a block azimuth, plus what the decoder's interpolation can add:
/// the step between two rounded azimuths is off by up to 0.01°, applied over at most
/// (55.296 + 15 × 2.304) / 110.592 of a block.
const AZIMUTH_BOUND_DEG: f64 = 0.005 + 0.01 * (55.296 + 15.0 * 2.304) / 110.592 + 1e-4;

/// Truths of one laser sorted by time, to find the one a decoded point belongs to.
fn index(truth: &[TruthReturn]) -> HashMap<(u8, TruthKindKey), Vec<TruthReturn>> {
    let mut by: HashMap<(u8, TruthKindKey), Vec<TruthReturn>> = HashMap::new();
    for t in truth {
        by.entry((t.laser, key(t.kind))).or_default().push(*t);
    }
    for v in by.values_mut() {
        v.sort_by_key(|t| t.time_ns);
    }
    by
}

type TruthKindKey = u8;
fn key(kind: TruthKind) -> TruthKindKey {
    match kind {
        TruthKind::Strongest => 0,
        TruthKind::Last => 1,
        TruthKind::Both => 2,
    }
}
fn decoded_key(kind: ReturnKind) -> TruthKindKey {
    match kind {
        ReturnKind::Strongest => 0,
        ReturnKind::Last => 1,
        ReturnKind::Both => 2,
    }
}

/// The truth a decoded point comes from: same laser and kind, fired at most 1 µs after the
/// decoded time (the packet timestamp is truncated to whole µs).
fn find<'a>(by: &'a HashMap<(u8, TruthKindKey), Vec<TruthReturn>>, p: &Point) -> &'a TruthReturn {
    let list = by
        .get(&(p.laser, decoded_key(p.return_kind)))
        .expect("truth for this laser and kind");
    let i = list.partition_point(|t| t.time_ns < p.time_ns);
    let t = list
        .get(i)
        .unwrap_or_else(|| panic!("no truth at or after {} for laser {}", p.time_ns, p.laser));
    assert!(
        t.time_ns - p.time_ns < 1000,
        "decoded time {} vs truth {} (laser {})",
        p.time_ns,
        t.time_ns,
        p.laser
    );
    t
}

struct Residuals {
    radial: Vec<f64>,
    tangential_excess: f64,
    max_radial: f64,
    max_azimuth_deg: f64,
    max_vertical: f64,
}

/// Compares every decoded point with its truth. Returns the residuals along the ray (decoded
/// range minus true range).
fn compare(points: &[Point], truth: &[TruthReturn], quantised_only: bool) -> Residuals {
    let by = index(truth);
    let mut r = Residuals {
        radial: Vec::new(),
        tangential_excess: 0.0,
        max_radial: 0.0,
        max_azimuth_deg: 0.0,
        max_vertical: 0.0,
    };
    for p in points {
        let t = find(&by, p);
        assert_eq!(
            p.ring,
            common::ring_of(p.laser),
            "ring of laser {}",
            p.laser
        );
        assert_eq!(usize::from(t.record) % 16, usize::from(p.laser));
        // The wire carries what the truth says was written.
        assert!((f64::from(p.range) - f64::from(t.distance) * 0.002).abs() < 1e-4);
        let radial = f64::from(p.range) - t.range_m;
        r.radial.push(radial);
        r.max_radial = r.max_radial.max(radial.abs());
        // Azimuth: the decoder's interpolation against the rotor's exact angle.
        let mut da = (f64::from(p.azimuth) - t.azimuth).to_degrees();
        if da > 180.0 {
            da -= 360.0;
        } else if da < -180.0 {
            da += 360.0;
        }
        r.max_azimuth_deg = r.max_azimuth_deg.max(da.abs());
        // Position: the difference is the range error along the ray plus the azimuth error
        // across it; nothing else (elevations and offsets agree within 0.05 mm).
        let dp = [
            f64::from(p.x) - t.point[0],
            f64::from(p.y) - t.point[1],
            f64::from(p.z) - t.point[2],
        ];
        let horizontal = (t.range_m
            * (glint_sim::sensor::ELEVATION_DEG[usize::from(p.laser)])
                .to_radians()
                .cos())
        .abs();
        let allowed = radial.abs() + horizontal * da.abs().to_radians() + 1e-4;
        let err = (dp[0] * dp[0] + dp[1] * dp[1] + dp[2] * dp[2]).sqrt();
        r.tangential_excess = r.tangential_excess.max(err - allowed);
        r.max_vertical = r.max_vertical.max(
            (dp[2]
                - radial
                    * glint_sim::sensor::ELEVATION_DEG[usize::from(p.laser)]
                        .to_radians()
                        .sin())
            .abs(),
        );
        if quantised_only {
            // Half the 2 mm unit, plus the decoder's f32 output (a few µm at 100 m).
            assert!(
                radial.abs() <= 0.001 + 1e-5,
                "range residual {radial} at laser {} (noise off: quantisation only)",
                p.laser
            );
        }
    }
    r
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

#[test]
fn noise_off_decoded_points_match_the_truth_within_quantisation_and_timing_rounding() {
    let config = SimConfig {
        scenario: Scenario::Warehouse,
        seed: 3,
        seconds: 2.0,
        noise: false,
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(&config).unwrap();
    let (pcap, truth) = common::capture(&mut sim);
    let decoded = common::decode(pcap);
    assert_eq!(decoded.data_packets as u64, sim.stats().data_packets);
    assert_eq!(
        decoded.points.len(),
        truth.len(),
        "every return decoded, no extra points"
    );
    assert!(
        truth.len() > 500_000,
        "{} returns in 2 s of warehouse",
        truth.len()
    );
    let r = compare(&decoded.points, &truth, true);
    assert!(
        r.max_azimuth_deg <= AZIMUTH_BOUND_DEG,
        "azimuth error {}° > {AZIMUTH_BOUND_DEG}°",
        r.max_azimuth_deg
    );
    assert!(
        r.tangential_excess <= 1e-4,
        "position error beyond range and azimuth rounding: {} m",
        r.tangential_excess
    );
    assert!(
        r.max_vertical < 1e-4,
        "vertical error beyond the range error: {} m",
        r.max_vertical
    );
    let (mean, std) = mean_std(&r.radial);
    // Rounding to 2 mm: uniform in ±1 mm, σ = 2 mm / √12.
    assert!(
        mean.abs() < 2e-5 && (std - 0.002 / 12f64.sqrt()).abs() < 2e-5,
        "{mean} {std}"
    );
    println!(
        "noise off: {} points; range residual max {:.3} mm, mean {:.4} mm, σ {:.4} mm; azimuth error max {:.4}°; vertical beyond range error {:.4} mm",
        truth.len(),
        r.max_radial * 1e3,
        mean * 1e3,
        std * 1e3,
        r.max_azimuth_deg,
        r.max_vertical * 1e3
    );
}

#[test]
fn noise_on_residuals_have_the_configured_sigma() {
    let config = SimConfig {
        scenario: Scenario::Yard,
        seed: 5,
        seconds: 1.0,
        range_noise_m: 0.015,
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(&config).unwrap();
    let (pcap, truth) = common::capture(&mut sim);
    let decoded = common::decode(pcap);
    assert_eq!(decoded.points.len(), truth.len());
    let r = compare(&decoded.points, &truth, false);
    let (mean, std) = mean_std(&r.radial);
    let expected = (0.015f64.powi(2) + 0.002f64.powi(2) / 12.0).sqrt();
    assert!(mean.abs() < 3e-4, "range residual mean {mean}");
    assert!(
        (std / expected - 1.0).abs() < 0.03,
        "range residual σ {std}, expected {expected}"
    );
    assert!(r.tangential_excess <= 1e-4);
    // Reflectivity noise: reported minus the model's mean, away from the clamps.
    let by = index(&truth);
    let refl: Vec<f64> = decoded
        .points
        .iter()
        .filter_map(|p| {
            let t = find(&by, p);
            (!t.retro && t.expected_reflectivity > 5.0 && t.expected_reflectivity < 95.0)
                .then(|| f64::from(p.reflectivity) - t.expected_reflectivity)
        })
        .collect();
    let (rm, rs) = mean_std(&refl);
    let expected_r = (1.0f64 + 1.0 / 12.0).sqrt();
    assert!(
        rm.abs() < 0.05 && (rs / expected_r - 1.0).abs() < 0.05,
        "reflectivity residual {rm} ± {rs}"
    );
    println!(
        "noise on: {} points; range residual mean {:.3} mm, σ {:.3} mm (expected {:.3}); reflectivity residual mean {rm:.3}, σ {rs:.3} (expected {expected_r:.3})",
        truth.len(),
        mean * 1e3,
        std * 1e3,
        expected * 1e3
    );
}

#[test]
fn dual_return_pairs_decode_to_the_same_echoes() {
    // The yard's chain-link fence and foliage let part of the beam through: two echoes.
    let config = SimConfig {
        scenario: Scenario::Yard,
        seed: 2,
        seconds: 0.6,
        noise: false,
        return_mode: ReturnMode::Dual,
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(&config).unwrap();
    let (pcap, truth) = common::capture(&mut sim);
    let decoded = common::decode(pcap);
    assert_eq!(decoded.points.len(), truth.len());
    let two = truth.iter().filter(|t| t.kind != TruthKind::Both).count();
    assert!(two > 100, "only {two} returns from two-echo firings");
    let r = compare(&decoded.points, &truth, true);
    assert!(r.max_azimuth_deg <= AZIMUTH_BOUND_DEG);
    // The last echo is never nearer than the strongest of the same firing.
    let mut by_firing: HashMap<(u64, u8), Vec<&TruthReturn>> = HashMap::new();
    for t in &truth {
        by_firing.entry((t.time_ns, t.laser)).or_default().push(t);
    }
    for v in by_firing.values() {
        if let [a, b] = v.as_slice() {
            let (last, strong) = if a.kind == TruthKind::Last {
                (a, b)
            } else {
                (b, a)
            };
            assert!(last.range_m > strong.range_m);
        }
    }
}

#[test]
fn timestamps_survive_the_top_of_the_hour() {
    // Start 0.4 s before 2024-03-01T13:00:00Z: the µs counter wraps during the run.
    let top = 1_709_298_000u64 * 1_000_000_000;
    let config = SimConfig {
        scenario: Scenario::Corridor,
        seconds: 1.0,
        noise: false,
        start_time_ns: Some(top - 400_000_000),
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(&config).unwrap();
    let (pcap, truth) = common::capture(&mut sim);
    let decoded = common::decode(pcap);
    assert_eq!(decoded.points.len(), truth.len());
    compare(&decoded.points, &truth, true);
    assert!(
        decoded.points.iter().any(|p| p.time_ns < top)
            && decoded.points.iter().any(|p| p.time_ns > top + 100_000_000)
    );
    // Packet times advance by exactly one packet (to the µs) across the wrap.
    for w in decoded.packet_times.windows(2) {
        let step = w[1].0 - w[0].0;
        assert!((1_327_000..=1_328_000).contains(&step), "step {step}");
        // And the pcap record (send) time follows the last firing by a few tens of µs.
        let after_first = w[0].1 - w[0].0;
        assert!(
            (1_306_000..1_400_000).contains(&after_first),
            "sent {after_first} ns after the first firing"
        );
    }
}

#[test]
fn driver_sweeps_end_where_the_ground_truth_says() {
    let config = SimConfig {
        scenario: Scenario::Warehouse,
        seed: 1,
        seconds: 1.05,
        noise: false,
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(&config).unwrap();
    let (pcap, _) = common::capture(&mut sim);
    let ends = sim.sweep_end_times();
    // 600 rpm for 1.05 s: 10 or 11 crossings of azimuth 0, plus the cut-off last sweep.
    assert!((11..=12).contains(&ends.len()), "{} sweep ends", ends.len());
    let mut reader =
        glint_driver::pcap::CaptureReader::from_reader(std::io::Cursor::new(pcap)).unwrap();
    let mut clock = glint_driver::clock::Clock::new();
    let mut sweeps = SweepAssembler::new(Decoder::for_model(Model::Vlp16), SweepConfig::default());
    let mut got = Vec::new();
    while let Some(d) = reader.next().unwrap() {
        if d.destination_port == 8308 {
            clock.observe_position(
                &glint_driver::wire::PositionPacket::new_checked(d.payload).unwrap(),
            );
            continue;
        }
        let p = DataPacket::new_checked(d.payload).unwrap();
        let t = clock.packet_time(p.timestamp_us(), d.time_ns);
        sweeps.push(&p, t, d.time_ns);
        got.extend(std::iter::from_fn(|| sweeps.take_sweep()));
    }
    sweeps.finish();
    got.extend(std::iter::from_fn(|| sweeps.take_sweep()));
    assert_eq!(got.len(), ends.len());
    for (s, &end) in got.iter().zip(&ends) {
        // The driver's end is its last return (at most the sweep's last firing, 1 µs of
        // timestamp truncation earlier) and may fall one 55.296 µs sequence either side where
        // a crossing lands within the 0.005° rounding of a block azimuth.
        let diff = s.end_ns as i64 - end as i64;
        assert!(
            (-(55_296 + 34_560 + 1_000)..=55_296).contains(&diff),
            "sweep {} ends {diff} ns from the truth",
            s.index
        );
    }
}

#[test]
fn any_rotation_rate_and_single_return_mode_round_trips() {
    for (rpm, mode) in [
        (300.0, ReturnMode::Last),
        (1200.0, ReturnMode::Strongest),
        (900.0, ReturnMode::Dual),
    ] {
        let config = SimConfig {
            scenario: Scenario::Warehouse,
            seed: 9,
            seconds: 0.3,
            rpm,
            return_mode: mode,
            noise: false,
            ..SimConfig::default()
        };
        let mut sim = Simulation::new(&config).unwrap();
        let (pcap, truth) = common::capture(&mut sim);
        let decoded = common::decode(pcap);
        assert_eq!(decoded.points.len(), truth.len(), "{rpm} rpm {mode:?}");
        let r = compare(&decoded.points, &truth, true);
        // The azimuth step per block scales with the rate; so does its rounding's effect.
        let bound = 0.005 + 0.01 * (55.296 + 15.0 * 2.304) / 110.592 + 1e-4;
        assert!(
            r.max_azimuth_deg <= bound,
            "{rpm} rpm: {}°",
            r.max_azimuth_deg
        );
        if mode == ReturnMode::Last {
            assert!(decoded
                .points
                .iter()
                .all(|p| p.return_kind == ReturnKind::Last));
        }
    }
}

//! The reflectivity on the wire behaves as the model says: on a known plane seen at known
//! incidence angles, diffuse surfaces report 100·ρ·cos α·gain (the sensor compensates range,
//! not angle) with about one count of noise; retro-reflective sheeting reports above 100; dark
//! surfaces at grazing angles and long range give no return. Everything is measured on the
//! decoded points, with the incidence angle computed from the decoded geometry.

mod common;

use glint_sim::scene::{Decal, Material, Pattern, SceneBuilder, Shape};
use glint_sim::trajectory::{Pose, Trajectory};
use glint_sim::{SimConfig, Simulation};

/// The sensor 1 m above the origin looking along +x; a wall at x = 6 m, 80 m wide and 20 m
/// high, grey (ρ 0.5) on y < 0 and white (ρ 0.8) on y > 0, with a retro-reflective panel.
fn wall_run(gain_bias: f64, seconds: f64) -> (Simulation, Vec<glint_driver::Point>) {
    let mut b = SceneBuilder::new();
    let wall = Material::diffuse("grey", 0.5)
        .with_decal(Decal::new([40.0, 0.0], [80.0, 20.0], Pattern::uniform(0.8)))
        .with_decal(Decal::new(
            [28.0, 9.0],
            [29.5, 11.5],
            Pattern::Retro { value: 200 },
        ));
    let m = b.material(wall).unwrap();
    // From (6, −40) to (6, 40): u = y + 40, v = z + 9 (the wall spans z −9…11).
    b.add(
        Shape::wall([6.0, -40.0], [6.0, 40.0], -9.0, 11.0),
        m,
        "wall",
    )
    .unwrap();
    let scene = b.build();
    let pose = Pose::from_xyz_ypr([0.0, 0.0, 1.0], 0.0, 0.0, 0.0);
    let config = SimConfig {
        seconds,
        laser_gain_bias: gain_bias,
        ..SimConfig::default()
    };
    let mut sim =
        Simulation::from_parts(&config, scene, Trajectory::fixed(pose), "a wall".into()).unwrap();
    let (pcap, _) = common::capture(&mut sim);
    let points = common::decode(pcap).points;
    (sim, points)
}

/// cos of the incidence angle of a decoded point on the wall x = 5 m (sensor frame: the wall
/// is 6 m ahead), from the beam origin of its laser.
fn cos_incidence(p: &glint_driver::Point) -> f64 {
    let offset = glint_sim::sensor::vertical_offset_m(usize::from(p.laser));
    let d = [f64::from(p.x), f64::from(p.y), f64::from(p.z) - offset];
    d[0] / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

#[test]
fn diffuse_reflectivity_follows_rho_times_cos_incidence_times_the_laser_gain() {
    let (sim, points) = wall_run(0.03, 0.5);
    let gains = sim.sensor().laser_gains();
    assert!(gains.iter().all(|g| (0.97..=1.03).contains(g)), "{gains:?}");
    assert!(
        gains.iter().any(|&g| (g - gains[0]).abs() > 1e-3),
        "gains differ per laser"
    );
    // Bins of incidence angle; per bin the mean of (reported − model) and its spread.
    let bins = [
        (0.0, 10.0),
        (25.0, 35.0),
        (40.0, 50.0),
        (55.0, 65.0),
        (70.0, 80.0),
    ];
    for (rho, side) in [(0.5, -1.0f32), (0.8, 1.0)] {
        for (lo, hi) in bins {
            let mut residuals = Vec::new();
            let mut reported = Vec::new();
            let mut expected = Vec::new();
            for p in points
                .iter()
                .filter(|p| p.y * side > 0.5 && p.reflectivity <= 100 && (p.x - 6.0).abs() < 0.1)
            {
                let c = cos_incidence(p);
                let angle = c.acos().to_degrees();
                if angle < lo || angle >= hi {
                    continue;
                }
                let model = 100.0 * rho * c * gains[usize::from(p.laser)];
                if !(2.0..98.0).contains(&model) {
                    continue;
                }
                residuals.push(f64::from(p.reflectivity) - model);
                reported.push(f64::from(p.reflectivity));
                expected.push(100.0 * rho * c);
            }
            let n = residuals.len() as f64;
            assert!(n > 200.0, "ρ {rho}, {lo}–{hi}°: only {n} returns");
            let mean = residuals.iter().sum::<f64>() / n;
            let sd = (residuals.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            // Noise σ 1 count plus rounding (1/12): 1.04 counts.
            assert!(
                mean.abs() < 0.15,
                "ρ {rho}, {lo}–{hi}°: mean residual {mean}"
            );
            assert!(
                (0.9..1.2).contains(&sd),
                "ρ {rho}, {lo}–{hi}°: residual σ {sd}"
            );
            // The plain figure the model promises: mean ≈ 100 ρ cos α, within the gain spread.
            let mean_reported = reported.iter().sum::<f64>() / n;
            let mean_expected = expected.iter().sum::<f64>() / n;
            assert!(
                (mean_reported / mean_expected - 1.0).abs() < 0.035,
                "ρ {rho}, {lo}–{hi}°: {mean_reported} vs {mean_expected}"
            );
            println!("ρ {rho} at {lo:>2}–{hi:<2}°: {n:>5} returns, mean {mean_reported:6.2} (100 ρ cos α = {mean_expected:6.2}), residual {mean:+.3} ± {sd:.3}");
        }
    }
}

#[test]
fn without_gain_bias_the_mean_is_exactly_the_model() {
    let (_, points) = wall_run(0.0, 0.3);
    let residuals: Vec<f64> = points
        .iter()
        .filter(|p| p.y < -0.5 && p.reflectivity <= 100)
        .map(|p| (p, 50.0 * cos_incidence(p)))
        .filter(|(_, m)| *m > 3.0)
        .map(|(p, m)| f64::from(p.reflectivity) - m)
        .collect();
    let mean = residuals.iter().sum::<f64>() / residuals.len() as f64;
    assert!(
        residuals.len() > 1000 && mean.abs() < 0.1,
        "{} returns, mean residual {mean}",
        residuals.len()
    );
}

#[test]
fn retro_reflective_markers_report_above_100() {
    let (_, points) = wall_run(0.03, 0.5);
    // The panel: u 28…29.5 → y −12…−10.5; v 9…11.5 → z 0…2.5 in the scene, −1…1.5 in the
    // sensor frame.
    let inside = |p: &&glint_driver::Point, margin: f32| {
        p.y > -12.0 + margin && p.y < -10.5 - margin && p.z > -1.0 + margin && p.z < 1.5 - margin
    };
    let on_panel: Vec<_> = points.iter().filter(|p| inside(p, 0.02)).collect();
    assert!(
        on_panel.len() > 50,
        "{} returns on the panel",
        on_panel.len()
    );
    assert!(
        on_panel.iter().all(|p| p.reflectivity > 100),
        "every return from retro sheeting is above 100"
    );
    assert!(
        points
            .iter()
            .filter(|p| p.reflectivity > 100)
            .all(|p| inside(&p, -0.02)),
        "only the panel is retro"
    );
    // Nominal 200 at normal incidence, weakly angle dependent: 200 (0.85 + 0.15 cos α).
    for p in &on_panel {
        let expected = 200.0 * (0.85 + 0.15 * cos_incidence(p));
        assert!(
            (f64::from(p.reflectivity) - expected).abs() < 10.0,
            "{} vs {expected}",
            p.reflectivity
        );
    }
    let mean = on_panel
        .iter()
        .map(|p| f64::from(p.reflectivity))
        .sum::<f64>()
        / on_panel.len() as f64;
    let expected = on_panel
        .iter()
        .map(|p| 200.0 * (0.85 + 0.15 * cos_incidence(p)))
        .sum::<f64>()
        / on_panel.len() as f64;
    assert!(
        (mean - expected).abs() < 0.5,
        "mean retro value {mean}, model {expected}"
    );
}

#[test]
fn dark_surfaces_at_grazing_incidence_and_long_range_give_no_return() {
    // A dark floor (ρ 0.1): near returns at steep incidence, none beyond the detection limit.
    let mut b = SceneBuilder::new();
    let m = b.material(Material::diffuse("dark floor", 0.1)).unwrap();
    b.add(
        Shape::horizontal(-150.0, -150.0, 150.0, 150.0, 0.0),
        m,
        "floor",
    )
    .unwrap();
    let pose = Pose::from_xyz_ypr([0.0, 0.0, 0.8], 0.0, 0.0, 0.0);
    let config = SimConfig {
        seconds: 0.2,
        ..SimConfig::default()
    };
    let mut sim = Simulation::from_parts(
        &config,
        b.build(),
        Trajectory::fixed(pose),
        "a floor".into(),
    )
    .unwrap();
    let (pcap, truth) = common::capture(&mut sim);
    let points = common::decode(pcap).points;
    assert_eq!(points.len(), truth.len());
    let lasers: std::collections::BTreeSet<u8> = points.iter().map(|p| p.laser).collect();
    // −15° (3 m), −13°, −11°, −9°, −7° (6.5 m) reach the floor steeply enough; −1° (46 m,
    // cos α 0.017) does not; upward lasers see nothing.
    for l in [0u8, 2, 4, 6, 8] {
        assert!(
            lasers.contains(&l),
            "laser {l} should see the floor: {lasers:?}"
        );
    }
    assert!(
        !lasers.contains(&14),
        "laser 14 (−1°) should fade: {lasers:?}"
    );
    assert!(lasers
        .iter()
        .all(|&l| glint_sim::sensor::ELEVATION_DEG[usize::from(l)] < 0.0));
    // No return is distance 0 on the wire: the decoder drops them, so the count is the truth's.
    let firings = sim.stats().rays as usize;
    assert!(points.len() < firings / 2);
}

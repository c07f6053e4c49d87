//! End to end on the simulator: its packets through our driver (stream, sweeps) and the
//! odometry, measured against its ground truth. Seeds are chosen here, not tuned on.

use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::metrics::{
    associate, ate_rmse, drift_along_axis, relative_errors, WAREHOUSE_LENGTHS,
};
use glint_core::odometry::{FrontEnd, Odometry, TrackingStatus};
use glint_core::trajectory::StampedPose;
use glint_sim::{Scenario, SimConfig, Simulation};
use glint_tests::{dense_groundtruth, for_each_scan};
use nalgebra::Vector3;

struct Run {
    estimates: Vec<StampedPose>,
    groundtruth: Vec<StampedPose>,
    statuses: Vec<TrackingStatus>,
}

fn run(scenario: Scenario, seed: u64, seconds: f64, config: &OdometryConfig) -> Run {
    let sim_config = SimConfig {
        scenario,
        seed,
        seconds,
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(&sim_config).expect("the scenario builds");
    let mut front_end = FrontEnd::new(config);
    let mut odometry = Odometry::new(config);
    let mut features = SweepFeatures::default();
    let mut estimates = Vec::new();
    let mut statuses = Vec::new();
    for_each_scan(&mut sim, |scan| {
        front_end.process(scan, &mut features);
        let e = odometry.register(&features, |_| {});
        estimates.push(StampedPose {
            time_ns: e.time_ns,
            pose: e.pose,
        });
        statuses.push(e.status);
    });
    // Dense ground truth from the simulator itself, every 10 ms over the run.
    let groundtruth = dense_groundtruth(&sim, &estimates);
    Run {
        estimates,
        groundtruth,
        statuses,
    }
}

#[test]
fn warehouse_odometry_with_intensity_stays_under_half_a_percent() {
    let r = run(Scenario::Warehouse, 21, 60.0, &OdometryConfig::default());
    let pairs = associate(&r.estimates, &r.groundtruth);
    assert!(pairs.len() > 550, "{} poses associated", pairs.len());
    let drift = relative_errors(&pairs, &WAREHOUSE_LENGTHS).expect("segments fit");
    let ate = ate_rmse(&pairs).expect("poses");
    eprintln!("warehouse seed 21: {drift}; {ate}");
    assert!(drift.overall.translation_pct <= 0.5, "{drift}");
    assert!(ate.rmse <= 0.06, "{ate}");
    assert!(
        r.statuses
            .iter()
            .filter(|s| **s == TrackingStatus::Lost)
            .count()
            == 0
    );
}

#[test]
fn yard_odometry_with_intensity_stays_under_half_a_percent() {
    // The open yard: long ranges, few edges, and ground seen far away at grazing angles, which
    // steered the tilt until plane residuals were weighted by their angular lever.
    let r = run(Scenario::Yard, 19, 60.0, &OdometryConfig::default());
    let pairs = associate(&r.estimates, &r.groundtruth);
    assert!(pairs.len() > 550, "{} poses associated", pairs.len());
    let drift = relative_errors(&pairs, &WAREHOUSE_LENGTHS).expect("segments fit");
    let ate = ate_rmse(&pairs).expect("poses");
    eprintln!("yard seed 19: {drift}; {ate}");
    assert!(drift.overall.translation_pct <= 0.5, "{drift}");
    assert!(ate.rmse <= 0.08, "{ate}");
    assert!(!r.statuses.contains(&TrackingStatus::Lost));
}

#[test]
fn replaying_the_same_packets_gives_the_same_poses_bit_for_bit() {
    let a = run(Scenario::Warehouse, 5, 6.0, &OdometryConfig::default());
    let b = run(Scenario::Warehouse, 5, 6.0, &OdometryConfig::default());
    assert!(a.estimates.len() > 50);
    for (x, y) in a.estimates.iter().zip(&b.estimates) {
        assert_eq!(x.time_ns, y.time_ns);
        assert_eq!(x.pose.translation.vector, y.pose.translation.vector);
        assert_eq!(x.pose.rotation, y.pose.rotation);
    }
}

#[test]
fn in_the_corridor_intensity_holds_the_axis_geometry_cannot() {
    // The corridor runs along the scene's x axis; geometry constrains nothing along it.
    let axis = Vector3::x();
    let with = run(Scenario::Corridor, 14, 60.0, &OdometryConfig::default());
    let without = run(
        Scenario::Corridor,
        14,
        60.0,
        &OdometryConfig::geometry_only(),
    );
    let pairs = associate(&with.estimates, &with.groundtruth);
    let pairs_without = associate(&without.estimates, &without.groundtruth);
    let along = |pairs| drift_along_axis(pairs, &WAREHOUSE_LENGTHS, axis).expect("segments fit");
    let (intensity, geometry) = (along(&pairs), along(&pairs_without));
    let drift = relative_errors(&pairs, &WAREHOUSE_LENGTHS).expect("segments fit");
    eprintln!("corridor seed 14: drift along the axis {intensity:.2} % with intensity, {geometry:.2} % geometry only; with intensity {drift}");
    // The floor for the corridor: 1 %, in every direction.
    assert!(drift.overall.translation_pct <= 1.0, "{drift}");
    assert!(
        geometry >= 2.0 * intensity,
        "intensity {intensity} %, geometry {geometry} %"
    );
    assert!(
        without.statuses.contains(&TrackingStatus::Degenerate),
        "geometry alone must report the degeneracy"
    );
}

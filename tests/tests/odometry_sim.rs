//! End to end on the simulator: its packets through our driver (stream, sweeps) and the
//! odometry, measured against its ground truth. Seeds are chosen here, not tuned on.

use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::front_end::FrontEnd;
use glint_core::metrics::{
    associate, ate_rmse, drift_along_axis, relative_errors, WAREHOUSE_LENGTHS,
};
use glint_core::odometry::TrackingStatus;
use glint_core::tracker::Tracker;
use glint_core::trajectory::StampedPose;
use glint_sim::{Scenario, SimConfig, Simulation};
use glint_tests::{dense_groundtruth, for_each_scan, sensor_pose};
use nalgebra::{Isometry3, Matrix6, Vector3, Vector6};

struct Run {
    estimates: Vec<StampedPose>,
    groundtruth: Vec<StampedPose>,
    statuses: Vec<TrackingStatus>,
    /// Per estimate: the alignment's covariance, if one ran.
    covariances: Vec<Option<Matrix6<f64>>>,
    /// Per estimate: the true sensor pose at its time, scene frame.
    truth: Vec<Isometry3<f64>>,
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
    let mut tracker = Tracker::new(config, None);
    let mut features = SweepFeatures::default();
    let mut estimates = Vec::new();
    let mut statuses = Vec::new();
    let mut covariances = Vec::new();
    for_each_scan(&mut sim, |scan| {
        front_end.process(scan, &mut features);
        let e = tracker.track(&features, None, |_| {}).estimate;
        estimates.push(StampedPose {
            time_ns: e.time_ns,
            pose: e.pose,
        });
        statuses.push(e.status);
        covariances.push(e.alignment.map(|a| a.covariance));
    });
    // Dense ground truth from the simulator itself, every 10 ms over the run.
    let groundtruth = dense_groundtruth(&sim, &estimates);
    let truth = estimates
        .iter()
        .map(|e| sensor_pose(&sim, e.time_ns))
        .collect();
    Run {
        estimates,
        groundtruth,
        statuses,
        covariances,
        truth,
    }
}

/// Per axis of the covariance's `[δθ, δt]` (map axes, about the sensor): how the pose's error
/// changes from one sweep to the next (its RMS ÷ √2, the two sweeps' errors taken as
/// independent: the slow drift they share cancels) over the median 1σ the odometry reported.
/// Near 1 when the reported covariance describes the sweep's error.
fn covariance_consistency(r: &Run) -> [f64; 6] {
    // The map frame is the sensor's at the first sweep.
    let origin = r.truth[0].inverse();
    let errors: Vec<Vector6<f64>> = r
        .estimates
        .iter()
        .zip(&r.truth)
        .map(|(e, truth)| {
            let truth = origin * truth;
            let rotation = (truth.rotation * e.pose.rotation.inverse()).scaled_axis();
            let translation = truth.translation.vector - e.pose.translation.vector;
            Vector6::new(
                rotation.x,
                rotation.y,
                rotation.z,
                translation.x,
                translation.y,
                translation.z,
            )
        })
        .collect();
    std::array::from_fn(|axis| {
        let changes: Vec<f64> = errors
            .windows(2)
            .skip(1)
            .map(|w| w[1][axis] - w[0][axis])
            .collect();
        let rms = (changes.iter().map(|c| c * c).sum::<f64>() / changes.len() as f64).sqrt();
        let mut sigmas: Vec<f64> = r
            .covariances
            .iter()
            .flatten()
            .map(|c| c[(axis, axis)].sqrt())
            .collect();
        sigmas.sort_by(f64::total_cmp);
        rms / std::f64::consts::SQRT_2 / sigmas[sigmas.len() / 2]
    })
}

/// The reported covariance is within a factor of 6 of the sweep's actual error on every axis.
/// (From the residuals alone, without its floors, it was 8–27 times too small in rotation.)
fn assert_covariance_consistent(name: &str, r: &Run) {
    let ratios = covariance_consistency(r);
    eprintln!("{name}: sweep-to-sweep error over reported 1σ, [δθ, δt]: {ratios:.2?}");
    for ratio in ratios {
        assert!((1.0 / 6.0..=6.0).contains(&ratio), "{name}: {ratios:.2?}");
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
    assert_covariance_consistent("warehouse seed 21", &r);
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
    assert_covariance_consistent("yard seed 19", &r);
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
    // The corridor's floor: 1 %, in every direction.
    assert!(drift.overall.translation_pct <= 1.0, "{drift}");
    assert!(
        geometry >= 2.0 * intensity,
        "intensity {intensity} %, geometry {geometry} %"
    );
    assert!(
        without.statuses.contains(&TrackingStatus::Degenerate),
        "geometry alone must report the degeneracy"
    );
    // And its covariance says which way: along the axis, the (1 m)² of a direction nothing
    // measured (the axis in the map frame: the sensor's start may be turned from the scene's
    // x); with intensity, the axis is measured (the consistency below).
    let axis_variance = |r: &Run, k: usize| {
        let in_map = r.truth[0].rotation.inverse() * axis;
        r.covariances[k].map(|c| {
            let t = c.fixed_view::<3, 3>(3, 3);
            (in_map.transpose() * t * in_map)[0]
        })
    };
    for (k, status) in without.statuses.iter().enumerate() {
        if *status == TrackingStatus::Degenerate {
            let v = axis_variance(&without, k).expect("aligned");
            assert!(v > 0.5, "sweep {k}: {v} m² along the axis");
        }
    }
    assert_covariance_consistent("corridor seed 14", &with);
}

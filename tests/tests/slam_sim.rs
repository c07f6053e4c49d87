//! End to end with the back end: the simulator's packets through our driver, the front end,
//! the odometry and the back end (keyframes, Intensity Scan Context, verification, pose graph),
//! measured against the simulator's ground truth. The back end runs in step with the odometry
//! (it gets each keyframe as it is made), as a deterministic replay does. Seeds are chosen
//! here, not tuned on.

use glint_core::backend::config::BackEndConfig;
use glint_core::backend::{BackEnd, BackEndStats};
use glint_core::config::OdometryConfig;
use glint_core::features::SweepFeatures;
use glint_core::front_end::FrontEnd;
use glint_core::metrics::{self, associate, ate_rmse};
use glint_core::tracker::Tracker;
use glint_core::trajectory::StampedPose;
use glint_sim::{Scenario, SimConfig, Simulation};
use glint_tests::{dense_groundtruth, for_each_scan, sensor_pose};

struct Run {
    odometry: Vec<StampedPose>,
    slam: Vec<StampedPose>,
    groundtruth: Vec<StampedPose>,
    stats: BackEndStats,
    /// Each accepted loop's error against the ground truth: (translation m, rotation rad).
    loop_errors: Vec<(f64, f64)>,
}

/// The length of one lap of the scenario's loop for `seed`, s.
fn lap_seconds(scenario: Scenario, seed: u64) -> f64 {
    let sim = Simulation::new(&SimConfig {
        scenario,
        seed,
        seconds: 1.0,
        ..SimConfig::default()
    })
    .expect("the scenario builds");
    sim.trajectory()
        .figures()
        .expect("scenarios drive loops")
        .lap_seconds
}

fn run(scenario: Scenario, seed: u64, seconds: f64, backend_config: &BackEndConfig) -> Run {
    let sim_config = SimConfig {
        scenario,
        seed,
        seconds,
        ..SimConfig::default()
    };
    let config = OdometryConfig::default();
    let mut sim = Simulation::new(&sim_config).expect("the scenario builds");
    let mut front_end = FrontEnd::new(&config);
    let mut tracker = Tracker::new(&config, Some(&backend_config.keyframes));
    let mut backend = BackEnd::new(backend_config);
    let mut features = SweepFeatures::default();
    let mut estimates = Vec::new();
    for_each_scan(&mut sim, |scan| {
        front_end.process(scan, &mut features);
        let tracked = tracker.track(&features, None, |_| {});
        estimates.push(StampedPose {
            time_ns: tracked.estimate.time_ns,
            pose: tracked.estimate.pose,
        });
        if let Some(keyframe) = tracked.keyframe {
            backend.add_keyframe(keyframe, |_| {});
        }
    });
    let slam = backend.trajectory(&estimates);
    let groundtruth = dense_groundtruth(&sim, &estimates);
    let keyframes = backend.keyframes();
    let loop_errors = backend
        .loops()
        .iter()
        .map(|l| {
            let truth = sensor_pose(&sim, keyframes[l.candidate].time_ns).inverse()
                * sensor_pose(&sim, keyframes[l.query].time_ns);
            let error = truth.inverse() * l.verification.relative;
            (error.translation.vector.norm(), error.rotation.angle())
        })
        .collect();
    Run {
        odometry: estimates,
        slam,
        groundtruth,
        stats: backend.stats(),
        loop_errors,
    }
}

/// The error where the robot is back at its start (see `metrics::return_to_start`), m.
fn return_to_start(estimate: &[StampedPose], groundtruth: &[StampedPose]) -> f64 {
    let pairs = associate(estimate, groundtruth);
    let r = metrics::return_to_start(&pairs, metrics::RETURN_MIN_TRAVEL_M).expect("a lap");
    // The scenarios drive closed loops: the truth passes within a few centimetres of its start.
    assert!(r.distance_from_start < 0.5, "{r:?}");
    r.error
}

/// A false loop: more than 0.3 m or 2° from the ground truth's relative pose.
fn false_loops(r: &Run) -> usize {
    r.loop_errors
        .iter()
        .filter(|(t, a)| *t > 0.3 || *a > 2f64.to_radians())
        .count()
}

/// What a closed loop showed, m.
struct LoopFigures {
    odometry_ate: f64,
    slam_ate: f64,
}

/// Prints the figures and checks what every closed loop must show: a loop accepted and none
/// false, the return to the start within 0.1 m, and SLAM's ATE at most half the odometry's or
/// 5 cm.
fn check_closed_loop(name: &str, r: &Run) -> LoopFigures {
    let odometry = ate_rmse(&associate(&r.odometry, &r.groundtruth)).expect("poses");
    let slam = ate_rmse(&associate(&r.slam, &r.groundtruth)).expect("poses");
    let back_odometry = return_to_start(&r.odometry, &r.groundtruth);
    let back_slam = return_to_start(&r.slam, &r.groundtruth);
    eprintln!(
        "{name}: {:?}; ATE odometry {:.3} m, SLAM {:.3} m; return to start odometry {:.3} m, SLAM {:.3} m; loop errors {:?}",
        r.stats, odometry.rmse, slam.rmse, back_odometry, back_slam, r.loop_errors
    );
    assert!(
        r.stats.accepted >= 1,
        "{name}: no loop accepted: {:?}",
        r.stats
    );
    assert_eq!(false_loops(r), 0, "{name}: {:?}", r.loop_errors);
    assert!(
        back_slam < 0.10,
        "{name}: return to start: SLAM {back_slam} m, odometry {back_odometry} m"
    );
    assert!(
        slam.rmse <= (0.5 * odometry.rmse).max(0.05),
        "{name}: SLAM ATE {} vs odometry {}",
        slam.rmse,
        odometry.rmse
    );
    LoopFigures {
        odometry_ate: odometry.rmse,
        slam_ate: slam.rmse,
    }
}

#[test]
fn warehouse_two_laps_close_the_loop() {
    let seed = 31;
    let seconds = 2.0 * lap_seconds(Scenario::Warehouse, seed) + 1.0;
    let r = run(
        Scenario::Warehouse,
        seed,
        seconds,
        &BackEndConfig::default(),
    );
    check_closed_loop("warehouse seed 31", &r);
}

#[test]
fn yard_loop_closes() {
    // The odometry's error on this seed is mostly height, mid-lap (a tilt of a few mrad held
    // over tens of metres), which loops at the end of the lap cannot see: the floor edges
    // remove it (SLAM's ATE 0.078 m without them, 0.038 m with; odometry 0.076 m).
    let seed = 8;
    let seconds = lap_seconds(Scenario::Yard, seed) + 8.0;
    let r = run(Scenario::Yard, seed, seconds, &BackEndConfig::default());
    let f = check_closed_loop("yard seed 8", &r);
    assert!(
        r.stats.on_floor * 10 >= r.stats.keyframes * 9,
        "{:?}",
        r.stats
    );
    assert!(f.slam_ate < f.odometry_ate, "SLAM {} m", f.slam_ate);
}

#[test]
fn corridor_with_repeating_patterns_accepts_no_false_loop() {
    // With the odometry's position gate opened from 5 m to 30 m, earlier stretches of the
    // corridor with the same patterns (posters every 3.6 m, ceiling marks every 20 m) are
    // candidates: the descriptor and the verification must reject the look-alikes.
    let mut config = BackEndConfig::default();
    config.scan_context.search_radius = 30.0;
    let r = run(Scenario::Corridor, 19, 60.0, &config);
    eprintln!(
        "corridor seed 19: {:?}; loop errors {:?}",
        r.stats, r.loop_errors
    );
    // Driving one way for 60 s (90 m) the robot never revisits a place: any loop is false.
    assert_eq!(r.stats.accepted, 0, "{:?}", r.loop_errors);
    assert!(r.stats.keyframes > 50, "{:?}", r.stats);
    assert!(
        r.stats.verified > 0,
        "nothing reached verification: {:?}",
        r.stats
    );
}

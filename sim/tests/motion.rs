//! The robot moves like an AGV: speeds within 0.5–2 m/s, bounded yaw rate and accelerations,
//! sub-degree pitch and roll, the sensor 0.5–1.0 m above the floor, laps that repeat exactly for
//! any duration, and a path that keeps clear of everything in the scene.

use glint_sim::{scenarios, Scenario, SimConfig, Simulation};

#[test]
fn speeds_accelerations_and_yaw_rates_are_agv_like() {
    for scenario in Scenario::ALL {
        for seed in 1..=4 {
            let built = scenarios::build(scenario, seed).unwrap();
            let tr = &built.trajectory;
            let limits = tr.limits().unwrap();
            let f = tr.figures().unwrap();
            assert!(
                f.min_speed >= 0.5 && f.max_speed <= 2.0,
                "{scenario}/{seed}: {f:?}"
            );
            let dt = 0.02;
            let laps = 2.0 * f.lap_seconds;
            let mut prev = tr.base_state(0.0);
            let mut t = dt;
            while t < laps {
                let s = tr.base_state(t);
                assert!(
                    (0.5..=2.0).contains(&s.speed),
                    "{scenario}/{seed} at {t:.2} s: speed {}",
                    s.speed
                );
                let mut dyaw = s.yaw - prev.yaw;
                if dyaw > std::f64::consts::PI {
                    dyaw -= std::f64::consts::TAU;
                } else if dyaw < -std::f64::consts::PI {
                    dyaw += std::f64::consts::TAU;
                }
                let yaw_rate = dyaw / dt;
                assert!(
                    yaw_rate.abs() <= limits.max_yaw_rate * 1.15,
                    "{scenario}/{seed} at {t:.2} s: yaw rate {yaw_rate}"
                );
                let lateral = yaw_rate * 0.5 * (s.speed + prev.speed);
                assert!(
                    lateral.abs() <= limits.max_lateral_accel * 1.25,
                    "{scenario}/{seed} at {t:.2} s: lateral {lateral}"
                );
                let accel = (s.speed - prev.speed) / dt;
                assert!(
                    accel.abs() <= limits.max_accel + 1e-6,
                    "{scenario}/{seed} at {t:.2} s: accel {accel}"
                );
                prev = s;
                t += dt;
            }
            // Sensor height and vibration.
            for k in 0..2000 {
                let pose = tr.sensor_pose(k as f64 * 0.0173);
                let (roll, pitch, _) = pose.rotation.euler_angles();
                assert!(roll.abs() < 0.5f64.to_radians() && pitch.abs() < 0.5f64.to_radians());
                assert!(
                    (0.5..=1.0).contains(&pose.translation.z),
                    "height {}",
                    pose.translation.z
                );
            }
        }
    }
}

#[test]
fn laps_repeat_for_any_duration() {
    for scenario in Scenario::ALL {
        let config = SimConfig {
            scenario,
            seconds: 600.0,
            ..SimConfig::default()
        };
        // Building a 10-minute run costs nothing until packets are asked for.
        let sim = Simulation::new(&config).unwrap();
        let lap = sim.trajectory().figures().unwrap().lap_seconds;
        for t in [0.0, 1.234, 17.5] {
            let a = sim.trajectory().base_state(t);
            let later = t + (600.0 / lap).floor() * lap;
            let b = sim.trajectory().base_state(later);
            assert!(
                (a.x - b.x).abs() < 1e-6
                    && (a.y - b.y).abs() < 1e-6
                    && (a.yaw - b.yaw).abs() < 1e-6,
                "{scenario} at {t} s and {later} s"
            );
            assert!(b.lap >= 1);
        }
        assert_eq!(
            sim.data_packets_total(),
            (600e9 / 1_327_104.0f64).ceil() as u64
        );
        let ends = sim.sweep_end_times();
        assert!(
            (ends.len() as i64 - 6001).abs() <= 1,
            "{} sweeps in 10 minutes",
            ends.len()
        );
        assert!(ends.windows(2).all(|w| w[1] > w[0]));
        // 0, 10 ms, …, 600 s: the last firing is just after 600 s.
        assert_eq!(sim.dense_times().len(), 60_001);
    }
}

#[test]
fn the_robot_keeps_clear_of_everything() {
    for scenario in Scenario::ALL {
        for seed in 1..=4 {
            let sim = Simulation::new(&SimConfig {
                scenario,
                seed,
                seconds: 1.0,
                ..SimConfig::default()
            })
            .unwrap();
            let tr = sim.trajectory();
            let lap = tr.figures().unwrap().lap_seconds;
            let mut t = 0.0;
            while t < lap {
                let s = tr.base_state(t);
                for z in [0.15, 0.5, 1.0, 1.6] {
                    for k in 0..24 {
                        let a = k as f64 * std::f64::consts::TAU / 24.0;
                        let hit = sim.scene().cast(
                            [s.x, s.y, z],
                            [a.cos(), a.sin(), 0.0],
                            0.0,
                            100.0,
                            t,
                            &[],
                        );
                        if let Some(h) = hit {
                            assert!(
                                h.t > 0.6,
                                "{scenario}/{seed}: {} {:.2} m away at {t:.1} s (z {z})",
                                sim.scene().tag_of(h.id),
                                h.t
                            );
                        }
                    }
                }
                t += 0.25;
            }
        }
    }
}

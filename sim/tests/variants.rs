//! Several runs of one scene: another route (path seed), the other direction, another start,
//! a kidnap, another sensor unit, changed goods, more or fewer movers. The layout and the scene
//! frame stay those of the scenario and seed; only what was asked for changes.

use std::fs;
use std::path::PathBuf;

use glint_sim::scene::Primitive;
use glint_sim::{
    scenarios, simulate_to_dir, ConfigError, Scenario, SimConfig, SimError, Simulation,
};

struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir =
            std::env::temp_dir().join(format!("glint-sim-variants-{}-{name}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

fn config(scenario: Scenario, seed: u64) -> SimConfig {
    SimConfig {
        scenario,
        seed,
        ..SimConfig::default()
    }
}

fn build(c: &SimConfig) -> scenarios::Built {
    scenarios::build_run(c).unwrap()
}

#[test]
fn path_seeds_drive_other_routes_through_the_same_scene() {
    for scenario in Scenario::ALL {
        for seed in [1, 3] {
            let own = build(&config(scenario, seed));
            let mut routes = vec![own.trajectory.waypoints().to_vec()];
            for path_seed in 1..=4 {
                let c = SimConfig {
                    path_seed: Some(path_seed),
                    ..config(scenario, seed)
                };
                let other = build(&c);
                assert_eq!(
                    other.scene.primitives(),
                    own.scene.primitives(),
                    "{scenario}/{seed}/{path_seed}: the scene changed"
                );
                assert_eq!(other.scene.materials(), own.scene.materials());
                assert_eq!(other.scene.movers(), own.scene.movers());
                assert_eq!(other.trajectory.mount(), own.trajectory.mount());
                assert_ne!(
                    other.trajectory.waypoints(),
                    own.trajectory.waypoints(),
                    "{scenario}/{seed}/{path_seed}: the same route"
                );
                // The same path seed always picks the same route.
                assert_eq!(
                    build(&c).trajectory.waypoints(),
                    other.trajectory.waypoints()
                );
                routes.push(other.trajectory.waypoints().to_vec());
            }
            routes.sort_by(|a, b| a.partial_cmp(b).unwrap());
            routes.dedup();
            assert!(routes.len() >= 3, "{scenario}/{seed}: too few routes");
        }
    }
}

#[test]
fn reverse_drives_the_same_waypoints_backwards() {
    for scenario in Scenario::ALL {
        let forward = build(&config(scenario, 2)).trajectory;
        let backward = build(&SimConfig {
            reverse: true,
            ..config(scenario, 2)
        })
        .trajectory;
        let (f, b) = (forward.waypoints(), backward.waypoints());
        assert_eq!(f.len(), b.len());
        assert_eq!(f[0], b[0], "{scenario}: both start at the first waypoint");
        let mut rest = f[1..].to_vec();
        rest.reverse();
        assert_eq!(&b[1..], &rest[..], "{scenario}");
        let lap_f = forward.figures().unwrap().lap_length_m;
        let lap_b = backward.figures().unwrap().lap_length_m;
        assert!((lap_f - lap_b).abs() < 1e-6, "{lap_f} vs {lap_b}");
        // The point a fraction x round one lap is the point 1 − x round the other, facing the
        // other way.
        for x in [0.1, 0.25, 0.5, 0.8] {
            let p = forward.base_state(forward.lap_time_at(x));
            let q = backward.base_state(backward.lap_time_at(1.0 - x));
            assert!(
                (p.x - q.x).hypot(p.y - q.y) < 0.03,
                "{scenario} at {x}: {p:?} vs {q:?}"
            );
            let turn = (p.yaw - q.yaw).rem_euclid(std::f64::consts::TAU);
            assert!(
                (turn - std::f64::consts::PI).abs() < 0.02,
                "{scenario} at {x}: heading differs by {turn}"
            );
        }
        // And it really moves the other way: just after the start, away from the forward run.
        let (p, q) = (forward.base_state(2.0), backward.base_state(2.0));
        assert!((p.x - q.x).hypot(p.y - q.y) > 1.0, "{scenario}");
    }
}

#[test]
fn a_start_fraction_starts_part_way_round_the_lap() {
    for scenario in Scenario::ALL {
        let own = build(&config(scenario, 5)).trajectory;
        let shifted = build(&SimConfig {
            start_fraction: 0.4,
            ..config(scenario, 5)
        })
        .trajectory;
        let lap = own.figures().unwrap().lap_length_m;
        for t in [0.0, 3.0, 10.0] {
            let a = shifted.base_state(t);
            let b = own.base_state(own.lap_time_at(0.4) + t);
            assert!((a.x - b.x).hypot(a.y - b.y) < 1e-9, "{scenario} at {t}");
        }
        assert!((shifted.base_state(0.0).s - 0.4 * lap).abs() < 0.02);
        let (a, b) = (shifted.base_state(0.0), own.base_state(0.0));
        assert!(
            (a.x - b.x).hypot(a.y - b.y) > 5.0,
            "{scenario}: start moved"
        );
    }
}

type TumLine = (u64, [f64; 3]);

fn read_tum(path: &std::path::Path) -> Vec<TumLine> {
    fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (
                parse_ns(f[0]),
                [f[1], f[2], f[3]].map(|v| v.parse::<f64>().unwrap()),
            )
        })
        .collect()
}

fn parse_ns(s: &str) -> u64 {
    let (a, b) = s.split_once('.').unwrap();
    a.parse::<u64>().unwrap() * 1_000_000_000 + b.parse::<u64>().unwrap()
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

#[test]
fn a_kidnap_jumps_at_least_10_m_and_no_ground_truth_spans_it() {
    let dir = TempDir::new("kidnap");
    let c = SimConfig {
        seconds: 4.0,
        kidnap_s: Some(1.5),
        noise: false,
        ..config(Scenario::Warehouse, 3)
    };
    simulate_to_dir(&c, &dir.0).unwrap();
    let kidnaps = fs::read_to_string(dir.0.join("kidnaps.txt")).unwrap();
    let lines: Vec<&str> = kidnaps.lines().collect();
    assert_eq!(lines.len(), 1, "{kidnaps}");
    let (before, after) = lines[0].split_once(' ').unwrap();
    let (before, after) = (parse_ns(before), parse_ns(after));
    let start = c.start_time_ns();
    let at = start + 1_500_000_000;
    assert!(
        before >= at && before < at + 110_000_000,
        "the jump follows the first sweep end at or after the requested time"
    );
    let sparse = read_tum(&dir.0.join("groundtruth.tum"));
    let dense = read_tum(&dir.0.join("groundtruth_dense.tum"));
    for (name, gt) in [("sparse", &sparse), ("dense", &dense)] {
        assert!(
            gt.iter().all(|(t, _)| *t <= before || *t >= after),
            "{name}: a line inside the jump"
        );
        // Consecutive lines bracket the jump (sweep ends in the sparse file, 10 ms instants in
        // the dense one); everywhere else they are close: the jump is the only one.
        for w in gt.windows(2) {
            let d = distance(w[0].1, w[1].1);
            if w[0].0 <= before && w[1].0 >= after {
                assert!(d >= 10.0, "{name}: jumped only {d} m");
            } else {
                assert!(d < 0.5, "{name}: {d} m between {} and {}", w[0].0, w[1].0);
            }
        }
    }
    assert!(sparse.iter().any(|(t, _)| *t == before) && sparse.iter().any(|(t, _)| *t == after));
    let scene: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(dir.0.join("scene.json")).unwrap()).unwrap();
    let recorded = &scene["variant"]["kidnaps"];
    assert_eq!(recorded.as_array().unwrap().len(), 1);
    assert_eq!(recorded[0]["before_ns"].as_u64(), Some(before));
    assert_eq!(recorded[0]["after_ns"].as_u64(), Some(after));
    assert!(recorded[0]["distance_m"].as_f64().unwrap() >= 10.0);

    // A run without a kidnap into the same directory leaves no stale kidnaps.txt behind.
    simulate_to_dir(
        &SimConfig {
            kidnap_s: None,
            seconds: 0.3,
            ..c
        },
        &dir.0,
    )
    .unwrap();
    assert!(!dir.0.join("kidnaps.txt").exists());
}

#[test]
fn a_kidnap_outside_the_run_or_with_nowhere_to_go_is_an_error() {
    for t in [0.0, -1.0, 3.9, 10.0, f64::NAN] {
        let c = SimConfig {
            seconds: 4.0,
            kidnap_s: Some(t),
            ..config(Scenario::Warehouse, 3)
        };
        assert!(
            matches!(c.validate(), Err(ConfigError::KidnapTime { .. })),
            "{t}"
        );
    }
    // A small loop has no place 10 m from anywhere on it.
    use glint_sim::scene::SceneBuilder;
    use glint_sim::trajectory::{rounded_polygon, MotionLimits, Mount, Trajectory, Vibration};
    let wps = rounded_polygon(&[[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]], 1.5, 1.0);
    let mount = Mount {
        x: 0.0,
        y: 0.0,
        z: 1.0,
    };
    let tr =
        Trajectory::closed_loop(&wps, MotionLimits::default(), mount, Vibration::none()).unwrap();
    let c = SimConfig {
        seconds: 3.0,
        kidnap_s: Some(1.0),
        ..SimConfig::default()
    };
    let err = Simulation::from_parts(&c, SceneBuilder::new().build(), tr, String::new());
    assert!(matches!(err, Err(SimError::Kidnap { .. })), "{err:?}");
}

/// The primitives of each movable object, and the primitives of nothing movable.
fn split(scene: &glint_sim::scene::Scene) -> (Vec<Vec<Primitive>>, Vec<Primitive>) {
    let mut fixed = vec![true; scene.primitives().len()];
    let objects = scene
        .movable_objects()
        .iter()
        .map(|&[a, b]| {
            fixed[a as usize..b as usize].fill(false);
            scene.primitives()[a as usize..b as usize].to_vec()
        })
        .collect();
    let rest = scene
        .primitives()
        .iter()
        .zip(&fixed)
        .filter(|(_, f)| **f)
        .map(|(p, _)| *p)
        .collect();
    (objects, rest)
}

#[test]
fn changes_move_or_remove_the_fraction_asked_for_and_nothing_else() {
    for scenario in [Scenario::Warehouse, Scenario::Yard] {
        let own = build(&config(scenario, 3));
        let (objects, fixed) = split(&own.scene);
        assert!(objects.len() > 20, "{scenario}: {} objects", objects.len());
        let tags: Vec<&str> = own
            .scene
            .movable_objects()
            .iter()
            .map(|&[a, _]| own.scene.tag_of(a))
            .collect();
        assert!(tags
            .iter()
            .all(|t| ["pallet", "car", "van", "skip", "trailer", "container"].contains(t)));
        let mut seen = Vec::new();
        for change_seed in [1, 2] {
            let c = SimConfig {
                change: 0.25,
                change_seed,
                ..config(scenario, 3)
            };
            let changed = build(&c);
            let (objects_after, fixed_after) = split(&changed.scene);
            assert_eq!(
                fixed_after, fixed,
                "{scenario}: walls, racks or pillars changed"
            );
            assert_eq!(changed.scene.materials(), own.scene.materials());
            let expected = (0.25 * objects.len() as f64).round() as usize;
            let unchanged = objects.iter().filter(|o| objects_after.contains(o)).count();
            assert_eq!(objects.len() - unchanged, expected, "{scenario}");
            assert_eq!(changed.changes.len(), expected);
            let removed = changed.changes.iter().filter(|c| c.shift.is_none()).count();
            assert_eq!(objects_after.len(), objects.len() - removed);
            assert!(removed > 0 && removed < expected, "{scenario}: {removed}");
            for d in changed.changes.iter().filter_map(|c| c.shift) {
                assert!((0.3..=1.5 + 1e-12).contains(&d[0].hypot(d[1])), "{d:?}");
            }
            assert_eq!(changed.trajectory.waypoints(), own.trajectory.waypoints());
            seen.push(changed.changes);
        }
        assert_ne!(seen[0], seen[1], "{scenario}: the change seed decides");
        // Changes do not depend on the route: the same ones for another path seed.
        let other_route = build(&SimConfig {
            change: 0.25,
            change_seed: 1,
            path_seed: Some(2),
            ..config(scenario, 3)
        });
        assert_eq!(other_route.changes, seen[0]);
    }
}

#[test]
fn a_unit_seed_changes_the_sensor_not_the_scene() {
    let c = config(Scenario::Warehouse, 3);
    let own = Simulation::new(&SimConfig {
        seconds: 1.0,
        ..c.clone()
    })
    .unwrap();
    let other = Simulation::new(&SimConfig {
        seconds: 1.0,
        unit_seed: Some(8),
        ..c.clone()
    })
    .unwrap();
    assert_ne!(own.sensor().laser_gains(), other.sensor().laser_gains());
    assert_ne!(own.sensor().start_azimuth(), other.sensor().start_azimuth());
    assert_eq!(own.scene().primitives(), other.scene().primitives());
    assert_eq!(own.trajectory().waypoints(), other.trajectory().waypoints());
    assert_eq!(
        own.sensor_pose_at(own.start_ns() + 500_000_000),
        other.sensor_pose_at(other.start_ns() + 500_000_000)
    );
    // The run's own seed as unit seed is the run's own unit.
    let same = Simulation::new(&SimConfig {
        seconds: 1.0,
        unit_seed: Some(3),
        ..c
    })
    .unwrap();
    assert_eq!(own.sensor().laser_gains(), same.sensor().laser_gains());
}

#[test]
fn movers_can_be_removed_or_multiplied() {
    let own = build(&config(Scenario::Warehouse, 2));
    assert_eq!(own.scene.movers().len(), 2);
    for n in [0, 1, 5] {
        let b = build(&SimConfig {
            movers: Some(n),
            ..config(Scenario::Warehouse, 2)
        });
        assert_eq!(b.scene.movers().len(), n);
        assert_eq!(b.scene.primitives(), own.scene.primitives());
        let kept = n.min(2);
        assert_eq!(&b.scene.movers()[..kept], &own.scene.movers()[..kept]);
    }
    assert!(matches!(
        SimConfig {
            movers: Some(100),
            ..SimConfig::default()
        }
        .validate(),
        Err(ConfigError::Movers(100))
    ));
}

#[test]
fn other_routes_and_changed_goods_keep_clear_of_everything() {
    for scenario in Scenario::ALL {
        for (path_seed, change) in [(1, 0.0), (2, 0.5), (3, 1.0)] {
            let sim = Simulation::new(&SimConfig {
                seconds: 1.0,
                path_seed: Some(path_seed),
                change,
                ..config(scenario, 4)
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
                        if let Some(h) = sim.scene().cast(
                            [s.x, s.y, z],
                            [a.cos(), a.sin(), 0.0],
                            0.0,
                            100.0,
                            t,
                            &[],
                        ) {
                            assert!(
                                h.t > 0.6,
                                "{scenario}/{path_seed}: {} {:.2} m away at {t:.1} s (z {z})",
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

//! The corridor is geometrically degenerate by construction: six plain rectangles, every hit
//! lies on one of the four long planes, and the end walls are never hit because the robot stays
//! more than 100 m (the sensor's range) from them. Along the axis, only reflectivity varies.

mod common;

use glint_sim::scenarios::{self};
use glint_sim::scene::Shape;
use glint_sim::trajectory::Trajectory;
use glint_sim::{Scenario, SimConfig, Simulation};

#[test]
fn the_corridor_is_six_plain_rectangles() {
    for seed in 1..=5 {
        let built = scenarios::build(Scenario::Corridor, seed).unwrap();
        let scene = &built.scene;
        assert_eq!(scene.primitives().len(), 6);
        assert!(scene.movers().is_empty());
        assert!(scene
            .primitives()
            .iter()
            .all(|p| matches!(p.shape, Shape::Rect { .. })));
        let mut tags: Vec<(String, usize)> = scene.tag_counts();
        tags.sort();
        assert_eq!(
            tags,
            vec![
                ("ceiling".into(), 1),
                ("end wall".into(), 2),
                ("floor".into(), 1),
                ("wall".into(), 2)
            ]
        );
        // Long walls parallel to x, spanning the whole length.
        for p in scene
            .primitives()
            .iter()
            .filter(|p| scene.tags()[usize::from(p.tag)] == "wall")
        {
            let Shape::Rect { u, half, .. } = p.shape else {
                unreachable!()
            };
            assert_eq!(u, [1.0, 0.0, 0.0]);
            assert_eq!(half[0], 200.0);
        }
    }
}

#[test]
fn the_robot_stays_out_of_range_of_the_end_walls() {
    for seed in 1..=8 {
        let built = scenarios::build(Scenario::Corridor, seed).unwrap();
        let tr = &built.trajectory;
        let lap = tr.figures().unwrap().lap_seconds;
        let mut t = 0.0;
        while t <= lap {
            let p = tr.sensor_pose(t).translation;
            assert!(
                p.x.abs() < 200.0 - 100.0 - 1.0,
                "seed {seed}: x {} at {t:.1} s",
                p.x
            );
            t += 0.05;
        }
    }
}

#[test]
fn no_ray_hits_an_end_wall_and_every_hit_is_on_a_long_plane() {
    let config = SimConfig {
        scenario: Scenario::Corridor,
        seed: 3,
        seconds: 1.0,
        noise: false,
        ..SimConfig::default()
    };
    let built = scenarios::build(Scenario::Corridor, 3).unwrap();
    let (hw, height) = {
        let b = built.scene.bounds();
        (b.max[1], b.max[2])
    };
    // Worst case first: the sensor held at the point of the loop nearest an end wall, facing it.
    let tr = &built.trajectory;
    let lap = tr.figures().unwrap().lap_seconds;
    let nearest = (0..(lap * 20.0) as usize)
        .map(|k| tr.sensor_pose(k as f64 * 0.05))
        .max_by(|a, b| a.translation.x.abs().total_cmp(&b.translation.x.abs()))
        .unwrap();
    let fixed = Simulation::from_parts(
        &config,
        built.scene.clone(),
        Trajectory::fixed(nearest),
        String::new(),
    )
    .unwrap();
    let moving = Simulation::new(&config).unwrap();
    for mut sim in [fixed, moving] {
        let mut truths = Vec::new();
        while sim.next_packet_with_truth(|t| truths.push(*t)).is_some() {}
        assert!(truths.len() > 100_000);
        let mut wall_values = std::collections::BTreeSet::new();
        for t in &truths {
            assert_ne!(sim.scene().tag_of(t.object), "end wall");
            let pose = sim.sensor_pose_at(t.time_ns);
            let p = pose.transform_point(&t.point.into());
            let on_plane =
                (p.y.abs() - hw).abs() < 1e-6 || p.z.abs() < 1e-6 || (p.z - height).abs() < 1e-6;
            assert!(on_plane, "hit at {p:?} is on none of the corridor's planes");
            if sim.scene().tag_of(t.object) == "wall" && !t.retro {
                wall_values.insert(t.reflectivity);
            }
        }
        // Along the walls, reflectivity varies (doors, frames, plates, posters): the only cue.
        assert!(
            wall_values.len() > 30,
            "{} distinct wall reflectivities",
            wall_values.len()
        );
    }
}

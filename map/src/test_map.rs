//! Tests' site maps: drawn from a seed, so every run and machine gets the same.

use glint_core::backend::config::ScanContextConfig;
use glint_core::backend::keyframe::{CloudPoint, Keyframe};
use glint_core::backend::pose_graph::Edge;
use glint_core::backend::scan_context::ScanContext;
use glint_core::config::IntensityMapConfig;
use glint_core::intensity_map::IntensityMap;
use glint_core::site_map::{SiteKeyframe, SiteMap};
use glint_testkit::SeededRng;
use nalgebra::{Isometry3, Matrix6, Vector3};

/// A map of `keyframes` keyframes along a wandering path, each holding `points` points (a
/// quarter edges, a quarter planes, half cloud) except every fourth, which has released them;
/// intensity cells on the floor along the path; odometry edges and a loop edge every fifth keyframe.
pub fn site_map(seed: u64, keyframes: usize, points: usize) -> SiteMap {
    let mut rng = SeededRng::new(seed);
    let sc = ScanContextConfig::default();
    let mut intensity = IntensityMap::new(&IntensityMapConfig::default());
    let mut site_keyframes = Vec::with_capacity(keyframes);
    let mut edges = Vec::new();
    for i in 0..keyframes {
        let yaw = rng.uniform(-3.0, 3.0);
        let position = Vector3::new(i as f64 * 0.8, (i as f64 * 0.1).sin() * 5.0, 0.3);
        let pose = Isometry3::new(position, Vector3::new(0.01, -0.02, yaw));
        let odom_pose = Isometry3::new(position * 1.01, Vector3::z() * (yaw + 0.01));
        let mut point = || {
            [
                rng.uniform(-30.0, 30.0) as f32,
                rng.uniform(-30.0, 30.0) as f32,
                rng.uniform(-1.5, 4.0) as f32,
            ]
        };
        let released = i % 4 == 3;
        let n = if released { 0 } else { points };
        let kf_edges: Vec<_> = (0..n / 4).map(|_| point()).collect();
        let planes: Vec<_> = (0..n / 4).map(|_| point()).collect();
        let positions: Vec<_> = (0..n - n / 4 * 2).map(|_| point()).collect();
        let cloud: Vec<_> = positions
            .into_iter()
            .map(|position| CloudPoint {
                position,
                eta: rng.uniform(0.0, 120.0) as f32,
            })
            .collect();
        let descriptor = ScanContext::new(cloud.iter().map(|c| (c.position.into(), c.eta)), &sc);
        // Intensity lies on surfaces, as in a real map: here a 6 m floor patch under each
        // keyframe holding its points, overlapping its neighbours'.
        if !released {
            for (a, b) in (0..30).flat_map(|a| (0..30).map(move |b| (a, b))) {
                let x = position.x as f32 - 3.0 + a as f32 * 0.2 + 0.1;
                let y = position.y as f32 - 3.0 + b as f32 * 0.2 + 0.1;
                intensity.insert(&Vector3::new(x, y, 0.1), rng.uniform(0.0, 120.0) as f32);
            }
        }
        if i > 0 {
            edges.push(edge(&mut rng, i - 1, i, false));
        }
        if i >= 5 && i % 5 == 0 {
            edges.push(edge(&mut rng, i - 5, i, true));
        }
        site_keyframes.push(SiteKeyframe {
            pose,
            keyframe: Keyframe {
                time_ns: 1_700_000_000_000_000_000 + i as u64 * 250_000_000,
                odom_pose,
                edges: kf_edges,
                planes,
                cloud,
            },
            descriptor,
        });
    }
    SiteMap {
        created_ns: 1_700_000_000_000_000_000 + seed,
        sensor_model: "VLP-16".into(),
        base_from_sensor: Isometry3::new(Vector3::new(0.1, 0.0, 1.2), Vector3::new(0.0, 0.0, 0.02)),
        keyframes: site_keyframes,
        intensity,
        edges,
    }
}

fn edge(rng: &mut SeededRng, from: usize, to: usize, robust: bool) -> Edge {
    let measurement = Isometry3::new(
        Vector3::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), 0.0),
        Vector3::z() * rng.uniform(-0.5, 0.5),
    );
    let mut information = Matrix6::from_diagonal_element(100.0);
    for r in 0..6 {
        for c in r + 1..6 {
            let v = rng.uniform(-1.0, 1.0);
            information[(r, c)] = v;
            information[(c, r)] = v;
        }
    }
    Edge {
        from,
        to,
        measurement,
        information,
        robust,
    }
}

/// Panics unless `a` and `b` hold the same map, bit for bit (the intensity maps compared
/// through their cells).
pub fn assert_same(a: &SiteMap, b: &SiteMap) {
    assert_eq!(a.created_ns, b.created_ns);
    assert_eq!(a.sensor_model, b.sensor_model);
    assert_eq!(a.base_from_sensor, b.base_from_sensor);
    assert_eq!(a.keyframes.len(), b.keyframes.len());
    for (i, (x, y)) in a.keyframes.iter().zip(&b.keyframes).enumerate() {
        assert_eq!(x, y, "keyframe {i}");
    }
    assert_eq!(a.intensity.config(), b.intensity.config());
    assert!(
        a.intensity.cells().eq(b.intensity.cells()),
        "intensity cells"
    );
    assert_eq!(a.edges, b.edges);
}

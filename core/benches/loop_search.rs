//! The back end's per-keyframe costs that grow or repeat: the Intensity Scan Context of a
//! keyframe's cloud, the candidate search over 10,000 stored keyframes (ring-key pre-filter
//! over all of them, shift search on the best few), every one eligible — the worst case, with
//! no position gate — and the optimisation of a 10,000-keyframe graph after ten new floor
//! edges, which a robot that has driven 10 km does every ten keyframes.
//!
//!     cargo bench -p glint-core --bench loop_search

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use glint_core::backend::config::{FloorConfig, GraphConfig, ScanContextConfig};
use glint_core::backend::floor::{FloorMeasurement, Plane};
use glint_core::backend::loop_closure::search;
use glint_core::backend::pose_graph::{Edge, PoseGraph};
use glint_core::backend::scan_context::ScanContext;
use glint_testkit::SeededRng;
use nalgebra::{Isometry3, Matrix6, Vector3};

/// A deterministic pseudo-random place: walls at varied ranges, patches of varied reflectivity.
fn place(seed: u64, points: usize) -> Vec<(Vector3<f32>, f32)> {
    let mut rng = SeededRng::new(seed);
    let mut next = move || rng.uniform(0.0, 1.0) as f32;
    let walls: Vec<f32> = (0..12).map(|_| 3.0 + 30.0 * next()).collect();
    let paint: Vec<f32> = (0..24).map(|_| 100.0 * next()).collect();
    (0..points)
        .map(|i| {
            let a = i as f32 * std::f32::consts::TAU / points as f32;
            let sector = (a / std::f32::consts::TAU * 12.0) as usize % 12;
            let r = walls[sector] * (0.8 + 0.2 * next());
            let eta = paint[(sector * 2 + (next() > 0.5) as usize) % 24];
            (
                Vector3::new(r * a.cos(), r * a.sin(), 2.0 * next() - 0.7),
                eta,
            )
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let config = ScanContextConfig::default();
    let cloud = place(1, 3000);
    c.bench_function("scan context of a 3000-point keyframe", |b| {
        b.iter(|| ScanContext::new(black_box(cloud.iter().copied()), &config))
    });
    let stored: Vec<ScanContext> = (0..10_000)
        .map(|k| ScanContext::new(place(k + 2, 600), &config))
        .collect();
    let query = ScanContext::new(place(5_000, 600), &config);
    c.bench_function("candidate search over 10000 keyframes", |b| {
        b.iter(|| search(black_box(&query), &stored, |_| true, &config))
    });
}

/// 10,000 keyframes 1 m apart around 40 m × 40 m laps, every one tied to the floor, a loop
/// edge every 160 keyframes, already optimised; then the last ten nodes displaced by 5 cm and
/// 5 mrad, as odometry would bring them.
fn lapped_graph() -> PoseGraph {
    let floor = FloorConfig::default();
    let level = Plane {
        normal: Vector3::z(),
        offset: 0.0,
    };
    let pose_at = |k: usize| {
        let (side, along) = ((k / 40) % 4, (k % 40) as f64);
        let yaw = side as f64 * std::f64::consts::FRAC_PI_2;
        let corner = [(0.0, 0.0), (40.0, 0.0), (40.0, 40.0), (0.0, 40.0)][side];
        let t = Vector3::new(corner.0, corner.1, 0.8)
            + Isometry3::rotation(Vector3::z() * yaw) * Vector3::x() * along;
        Isometry3::new(t, Vector3::z() * yaw)
    };
    // Measurements off by up to a centimetre and a milliradian, so the optimum is not exact.
    let mut rng = SeededRng::new(0x2545_F491_4F6C_DD1D);
    let mut noise = move |scale: f64| scale * rng.centred();
    let mut jitter = move || {
        let t = Vector3::new(noise(0.02), noise(0.02), noise(0.02));
        let r = Vector3::new(noise(0.002), noise(0.002), noise(0.002));
        Isometry3::new(t, r)
    };
    // Odometry (from the previous keyframe) and loop (robust) edges.
    let mut measured = |from: usize, to: usize, robust: bool| Edge {
        from,
        to,
        measurement: pose_at(from).inverse() * pose_at(to) * jitter(),
        information: Matrix6::from_diagonal_element(1e4),
        robust,
    };
    let mut graph = PoseGraph::default();
    for k in 0..10_000 {
        graph.add_node(pose_at(k), k == 0);
        if k > 0 {
            graph.edges.push(measured(k - 1, k, false));
            let seen = FloorMeasurement {
                plane: level
                    .transformed(&(pose_at(k) * measured(k, k, false).measurement).inverse()),
                points: 300,
                rms: 0.01,
            };
            graph
                .edges
                .push(seen.edge(&level, 0, &pose_at(0), k, &pose_at(k), &floor));
        }
        if k >= 160 && k % 160 == 0 {
            graph.edges.push(measured(k - 160, k, true));
        }
    }
    // The graph as the last optimisation left it, then the newest keyframes as odometry
    // brings them.
    let _ = graph.optimize(&GraphConfig::default().optimizer);
    for pose in graph.poses.iter_mut().skip(9_990) {
        *pose = Isometry3::new(Vector3::new(0.05, 0.0, 0.05), Vector3::x() * 0.005) * *pose;
    }
    graph
}

fn optimisation(c: &mut Criterion) {
    let graph = lapped_graph();
    let config = GraphConfig::default().optimizer;
    let mut group = c.benchmark_group("pose graph");
    group.sample_size(10);
    group.bench_function(
        "optimisation of 10000 keyframes after ten floor edges",
        |b| {
            b.iter_batched(
                || graph.clone(),
                |mut g| g.optimize(&config),
                BatchSize::LargeInput,
            )
        },
    );
    group.finish();
}

criterion_group!(benches, bench, optimisation);
criterion_main!(benches);

//! The solver's tests: alignments of synthetic scenes, and the residuals' analytic Jacobians
//! against finite differences.

use super::*;
use crate::config::{IntensityMapConfig, LocalMapConfig};
use crate::se3::log;
use glint_testkit::SeededRng;

/// A box room (planes at x = ±6, y = ±4, z = 0 and 3) with edges along its vertical corners.
fn room() -> (LocalMap, LocalMap, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let mut planes = LocalMap::new(&LocalMapConfig::default());
    let mut edges = LocalMap::new(&LocalMapConfig {
        min_spacing: 0.05,
        ..LocalMapConfig::default()
    });
    let mut plane_pts = Vec::new();
    let mut edge_pts = Vec::new();
    let step = 0.25;
    for i in 0..=48 {
        for j in 0..=12 {
            let (a, b) = (-6.0 + i as f64 * step, j as f64 * step);
            for p in [Vector3::new(a, -4.0, b), Vector3::new(a, 4.0, b)] {
                plane_pts.push(p);
            }
        }
    }
    for i in 0..=32 {
        for j in 0..=12 {
            let (a, b) = (-4.0 + i as f64 * step, j as f64 * step);
            plane_pts.push(Vector3::new(-6.0, a, b));
            plane_pts.push(Vector3::new(6.0, a, b));
        }
    }
    for i in 0..=48 {
        for j in 0..=32 {
            plane_pts.push(Vector3::new(
                -6.0 + i as f64 * step,
                -4.0 + j as f64 * step,
                0.0,
            ));
        }
    }
    for k in 0..=30 {
        for (x, y) in [(-6.0, -4.0), (-6.0, 4.0), (6.0, -4.0), (6.0, 4.0)] {
            edge_pts.push(Vector3::new(x, y, k as f64 * 0.1));
        }
    }
    for p in &plane_pts {
        planes.insert(p.cast());
    }
    for p in &edge_pts {
        edges.insert(p.cast());
    }
    (edges, planes, edge_pts, plane_pts)
}

#[test]
fn closed_form_eigen_matches_the_iterative_solver() {
    let mut rng = SeededRng::new(7);
    let mut next = || rng.centred();
    for _ in 0..200 {
        let m = Matrix3::from_fn(|_, _| next());
        let a = m * m.transpose();
        let (values, vectors) = eigen3(&a);
        for i in 0..3 {
            assert!(
                (a * vectors[i] - vectors[i] * values[i]).norm() < 1e-9,
                "{a} {values:?}"
            );
        }
        assert!(values[0] <= values[1] && values[1] <= values[2]);
    }
    // Repeated eigenvalues go through the fallback.
    let (values, _) = eigen3(&Matrix3::identity());
    assert_eq!(values, [1.0, 1.0, 1.0]);
}

#[test]
fn a_planar_neighbourhood_s_normal_is_its_smallest_eigenvector() {
    let mut rng = SeededRng::new(11);
    let mut next = || rng.centred();
    for _ in 0..200 {
        // Five points on a tilted plane, 0.4 m across, with 1 cm of noise off it.
        let normal = Vector3::new(next(), next(), next()).normalize();
        let u = normal
            .cross(&Vector3::new(next(), next(), next()))
            .normalize();
        let v = normal.cross(&u);
        let origin = Vector3::new(next(), next(), next()) * 40.0;
        let points: Vec<Vector3<f32>> = (0..5)
            .map(|_| {
                let p = origin + u * 0.8 * next() + v * 0.8 * next() + normal * 0.02 * next();
                p.cast()
            })
            .collect();
        let (_, a) = covariance(&points);
        let (_, vectors) = eigen3(&a);
        let found = plane_normal(&a).expect("a plane has a normal");
        // Within 0.15 mrad, when five random points may come close to a line.
        assert!(
            found.dot(&vectors[0]).abs() > 1.0 - 1e-8,
            "{found} vs {}",
            vectors[0]
        );
    }
    // Points on a line, or all in one place, have none.
    let line: Vec<Vector3<f32>> = (0..5)
        .map(|i| Vector3::new(1.0, 2.0, 3.0) * (0.1 * i as f32))
        .collect();
    assert_eq!(plane_normal(&covariance(&line).1), None);
    assert_eq!(plane_normal(&Matrix3::zeros()), None);
}

#[test]
fn recovers_a_known_offset() {
    let (edges, planes, edge_pts, plane_pts) = room();
    let intensity = IntensityMap::new(&IntensityMapConfig::default());
    let truth = exp(&Vector6::new(0.01, -0.02, 0.05, 0.3, -0.2, 0.05));
    // The scan sees the room from the true pose: its points are truth⁻¹·world.
    let inverse = truth.inverse();
    let input = AlignmentInput {
        edges: edge_pts
            .iter()
            .step_by(3)
            .map(|p| (inverse * Point3::from(*p)).coords)
            .collect(),
        planes: plane_pts
            .iter()
            .step_by(7)
            .map(|p| (inverse * Point3::from(*p)).coords)
            .collect(),
        intensity: Vec::new(),
    };
    let maps = MapView {
        edges: &edges,
        planes: &planes,
        intensity: &intensity,
    };
    let a = align(
        &Isometry3::identity(),
        &input,
        maps,
        &SolverConfig::default(),
    );
    let error = log(&(a.pose.inverse() * truth));
    assert!(error.norm() < 1e-4, "error {error}, {a:?}");
    assert!(!a.degenerate, "{}", a.degeneracy);
    // Every direction measured: the residuals add little to the floors.
    let config = SolverConfig::default();
    for i in 0..6 {
        let floor = if i < 3 {
            config.angular_noise
        } else {
            config.motion_noise
        };
        let sigma = a.covariance[(i, i)].sqrt();
        assert!(
            sigma >= floor && sigma < 1.5 * floor,
            "{i}: {}",
            a.covariance
        );
    }
    assert_eq!(a.covariance, a.covariance.transpose());
}

#[test]
fn a_corridor_is_degenerate_along_its_axis() {
    // Two walls and a floor, all parallel to x.
    let mut planes = LocalMap::new(&LocalMapConfig::default());
    let mut pts = Vec::new();
    for i in 0..200 {
        for j in 0..12 {
            let x = -25.0 + i as f64 * 0.25;
            let h = j as f64 * 0.25;
            pts.extend([
                Vector3::new(x, -1.75, h),
                Vector3::new(x, 1.75, h),
                Vector3::new(x, -1.75 + h, 0.0),
            ]);
        }
    }
    for p in &pts {
        planes.insert(p.cast());
    }
    let edges = LocalMap::new(&LocalMapConfig::default());
    let intensity = IntensityMap::new(&IntensityMapConfig::default());
    let input = AlignmentInput {
        edges: vec![],
        planes: pts.iter().step_by(5).copied().collect(),
        intensity: vec![],
    };
    let maps = MapView {
        edges: &edges,
        planes: &planes,
        intensity: &intensity,
    };
    let a = align(
        &Isometry3::identity(),
        &input,
        maps,
        &SolverConfig::default(),
    );
    assert!(a.degenerate, "{}", a.degeneracy);
    assert!(
        a.weakest_direction.x.abs() > 0.99,
        "{}",
        a.weakest_direction
    );
    // The covariance says which direction: the axis was held, height was measured. (Seen
    // from 15 m away on average, roll inside the corridor is weak too, and mixes with y.)
    let c = &a.covariance;
    assert!(c[(3, 3)] >= 0.5 * HELD_SIGMA * HELD_SIGMA, "{c}");
    assert!(c[(5, 5)] < 1e-3, "{c}");
    let translation = SymmetricEigen::new(c.fixed_view::<3, 3>(3, 3).into_owned());
    let widest = translation.eigenvalues.imax();
    assert!(translation.eigenvectors[(0, widest)].abs() > 0.99, "{c}");
}

#[test]
fn intensity_resolves_the_corridor_axis() {
    // The same corridor, with reflectivity stripes on the walls every 2 m along x.
    let mut planes = LocalMap::new(&LocalMapConfig::default());
    let mut map = IntensityMap::new(&IntensityMapConfig::default());
    let stripe = |x: f64| if x.rem_euclid(2.0) < 0.6 { 80.0 } else { 20.0 };
    for i in 0..500 {
        for j in 0..30 {
            let x = -25.0 + i as f64 * 0.1;
            let h = 0.1 + j as f64 * 0.1;
            for y in [-1.75, 1.75] {
                let p = Vector3::new(x, y, h);
                planes.insert(p.cast());
                map.insert(&p.cast(), stripe(x) as f32);
            }
        }
    }
    let edges = LocalMap::new(&LocalMapConfig::default());
    let truth = exp(&Vector6::new(0.0, 0.0, 0.0, 0.15, 0.0, 0.0));
    let inverse = truth.inverse();
    // The scan samples the walls on its own lattice, offset from the map's, as a sensor
    // would: near the stripes' edges for intensity, everywhere for planes.
    let scan: Vec<Vector3<f64>> = (0..495)
        .flat_map(|i| {
            (0..29).flat_map(move |j| {
                [-1.75, 1.75]
                    .map(|y| Vector3::new(-24.7 + i as f64 * 0.1 + 0.037, y, 0.15 + j as f64 * 0.1))
            })
        })
        .collect();
    let input = AlignmentInput {
        edges: vec![],
        planes: scan
            .iter()
            .step_by(11)
            .map(|p| (inverse * Point3::from(*p)).coords)
            .collect(),
        intensity: scan
            .iter()
            .filter(|p| {
                let f = p.x.rem_euclid(2.0);
                f.min((f - 0.6).abs()).min(2.0 - f) < 0.3
            })
            .map(|p| IntensityPoint {
                point: (inverse * Point3::from(*p)).coords,
                eta: stripe(p.x),
                normal: inverse.rotation * Vector3::y(),
            })
            .collect(),
    };
    let maps = MapView {
        edges: &edges,
        planes: &planes,
        intensity: &map,
    };
    let a = align(
        &Isometry3::identity(),
        &input,
        maps,
        &SolverConfig::default(),
    );
    assert!(
        (a.pose.translation.vector.x - 0.15).abs() < 0.02,
        "{}",
        a.pose.translation.vector
    );
    let geometry_only = SolverConfig {
        use_intensity: false,
        ..SolverConfig::default()
    };
    let g = align(&Isometry3::identity(), &input, maps, &geometry_only);
    assert!(
        g.pose.translation.vector.x.abs() < 0.05,
        "geometry alone cannot see the offset"
    );
    // With intensity the axis is measured (to about the floor); without, it was held.
    let (with, without) = (a.covariance[(3, 3)], g.covariance[(3, 3)]);
    assert!(with < 1e-3, "{}", a.covariance);
    assert!(without >= 0.5 * HELD_SIGMA * HELD_SIGMA, "{}", g.covariance);
    // Trilinear cells make the cost piecewise smooth: near the minimum a step can raise it
    // by a hair however it is damped. Stopping there (`cost_tolerance`) instead of retrying
    // saves trials and gives the same pose (compared with no step tolerance, which would
    // end both first).
    let stopping = SolverConfig {
        convergence: 0.0,
        ..SolverConfig::default()
    };
    let retrying = SolverConfig {
        cost_tolerance: 0.0,
        ..stopping.clone()
    };
    let s = align(&Isometry3::identity(), &input, maps, &stopping);
    let r = align(&Isometry3::identity(), &input, maps, &retrying);
    assert!(
        s.iterations < r.iterations,
        "{} trials stopping, {} retrying",
        s.iterations,
        r.iterations
    );
    for stopped in [&a, &s] {
        assert!(
            (stopped.pose.translation.vector - r.pose.translation.vector).norm() < 0.005,
            "{} against {}",
            stopped.pose.translation.vector,
            r.pose.translation.vector
        );
    }
}

mod jacobians {
    use super::*;
    use crate::config::IntensityMapConfig;
    use crate::se3::exp;

    /// The intensity residual's analytic gradient of the cost equals the finite-difference one,
    /// for rotation and translation alike.
    #[test]
    fn intensity_gradient_matches_finite_differences() {
        let mut map = IntensityMap::new(&IntensityMapConfig {
            voxel: 0.2,
            max_count: 20,
            min_weight: 0.5,
        });
        let field = |p: &Vector3<f64>| {
            50.0 + 20.0 * (1.3 * p.x).sin() + 10.0 * (0.7 * p.y + 0.4 * p.z).cos()
        };
        for i in -60..60 {
            for j in -60..60 {
                for k in -10..10 {
                    let p = Vector3::new(
                        i as f64 * 0.1 + 0.05,
                        j as f64 * 0.1 + 0.05,
                        k as f64 * 0.1 + 0.05,
                    );
                    map.insert(&p.cast(), field(&p) as f32);
                }
            }
        }
        let pose = exp(&Vector6::new(0.05, -0.03, 0.2, 0.3, -0.2, 0.1));
        let points: Vec<IntensityPoint> = (0..40)
            .map(|i| {
                let p = Vector3::new(
                    (i % 7) as f64 * 0.6 - 2.0,
                    (i % 5) as f64 * 0.5 - 1.0,
                    (i % 3) as f64 * 0.2 - 0.2,
                );
                IntensityPoint {
                    point: p,
                    eta: field(&p) + 3.0,
                    normal: Vector3::zeros(),
                }
            })
            .collect();
        let input = AlignmentInput {
            edges: vec![],
            planes: vec![],
            intensity: points,
        };
        let config = SolverConfig {
            huber_intensity: 1e9,
            intensity_weight: 0.01,
            ..SolverConfig::default()
        };
        let cost = |pose: &Isometry3<f64>| {
            build(
                pose,
                &[],
                &input,
                &map,
                &config,
                &mut Vec::new(),
                IntensitySet::Select,
            )
        };
        assert_gradient_matches(cost, &pose, 1e-3);
    }

    /// Within a round, trials keep the residuals of the round's first system: a point moved out
    /// of the map's cover by a millimetre still counts, so the costs compared are sums over the
    /// same residuals.
    #[test]
    fn trials_keep_the_rounds_intensity_residuals() {
        // The weight crosses the map's 0.5 at x = 1.
        let map = crate::intensity_map::one_cell_map(40.0);
        let input = AlignmentInput {
            edges: vec![],
            planes: vec![],
            intensity: vec![IntensityPoint {
                point: Vector3::new(0.995, 0.5, 0.5),
                eta: 60.0,
                normal: Vector3::zeros(),
            }],
        };
        let config = SolverConfig::default();
        let moved = Isometry3::translation(0.01, 0.0, 0.0);
        let mut links = Vec::new();
        let at = |pose: &Isometry3<f64>, links: &mut Vec<IntensityLink>, set| {
            build(pose, &[], &input, &map, &config, links, set)
        };
        let start = at(&Isometry3::identity(), &mut links, IntensitySet::Select);
        assert_eq!(start.intensity, 1);
        let kept = at(&moved, &mut links, IntensitySet::Keep);
        assert_eq!(kept.intensity, 1, "the trial keeps the residual");
        assert!((kept.cost - start.cost).abs() < 1e-3 * start.cost);
        let selected = at(&moved, &mut links, IntensitySet::Select);
        assert_eq!(selected.intensity, 0, "a new round selects afresh");
        // And a point the round left out stays out.
        let kept = at(&Isometry3::identity(), &mut links, IntensitySet::Keep);
        assert_eq!(kept.intensity, 0);
    }

    /// `cost`'s gradient at `pose` equals central finite differences along each axis of the
    /// perturbation, to `tolerance` relative.
    fn assert_gradient_matches(
        cost: impl Fn(&Isometry3<f64>) -> System,
        pose: &Isometry3<f64>,
        tolerance: f64,
    ) {
        let system = cost(pose);
        for axis in 0..6 {
            let mut d = Vector6::zeros();
            d[axis] = 1e-6;
            let plus = cost(&(exp(&d) * pose)).cost;
            let minus = cost(&(exp(&-d) * pose)).cost;
            let fd = (plus - minus) / 2e-6;
            assert!(
                (fd - system.gradient[axis]).abs() < tolerance * (1.0 + fd.abs()),
                "axis {axis}: fd {fd} vs {}",
                system.gradient[axis]
            );
        }
    }

    /// Both geometric residuals' analytic gradients equal the finite-difference ones.
    #[test]
    fn geometric_gradient_matches_finite_differences() {
        let direction = Vector3::new(0.3, -0.5, 0.8).normalize();
        for shape in [Shape::Plane(direction), Shape::Line(direction)] {
            let model = Model {
                point: Vector3::new(1.0, 2.0, 0.5),
                center: Vector3::new(0.8, 2.5, 0.4),
                shape,
                scale: 0.37_f64.sqrt(),
            };
            let map = IntensityMap::new(&IntensityMapConfig::default());
            let input = AlignmentInput::default();
            let config = SolverConfig {
                huber_geometric: 1e9,
                ..SolverConfig::default()
            };
            let cost = |pose: &Isometry3<f64>| {
                build(
                    pose,
                    &[model],
                    &input,
                    &map,
                    &config,
                    &mut Vec::new(),
                    IntensitySet::Select,
                )
            };
            let pose = exp(&Vector6::new(0.1, 0.2, -0.3, 0.5, 0.1, -0.2));
            assert_gradient_matches(cost, &pose, 1e-6);
        }
    }

    /// A wall seen head-on keeps its full weight whatever its range; ground seen at a grazing
    /// angle loses weight with range, as r·δ outgrows the range noise; a line is weighted by the
    /// same lever.
    #[test]
    fn residual_weights_follow_the_angular_lever() {
        let config = SolverConfig::default();
        let pose = exp(&Vector6::new(0.0, 0.0, 0.7, 1.0, -2.0, 0.3));
        let world = |v: Vector3<f64>| pose.rotation * v;
        let wall = Shape::Plane(world(Vector3::x()));
        let ground = Shape::Plane(world(Vector3::z()));
        let weight = |p: Vector3<f64>, shape: &Shape| residual_weight(&pose, &p, shape, &config);
        assert!((weight(Vector3::new(40.0, 0.0, 0.0), &wall) - 1.0).abs() < 1e-12);
        let near = weight(Vector3::new(3.0, 0.0, -0.9), &ground);
        let far = weight(Vector3::new(30.0, 0.0, -0.9), &ground);
        // σ² / (σ² + (30 m · δ)²) with σ = 2 cm, δ = 2 mrad: 0.1.
        assert!((far - 0.0004 / (0.0004 + 0.0036)).abs() < 1e-3, "{far}");
        assert!(near > 0.5 && near < 1.0, "{near}");
        let pole = Shape::Line(world(Vector3::z()));
        let w = weight(Vector3::new(30.0, 0.0, 0.0), &pole);
        assert!((w - far).abs() < 1e-3, "{w}");
        let flat = SolverConfig {
            angular_noise: 0.0,
            ..SolverConfig::default()
        };
        assert_eq!(
            residual_weight(&pose, &Vector3::new(30.0, 0.0, -0.9), &ground, &flat),
            1.0
        );
    }
}

//! The floor as a landmark of the pose graph. An AGV drives on one flat floor, and every sweep
//! sees it around the robot, so each keyframe measures its own height above the floor and its
//! tilt against it. Odometry alone lets height and tilt wander (a tilt of a few mrad held over
//! tens of metres bends the map into a saddle of ±0.1 m); loops cannot remove that when the
//! error returns to near zero where the loop closes. So the back end ties every keyframe that
//! sees the floor to the one floor plane: hdl_graph_slam's floor constraint, here as an
//! ordinary `EDGE_SE3:QUAT` from the fixed first node whose information spans only height and
//! tilt (see [`FloorMeasurement::edge`]), so the graph, its optimiser and its g2o files need
//! nothing new.
//!
//! Planes are `n·x + d = 0` with `n` a unit normal pointing to the side the sensor is on, so
//! `d` is the sensor's height above the plane in the frame the plane is expressed in.

use nalgebra::{Isometry3, Matrix3, Matrix6, SymmetricEigen, UnitQuaternion, Vector3};

use super::config::FloorConfig;
use super::pose_graph::Edge;

/// A plane `normal·x + offset = 0`, `normal` unit length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vector3<f64>,
    /// Offset: the origin's signed distance from the plane.
    pub offset: f64,
}

impl Plane {
    /// The same plane in frame A, given this one in frame B and `a_from_b`.
    pub fn transformed(&self, a_from_b: &Isometry3<f64>) -> Plane {
        let normal = a_from_b.rotation * self.normal;
        Plane {
            normal,
            offset: self.offset - normal.dot(&a_from_b.translation.vector),
        }
    }

    /// Signed distance of `p` from the plane.
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) + self.offset
    }
}

/// One keyframe's view of the floor, in its sensor frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorMeasurement {
    /// The fitted floor, its normal towards the sensor.
    pub plane: Plane,
    /// Returns it was fitted to.
    pub points: usize,
    /// Their RMS distance from it, m.
    pub rms: f64,
}

/// Fits the floor to `points` (sensor frame). `expected` is where the graph says the floor
/// is, in the same frame; without it (the first floor of a run) the sensor's z axis is taken
/// as up, as a VLP-16 sits level on an AGV, and the floor is looked for at least
/// `config.min_clearance` below the sensor. Returns `None` unless enough returns within
/// `config.radius` form a plane spread in two directions, flat to `config.max_rms`, within
/// `config.max_tilt` of the expected normal (or of z) and `config.search_band` of the
/// expected plane.
pub fn measure(
    points: impl IntoIterator<Item = Vector3<f64>>,
    expected: Option<&Plane>,
    config: &FloorConfig,
) -> Option<FloorMeasurement> {
    let reference = expected.copied().unwrap_or(Plane {
        normal: Vector3::z(),
        offset: 0.0,
    });
    let near: Vec<Vector3<f64>> = points
        .into_iter()
        .filter(|p| {
            let up = reference.normal;
            p.iter().all(|v| v.is_finite()) && (p - up * up.dot(p)).norm() <= config.radius
        })
        .collect();
    // The most crowded layer parallel to the reference, where the floor may be: kerbs, pallets
    // and the feet of walls and racks are near it too, and a least-squares fit over all of
    // them would tilt towards them. Without a reference, the layer is searched over every tilt
    // up to `max_tilt`: a floor 12 m across seen 2° tilted spans eight layers.
    let normals = match expected {
        Some(e) => vec![e.normal],
        None => tilts(config),
    };
    let (up, layer, _) = normals
        .into_iter()
        .filter_map(|normal| {
            let reference = Plane {
                normal,
                ..reference
            };
            let heights = near.iter().map(|p| reference.distance(p));
            let (layer, count) = crowded_layer(heights, |h| match expected {
                Some(_) => h.abs() <= config.search_band,
                None => h <= -config.min_clearance,
            })?;
            Some((normal, layer, count))
        })
        .max_by_key(|&(_, _, count)| count)?;
    let mut plane = Plane {
        normal: up,
        offset: reference.offset - layer,
    };
    let mut band = LAYER;
    let mut fit = None;
    // Each pass refits within at most half the last band (and 3 RMS of the last fit), down to
    // the floor's own noise.
    for _ in 0..3 {
        let inliers: Vec<&Vector3<f64>> = near
            .iter()
            .filter(|p| plane.distance(p).abs() <= band)
            .collect();
        let f = fit_plane(&inliers, config)?;
        plane = f.plane;
        band = (3.0 * f.rms).min(0.5 * band).max(0.03);
        fit = Some(f);
    }
    let fit = fit?;
    let tilt = fit.plane.normal.angle(&up);
    let height_change = (fit.plane.offset - reference.offset).abs();
    // Narrowing bands would slice a thin layer out of any rough surface, or a strip out of a
    // floor tilted beyond the search (a ramp): the floor must hold at least half the returns
    // below `search_band` above it (on the simulated floors, three quarters: pallets and the
    // feet of racks and walls are the rest).
    let low = near
        .iter()
        .filter(|p| fit.plane.distance(p) <= config.search_band)
        .count();
    (2 * fit.points >= low
        && fit.rms <= config.max_rms
        && tilt <= config.max_tilt
        && (expected.is_none() || height_change <= config.search_band))
        .then_some(fit)
}

/// Thickness of the layers in which the floor is first looked for, m.
const LAYER: f64 = 0.1;

/// Unit normals tilted from z by up to `config.max_tilt` about x and y, in steps that move the
/// floor at `config.radius` by half a layer.
fn tilts(config: &FloorConfig) -> Vec<Vector3<f64>> {
    let limit = config.max_tilt.tan();
    let step = 0.5 * LAYER / config.radius.max(LAYER);
    let n = if limit.is_finite() {
        (limit / step).ceil().min(100.0) as i32
    } else {
        0
    };
    let slopes = (-n..=n).map(|k| k as f64 * step);
    slopes
        .clone()
        .flat_map(|a| {
            slopes
                .clone()
                .map(move |b| Vector3::new(a, b, 1.0).normalize())
        })
        .collect()
}

/// The centre of the most populated `LAYER`-thick layer among the `heights` that `allowed`
/// keeps, and its count; ties go to the lower layer.
fn crowded_layer(
    heights: impl Iterator<Item = f64>,
    allowed: impl Fn(f64) -> bool,
) -> Option<(f64, usize)> {
    let mut counts: Vec<(i64, usize)> = Vec::new();
    for h in heights.filter(|&h| allowed(h)) {
        let key = (h / LAYER).floor() as i64;
        match counts.iter_mut().find(|(k, _)| *k == key) {
            Some((_, n)) => *n += 1,
            None => counts.push((key, 1)),
        }
    }
    counts.sort_unstable();
    let &(key, count) = counts.iter().rev().max_by_key(|(_, n)| *n)?;
    Some(((key as f64 + 0.5) * LAYER, count))
}

/// Least-squares plane through `points`, its normal towards the origin (the sensor), or `None`
/// when too few points or too little spread in the plane's second direction.
fn fit_plane(points: &[&Vector3<f64>], config: &FloorConfig) -> Option<FloorMeasurement> {
    if points.len() < config.min_points.max(3) {
        return None;
    }
    let n = points.len() as f64;
    let mean = points.iter().fold(Vector3::zeros(), |a, p| a + *p) / n;
    let covariance = points.iter().fold(Matrix3::zeros(), |a, p| {
        let d = *p - mean;
        a + d * d.transpose()
    }) / n;
    let eigen = SymmetricEigen::new(covariance);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    // The floor around the robot is seen along rings: points on one line would leave the tilt
    // about that line free.
    if eigen.eigenvalues[order[1]] < config.min_spread * config.min_spread {
        return None;
    }
    let mut normal: Vector3<f64> = eigen.eigenvectors.column(order[0]).into();
    let mut offset = -normal.dot(&mean);
    if offset < 0.0 {
        normal = -normal;
        offset = -offset;
    }
    Some(FloorMeasurement {
        plane: Plane { normal, offset },
        points: points.len(),
        rms: eigen.eigenvalues[order[0]].max(0.0).sqrt(),
    })
}

impl FloorMeasurement {
    /// The graph edge that ties a node to the floor: from `anchor` (a fixed node at
    /// `anchor_pose`) to `node` (sensor → map `node_pose`), given the floor `world` in the map
    /// frame. Its measurement is the node's pose moved the least (turned about a horizontal
    /// axis, shifted along the floor's normal) to see the floor as measured, and its
    /// information spans only the three directions the floor fixes: height along the measured
    /// normal `u` (sensor frame), and rotation about the two axes perpendicular to it. Yaw and
    /// position along the floor are free, so the edge holds exactly at any of them: the error's
    /// translation along `u` is the height error, and a yaw about the normal leaves a rotation
    /// error along `u`, which has no information.
    pub fn edge(
        &self,
        world: &Plane,
        anchor: usize,
        anchor_pose: &Isometry3<f64>,
        node: usize,
        node_pose: &Isometry3<f64>,
        config: &FloorConfig,
    ) -> Edge {
        let seen = node_pose.rotation * self.plane.normal;
        let turn = UnitQuaternion::rotation_between(&seen, &world.normal)
            .unwrap_or_else(UnitQuaternion::identity);
        let rotation = turn * node_pose.rotation;
        let t = node_pose.translation.vector;
        // n_w·t = d_s − d_w puts the sensor at the measured height.
        let translation =
            t + world.normal * (self.plane.offset - world.offset - world.normal.dot(&t));
        let target = Isometry3::from_parts(translation.into(), rotation);
        let u = self.plane.normal;
        let along = u * u.transpose();
        let mut information = Matrix6::zeros();
        information
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(along / config.sigma_height.powi(2)));
        // The error's rotation part is a quaternion's vector part, ≈ θ/2.
        information
            .fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&((Matrix3::identity() - along) * (4.0 / config.sigma_tilt.powi(2))));
        Edge {
            from: anchor,
            to: node,
            measurement: anchor_pose.inverse() * target,
            information,
            robust: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::pose_graph::edge_error;
    use glint_testkit::SeededRng;

    /// A floor seen from `height` up, along rings of returns out to 20 m, a wall and a pallet
    /// top; then the whole scene as seen by a sensor tilted by `tilt` (sensor → level).
    fn scene(height: f64, tilt: &UnitQuaternion<f64>, seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = SeededRng::new(seed);
        let mut noise = || rng.centred();
        let mut points = Vec::new();
        for ring in 0..8 {
            let r = 3.0 + 2.3 * ring as f64;
            for k in 0..200 {
                let a = k as f64 * std::f64::consts::TAU / 200.0;
                points.push(Vector3::new(
                    r * a.cos(),
                    r * a.sin(),
                    -height + 0.01 * noise(),
                ));
            }
        }
        // A wall 6 m ahead and a pallet's top 0.15 m above the floor, one return per 0.1 m.
        for i in 0..80 {
            for k in 0..30 {
                let (y, z) = (-4.0 + 0.1 * i as f64, -height + 0.1 * k as f64);
                points.push(Vector3::new(6.0, y, z));
            }
        }
        for i in 0..12 {
            for k in 0..8 {
                let (x, y) = (-3.0 + 0.1 * i as f64, 2.0 + 0.1 * k as f64);
                points.push(Vector3::new(x, y, -height + 0.15));
            }
        }
        let level_from_sensor = Isometry3::from_parts(Vector3::zeros().into(), *tilt);
        let sensor_from_level = level_from_sensor.inverse();
        points.iter().map(|p| sensor_from_level * p).collect()
    }

    #[test]
    fn the_floor_is_found_under_a_tilted_sensor() {
        let config = FloorConfig::default();
        let tilt = UnitQuaternion::from_scaled_axis(Vector3::new(0.02, -0.03, 0.4));
        let points = scene(0.8, &tilt, 1);
        let f = measure(points.iter().copied(), None, &config).expect("a floor");
        // The level floor's normal, seen from the tilted sensor.
        let truth = tilt.inverse() * Vector3::z();
        assert!(f.plane.normal.angle(&truth) < 1e-3, "{:?}", f.plane);
        assert!((f.plane.offset - 0.8).abs() < 0.01, "{:?}", f.plane);
        assert!(f.rms < 0.02);

        // Given where the graph expects it, the same; a floor 0.5 m off or 0.1 rad away is
        // not this one.
        let expected = Plane {
            normal: truth,
            offset: 0.85,
        };
        let g = measure(points.iter().copied(), Some(&expected), &config).expect("a floor");
        assert!(g.plane.normal.angle(&truth) < 1e-3);
        let far = Plane {
            normal: truth,
            offset: 1.3,
        };
        assert!(measure(points.iter().copied(), Some(&far), &config).is_none());
        let steep = Plane {
            normal: UnitQuaternion::from_scaled_axis(Vector3::x() * 0.1) * truth,
            offset: 0.8,
        };
        assert!(measure(points.iter().copied(), Some(&steep), &config).is_none());
    }

    #[test]
    fn no_floor_from_a_line_a_wall_or_nothing() {
        let config = FloorConfig::default();
        assert!(measure(Vec::new(), None, &config).is_none());
        let line = (0..500).map(|k| Vector3::new(0.02 * k as f64, 1.0, -0.8));
        assert!(measure(line, None, &config).is_none());
        // A ramp's rough slope: not flat.
        let mut rng = SeededRng::new(3);
        let mut noise = || rng.centred();
        let rough: Vec<Vector3<f64>> = (0..2000)
            .map(|k| {
                let (x, y) = ((k % 40) as f64 * 0.25, (k / 40) as f64 * 0.25 - 6.0);
                Vector3::new(x, y, -0.8 + 0.2 * noise())
            })
            .collect();
        assert!(measure(rough, None, &config).is_none());
    }

    #[test]
    fn the_floor_edge_fixes_height_and_tilt_and_nothing_else() {
        let config = FloorConfig::default();
        let world = Plane {
            normal: Vector3::z(),
            offset: 0.0,
        };
        let anchor = Isometry3::new(Vector3::new(1.0, 2.0, 0.8), Vector3::z() * 0.3);
        // The node believes it is 0.1 m too high and tilted by 10 mrad; it sees the floor
        // 0.8 m below, level.
        let truth = Isometry3::new(Vector3::new(20.0, 5.0, 0.8), Vector3::z() * 1.2);
        let wrong = Isometry3::from_parts(
            (truth.translation.vector + Vector3::z() * 0.1).into(),
            UnitQuaternion::from_scaled_axis(Vector3::x() * 0.01) * truth.rotation,
        );
        let seen = FloorMeasurement {
            plane: world.transformed(&truth.inverse()),
            points: 500,
            rms: 0.01,
        };
        assert!((seen.plane.offset - 0.8).abs() < 1e-12);
        let edge = seen.edge(&world, 0, &anchor, 7, &wrong, &config);
        let chi2 = |pose: &Isometry3<f64>| {
            let e = edge_error(&edge, &anchor, pose);
            (e.transpose() * edge.information * e)[0]
        };
        assert!(chi2(&truth) < 1e-12, "{}", chi2(&truth));
        // Any yaw and any position along the floor still fit.
        let elsewhere = Isometry3::new(Vector3::new(-4.0, 9.0, 0.0), Vector3::z() * 2.0) * truth;
        assert!(chi2(&elsewhere) < 1e-12, "{}", chi2(&elsewhere));
        // Height and tilt do not: 0.1 m is (0.1 / σ)² and 10 mrad (0.01 / σ)².
        let expected = (0.1 / config.sigma_height).powi(2) + (0.01 / config.sigma_tilt).powi(2);
        assert!(
            (chi2(&wrong) / expected - 1.0).abs() < 0.01,
            "{}",
            chi2(&wrong)
        );
    }
}

//! Step 6 of the method: keyframes. A cheap decision per sweep (moved, turned or waited enough
//! since the last keyframe), meant for the odometry's thread, and the keyframe itself: the
//! sweep's time and odometry pose with a bounded, voxel-thinned copy of its deskewed features
//! and calibrated returns in the sensor frame — all the back end needs, so it never touches the
//! odometry's state.

use nalgebra::{Isometry3, Vector3};
use rustc_hash::FxHashMap;

use super::config::KeyframeConfig;
use crate::solver::AlignmentInput;

/// Decides which sweeps become keyframes.
#[derive(Debug, Clone, Default)]
pub struct KeyframeSelector {
    last: Option<(u64, Isometry3<f64>)>,
}

impl KeyframeSelector {
    /// A selector that takes the first sweep it sees.
    pub fn new() -> Self {
        Self::default()
    }

    /// Whether the sweep at `time_ns` with odometry pose `pose` (sensor → odom) is a keyframe;
    /// if so it becomes the reference for the next decision.
    pub fn is_keyframe(
        &mut self,
        time_ns: u64,
        pose: &Isometry3<f64>,
        config: &KeyframeConfig,
    ) -> bool {
        let take = match self.last {
            None => true,
            Some((t, last)) => {
                let relative = last.inverse() * pose;
                relative.translation.vector.norm() >= config.min_distance
                    || relative.rotation.angle() >= config.min_rotation
                    || time_ns.saturating_sub(t) >= config.max_interval_ns
            }
        };
        if take {
            self.last = Some((time_ns, *pose));
        }
        take
    }
}

/// A point of a keyframe's cloud: position in the sensor frame (m) and calibrated
/// reflectivity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CloudPoint {
    /// Sensor frame, m.
    pub position: [f32; 3],
    /// Calibrated reflectivity η.
    pub eta: f32,
}

/// One keyframe. Its size is bounded by [`KeyframeConfig`]: with the defaults at most
/// 1000 + 1500 points of 12 bytes and 3000 of 16, about 78 kB.
#[derive(Debug, Clone, PartialEq)]
pub struct Keyframe {
    /// The sweep's reference time, ns since the epoch.
    pub time_ns: u64,
    /// Sensor → odom at `time_ns`, as the odometry published it.
    pub odom_pose: Isometry3<f64>,
    /// Edge points, sensor frame at `time_ns` (deskewed), m.
    pub edges: Vec<[f32; 3]>,
    /// Planar points, likewise.
    pub planes: Vec<[f32; 3]>,
    /// Calibrated returns, likewise, one per voxel (the brightest).
    pub cloud: Vec<CloudPoint>,
}

impl Keyframe {
    /// Whether it holds points to register against (a redundant keyframe released them).
    pub fn holds_points(&self) -> bool {
        !(self.edges.is_empty() && self.planes.is_empty())
    }

    /// A keyframe from the odometry's deskewed alignment input (edges and planes in the sensor
    /// frame at the reference time) and the sweep's calibrated returns in the same frame
    /// (`Odometry::map_points` at the identity pose).
    pub fn new(
        time_ns: u64,
        odom_pose: Isometry3<f64>,
        input: &AlignmentInput,
        calibrated: impl IntoIterator<Item = (Vector3<f32>, f32)>,
        config: &KeyframeConfig,
    ) -> Self {
        let edges = thin(
            input.edges.iter().map(|p| (p.cast::<f32>(), 0.0)),
            config.voxel,
            config.max_edges,
        )
        .into_iter()
        .map(|p| p.position)
        .collect();
        let planes = thin(
            input.planes.iter().map(|p| (p.cast::<f32>(), 0.0)),
            config.voxel,
            config.max_planes,
        )
        .into_iter()
        .map(|p| p.position)
        .collect();
        let cloud = thin(calibrated, config.voxel, config.max_cloud);
        Self {
            time_ns,
            odom_pose,
            edges,
            planes,
            cloud,
        }
    }
}

/// One point per voxel (the first seen, its reflectivity raised to the voxel's brightest, as
/// the descriptor keeps maxima), then at most `max` of them, evenly strided. The result's order
/// follows the input's, so it is deterministic.
fn thin(
    points: impl IntoIterator<Item = (Vector3<f32>, f32)>,
    voxel: f32,
    max: usize,
) -> Vec<CloudPoint> {
    let mut index: FxHashMap<[i32; 3], usize> = FxHashMap::default();
    let mut out: Vec<CloudPoint> = Vec::new();
    let inverse = 1.0 / voxel.max(1e-3);
    for (p, eta) in points {
        if !(p.iter().all(|v| v.is_finite()) && eta.is_finite()) {
            continue;
        }
        let key = [
            (p.x * inverse).floor() as i32,
            (p.y * inverse).floor() as i32,
            (p.z * inverse).floor() as i32,
        ];
        match index.get(&key) {
            Some(&i) => out[i].eta = out[i].eta.max(eta),
            None => {
                index.insert(key, out.len());
                out.push(CloudPoint {
                    position: [p.x, p.y, p.z],
                    eta,
                });
            }
        }
    }
    if out.len() > max && max > 0 {
        let n = out.len();
        out = (0..max).map(|i| out[i * n / max]).collect();
    } else if max == 0 {
        out.clear();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn keyframes_come_by_distance_rotation_and_time() {
        let config = KeyframeConfig::default();
        let mut s = KeyframeSelector::new();
        let at = |x: f64, yaw: f64| Isometry3::new(Vector3::new(x, 0.0, 0.0), Vector3::z() * yaw);
        assert!(s.is_keyframe(0, &at(0.0, 0.0), &config));
        assert!(!s.is_keyframe(100_000_000, &at(0.5, 0.0), &config));
        assert!(s.is_keyframe(200_000_000, &at(1.01, 0.0), &config));
        assert!(!s.is_keyframe(300_000_000, &at(1.02, 0.1), &config));
        assert!(s.is_keyframe(400_000_000, &at(1.02, 0.3), &config));
        assert!(!s.is_keyframe(5_000_000_000, &at(1.02, 0.3), &config));
        assert!(s.is_keyframe(5_400_000_000, &at(1.02, 0.3), &config));
    }

    #[test]
    fn keyframes_are_bounded_and_thinned() {
        let config = KeyframeConfig::default();
        let dense: Vec<Vector3<f64>> = (0..200_000)
            .map(|i| Vector3::new((i % 400) as f64 * 0.05, (i / 400) as f64 * 0.05, 0.0))
            .collect();
        let input = AlignmentInput {
            edges: dense.clone(),
            planes: dense.clone(),
            intensity: Vec::new(),
        };
        let calibrated = dense.iter().map(|p| (p.cast::<f32>(), (p.x * 3.0) as f32));
        let k = Keyframe::new(7, Isometry3::identity(), &input, calibrated, &config);
        assert_eq!(k.edges.len(), config.max_edges);
        assert_eq!(k.planes.len(), config.max_planes);
        assert_eq!(k.cloud.len(), config.max_cloud);
        // One point per 0.3 m voxel: no two kept points share one.
        let mut keys: Vec<[i32; 2]> = k
            .planes
            .iter()
            .map(|p| {
                let inverse = 1.0 / 0.3f32;
                [
                    (p[0] * inverse).floor() as i32,
                    (p[1] * inverse).floor() as i32,
                ]
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        assert_eq!(keys.len(), k.planes.len());
        // The brightest return of a voxel is kept.
        let few = thin(
            [
                (Vector3::new(0.01, 0.0, 0.0), 5.0),
                (Vector3::new(0.02, 0.0, 0.0), 9.0),
            ],
            0.3,
            10,
        );
        assert_eq!(few.len(), 1);
        assert_eq!(few[0].eta, 9.0);
    }
}

//! The saved site map as plain data: what a mapping run leaves for the runs that localise in
//! it — the keyframes with their optimised poses, points and descriptors, the intensity voxel
//! map and the pose graph's edges. Reading and writing it is `glint-map`'s job; this module
//! only holds it and derives what a reader asks of it (bounds, counts, the graph).
//!
//! The map frame is the mapping run's first base_link pose; keyframe poses are the sensor's in
//! it (sensor → map). `base_from_sensor` is the mapping robot's mounting, so the first
//! keyframe's pose is that mounting when the graph has not moved it.

use nalgebra::{Isometry3, Point3};

use crate::backend::keyframe::Keyframe;
use crate::backend::pose_graph::{Edge, PoseGraph};
use crate::backend::scan_context::ScanContext;
use crate::intensity_map::IntensityMap;

/// A site map. Its map frame is the mapping run's first base_link pose; keyframe poses are the
/// sensor's in it.
#[derive(Debug, Clone)]
pub struct SiteMap {
    /// When the map was made, ns since the Unix epoch.
    pub created_ns: u64,
    /// The sensor that made it, e.g. "VLP-16".
    pub sensor_model: String,
    /// The mapping robot's mounting: sensor → base_link.
    pub base_from_sensor: Isometry3<f64>,
    /// The keyframes, in the order the run made them; the graph's node `i` is keyframe `i`.
    pub keyframes: Vec<SiteKeyframe>,
    /// The intensity voxel map, in the map frame.
    pub intensity: IntensityMap,
    /// The pose graph's edges, between keyframe indices.
    pub edges: Vec<Edge>,
}

/// One keyframe of a site map.
#[derive(Debug, Clone, PartialEq)]
pub struct SiteKeyframe {
    /// Sensor → map, as the graph last optimised it.
    pub pose: Isometry3<f64>,
    /// Time, odom pose and points in the sensor frame; a keyframe that released its points
    /// as redundant has none, and keeps its place in the graph.
    pub keyframe: Keyframe,
    /// Its Intensity Scan Context.
    pub descriptor: ScanContext,
}

impl SiteMap {
    /// Axis-aligned bounds `(min, max)` in the map frame, m, of the keyframe positions and of
    /// every keyframe point (edges, planes, cloud) placed at its keyframe's pose; `None`
    /// without keyframes.
    pub fn extent(&self) -> Option<([f32; 3], [f32; 3])> {
        let mut bounds: Option<([f32; 3], [f32; 3])> = None;
        let mut grow = |p: [f32; 3]| {
            let (min, max) = bounds.get_or_insert((p, p));
            for a in 0..3 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        };
        for k in &self.keyframes {
            let pose = k.pose.cast::<f32>();
            let t = pose.translation.vector;
            grow([t.x, t.y, t.z]);
            let kf = &k.keyframe;
            let points = kf
                .edges
                .iter()
                .chain(&kf.planes)
                .copied()
                .chain(kf.cloud.iter().map(|c| c.position));
            for p in points {
                let q = pose * Point3::from(p);
                grow([q.x, q.y, q.z]);
            }
        }
        bounds
    }

    /// Points held by the keyframes: edges, planes and cloud together.
    pub fn point_count(&self) -> usize {
        self.keyframes
            .iter()
            .map(|k| k.keyframe.edges.len() + k.keyframe.planes.len() + k.keyframe.cloud.len())
            .sum()
    }

    /// The pose graph: a node per keyframe at its pose, the first one fixed (it anchors the
    /// map frame), and the edges.
    pub fn graph(&self) -> PoseGraph {
        PoseGraph {
            poses: self.keyframes.iter().map(|k| k.pose).collect(),
            fixed: (0..self.keyframes.len()).map(|i| i == 0).collect(),
            edges: self.edges.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix6, Vector3};

    use super::*;
    use crate::backend::config::ScanContextConfig;
    use crate::backend::keyframe::CloudPoint;
    use crate::config::IntensityMapConfig;

    fn keyframe(x: f64, yaw: f64, points: bool) -> SiteKeyframe {
        let pose = Isometry3::new(Vector3::new(x, 0.0, 0.0), Vector3::z() * yaw);
        let cloud = vec![CloudPoint {
            position: [2.0, 0.0, 0.5],
            eta: 30.0,
        }];
        let keyframe = Keyframe {
            time_ns: 1,
            odom_pose: pose,
            edges: if points {
                vec![[0.0, 1.0, -1.0]]
            } else {
                vec![]
            },
            planes: if points {
                vec![[0.0, 0.0, -2.0]]
            } else {
                vec![]
            },
            cloud: if points { cloud } else { vec![] },
        };
        let descriptor = ScanContext::new(std::iter::empty(), &ScanContextConfig::default());
        SiteKeyframe {
            pose,
            keyframe,
            descriptor,
        }
    }

    fn map(keyframes: Vec<SiteKeyframe>) -> SiteMap {
        SiteMap {
            created_ns: 0,
            sensor_model: "VLP-16".into(),
            base_from_sensor: Isometry3::identity(),
            keyframes,
            intensity: IntensityMap::new(&IntensityMapConfig::default()),
            edges: vec![Edge {
                from: 0,
                to: 1,
                measurement: Isometry3::translation(10.0, 0.0, 0.0),
                information: Matrix6::identity(),
                robust: false,
            }],
        }
    }

    #[test]
    fn the_extent_covers_positions_and_placed_points() {
        assert_eq!(map(vec![]).extent(), None);
        let turned = std::f64::consts::FRAC_PI_2;
        let m = map(vec![
            keyframe(0.0, 0.0, true),
            keyframe(10.0, turned, false),
        ]);
        let (min, max) = m.extent().unwrap();
        // The released keyframe counts by its position alone.
        let close = |a: [f32; 3], b: [f32; 3]| (0..3).all(|i| (a[i] - b[i]).abs() < 1e-5);
        assert!(close(min, [0.0, 0.0, -2.0]), "{min:?}");
        assert!(close(max, [10.0, 1.0, 0.5]), "{max:?}");
        let m = map(vec![keyframe(0.0, 0.0, true), keyframe(10.0, turned, true)]);
        let (min, max) = m.extent().unwrap();
        // Turned a quarter, the second keyframe's cloud point (2, 0) lands at (10, 2) and its
        // edge point (0, 1) at (9, 0).
        assert!(close(min, [0.0, 0.0, -2.0]), "{min:?}");
        assert!(close(max, [10.0, 2.0, 0.5]), "{max:?}");
        assert_eq!(m.point_count(), 6);
    }

    #[test]
    fn the_graph_fixes_the_first_keyframe() {
        let m = map(vec![keyframe(0.0, 0.0, true), keyframe(10.0, 0.0, false)]);
        let g = m.graph();
        assert_eq!(g.fixed, vec![true, false]);
        assert_eq!(g.poses[1], m.keyframes[1].pose);
        assert_eq!(g.edges, m.edges);
        assert!(g.validate().is_ok());
    }
}

//! Tests' scenes: an L-shaped room with a pillar and a shelf, and keyframes of it seen from
//! any pose, for the loop verification's and the localiser's tests.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::backend::config::KeyframeConfig;
use crate::backend::keyframe::Keyframe;
use crate::solver::AlignmentInput;

/// An L-shaped room with a pillar and a shelf: every direction constrained.
pub fn room() -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let mut planes = Vec::new();
    let mut edges = Vec::new();
    let step = 0.2;
    for i in 0..=100 {
        for j in 0..=15 {
            let (a, h) = (-10.0 + i as f64 * step, j as f64 * step);
            planes.push(Vector3::new(a, -6.0, h));
            planes.push(Vector3::new(a, 8.0, h));
        }
    }
    for i in 0..=70 {
        for j in 0..=15 {
            let (a, h) = (-6.0 + i as f64 * step, j as f64 * step);
            planes.push(Vector3::new(-10.0, a, h));
            planes.push(Vector3::new(10.0, a, h));
        }
    }
    for i in 0..=100 {
        for j in 0..=70 {
            planes.push(Vector3::new(
                -10.0 + i as f64 * step,
                -6.0 + j as f64 * step,
                -0.5,
            ));
        }
    }
    // A box (shelf) at (3, 2), 2 × 1 × 1.5 m.
    for i in 0..=10 {
        for j in 0..=7 {
            let (a, h) = (3.0 + i as f64 * 0.2, j as f64 * 0.2);
            planes.push(Vector3::new(a, 2.0, h));
            planes.push(Vector3::new(a, 3.0, h));
        }
    }
    for k in 0..=30 {
        let h = k as f64 * 0.1;
        for (x, y) in [
            (-10.0, -6.0),
            (10.0, 8.0),
            (3.0, 2.0),
            (5.0, 2.0),
            (-4.0, 5.0),
        ] {
            edges.push(Vector3::new(x, y, h));
        }
    }
    (planes, edges)
}

/// The room seen from `pose`: its edges and planes, no calibrated returns.
pub fn keyframe_at(pose: &Isometry3<f64>) -> Keyframe {
    let (input, _) = seen_from(pose);
    Keyframe::new(
        0,
        *pose,
        &input,
        std::iter::empty(),
        &KeyframeConfig::default(),
    )
}

/// The room seen from `pose` at `time_ns`, with calibrated returns on its surfaces whose
/// reflectivity varies along the walls (a pattern the descriptor tells places by); `odom` is
/// the keyframe's odometry pose.
pub fn keyframe_seen(pose: &Isometry3<f64>, odom: &Isometry3<f64>, time_ns: u64) -> Keyframe {
    let (input, cloud) = seen_from(pose);
    Keyframe::new(time_ns, *odom, &input, cloud, &KeyframeConfig::default())
}

/// The room's edges and planes in the frame of a sensor at `pose`, and its surfaces as
/// calibrated returns there.
fn seen_from(pose: &Isometry3<f64>) -> (AlignmentInput, Vec<(Vector3<f32>, f32)>) {
    let (planes, edges) = room();
    let inverse = pose.inverse();
    let local = |p: &Vector3<f64>| (inverse * Point3::from(*p)).coords;
    let cloud = planes
        .iter()
        .map(|p| {
            let eta = 20.0 + 60.0 * ((p.x * 0.7).sin() * (p.y * 1.3).cos()).abs();
            (local(p).cast::<f32>(), eta as f32)
        })
        .collect();
    let input = AlignmentInput {
        edges: edges.iter().map(local).collect(),
        planes: planes.iter().map(local).collect(),
        intensity: Vec::new(),
    };
    (input, cloud)
}

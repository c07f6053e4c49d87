//! How far an estimated trajectory is from the ground truth: association by time, the absolute
//! trajectory error after a rigid alignment (the number `evo_ape tum GT EST -a` reports), and
//! the KITTI-style relative error over stretches of path (drift in % and °/m); and, for a run
//! localising in a saved map, the errors in the map's own frame without alignment, the map
//! frame anchored to the ground truth through the mapping run's first pose.

use std::fmt;

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::trajectory::{interpolate, rotation_vector, StampedPose};

/// An estimated pose and the ground-truth pose at the same time, in that order.
pub type PosePair = (Isometry3<f64>, Isometry3<f64>);

/// A time interval the ground truth jumps across (a kidnapped robot): `before_ns` is its last
/// pose before the jump, `after_ns` its first after. Nothing may be interpolated across it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Jump {
    pub before_ns: u64,
    pub after_ns: u64,
}

/// Position error above which a localised pose counts as wrong, m.
pub const WRONG_POSITION_M: f64 = 0.5;
/// Heading error above which a localised pose counts as wrong, degrees.
pub const WRONG_YAW_DEG: f64 = 5.0;

/// Segment lengths (m) for the relative error: KITTI uses 100–800 m, far longer than a
/// warehouse aisle, so these span one aisle to a few.
pub const WAREHOUSE_LENGTHS: [f64; 6] = [5.0, 10.0, 20.0, 30.0, 40.0, 50.0];

/// Pairs every estimated pose inside the ground truth's time span (ends included) with the ground
/// truth interpolated at the estimate's own time. Assumes the ground truth is dense enough for
/// linear/slerp interpolation, as evo does.
pub fn associate(estimate: &[StampedPose], groundtruth: &[StampedPose]) -> Vec<PosePair> {
    estimate
        .iter()
        .filter_map(|e| interpolate(groundtruth, e.time_ns).map(|g| (e.pose, g)))
        .collect()
}

/// The ground truth at `time_ns` unless that needs the poses on both sides of a jump: `None`
/// strictly inside a jump, when the two poses that bracket the time lie on either side of one,
/// or outside the ground truth's span.
pub fn interpolate_without_jumps(
    groundtruth: &[StampedPose],
    time_ns: u64,
    jumps: &[Jump],
) -> Option<Isometry3<f64>> {
    if jumps
        .iter()
        .any(|j| j.before_ns < time_ns && time_ns < j.after_ns)
    {
        return None;
    }
    let idx = groundtruth.partition_point(|p| p.time_ns < time_ns);
    let later = groundtruth.get(idx)?;
    if later.time_ns > time_ns {
        let earlier = groundtruth.get(idx.checked_sub(1)?)?;
        let spans = |j: &Jump| earlier.time_ns <= j.before_ns && later.time_ns >= j.after_ns;
        if jumps.iter().any(spans) {
            return None;
        }
    }
    interpolate(groundtruth, time_ns)
}

/// The map frame in the scene frame, `scene←map = GT_map(t0) · EST_map(t0)⁻¹`, where t0 is the
/// time of the mapping run's first estimated pose, `EST_map(t0)` that pose and `GT_map(t0)` the
/// mapping run's ground truth there. `None` when the estimate is empty or t0 has no ground
/// truth (outside it, or inside a jump).
pub fn anchor_map_frame(
    map_estimate: &[StampedPose],
    map_groundtruth: &[StampedPose],
    jumps: &[Jump],
) -> Option<Isometry3<f64>> {
    let first = map_estimate.first()?;
    let truth = interpolate_without_jumps(map_groundtruth, first.time_ns, jumps)?;
    Some(truth * first.pose.inverse())
}

/// The map frame in the scene frame fitted to the whole mapping run instead of its first pose:
/// the rigid motion taking the mapping run's positions onto its ground truth's (see
/// [`align_se3`]), never across a jump. A diagnostic beside [`anchor_map_frame`]: one pose
/// carries its own error (a sweep's tilt under vibration, its heading noise) into the anchor,
/// and the distance from the anchor multiplies it; the fit averages it out. `None` with fewer
/// than three poses with ground truth.
pub fn fit_map_frame(
    map_estimate: &[StampedPose],
    map_groundtruth: &[StampedPose],
    jumps: &[Jump],
) -> Option<Isometry3<f64>> {
    let (est, gt): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = map_estimate
        .iter()
        .filter_map(|e| {
            interpolate_without_jumps(map_groundtruth, e.time_ns, jumps)
                .map(|g| (e.pose.translation.vector, g.translation.vector))
        })
        .unzip();
    (est.len() >= 3).then(|| align_se3(&est, &gt))
}

/// How far apart two placements of the map frame in the scene are: the angle between their z
/// axes (tilt) and their heading difference, both in degrees.
pub fn frame_difference_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let (za, zb) = (a.rotation * Vector3::z(), b.rotation * Vector3::z());
    let tilt = za.angle(&zb).to_degrees();
    (tilt, yaw_difference(&a.rotation, &b.rotation).to_degrees())
}

/// Errors of poses in a fixed frame, without alignment.
#[derive(Clone, Debug, PartialEq)]
pub struct FixedFrameReport {
    /// Poses compared.
    pub poses: usize,
    /// Estimated poses left out because their time is inside a jump or its ground truth would
    /// be interpolated across one.
    pub in_jumps: usize,
    /// Root mean square of the position errors, m.
    pub position_rmse: f64,
    /// Root mean square of the heading (yaw) errors, degrees.
    pub yaw_rmse_deg: f64,
    /// Root mean square of the position errors' horizontal part (scene x, y), m: what a robot
    /// navigating on the floor feels.
    pub horizontal_rmse: f64,
    /// Root mean square of the position errors' vertical part (scene z), m.
    pub vertical_rmse: f64,
    /// The largest position error, m.
    pub max_position: f64,
    /// Poses with a position error above [`WRONG_POSITION_M`] or a heading error above
    /// [`WRONG_YAW_DEG`].
    pub wrong_poses: usize,
}

/// Every estimated pose mapped into the scene frame by `scene_from_map` and compared with the
/// ground truth at its own time (interpolated, never across a jump); no alignment. `None` when
/// no pose can be compared.
pub fn fixed_frame_errors(
    estimate: &[StampedPose],
    groundtruth: &[StampedPose],
    scene_from_map: &Isometry3<f64>,
    jumps: &[Jump],
) -> Option<FixedFrameReport> {
    let (mut poses, mut in_jumps, mut wrong) = (0, 0, 0);
    let (mut sum_position, mut sum_yaw, mut max_position) = (0.0, 0.0, 0.0f64);
    let (mut sum_horizontal, mut sum_vertical) = (0.0, 0.0);
    for e in estimate {
        let Some(truth) = interpolate_without_jumps(groundtruth, e.time_ns, jumps) else {
            let inside = interpolate(groundtruth, e.time_ns).is_some();
            in_jumps += usize::from(inside);
            continue;
        };
        let pose = scene_from_map * e.pose;
        let error = pose.translation.vector - truth.translation.vector;
        let position = error.norm();
        sum_horizontal += error.x * error.x + error.y * error.y;
        sum_vertical += error.z * error.z;
        let yaw = yaw_difference(&pose.rotation, &truth.rotation).to_degrees();
        poses += 1;
        sum_position += position * position;
        sum_yaw += yaw * yaw;
        max_position = max_position.max(position);
        wrong += usize::from(position > WRONG_POSITION_M || yaw.abs() > WRONG_YAW_DEG);
    }
    (poses > 0).then(|| FixedFrameReport {
        poses,
        in_jumps,
        position_rmse: (sum_position / poses as f64).sqrt(),
        yaw_rmse_deg: (sum_yaw / poses as f64).sqrt(),
        horizontal_rmse: (sum_horizontal / poses as f64).sqrt(),
        vertical_rmse: (sum_vertical / poses as f64).sqrt(),
        max_position,
        wrong_poses: wrong,
    })
}

/// The heading (rotation about the scene's z axis of the forward axis) of `a` minus that of
/// `b`, in (−π, π].
pub fn yaw_difference(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    let heading = |q: &UnitQuaternion<f64>| {
        let x = q * Vector3::x();
        x.y.atan2(x.x)
    };
    let d = heading(a) - heading(b);
    let wrapped = d.rem_euclid(std::f64::consts::TAU);
    if wrapped > std::f64::consts::PI {
        wrapped - std::f64::consts::TAU
    } else {
        wrapped
    }
}

/// The rigid motion `T` minimising Σ|T·est_k − gt_k|² (Umeyama without scale). Points past the
/// shorter slice are ignored. With no points, or non-finite ones, the identity: the errors
/// computed with it then show the problem (NaN), where nalgebra's SVD would never return.
pub fn align_se3(est: &[Vector3<f64>], gt: &[Vector3<f64>]) -> Isometry3<f64> {
    let n = est.len().min(gt.len());
    if n == 0 {
        return Isometry3::identity();
    }
    let (est, gt) = (&est[..n], &gt[..n]);
    let centroid = |v: &[Vector3<f64>]| v.iter().sum::<Vector3<f64>>() / n as f64;
    let (est_mean, gt_mean) = (centroid(est), centroid(gt));
    // Unnormalised: the rotation does not depend on the covariance's scale.
    let cov: Matrix3<f64> = est
        .iter()
        .zip(gt)
        .map(|(e, g)| (g - gt_mean) * (e - est_mean).transpose())
        .sum();
    if !cov.iter().all(|x| x.is_finite()) {
        return Isometry3::identity();
    }
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Isometry3::identity();
    };
    // U·Vᵀ may be a reflection (always possible for planar or noisy points); the best proper
    // rotation flips the axis of the smallest singular value, which `svd` sorts last.
    let mut s = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let r = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(u * s * v_t));
    let rotation = UnitQuaternion::new_normalize(r.into_inner());
    Isometry3::from_parts(Translation3::from(gt_mean - rotation * est_mean), rotation)
}

/// Absolute trajectory error: translational error per pose after aligning the estimate onto
/// the ground truth with [`align_se3`].
#[derive(Clone, Debug, PartialEq)]
pub struct AteReport {
    pub poses: usize,
    pub rmse: f64,
    pub mean: f64,
    pub median: f64,
    pub max: f64,
    /// The motion applied to the estimate (estimate frame → ground-truth frame).
    pub alignment: Isometry3<f64>,
}

/// The ATE over `pairs`; `None` when there are none.
pub fn ate_rmse(pairs: &[PosePair]) -> Option<AteReport> {
    if pairs.is_empty() {
        return None;
    }
    let (est, gt): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = pairs
        .iter()
        .map(|(e, g)| (e.translation.vector, g.translation.vector))
        .unzip();
    let alignment = align_se3(&est, &gt);
    let mut errors: Vec<f64> = est
        .iter()
        .zip(&gt)
        .map(|(e, g)| (alignment.transform_point(&Point3::from(*e)).coords - g).norm())
        .collect();
    let n = errors.len() as f64;
    let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    let mean = errors.iter().sum::<f64>() / n;
    errors.sort_by(f64::total_cmp);
    Some(AteReport {
        poses: errors.len(),
        rmse,
        mean,
        median: median_of_sorted(&errors),
        max: errors[errors.len() - 1],
        alignment,
    })
}

/// The middle value, or the mean of the two middle values (as numpy's median).
fn median_of_sorted(sorted: &[f64]) -> f64 {
    let mid = sorted.len() / 2;
    if sorted.len() % 2 == 1 {
        sorted[mid]
    } else {
        (sorted[mid - 1] + sorted[mid]) / 2.0
    }
}

/// Mean relative error over a set of segments, each error divided by its nominal length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelativeError {
    pub segments: usize,
    /// Mean of |t(E)| / L, in %.
    pub translation_pct: f64,
    /// Mean of angle(E) / L, in °/m.
    pub rotation_deg_per_m: f64,
}

/// KITTI-style relative error: overall (the mean over every segment of every length, as the
/// KITTI devkit averages) and per length.
#[derive(Clone, Debug, PartialEq)]
pub struct RpeReport {
    pub overall: RelativeError,
    /// `(length in m, errors)` in the order the lengths were given; lengths no segment fits
    /// are left out.
    pub per_length: Vec<(f64, RelativeError)>,
}

#[derive(Default)]
struct Sums {
    segments: usize,
    translation: f64,
    rotation: f64,
}

impl Sums {
    fn add(&mut self, translation: f64, rotation: f64) {
        self.segments += 1;
        self.translation += translation;
        self.rotation += rotation;
    }

    fn mean(&self) -> Option<RelativeError> {
        (self.segments > 0).then(|| {
            let n = self.segments as f64;
            RelativeError {
                segments: self.segments,
                translation_pct: 100.0 * self.translation / n,
                rotation_deg_per_m: (self.rotation / n).to_degrees(),
            }
        })
    }
}

/// KITTI-style relative error. For every start `i` (step 1) and every length `L`, `j` is the
/// first index with `dist[j] − dist[i] ≥ L` along the ground truth's path; the segment error
/// is `E = (gt_i⁻¹·gt_j)⁻¹·(est_i⁻¹·est_j)`, scored as |t(E)| / L and angle(E) / L. Lengths that
/// are not finite and positive fit no segment. `None` when no segment fits at all.
pub fn relative_errors(pairs: &[PosePair], lengths_m: &[f64]) -> Option<RpeReport> {
    let dist = cumulative_distance(pairs);
    let mut overall = Sums::default();
    let mut per_length = Vec::new();
    for &length in lengths_m {
        let mut sums = Sums::default();
        for_each_segment(&dist, length, |i, j| {
            let e = segment_error(&pairs[i], &pairs[j]);
            let translation = e.translation.vector.norm() / length;
            let rotation = rotation_vector(&e.rotation).norm() / length;
            sums.add(translation, rotation);
            overall.add(translation, rotation);
        });
        if let Some(mean) = sums.mean() {
            per_length.push((length, mean));
        }
    }
    Some(RpeReport {
        overall: overall.mean()?,
        per_length,
    })
}

/// Drift along one world direction, in %: over the same segments as [`relative_errors`], the
/// mean of |d·â| / L, where â is `axis_world` normalised and d is the world-frame vector from
/// where the ground truth's segment ends to where the estimate's ends when the estimate's segment
/// is started at the ground truth's start pose: d = R(gt_i)·(t(est_i⁻¹·est_j) − t(gt_i⁻¹·gt_j)).
/// |d| equals |t(E)|, so this is the share of the translational error along â: large along a
/// corridor's axis when the geometry cannot pin the position there. `None` for a zero or
/// non-finite axis, or when no segment fits.
pub fn drift_along_axis(
    pairs: &[PosePair],
    lengths_m: &[f64],
    axis_world: Vector3<f64>,
) -> Option<f64> {
    if !axis_world.iter().all(|x| x.is_finite()) {
        return None;
    }
    let axis = axis_world.try_normalize(0.0)?;
    let dist = cumulative_distance(pairs);
    let mut sums = Sums::default();
    for &length in lengths_m {
        for_each_segment(&dist, length, |i, j| {
            let ((est_i, gt_i), (est_j, gt_j)) = (&pairs[i], &pairs[j]);
            let d_start_frame =
                est_i.inv_mul(est_j).translation.vector - gt_i.inv_mul(gt_j).translation.vector;
            let d = gt_i.rotation * d_start_frame;
            sums.add(d.dot(&axis).abs() / length, 0.0);
        });
    }
    sums.mean().map(|m| m.translation_pct)
}

/// End-point error, m: how far the estimate's displacement from its first pose to its last
/// differs from the ground truth's, |t(est₀⁻¹·estₙ) − t(gt₀⁻¹·gtₙ)|: the end's error in the
/// start's frame, whatever the frame the estimate is in. `None` for fewer than two poses.
pub fn end_point_error(pairs: &[PosePair]) -> Option<f64> {
    if pairs.len() < 2 {
        return None;
    }
    let ((est_0, gt_0), (est_n, gt_n)) = (pairs.first()?, pairs.last()?);
    Some(displacement_error(est_0, gt_0, est_n, gt_n))
}

/// The travel [`return_to_start`] asks for before a pose counts as a return, m: well past the
/// start's own neighbourhood on any warehouse-scale loop.
pub const RETURN_MIN_TRAVEL_M: f64 = 10.0;

/// The error when the robot is back at its start (the paper's "return to start" figure).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReturnToStart {
    /// Index of the pose pair where the ground truth comes closest to its first position after
    /// the minimum travel.
    pub index: usize,
    /// How far that ground-truth position is from the first, m.
    pub distance_from_start: f64,
    /// The displacement error there, as [`end_point_error`] computes it, m.
    pub error: f64,
}

/// Where the ground truth, having travelled at least `min_travel_m` along its path, comes
/// closest to its first position, and the estimate's displacement error there. A run that goes
/// on past its start (a lap and some) is scored at the return, not at its end. `None` when
/// the path never gets that long.
pub fn return_to_start(pairs: &[PosePair], min_travel_m: f64) -> Option<ReturnToStart> {
    let (est_0, gt_0) = pairs.first()?;
    let dist = cumulative_distance(pairs);
    let (index, distance_from_start) = pairs
        .iter()
        .enumerate()
        .filter(|(i, _)| dist[*i] >= min_travel_m)
        .map(|(i, (_, gt))| (i, (gt.translation.vector - gt_0.translation.vector).norm()))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let (est_j, gt_j) = &pairs[index];
    Some(ReturnToStart {
        index,
        distance_from_start,
        error: displacement_error(est_0, gt_0, est_j, gt_j),
    })
}

/// |t(est_a⁻¹·est_b) − t(gt_a⁻¹·gt_b)|.
fn displacement_error(
    est_a: &Isometry3<f64>,
    gt_a: &Isometry3<f64>,
    est_b: &Isometry3<f64>,
    gt_b: &Isometry3<f64>,
) -> f64 {
    let est = est_a.inv_mul(est_b).translation.vector;
    let gt = gt_a.inv_mul(gt_b).translation.vector;
    (est - gt).norm()
}

/// The length of the ground truth's path through the associated poses, in m.
pub fn path_length(pairs: &[PosePair]) -> f64 {
    cumulative_distance(pairs).last().copied().unwrap_or(0.0)
}

fn cumulative_distance(pairs: &[PosePair]) -> Vec<f64> {
    let mut total = 0.0;
    let mut last: Option<&Vector3<f64>> = None;
    pairs
        .iter()
        .map(|(_, gt)| {
            let here = &gt.translation.vector;
            total += last.map_or(0.0, |prev| (here - prev).norm());
            last = Some(here);
            total
        })
        .collect()
}

/// Calls `f(i, j)` for every segment of `length`: each start `i` and the first `j` at least
/// `length` further along the path.
fn for_each_segment(dist: &[f64], length: f64, mut f: impl FnMut(usize, usize)) {
    if !(length.is_finite() && length > 0.0) {
        return;
    }
    for (i, &start) in dist.iter().enumerate() {
        let j = i + dist[i..].partition_point(|d| d - start < length);
        if j == dist.len() {
            // Later starts have even less path ahead of them.
            break;
        }
        f(i, j);
    }
}

fn segment_error(start: &PosePair, end: &PosePair) -> Isometry3<f64> {
    let est = start.0.inv_mul(&end.0);
    let gt = start.1.inv_mul(&end.1);
    gt.inv_mul(&est)
}

impl fmt::Display for RelativeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:.3} % / {:.4} °/m ({} segments)",
            self.translation_pct, self.rotation_deg_per_m, self.segments
        )
    }
}

impl fmt::Display for RpeReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let lengths = self.per_length.iter().map(|(l, _)| *l);
        let shortest = lengths.clone().fold(f64::INFINITY, f64::min);
        let longest = lengths.fold(f64::NEG_INFINITY, f64::max);
        let span = if shortest == longest {
            format!("{shortest}")
        } else {
            format!("{shortest}–{longest}")
        };
        let o = &self.overall;
        write!(
            f,
            "drift {:.3} % / {:.4} °/m over {span} m segments ({} segments)",
            o.translation_pct, o.rotation_deg_per_m, o.segments
        )
    }
}

impl fmt::Display for AteReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "ATE RMSE {:.3} m (max {:.3} m) over {} poses",
            self.rmse, self.max, self.poses
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::PI;

    fn pose(t: [f64; 3], yaw: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(t[0], t[1], t[2]), Vector3::z() * yaw)
    }

    /// A figure-of-eight through a warehouse, ~75 m long, heading along the path.
    fn warehouse_loop() -> Vec<Isometry3<f64>> {
        (0..600)
            .map(|k| {
                let a = 2.0 * PI * k as f64 / 600.0;
                let (x, y) = (10.0 * a.cos(), 5.0 * (2.0 * a).sin());
                let yaw = (10.0 * (2.0 * a).cos()).atan2(-10.0 * a.sin());
                pose([x, y, 0.05 * a.sin()], yaw)
            })
            .collect()
    }

    /// Poses every `step` m along +x, heading +x.
    fn straight(n: usize, step: f64) -> Vec<Isometry3<f64>> {
        (0..n)
            .map(|k| pose([k as f64 * step, 0.0, 0.0], 0.0))
            .collect()
    }

    fn angle_between(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
        rotation_vector(&(a.inverse() * b)).norm()
    }

    #[test]
    fn associate_interpolates_ground_truth_at_estimate_times() {
        let s = 1_000_000_000;
        let gt: Vec<StampedPose> = (1..=3)
            .map(|k| StampedPose {
                time_ns: k * s,
                pose: pose([(k - 1) as f64, 0.0, 0.0], 0.0),
            })
            .collect();
        let est: Vec<StampedPose> = [s / 2, 3 * s / 2, 9 * s / 4, 3 * s, 7 * s / 2]
            .into_iter()
            .map(|time_ns| StampedPose {
                time_ns,
                pose: pose([time_ns as f64, 0.0, 0.0], 0.0),
            })
            .collect();
        let pairs = associate(&est, &gt);
        let got: Vec<(f64, f64)> = pairs
            .iter()
            .map(|(e, g)| (e.translation.x, g.translation.x))
            .collect();
        assert_eq!(
            got,
            [(1.5e9, 0.5), (2.25e9, 1.25), (3e9, 2.0)],
            "the first and last estimates are outside the ground truth"
        );
    }

    fn stamped(poses: &[(u64, Isometry3<f64>)]) -> Vec<StampedPose> {
        poses
            .iter()
            .map(|&(time_ns, pose)| StampedPose { time_ns, pose })
            .collect()
    }

    #[test]
    fn the_map_frame_is_anchored_through_the_mapping_runs_first_pose() {
        let s = 1_000_000_000;
        // The mapping run starts at (3, 4) heading 90° in the scene; its estimate starts at the
        // origin heading 0 (its own map frame), so scene←map turns by 90° and moves by (3, 4).
        let gt = stamped(&[
            (s, pose([3.0, 3.0, 0.0], PI / 2.0)),
            (3 * s, pose([3.0, 5.0, 0.0], PI / 2.0)),
        ]);
        let est = stamped(&[(2 * s, pose([0.0, 0.0, 0.0], 0.0))]);
        let anchor = anchor_map_frame(&est, &gt, &[]).expect("anchored");
        let expected = pose([3.0, 4.0, 0.0], PI / 2.0);
        assert!((anchor.translation.vector - expected.translation.vector).norm() < 1e-12);
        assert!(angle_between(&anchor.rotation, &expected.rotation) < 1e-12);
        // A map point 1 m ahead of the start is 1 m further along +y in the scene.
        let p = anchor.transform_point(&Point3::new(1.0, 0.0, 0.0));
        assert!((p.coords - Vector3::new(3.0, 5.0, 0.0)).norm() < 1e-12);
        assert_eq!(anchor_map_frame(&[], &gt, &[]), None);
        let outside = stamped(&[(5 * s, pose([0.0; 3], 0.0))]);
        assert_eq!(anchor_map_frame(&outside, &gt, &[]), None);
        let jump = Jump {
            before_ns: s,
            after_ns: 3 * s,
        };
        assert_eq!(anchor_map_frame(&est, &gt, &[jump]), None);
    }

    #[test]
    fn a_fitted_map_frame_averages_out_the_first_poses_own_error() {
        let s = 100_000_000;
        // A square loop, 10 m a side, in the scene; the mapping run's estimate is exact in a
        // map frame turned 30° and moved, except its first pose, tilted 0.3° and turned 0.2°.
        let gt: Vec<StampedPose> = (0..400)
            .map(|k| {
                let (side, f) = (k / 100, (k % 100) as f64 / 10.0);
                let xy = [[f, 0.0], [10.0, f], [10.0 - f, 10.0], [0.0, 10.0 - f]][side];
                StampedPose {
                    time_ns: k as u64 * s,
                    pose: pose([xy[0], xy[1], 0.7], side as f64 * PI / 2.0),
                }
            })
            .collect();
        let map_from_scene = pose([2.0, -1.0, 0.0], PI / 6.0);
        let mut est: Vec<StampedPose> = gt
            .iter()
            .map(|g| StampedPose {
                time_ns: g.time_ns,
                pose: map_from_scene * g.pose,
            })
            .collect();
        est[0].pose *=
            UnitQuaternion::from_euler_angles(0.3f64.to_radians(), 0.0, 0.2f64.to_radians());
        let anchor = anchor_map_frame(&est, &gt, &[]).expect("anchored");
        let fit = fit_map_frame(&est, &gt, &[]).expect("fitted");
        // The fit is the true placement, up to the one pose's position (exact here).
        let (tilt, yaw) = frame_difference_deg(&fit, &map_from_scene.inverse());
        assert!(tilt < 1e-6 && yaw.abs() < 1e-6, "{tilt} {yaw}");
        // The anchor carries the first pose's error, seen as tilt and heading.
        let (tilt, yaw) = frame_difference_deg(&anchor, &fit);
        assert!(
            (tilt - 0.3).abs() < 0.01 && (yaw + 0.2).abs() < 0.01,
            "{tilt} {yaw}"
        );
        // 10 m away, 0.3° of tilt is 5 cm of height: the anchored errors are vertical.
        let anchored = fixed_frame_errors(&est, &gt, &anchor, &[]).expect("poses");
        let fitted = fixed_frame_errors(&est, &gt, &fit, &[]).expect("poses");
        assert!(anchored.vertical_rmse > 0.02, "{anchored:?}");
        assert!(fitted.position_rmse < 1e-6, "{fitted:?}");
        assert_eq!(fit_map_frame(&est[..2], &gt, &[]), None);
    }

    #[test]
    fn fixed_frame_errors_are_not_aligned_away() {
        let s = 100_000_000;
        let gt: Vec<StampedPose> = (0..=100)
            .map(|k| StampedPose {
                time_ns: k * s,
                pose: pose([0.1 * k as f64, 0.0, 0.0], 0.0),
            })
            .collect();
        // The estimate is in a map frame moved by (−1, 2) and turned by 30° from the scene;
        // mapped back it is exact except 10 poses 0.6 m off sideways and 10 turned by 6°.
        let scene_from_map = pose([1.0, -2.0, 0.0], PI / 6.0);
        let est: Vec<StampedPose> = gt
            .iter()
            .enumerate()
            .map(|(k, g)| {
                let mut p = g.pose;
                if (10..20).contains(&k) {
                    p = Isometry3::translation(0.0, 0.6, 0.0) * p;
                }
                if (50..60).contains(&k) {
                    p *= Isometry3::rotation(Vector3::z() * 6f64.to_radians());
                }
                StampedPose {
                    time_ns: g.time_ns,
                    pose: scene_from_map.inverse() * p,
                }
            })
            .collect();
        let r = fixed_frame_errors(&est, &gt, &scene_from_map, &[]).expect("poses");
        assert_eq!((r.poses, r.in_jumps), (101, 0));
        assert!(
            (r.position_rmse - (10.0 * 0.36f64 / 101.0).sqrt()).abs() < 1e-9,
            "{r:?}"
        );
        assert!(
            (r.yaw_rmse_deg - (10.0 * 36.0f64 / 101.0).sqrt()).abs() < 1e-9,
            "{r:?}"
        );
        assert!((r.max_position - 0.6).abs() < 1e-9);
        // The sideways errors are horizontal, none vertical.
        assert!((r.horizontal_rmse - r.position_rmse).abs() < 1e-9, "{r:?}");
        assert!(r.vertical_rmse < 1e-9, "{r:?}");
        assert_eq!(r.wrong_poses, 20);
        // The same estimate without the map frame is off by metres: nothing is aligned.
        let raw = fixed_frame_errors(&est, &gt, &Isometry3::identity(), &[]).expect("poses");
        assert!(raw.position_rmse > 1.0 && raw.wrong_poses == 101, "{raw:?}");
    }

    #[test]
    fn fixed_frame_errors_skip_poses_inside_or_across_a_jump() {
        let s = 100_000_000;
        // The truth jumps from x = 1 to x = 20 between its poses at 1.0 s and 1.1 s.
        let gt: Vec<StampedPose> = (0..=20)
            .map(|k| StampedPose {
                time_ns: k * s,
                pose: pose([if k <= 10 { 0.1 * k as f64 } else { 20.0 }, 0.0, 0.0], 0.0),
            })
            .collect();
        let jump = Jump {
            before_ns: 10 * s,
            after_ns: 11 * s,
        };
        let est: Vec<StampedPose> = [5 * s, 10 * s, 10 * s + s / 2, 11 * s, 15 * s]
            .iter()
            .map(|&t| StampedPose {
                time_ns: t,
                pose: interpolate(&gt, t).expect("inside"),
            })
            .collect();
        let r = fixed_frame_errors(&est, &gt, &Isometry3::identity(), &[jump]).expect("poses");
        assert_eq!((r.poses, r.in_jumps), (4, 1));
        assert!(r.max_position < 1e-12, "{r:?}");
        // A sparser ground truth whose poses straddle the jump is not interpolated across it.
        let sparse: Vec<StampedPose> = gt.iter().step_by(4).copied().collect();
        assert_eq!(interpolate_without_jumps(&sparse, 10 * s, &[jump]), None);
        assert!(interpolate_without_jumps(&sparse, 5 * s, &[jump]).is_some());
        assert!(
            interpolate(&sparse, 10 * s).is_some(),
            "plain interpolation would"
        );
    }

    #[test]
    fn yaw_differences_wrap_to_half_a_turn() {
        let q = |yaw: f64| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        assert!((yaw_difference(&q(3.0), &q(-3.0)) - (6.0 - 2.0 * PI)).abs() < 1e-12);
        assert!((yaw_difference(&q(-0.1), &q(0.2)) + 0.3).abs() < 1e-12);
        assert!(yaw_difference(&q(1.0), &q(1.0)).abs() < 1e-12);
    }

    #[test]
    fn identical_trajectories_have_zero_error() {
        let pairs: Vec<PosePair> = warehouse_loop().into_iter().map(|p| (p, p)).collect();
        let ate = ate_rmse(&pairs).expect("poses");
        assert_eq!(ate.poses, 600);
        assert!(ate.max < 1e-12, "{ate:?}");
        let rpe = relative_errors(&pairs, &WAREHOUSE_LENGTHS).expect("segments");
        assert_eq!(rpe.per_length.len(), 6);
        assert!(rpe.overall.segments > 600);
        assert!(rpe.overall.translation_pct < 1e-10, "{rpe:?}");
        assert!(rpe.overall.rotation_deg_per_m < 1e-10, "{rpe:?}");
    }

    #[test]
    fn a_rigidly_moved_estimate_has_zero_error_after_alignment() {
        let motion = Isometry3::new(
            Vector3::new(100.0, -50.0, 3.0),
            Vector3::new(0.1, -0.2, 2.0),
        );
        let pairs: Vec<PosePair> = warehouse_loop()
            .into_iter()
            .map(|g| (motion * g, g))
            .collect();
        let raw = pairs
            .iter()
            .map(|(e, g)| (e.translation.vector - g.translation.vector).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(raw > 50.0, "the raw error is large: {raw}");
        let ate = ate_rmse(&pairs).expect("poses");
        assert!(ate.max < 1e-9, "{ate:?}");
        let undo = ate.alignment * motion;
        assert!(undo.translation.vector.norm() < 1e-9);
        assert!(rotation_vector(&undo.rotation).norm() < 1e-12);
        let rpe = relative_errors(&pairs, &WAREHOUSE_LENGTHS).expect("segments");
        assert!(rpe.overall.translation_pct < 1e-9, "{rpe:?}");
        assert!(rpe.overall.rotation_deg_per_m < 1e-9, "{rpe:?}");
    }

    #[test]
    fn a_one_percent_scale_error_is_one_percent_drift_along_the_line() {
        // 0.5 m steps keep the path distances exact, so each segment is exactly L long.
        let gt = straight(201, 0.5);
        let pairs: Vec<PosePair> = gt
            .iter()
            .map(|g| {
                (
                    Isometry3::from_parts((g.translation.vector * 1.01).into(), g.rotation),
                    *g,
                )
            })
            .collect();
        let rpe = relative_errors(&pairs, &WAREHOUSE_LENGTHS).expect("segments");
        assert_eq!(rpe.per_length.len(), 6);
        let mut total = 0;
        for ((length, err), expected_length) in rpe.per_length.iter().zip(WAREHOUSE_LENGTHS) {
            assert_eq!(*length, expected_length);
            // Starts at 0, 0.5, …, 100 − L.
            assert_eq!(err.segments, 2 * (100 - expected_length as usize) + 1);
            assert!((err.translation_pct - 1.0).abs() < 1e-9, "{err:?}");
            assert_eq!(err.rotation_deg_per_m, 0.0);
            total += err.segments;
        }
        assert_eq!(rpe.overall.segments, total);
        assert!((rpe.overall.translation_pct - 1.0).abs() < 1e-9);
        let along = |axis| drift_along_axis(&pairs, &WAREHOUSE_LENGTHS, axis).expect("segments");
        assert!((along(Vector3::x()) - 1.0).abs() < 1e-9);
        assert!((along(-3.0 * Vector3::x()) - 1.0).abs() < 1e-9);
        assert!(along(Vector3::y()).abs() < 1e-12);
        assert!((along(Vector3::new(1.0, 1.0, 0.0)) - 0.5f64.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn a_yaw_rate_error_is_that_rate_per_metre() {
        // The estimate turns k rad per metre while the truth drives straight: it follows an arc
        // of radius 1/k, so every segment of length L ends rotated by kL and displaced by the
        // arc's chord instead of the straight line's L.
        let (k, step, length) = (0.002, 0.25, 20.0);
        let gt = straight(401, step);
        let pairs: Vec<PosePair> = gt
            .iter()
            .map(|g| {
                let theta = k * g.translation.x;
                let arc = [theta.sin() / k, (1.0 - theta.cos()) / k, 0.0];
                (pose(arc, theta), *g)
            })
            .collect();
        let rpe = relative_errors(&pairs, &[length]).expect("segments");
        assert_eq!(rpe.overall.segments, 401 - 80);
        assert!((rpe.overall.rotation_deg_per_m - k.to_degrees()).abs() < 1e-9);
        let chord = Vector3::new((k * length).sin() / k, (1.0 - (k * length).cos()) / k, 0.0);
        let translation_pct = 100.0 * (chord - Vector3::x() * length).norm() / length;
        assert!((rpe.overall.translation_pct - translation_pct).abs() < 1e-9);
        let along = |axis| drift_along_axis(&pairs, &[length], axis).expect("segments");
        assert!((along(Vector3::y()) - 100.0 * chord.y / length).abs() < 1e-9);
        assert!((along(Vector3::x()) - 100.0 * (length - chord.x) / length).abs() < 1e-9);
        assert!(along(Vector3::z()).abs() < 1e-12);
    }

    #[test]
    fn align_se3_recovers_a_planar_motion() {
        // Planar points leave one singular value zero, where U·Vᵀ may come out a reflection.
        let est: Vec<Vector3<f64>> = (0..40)
            .map(|k| {
                let s = k as f64;
                if k < 20 {
                    Vector3::new(s, 0.0, 0.0)
                } else {
                    Vector3::new(19.0, s - 19.0, 0.0)
                }
            })
            .collect();
        let motion = pose([3.0, -2.0, 0.0], 0.7);
        let gt: Vec<Vector3<f64>> = est
            .iter()
            .map(|p| motion.transform_point(&Point3::from(*p)).coords)
            .collect();
        let found = align_se3(&est, &gt);
        assert!(angle_between(&found.rotation, &motion.rotation) < 1e-12);
        assert!((found.translation.vector - motion.translation.vector).norm() < 1e-9);
    }

    #[test]
    fn align_se3_answers_a_mirror_image_with_the_best_proper_rotation() {
        // The mirror x → −x fits exactly but is no rotation; the best rotation turns half a
        // turn about y, giving up the points on the shortest axis (z).
        let est: Vec<Vector3<f64>> = [3.0, -3.0]
            .iter()
            .map(|&a| Vector3::new(a, 0.0, 0.0))
            .chain([2.0, -2.0].iter().map(|&a| Vector3::new(0.0, a, 0.0)))
            .chain([1.0, -1.0].iter().map(|&a| Vector3::new(0.0, 0.0, a)))
            .collect();
        let gt: Vec<Vector3<f64>> = est.iter().map(|p| Vector3::new(-p.x, p.y, p.z)).collect();
        let found = align_se3(&est, &gt);
        let half_turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), PI);
        assert!(angle_between(&found.rotation, &half_turn) < 1e-12);
        assert!(found.translation.vector.norm() < 1e-12);
    }

    #[test]
    fn align_se3_of_nothing_or_nan_is_the_identity() {
        assert_eq!(align_se3(&[], &[]), Isometry3::identity());
        let nan = [Vector3::new(f64::NAN, 0.0, 0.0), Vector3::x()];
        assert_eq!(align_se3(&nan, &[Vector3::y(); 2]), Isometry3::identity());
    }

    #[test]
    fn ate_statistics_of_known_errors() {
        // Scaled 1.1× about the centroid: symmetric, so the best rigid fit is the identity and
        // each point's error is 0.1 × its distance from the centroid.
        let gt = [
            Vector3::zeros(),
            Vector3::x(),
            -Vector3::x(),
            2.0 * Vector3::y(),
            -2.0 * Vector3::y(),
        ];
        let pairs: Vec<PosePair> = gt
            .iter()
            .map(|g| (pose((g * 1.1).into(), 0.0), pose((*g).into(), 0.0)))
            .collect();
        let ate = ate_rmse(&pairs).expect("poses");
        assert_eq!(ate.poses, 5);
        assert!((ate.rmse - 0.02f64.sqrt()).abs() < 1e-12, "{ate:?}");
        assert!((ate.mean - 0.12).abs() < 1e-12);
        assert!((ate.median - 0.1).abs() < 1e-12);
        assert!((ate.max - 0.2).abs() < 1e-12);
        let even = ate_rmse(&pairs[1..]).expect("poses");
        assert!((even.median - 0.15).abs() < 1e-12, "{even:?}");
        assert!((even.rmse - 0.025f64.sqrt()).abs() < 1e-12);
        assert_eq!(ate_rmse(&[]), None);
    }

    #[test]
    fn no_segment_fits_a_short_path_or_a_bad_length() {
        let pairs: Vec<PosePair> = straight(9, 0.5).into_iter().map(|p| (p, p)).collect();
        assert_eq!(path_length(&pairs), 4.0);
        assert_eq!(relative_errors(&pairs, &WAREHOUSE_LENGTHS), None);
        assert_eq!(drift_along_axis(&pairs, &[5.0], Vector3::x()), None);
        assert_eq!(relative_errors(&pairs, &[0.0, -1.0, f64::NAN]), None);
        assert_eq!(drift_along_axis(&pairs, &[1.0], Vector3::zeros()), None);
        assert_eq!(
            drift_along_axis(&pairs, &[1.0], Vector3::x() * f64::NAN),
            None
        );
        let rpe = relative_errors(&pairs, &[4.0, 5.0, 1.0]).expect("segments");
        let lengths: Vec<f64> = rpe.per_length.iter().map(|(l, _)| *l).collect();
        assert_eq!(lengths, [4.0, 1.0]);
        assert_eq!(rpe.overall.segments, 1 + 7);
    }

    #[test]
    fn reports_print_one_line() {
        let err = |segments, translation_pct, rotation_deg_per_m| RelativeError {
            segments,
            translation_pct,
            rotation_deg_per_m,
        };
        let rpe = RpeReport {
            overall: err(1234, 0.3124, 0.00214),
            per_length: vec![(5.0, err(1000, 0.3, 0.002)), (50.0, err(234, 0.4, 0.003))],
        };
        assert_eq!(
            rpe.to_string(),
            "drift 0.312 % / 0.0021 °/m over 5–50 m segments (1234 segments)"
        );
        assert_eq!(
            rpe.per_length[0].1.to_string(),
            "0.300 % / 0.0020 °/m (1000 segments)"
        );
        let single = RpeReport {
            per_length: vec![(20.0, err(7, 1.0, 0.5))],
            overall: err(7, 1.0, 0.5),
        };
        assert!(single.to_string().contains(" over 20 m segments "));
        let ate = AteReport {
            poses: 612,
            rmse: 0.0431,
            mean: 0.04,
            median: 0.039,
            max: 0.0974,
            alignment: Isometry3::identity(),
        };
        assert_eq!(
            ate.to_string(),
            "ATE RMSE 0.043 m (max 0.097 m) over 612 poses"
        );
    }

    /// What floating-point rounding may leave of a zero ATE: relative precision 1e-8 of the
    /// largest coordinate (the SVD of nearly collinear points loses a few digits; a wrong
    /// alignment would be off by metres, not by micrometres).
    fn rounding_bound(pairs: &[PosePair]) -> f64 {
        let scale = pairs
            .iter()
            .flat_map(|(e, g)| [e.translation.vector.norm(), g.translation.vector.norm()])
            .fold(1.0, f64::max);
        1e-8 * scale
    }

    #[test]
    fn end_point_error_is_the_end_in_the_start_frame() {
        let start = Isometry3::new(Vector3::new(5.0, 1.0, 0.0), Vector3::new(0.0, 0.0, 1.0));
        let gt = [start, start * Isometry3::translation(10.0, 0.0, 0.0), start];
        // The estimate ends 0.3 m along its start's y axis from where it began, in another
        // world frame altogether.
        let frame = Isometry3::new(Vector3::new(-40.0, 7.0, 2.0), Vector3::new(0.2, 0.0, -2.0));
        let est = [
            frame * start,
            frame * gt[1],
            frame * start * Isometry3::translation(0.0, 0.3, 0.0),
        ];
        let pairs: Vec<PosePair> = est.into_iter().zip(gt).collect();
        let error = end_point_error(&pairs).expect("poses");
        assert!((error - 0.3).abs() < 1e-12, "{error}");
        assert_eq!(end_point_error(&pairs[..1]), None);
    }

    #[test]
    fn return_to_start_is_scored_where_the_truth_comes_back() {
        // A 40 m square lap, then 5 m more; the estimate is exact until the return, 0.2 m off
        // sideways there, and 1 m off at the end.
        let mut pose = Isometry3::identity();
        let mut gt = vec![pose];
        for _side in 0..4 {
            for _ in 0..10 {
                pose *= Isometry3::translation(1.0, 0.0, 0.0);
                gt.push(pose);
            }
            pose *= Isometry3::rotation(Vector3::z() * (PI / 2.0));
            *gt.last_mut().expect("poses") = pose;
        }
        let returned = gt.len() - 1;
        for step in 1..=5 {
            gt.push(gt[returned] * Isometry3::translation(step as f64, 0.0, 0.0));
        }
        let mut est = gt.clone();
        est[returned] *= Isometry3::translation(0.0, 0.2, 0.0);
        *est.last_mut().expect("poses") *= Isometry3::translation(0.0, 1.0, 0.0);
        let pairs: Vec<PosePair> = est.into_iter().zip(gt).collect();
        let r = return_to_start(&pairs, 10.0).expect("a lap");
        assert_eq!(r.index, returned);
        assert!(r.distance_from_start < 1e-9, "{r:?}");
        assert!((r.error - 0.2).abs() < 1e-9, "{r:?}");
        assert!((end_point_error(&pairs).expect("poses") - 1.0).abs() < 1e-9);
        assert_eq!(return_to_start(&pairs, 1000.0), None);
    }

    #[test]
    fn ate_of_three_nearly_collinear_poses_is_rounding_only() {
        // Found by the property below in CI: 6.6e-9 m, which a fixed 1e-9 m bound refused.
        let gt: Vec<Isometry3<f64>> = [
            [-23.740299859853444, 35.53970729774131, -35.37644212666186],
            [-69.79990958940378, -74.6363821234672, 92.26056292420675],
            [-16.912718755517464, 55.06794039314432, -55.31619770532315],
        ]
        .iter()
        .map(|t| Isometry3::translation(t[0], t[1], t[2]))
        .collect();
        let pairs: Vec<PosePair> = gt.iter().map(|g| (*g, *g)).collect();
        let ate = ate_rmse(&pairs).expect("poses");
        assert!(ate.rmse < rounding_bound(&pairs), "{ate:?}");
    }

    fn arb_pose(reach: f64) -> impl Strategy<Value = Isometry3<f64>> {
        (
            prop::array::uniform3(-reach..reach),
            prop::array::uniform3(-3.0..3.0f64),
        )
            .prop_map(|(t, r)| Isometry3::new(t.into(), r.into()))
    }

    proptest! {
        #[test]
        fn ate_vanishes_under_any_rigid_motion(
            gt in prop::collection::vec(arb_pose(100.0), 2..60),
            motion in arb_pose(1000.0),
        ) {
            let pairs: Vec<PosePair> = gt.iter().map(|g| (motion * g, *g)).collect();
            let ate = ate_rmse(&pairs).expect("poses");
            prop_assert!(ate.rmse < rounding_bound(&pairs), "{:?}", ate);
        }

        #[test]
        fn relative_error_ignores_the_estimate_frame(
            gt in prop::collection::vec(arb_pose(10.0), 2..40),
            motion in arb_pose(1000.0),
        ) {
            let pairs: Vec<PosePair> = gt.iter().map(|g| (motion * g, *g)).collect();
            if let Some(rpe) = relative_errors(&pairs, &[1.0, 5.0]) {
                // Composing with a motion 1 km away rounds at ~1e-13 m; 1e-7 % of 1 m is 1e-9 m.
                prop_assert!(rpe.overall.translation_pct < 1e-7, "{:?}", rpe);
                prop_assert!(rpe.overall.rotation_deg_per_m < 1e-9, "{:?}", rpe);
            }
        }
    }
}

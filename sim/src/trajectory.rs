//! Robot motion in continuous time: a closed path through waypoints (a periodic cubic spline,
//! resampled every 2 cm of arc length), a speed profile bounded in speed, longitudinal and
//! lateral acceleration and yaw rate, small pitch/roll/heave vibration, and the sensor's mount.
//!
//! Longer than most modules: the path, the speed profile, vibration, routes' variants (reverse,
//! start fraction, kidnaps) and their closed-form timing depend on one another's grid and stay
//! together.
//!
//! The speed profile is the classic two-pass one: the curvature caps the speed (lateral
//! acceleration and yaw rate), then a forward and a backward pass cap the change of v² per metre
//! by twice the acceleration limit. Between grid nodes v² is linear in arc length, i.e. the
//! acceleration is constant, so s(t) is a closed form and every firing gets its exact pose.
//! The motion repeats lap after lap, so any duration can be simulated.
//!
//! The run's clock maps onto time along the path through a schedule: an offset (a run that
//! starts part-way round the lap) and jumps (a kidnapped robot continues from another place),
//! so a variation of a run moves the robot without rebuilding its path.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use rand::Rng;
use serde::Serialize;
use thiserror::Error;

pub use crate::spline::rounded_polygon;
use crate::spline::PeriodicSpline;

type V3 = Vector3<f64>;

/// Arc-length spacing of the resampled path, m.
const DS: f64 = 0.02;
/// Spline sub-steps per segment when measuring arc length.
const SUBSTEPS: usize = 64;

/// A rigid pose: rotation and translation, mapping a frame's vectors into the parent frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation from the child frame to the parent frame.
    pub rotation: Rotation3<f64>,
    /// Origin of the child frame in the parent frame, m.
    pub translation: V3,
}

impl Pose {
    /// The identity.
    pub fn identity() -> Pose {
        Pose {
            rotation: Rotation3::identity(),
            translation: V3::zeros(),
        }
    }

    /// A pose from a position and yaw/pitch/roll (rotation Rz(yaw)·Ry(pitch)·Rx(roll)).
    pub fn from_xyz_ypr(xyz: [f64; 3], yaw: f64, pitch: f64, roll: f64) -> Pose {
        Pose {
            rotation: Rotation3::from_euler_angles(roll, pitch, yaw),
            translation: V3::from(xyz),
        }
    }

    /// Composition: `self ∘ other` (other expressed in self's frame).
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            rotation: self.rotation * other.rotation,
            translation: self.translation + self.rotation * other.translation,
        }
    }

    /// A point of the child frame in the parent frame.
    #[inline]
    pub fn transform_point(&self, p: &V3) -> V3 {
        self.rotation * p + self.translation
    }

    /// The rotation as a Hamilton quaternion `[qx, qy, qz, qw]` with `qw ≥ 0`.
    pub fn quaternion_xyzw(&self) -> [f64; 4] {
        let q = UnitQuaternion::from_rotation_matrix(&self.rotation);
        let c = q.into_inner().coords;
        let s = if c[3] < 0.0 { -1.0 } else { 1.0 };
        [s * c[0], s * c[1], s * c[2], s * c[3]]
    }
}

/// Bounds of an AGV's motion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MotionLimits {
    /// Speed on straights, m/s.
    pub cruise_speed: f64,
    /// No curve may force the speed below this, m/s.
    pub min_speed: f64,
    /// Longitudinal acceleration and braking limit, m/s².
    pub max_accel: f64,
    /// Lateral (centripetal) acceleration limit, m/s².
    pub max_lateral_accel: f64,
    /// Yaw-rate limit, rad/s.
    pub max_yaw_rate: f64,
}

impl Default for MotionLimits {
    fn default() -> Self {
        Self {
            cruise_speed: 1.4,
            min_speed: 0.5,
            max_accel: 0.4,
            max_lateral_accel: 0.5,
            max_yaw_rate: 0.8,
        }
    }
}

/// Where the sensor sits on the robot base: forward, left and up offsets, m (no rotation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Mount {
    /// Forward offset, m.
    pub x: f64,
    /// Left offset, m.
    pub y: f64,
    /// Height above the floor, m.
    pub z: f64,
}

/// One sinusoid: amplitude, frequency (Hz), phase (rad).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Sinusoid {
    /// Amplitude (rad for angles, m for heave).
    pub amplitude: f64,
    /// Frequency, Hz.
    pub frequency: f64,
    /// Phase, rad.
    pub phase: f64,
}

/// Small body motions on a rolling AGV: sums of sinusoids in pitch, roll and heave.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct Vibration {
    /// Pitch components, rad.
    pub pitch: Vec<Sinusoid>,
    /// Roll components, rad.
    pub roll: Vec<Sinusoid>,
    /// Heave components, m.
    pub heave: Vec<Sinusoid>,
}

impl Vibration {
    /// No vibration.
    pub fn none() -> Vibration {
        Vibration::default()
    }

    /// Two components each in pitch and roll (3–14 Hz, summing to at most `max_angle` rad)
    /// and heave (summing to at most `max_heave` m), drawn from `rng`.
    pub fn random(rng: &mut impl Rng, max_angle: f64, max_heave: f64) -> Vibration {
        let mut draw = |total: f64| -> Vec<Sinusoid> {
            let weights: Vec<f64> = (0..2).map(|_| rng.random_range(0.2..1.0)).collect();
            let sum: f64 = weights.iter().sum();
            weights
                .iter()
                .map(|w| Sinusoid {
                    amplitude: total * w / sum * rng.random_range(0.6..1.0),
                    frequency: rng.random_range(3.0..14.0),
                    phase: rng.random_range(0.0..std::f64::consts::TAU),
                })
                .collect()
        };
        let pitch = draw(max_angle);
        let roll = draw(max_angle);
        let heave = draw(max_heave);
        Vibration { pitch, roll, heave }
    }

    /// Adds the components' values on the grid `t0 + i·outer_step + j·inner_step` to
    /// `acc[i·inner + j]`, advancing each sinusoid by angle addition.
    fn accumulate(components: &[Sinusoid], grid: (f64, f64, usize, f64, usize), acc: &mut [f64]) {
        let (t0, outer_step, outer, inner_step, inner) = grid;
        for c in components {
            let w = std::f64::consts::TAU * c.frequency;
            let (mut s0, mut c0) = (w * t0 + c.phase).sin_cos();
            let (so, co) = (w * outer_step).sin_cos();
            let (si, ci) = (w * inner_step).sin_cos();
            for i in 0..outer {
                let (mut s, mut cc) = (s0, c0);
                for a in &mut acc[i * inner..(i + 1) * inner] {
                    *a += c.amplitude * s;
                    (s, cc) = (s * ci + cc * si, cc * ci - s * si);
                }
                (s0, c0) = (s0 * co + c0 * so, c0 * co - s0 * so);
            }
        }
    }
}

/// The robot base's planar state at an instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseState {
    /// Position on the floor, m.
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Heading, rad from +x counter-clockwise.
    pub yaw: f64,
    /// Forward speed, m/s.
    pub speed: f64,
    /// Longitudinal acceleration, m/s².
    pub accel: f64,
    /// Arc length into the lap, m.
    pub s: f64,
    /// Lap number, from 0.
    pub lap: u64,
}

/// Why a trajectory cannot be built.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum TrajectoryError {
    /// A loop needs at least three distinct waypoints.
    #[error("a loop needs at least 3 waypoints, got {0}")]
    TooFewWaypoints(usize),
    /// Two consecutive waypoints coincide, or a coordinate is not finite.
    #[error("waypoint {0} is not finite or coincides with the next one")]
    BadWaypoint(usize),
    /// The limits are not positive and ordered.
    #[error("motion limits must be positive with min_speed <= cruise_speed: {0:?}")]
    BadLimits(MotionLimits),
    /// A curve is so tight that the limits force the speed below the minimum.
    #[error("the path turns too tightly {s:.1} m into the lap (radius {radius:.2} m): the limits allow only {speed:.2} m/s")]
    TooTight {
        /// Arc length of the tightest point, m.
        s: f64,
        /// Its radius of curvature, m.
        radius: f64,
        /// The speed the limits allow there, m/s.
        speed: f64,
    },
}

/// The robot's motion: a looped path with a speed profile, or a fixed sensor pose (for tests).
#[derive(Debug, Clone)]
pub struct Trajectory {
    motion: Motion,
    mount: Mount,
    vibration: Vibration,
    schedule: Schedule,
}

/// Time along the path at each run time: `t + offset`, with the offset of the last jump whose
/// instant `t` is later than.
#[derive(Debug, Clone, Default, PartialEq)]
struct Schedule {
    offset: f64,
    jumps: Vec<Jump>,
}

/// A discontinuity of the motion: instants later than `after` (s since the start) are at path
/// time `t + offset`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Jump {
    after: f64,
    offset: f64,
}

impl Schedule {
    #[inline]
    fn path_time(&self, t: f64) -> f64 {
        let offset = self
            .jumps
            .iter()
            .rev()
            .find(|j| t > j.after)
            .map_or(self.offset, |j| j.offset);
        t + offset
    }
}

#[derive(Debug, Clone)]
enum Motion {
    Loop(Box<LoopPath>),
    Fixed(Pose),
}

/// Figures of a looped trajectory, for reports and tests.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LoopFigures {
    /// Length of one lap, m.
    pub lap_length_m: f64,
    /// Duration of one lap, s.
    pub lap_seconds: f64,
    /// Slowest speed on the lap, m/s.
    pub min_speed: f64,
    /// Fastest speed, m/s.
    pub max_speed: f64,
    /// Largest |longitudinal acceleration|, m/s².
    pub max_accel: f64,
    /// Largest |yaw rate| at the grid nodes, rad/s.
    pub max_yaw_rate: f64,
    /// Tightest radius of curvature, m.
    pub min_radius: f64,
}

#[derive(Debug, Clone)]
struct LoopPath {
    waypoints: Vec<[f64; 2]>,
    limits: MotionLimits,
    /// Node spacing (the lap length divided into whole steps), its inverse and 1/(4 ds).
    ds: f64,
    inv_ds: f64,
    inv_4ds: f64,
    /// Nodes every `ds` of arc length; the last repeats the first a lap later.
    nodes: Vec<PathNode>,
    /// Node times into the lap (searched on their own).
    t: Vec<f64>,
    figures: LoopFigures,
}

/// A resampled path node: position, unit tangent, speed.
#[derive(Debug, Clone, Copy)]
struct PathNode {
    x: f64,
    y: f64,
    tx: f64,
    ty: f64,
    v: f64,
}

impl Trajectory {
    /// A closed loop through `waypoints` (visited in order, then back to the first), started at
    /// the first waypoint at the speed the profile has there.
    pub fn closed_loop(
        waypoints: &[[f64; 2]],
        limits: MotionLimits,
        mount: Mount,
        vibration: Vibration,
    ) -> Result<Trajectory, TrajectoryError> {
        let path = LoopPath::new(waypoints, limits)?;
        Ok(Trajectory {
            motion: Motion::Loop(Box::new(path)),
            mount,
            vibration,
            schedule: Schedule::default(),
        })
    }

    /// The same loop driven the other way round: the waypoints in reverse order from the same
    /// first one, with the speed profile that direction gets. A fixed pose stays as it is.
    pub fn reversed(&self) -> Result<Trajectory, TrajectoryError> {
        let Motion::Loop(path) = &self.motion else {
            return Ok(self.clone());
        };
        let mut waypoints = path.waypoints.clone();
        waypoints[1..].reverse();
        Ok(Trajectory {
            motion: Motion::Loop(Box::new(LoopPath::new(&waypoints, path.limits)?)),
            mount: self.mount,
            vibration: self.vibration.clone(),
            schedule: self.schedule.clone(),
        })
    }

    /// The same motion started `fraction` of the lap length along the path (to the 2 cm of
    /// the path's grid), at the speed the profile has there.
    pub fn starting_at(mut self, fraction: f64) -> Trajectory {
        self.schedule.offset = self.lap_time_at(fraction);
        self
    }

    /// Time into the lap at which the base has covered `fraction` of the lap's length (the
    /// nearest grid node); 0 for a fixed pose.
    pub fn lap_time_at(&self, fraction: f64) -> f64 {
        match &self.motion {
            Motion::Loop(p) => {
                let nodes = p.t.len() - 1;
                let k = (fraction.rem_euclid(1.0) * nodes as f64).round() as usize % nodes;
                p.t[k]
            }
            Motion::Fixed(_) => 0.0,
        }
    }

    /// Points along the path every grid node (2 cm), one lap, from the lap's start.
    pub fn route_points(&self) -> Vec<[f64; 2]> {
        match &self.motion {
            Motion::Loop(p) => p.nodes[..p.nodes.len() - 1]
                .iter()
                .map(|n| [n.x, n.y])
                .collect(),
            Motion::Fixed(pose) => vec![[pose.translation.x, pose.translation.y]],
        }
    }

    /// Times into the lap of the path's grid nodes at least `min_distance` m in a straight
    /// line from `xy` (empty for a fixed pose).
    pub fn lap_times_away_from(&self, xy: [f64; 2], min_distance: f64) -> Vec<f64> {
        let Motion::Loop(p) = &self.motion else {
            return Vec::new();
        };
        p.nodes[..p.nodes.len() - 1]
            .iter()
            .zip(&p.t)
            .filter(|(n, _)| (n.x - xy[0]).hypot(n.y - xy[1]) >= min_distance)
            .map(|(_, &t)| t)
            .collect()
    }

    /// The same motion, except that at instants later than `after` s since the start the base
    /// is where the path puts it `lap_time` s into a lap, driving on from there: a teleport.
    /// Jumps must be added in time order.
    pub fn with_jump(mut self, after: f64, lap_time: f64) -> Trajectory {
        self.schedule.jumps.push(Jump {
            after,
            offset: lap_time - after,
        });
        self
    }

    /// The instants (s since the start) after which the motion jumps.
    pub fn jumps(&self) -> Vec<f64> {
        self.schedule.jumps.iter().map(|j| j.after).collect()
    }

    /// A sensor held still at `sensor_pose` (scene frame); for tests on known geometry.
    pub fn fixed(sensor_pose: Pose) -> Trajectory {
        Trajectory {
            motion: Motion::Fixed(sensor_pose),
            mount: Mount {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            },
            vibration: Vibration::none(),
            schedule: Schedule::default(),
        }
    }

    /// The sensor's mount on the base.
    pub fn mount(&self) -> Mount {
        self.mount
    }

    /// The vibration model.
    pub fn vibration(&self) -> &Vibration {
        &self.vibration
    }

    /// The waypoints of a loop (empty for a fixed pose).
    pub fn waypoints(&self) -> &[[f64; 2]] {
        match &self.motion {
            Motion::Loop(p) => &p.waypoints,
            Motion::Fixed(_) => &[],
        }
    }

    /// The motion limits of a loop.
    pub fn limits(&self) -> Option<MotionLimits> {
        match &self.motion {
            Motion::Loop(p) => Some(p.limits),
            Motion::Fixed(_) => None,
        }
    }

    /// Lap figures of a loop.
    pub fn figures(&self) -> Option<LoopFigures> {
        match &self.motion {
            Motion::Loop(p) => Some(p.figures),
            Motion::Fixed(_) => None,
        }
    }

    /// The base's planar state at `t` s after the start (a fixed pose stands still).
    pub fn base_state(&self, t: f64) -> BaseState {
        match &self.motion {
            Motion::Loop(p) => {
                let q = p.planar(self.schedule.path_time(t), &mut None);
                BaseState {
                    x: q.x,
                    y: q.y,
                    yaw: q.sin_yaw.atan2(q.cos_yaw),
                    speed: q.speed,
                    accel: q.accel,
                    s: q.s,
                    lap: q.lap,
                }
            }
            Motion::Fixed(pose) => {
                let (_, _, yaw) = pose.rotation.euler_angles();
                BaseState {
                    x: pose.translation.x,
                    y: pose.translation.y,
                    yaw,
                    speed: 0.0,
                    accel: 0.0,
                    s: 0.0,
                    lap: 0,
                }
            }
        }
    }

    /// The sensor's pose in the scene frame at `t` s after the start.
    pub fn sensor_pose(&self, t: f64) -> Pose {
        let mut buf = PoseBuffer::default();
        self.sensor_poses(t, 0.0, 1, 0.0, 1, &mut buf);
        buf.poses[0]
    }

    /// The sensor's poses at the instants `t0 + i·outer_step + j·inner_step` for `i` in
    /// `0..outer` and `j` in `0..inner`, into `buf` in that order (`i` major). Each pose is
    /// exact for its own instant; they are computed together because every sinusoid then
    /// advances by a fixed angle per step (angle addition instead of a sine per term and
    /// instant) and the path lookup moves forward from the previous instant. The firing grid
    /// of a packet — sequences 55.296 µs apart, lasers 2.304 µs apart within one — is such a
    /// set of instants.
    pub fn sensor_poses(
        &self,
        t0: f64,
        outer_step: f64,
        outer: usize,
        inner_step: f64,
        inner: usize,
        buf: &mut PoseBuffer,
    ) {
        let n = outer * inner;
        buf.poses.clear();
        let path = match &self.motion {
            Motion::Fixed(pose) => {
                buf.poses.resize(n, *pose);
                return;
            }
            Motion::Loop(p) => p,
        };
        for acc in [&mut buf.pitch, &mut buf.roll, &mut buf.heave] {
            acc.clear();
            acc.resize(n, 0.0);
        }
        let grid = (t0, outer_step, outer, inner_step, inner);
        Vibration::accumulate(&self.vibration.pitch, grid, &mut buf.pitch);
        Vibration::accumulate(&self.vibration.roll, grid, &mut buf.roll);
        Vibration::accumulate(&self.vibration.heave, grid, &mut buf.heave);
        let mount = V3::new(self.mount.x, self.mount.y, self.mount.z);
        let mut cursor = None;
        for i in 0..outer {
            for j in 0..inner {
                let k = i * inner + j;
                let (x, y, cy, sy, ..) = path.locate(
                    self.schedule
                        .path_time(t0 + i as f64 * outer_step + j as f64 * inner_step),
                    &mut cursor,
                );
                let (sp, cp) = small_sin_cos(buf.pitch[k]);
                let (sr, cr) = small_sin_cos(buf.roll[k]);
                // Rz(yaw)·Ry(pitch)·Rx(roll), written out.
                let m = Matrix3::new(
                    cy * cp,
                    cy * sp * sr - sy * cr,
                    cy * sp * cr + sy * sr,
                    sy * cp,
                    sy * sp * sr + cy * cr,
                    sy * sp * cr - cy * sr,
                    -sp,
                    cp * sr,
                    cp * cr,
                );
                let rotation = Rotation3::from_matrix_unchecked(m);
                buf.poses.push(Pose {
                    rotation,
                    translation: V3::new(x, y, buf.heave[k]) + rotation * mount,
                });
            }
        }
    }
}

/// Poses computed by [`Trajectory::sensor_poses`], with its scratch space (kept between calls
/// so that steady state does not allocate).
#[derive(Debug, Clone, Default)]
pub struct PoseBuffer {
    poses: Vec<Pose>,
    pitch: Vec<f64>,
    roll: Vec<f64>,
    heave: Vec<f64>,
}

impl PoseBuffer {
    /// The poses of the last call.
    pub fn poses(&self) -> &[Pose] {
        &self.poses
    }
}

/// sin and cos of an angle; below 0.02 rad by their series, which is exact in f64 there and
/// much cheaper than the library calls (vibration angles are always this small).
#[inline]
fn small_sin_cos(x: f64) -> (f64, f64) {
    if x.abs() >= 0.02 {
        return x.sin_cos();
    }
    // Taylor coefficients as products (a division by a constant is not turned into one).
    const S3: f64 = 1.0 / 6.0;
    const S5: f64 = 1.0 / 120.0;
    const S7: f64 = 1.0 / 5040.0;
    const C2: f64 = 0.5;
    const C4: f64 = 1.0 / 24.0;
    const C6: f64 = 1.0 / 720.0;
    const C8: f64 = 1.0 / 40320.0;
    let x2 = x * x;
    let s = x * (1.0 - x2 * (S3 - x2 * (S5 - x2 * S7)));
    let c = 1.0 - x2 * (C2 - x2 * (C4 - x2 * (C6 - x2 * C8)));
    (s, c)
}

/// Where on the path the base is, with its heading as a unit vector.
#[derive(Debug, Clone, Copy)]
struct Planar {
    x: f64,
    y: f64,
    cos_yaw: f64,
    sin_yaw: f64,
    speed: f64,
    accel: f64,
    s: f64,
    lap: u64,
}

impl LoopPath {
    fn new(waypoints: &[[f64; 2]], limits: MotionLimits) -> Result<LoopPath, TrajectoryError> {
        let n = waypoints.len();
        if n < 3 {
            return Err(TrajectoryError::TooFewWaypoints(n));
        }
        let lim_ok = [
            limits.cruise_speed,
            limits.min_speed,
            limits.max_accel,
            limits.max_lateral_accel,
            limits.max_yaw_rate,
        ]
        .iter()
        .all(|x| x.is_finite() && *x > 0.0);
        if !lim_ok || limits.min_speed > limits.cruise_speed {
            return Err(TrajectoryError::BadLimits(limits));
        }
        let mut h = Vec::with_capacity(n);
        for i in 0..n {
            let (a, b) = (waypoints[i], waypoints[(i + 1) % n]);
            let d = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
            if !(d.is_finite() && d > 1e-6) {
                return Err(TrajectoryError::BadWaypoint(i));
            }
            h.push(d);
        }
        let spline = PeriodicSpline::new(waypoints, &h);
        // Arc length by fine chords, then nodes at uniform arc length.
        let mut chords: Vec<(usize, f64, f64)> = Vec::with_capacity(n * SUBSTEPS + 1);
        let mut s = 0.0;
        let mut prev = spline.eval(0, 0.0).0;
        chords.push((0, 0.0, 0.0));
        for (seg, &hs) in h.iter().enumerate() {
            for k in 1..=SUBSTEPS {
                let x = hs * k as f64 / SUBSTEPS as f64;
                let p = spline.eval(seg, x).0;
                s += ((p[0] - prev[0]).powi(2) + (p[1] - prev[1]).powi(2)).sqrt();
                prev = p;
                chords.push((seg, x, s));
            }
        }
        let length = s;
        let nodes = (length / DS).round().max(8.0) as usize;
        let ds = length / nodes as f64;
        let (mut x, mut y, mut tx, mut ty, mut kappa) = (vec![], vec![], vec![], vec![], vec![]);
        let mut c = 0;
        for k in 0..nodes {
            let target = k as f64 * ds;
            while c + 1 < chords.len() - 1 && chords[c + 1].2 <= target {
                c += 1;
            }
            let (seg0, x0, s0) = chords[c];
            let (seg1, x1, s1) = chords[c + 1];
            // The first chord of a segment starts where the previous segment ended: at 0.
            let x0 = if seg0 == seg1 { x0 } else { 0.0 };
            let f = if s1 > s0 {
                (target - s0) / (s1 - s0)
            } else {
                0.0
            };
            let (p, d1, d2) = spline.eval(seg1, x0 + f * (x1 - x0));
            let speed = (d1[0] * d1[0] + d1[1] * d1[1]).sqrt();
            x.push(p[0]);
            y.push(p[1]);
            tx.push(d1[0] / speed);
            ty.push(d1[1] / speed);
            kappa.push((d1[0] * d2[1] - d1[1] * d2[0]) / speed.powi(3));
        }
        // Speed caps from curvature.
        let mut v: Vec<f64> = kappa
            .iter()
            .map(|k| {
                let k = k.abs().max(1e-9);
                limits
                    .cruise_speed
                    .min((limits.max_lateral_accel / k).sqrt())
                    .min(limits.max_yaw_rate / k)
            })
            .collect();
        if let Some((i, &vmin)) = v.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)) {
            if vmin < limits.min_speed {
                return Err(TrajectoryError::TooTight {
                    s: i as f64 * ds,
                    radius: 1.0 / kappa[i].abs(),
                    speed: vmin,
                });
            }
        }
        // Forward (acceleration) and backward (braking) passes, twice round the loop so that
        // the cap carries across the lap boundary.
        let two_a_ds = 2.0 * limits.max_accel * ds;
        for i in 0..2 * nodes {
            let (a, b) = (i % nodes, (i + 1) % nodes);
            v[b] = v[b].min((v[a] * v[a] + two_a_ds).sqrt());
        }
        for i in (0..2 * nodes).rev() {
            let (a, b) = (i % nodes, (i + 1) % nodes);
            v[a] = v[a].min((v[b] * v[b] + two_a_ds).sqrt());
        }
        // Close the loop: node `nodes` is node 0 a lap later.
        for vec in [&mut x, &mut y, &mut tx, &mut ty, &mut v] {
            vec.push(vec[0]);
        }
        let mut t = Vec::with_capacity(nodes + 1);
        t.push(0.0);
        for k in 0..nodes {
            t.push(t[k] + 2.0 * ds / (v[k] + v[k + 1]));
        }
        let max_accel = (0..nodes)
            .map(|k| ((v[k + 1] * v[k + 1] - v[k] * v[k]) / (2.0 * ds)).abs())
            .fold(0.0, f64::max);
        let max_yaw_rate = (0..nodes)
            .map(|k| (kappa[k] * v[k]).abs())
            .fold(0.0, f64::max);
        let min_radius = 1.0 / kappa.iter().map(|k| k.abs()).fold(1e-9, f64::max);
        let figures = LoopFigures {
            lap_length_m: length,
            lap_seconds: t[nodes],
            min_speed: v.iter().copied().fold(f64::INFINITY, f64::min),
            max_speed: v.iter().copied().fold(0.0, f64::max),
            max_accel,
            max_yaw_rate,
            min_radius,
        };
        let nodes = (0..=nodes)
            .map(|k| PathNode {
                x: x[k],
                y: y[k],
                tx: tx[k],
                ty: ty[k],
                v: v[k],
            })
            .collect();
        Ok(LoopPath {
            waypoints: waypoints.to_vec(),
            limits,
            ds,
            inv_ds: 1.0 / ds,
            inv_4ds: 0.25 / ds,
            nodes,
            t,
            figures,
        })
    }

    /// The base at `time`. `cursor` remembers the grid cell between calls with increasing
    /// times, so a run of nearby instants costs one search.
    fn planar(&self, time: f64, cursor: &mut Option<usize>) -> Planar {
        let (x, y, cos_yaw, sin_yaw, k, dt, ds) = self.locate(time, cursor);
        let (v0, v1) = (self.nodes[k].v, self.nodes[k + 1].v);
        let a = (v1 * v1 - v0 * v0) / (2.0 * self.ds);
        let laps = crate::num::floor(time / self.figures.lap_seconds);
        Planar {
            x,
            y,
            cos_yaw,
            sin_yaw,
            speed: v0 + a * dt,
            accel: a,
            s: k as f64 * self.ds + ds,
            lap: laps.max(0.0) as u64,
        }
    }

    /// Position and heading at `time`, and where on the grid: (x, y, cos yaw, sin yaw, cell,
    /// time into the cell, distance into the cell). The hot path of the pose evaluation.
    #[inline]
    fn locate(
        &self,
        time: f64,
        cursor: &mut Option<usize>,
    ) -> (f64, f64, f64, f64, usize, f64, f64) {
        let lap_time = self.figures.lap_seconds;
        let laps = crate::num::floor(time / lap_time);
        let tau = time - laps * lap_time;
        let nodes = self.t.len() - 1;
        let k = match *cursor {
            Some(k) if self.t[k] <= tau => {
                let mut k = k;
                while k + 1 < nodes && self.t[k + 1] <= tau {
                    k += 1;
                }
                k
            }
            // Last node whose time is <= tau.
            _ => self.t.partition_point(|&t| t <= tau).clamp(1, nodes) - 1,
        };
        *cursor = Some(k);
        let dt = tau - self.t[k];
        let (n0, n1) = (self.nodes[k], self.nodes[k + 1]);
        let (v0, v1) = (n0.v, n1.v);
        let half_a = (v1 * v1 - v0 * v0) * self.inv_4ds;
        let ds = (v0 * dt + half_a * dt * dt).clamp(0.0, self.ds);
        let f = ds * self.inv_ds;
        // Cubic Hermite between nodes with the exact unit tangents.
        let (f2, f3) = (f * f, f * f * f);
        let (h00, h10, h01, h11) = (
            2.0 * f3 - 3.0 * f2 + 1.0,
            f3 - 2.0 * f2 + f,
            -2.0 * f3 + 3.0 * f2,
            f3 - f2,
        );
        let (d00, d10, d01, d11) = (
            6.0 * f2 - 6.0 * f,
            3.0 * f2 - 4.0 * f + 1.0,
            -6.0 * f2 + 6.0 * f,
            3.0 * f2 - 2.0 * f,
        );
        let l = self.ds;
        let x = h00 * n0.x + h10 * l * n0.tx + h01 * n1.x + h11 * l * n1.tx;
        let y = h00 * n0.y + h10 * l * n0.ty + h01 * n1.y + h11 * l * n1.ty;
        let dx = d00 * n0.x + d10 * l * n0.tx + d01 * n1.x + d11 * l * n1.tx;
        let dy = d00 * n0.y + d10 * l * n0.ty + d01 * n1.y + d11 * l * n1.ty;
        let inv_norm = 1.0 / (dx * dx + dy * dy).sqrt();
        (x, y, dx * inv_norm, dy * inv_norm, k, dt, ds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn racetrack() -> Trajectory {
        let corners = [[0.0, 0.0], [20.0, 0.0], [20.0, 6.0], [0.0, 6.0]];
        let wps = rounded_polygon(&corners, 1.5, 2.0);
        Trajectory::closed_loop(
            &wps,
            MotionLimits::default(),
            Mount {
                x: 0.2,
                y: 0.0,
                z: 0.8,
            },
            Vibration::none(),
        )
        .unwrap()
    }

    #[test]
    fn loop_length_and_lap_are_consistent() {
        let tr = racetrack();
        let f = tr.figures().unwrap();
        // A 20 × 6 rectangle with 1.5 m corners: 52 − 4 × (2 − π/2) × 1.5.
        let expected = 52.0 - 4.0 * (2.0 - std::f64::consts::FRAC_PI_2) * 1.5;
        assert!(
            (f.lap_length_m - expected).abs() < 0.05,
            "{}",
            f.lap_length_m
        );
        assert!(f.lap_seconds > expected / 1.4 && f.lap_seconds < expected / 0.5);
        let a = tr.base_state(3.0);
        let b = tr.base_state(3.0 + f.lap_seconds);
        assert!((a.x - b.x).abs() < 1e-9 && (a.y - b.y).abs() < 1e-9 && b.lap == 1);
    }

    #[test]
    fn speed_matches_the_distance_travelled() {
        let tr = racetrack();
        let dt = 0.01;
        for i in 0..3000 {
            let t = i as f64 * 0.013;
            let (a, b) = (tr.base_state(t), tr.base_state(t + dt));
            let travelled = (b.x - a.x).hypot(b.y - a.y) / dt;
            assert!(
                (travelled - 0.5 * (a.speed + b.speed)).abs() < 0.01,
                "t {t}: {travelled} vs {}",
                a.speed
            );
        }
    }

    #[test]
    fn too_tight_corners_are_refused() {
        let corners = [[0.0, 0.0], [5.0, 0.0], [5.0, 2.0], [0.0, 2.0]];
        let wps = rounded_polygon(&corners, 0.3, 1.0);
        let err = Trajectory::closed_loop(
            &wps,
            MotionLimits::default(),
            Mount {
                x: 0.0,
                y: 0.0,
                z: 1.0,
            },
            Vibration::none(),
        );
        assert!(
            matches!(err, Err(TrajectoryError::TooTight { .. })),
            "{err:?}"
        );
        let err = Trajectory::closed_loop(
            &[[0.0, 0.0], [1.0, 0.0]],
            MotionLimits::default(),
            Mount {
                x: 0.0,
                y: 0.0,
                z: 1.0,
            },
            Vibration::none(),
        );
        assert_eq!(err.unwrap_err(), TrajectoryError::TooFewWaypoints(2));
    }

    #[test]
    fn batched_poses_equal_direct_evaluation() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let vib = Vibration::random(&mut rng, 0.3f64.to_radians(), 0.003);
        let corners = [[0.0, 0.0], [20.0, 0.0], [20.0, 6.0], [0.0, 6.0]];
        let tr = Trajectory::closed_loop(
            &rounded_polygon(&corners, 1.5, 2.0),
            MotionLimits::default(),
            Mount {
                x: 0.2,
                y: 0.1,
                z: 0.8,
            },
            vib.clone(),
        )
        .unwrap();
        let t0 = 123.456_789;
        let (outer, inner) = (55.296e-6, 2.304e-6);
        let mut buf = PoseBuffer::default();
        tr.sensor_poses(t0, outer, 24, inner, 16, &mut buf);
        assert_eq!(buf.poses().len(), 24 * 16);
        for (k, pose) in buf.poses().iter().enumerate() {
            let (i, j) = (k / 16, k % 16);
            let t = t0 + i as f64 * outer + j as f64 * inner;
            let st = tr.base_state(t);
            let sum = |cs: &[Sinusoid]| {
                cs.iter()
                    .map(|c| {
                        c.amplitude * (std::f64::consts::TAU * c.frequency * t + c.phase).sin()
                    })
                    .sum::<f64>()
            };
            let r = Rotation3::from_euler_angles(sum(&vib.roll), sum(&vib.pitch), st.yaw);
            let p = V3::new(st.x, st.y, sum(&vib.heave)) + r * V3::new(0.2, 0.1, 0.8);
            assert!(
                (pose.rotation.matrix() - r.matrix()).abs().max() < 1e-12,
                "rotation at {j}"
            );
            assert!((pose.translation - p).norm() < 1e-12, "translation at {j}");
        }
        // Vibration stays small, as promised.
        for k in 0..1000 {
            let (roll, pitch, _) = tr.sensor_pose(k as f64 * 0.0137).rotation.euler_angles();
            assert!(roll.abs() < 0.5f64.to_radians() && pitch.abs() < 0.5f64.to_radians());
        }
    }

    #[test]
    fn quaternions_are_hamilton_xyzw() {
        // A yaw of 90°: q = (0, 0, sin 45°, cos 45°), and it maps +x to +y.
        let p = Pose::from_xyz_ypr([1.0, 2.0, 3.0], std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        let q = p.quaternion_xyzw();
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!(
            (q[0]).abs() < 1e-12
                && (q[1]).abs() < 1e-12
                && (q[2] - h).abs() < 1e-12
                && (q[3] - h).abs() < 1e-12
        );
        let moved = p.transform_point(&V3::new(1.0, 0.0, 0.0));
        assert!((moved - V3::new(1.0, 3.0, 3.0)).norm() < 1e-12);
    }
}

//! Timestamped poses: the TUM and KITTI text formats and interpolation in time. Pure: text in,
//! text out; reading and writing files is the caller's business.
//!
//! TUM: one pose per line, `t x y z qx qy qz qw`, t in seconds; `#` starts a comment line.
//! KITTI: one pose per line, the top three rows of the 4×4 matrix, row-major.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use thiserror::Error;

/// A pose (moving frame → fixed frame) at a time in ns since the Unix epoch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StampedPose {
    pub time_ns: u64,
    pub pose: Isometry3<f64>,
}

/// Poses in non-decreasing time order.
pub type Trajectory = Vec<StampedPose>;

/// A TUM line that cannot be read; `line` counts from 1.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum TrajectoryError {
    #[error("line {line}: expected 8 fields `t x y z qx qy qz qw`, found {found}")]
    FieldCount { line: usize, found: usize },
    #[error("line {line}: field {field} `{text}` is not a number")]
    NotANumber {
        line: usize,
        field: usize,
        text: String,
    },
    #[error("line {line}: field {field} `{text}` is not finite")]
    NotFinite {
        line: usize,
        field: usize,
        text: String,
    },
    #[error("line {line}: time `{text}` s is negative or beyond the u64 ns range")]
    TimeOutOfRange { line: usize, text: String },
    #[error("line {line}: quaternion norm {norm} is not close to 1")]
    QuaternionNorm { line: usize, norm: f64 },
    #[error("line {line}: time {time_ns} ns is before the previous pose's {previous_ns} ns")]
    TimeGoesBack {
        line: usize,
        time_ns: u64,
        previous_ns: u64,
    },
}

impl TrajectoryError {
    /// The 1-based line the error is on.
    pub fn line(&self) -> usize {
        match self {
            Self::FieldCount { line, .. }
            | Self::NotANumber { line, .. }
            | Self::NotFinite { line, .. }
            | Self::TimeOutOfRange { line, .. }
            | Self::QuaternionNorm { line, .. }
            | Self::TimeGoesBack { line, .. } => *line,
        }
    }
}

/// How far from 1 a quaternion's norm may be and still be taken as a rotation. Files written
/// with 4–6 decimals are off by ~1e-4; anything further is a wrong column or a broken writer.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

const NS_PER_S: u64 = 1_000_000_000;

/// One TUM line (no newline): the time exact to the ns, the rest to 1e-9.
pub fn format_tum_line(p: &StampedPose) -> String {
    let t = &p.pose.translation.vector;
    let q = &p.pose.rotation;
    format!(
        "{}.{:09} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
        p.time_ns / NS_PER_S,
        p.time_ns % NS_PER_S,
        t.x,
        t.y,
        t.z,
        q.i,
        q.j,
        q.k,
        q.w
    )
}

/// Reads a TUM trajectory. Quaternions within 1e-3 of unit norm are normalised; times must not
/// go back (equal times are allowed).
pub fn parse_tum(text: &str) -> Result<Trajectory, TrajectoryError> {
    let mut poses: Trajectory = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = content.split_whitespace().collect();
        if fields.len() != 8 {
            return Err(TrajectoryError::FieldCount {
                line,
                found: fields.len(),
            });
        }
        let time_ns = parse_time_ns(line, fields[0])?;
        let mut v = [0.0; 7];
        for (k, (slot, text)) in v.iter_mut().zip(&fields[1..]).enumerate() {
            *slot = parse_finite(line, k + 2, text)?;
        }
        let q = Quaternion::new(v[6], v[3], v[4], v[5]);
        let norm = q.norm();
        if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
            return Err(TrajectoryError::QuaternionNorm { line, norm });
        }
        if let Some(prev) = poses.last() {
            if time_ns < prev.time_ns {
                return Err(TrajectoryError::TimeGoesBack {
                    line,
                    time_ns,
                    previous_ns: prev.time_ns,
                });
            }
        }
        poses.push(StampedPose {
            time_ns,
            pose: Isometry3::from_parts(
                Translation3::new(v[0], v[1], v[2]),
                UnitQuaternion::new_normalize(q),
            ),
        });
    }
    Ok(poses)
}

fn parse_finite(line: usize, field: usize, text: &str) -> Result<f64, TrajectoryError> {
    let value: f64 = text.parse().map_err(|_| TrajectoryError::NotANumber {
        line,
        field,
        text: text.to_owned(),
    })?;
    if value.is_finite() {
        Ok(value)
    } else {
        Err(TrajectoryError::NotFinite {
            line,
            field,
            text: text.to_owned(),
        })
    }
}

/// Seconds as written → ns. Plain decimals are converted digit by digit, because an f64 holds
/// only ~16 significant digits and `1700000000.123456789` needs 19; anything else (an exponent)
/// goes through f64.
fn parse_time_ns(line: usize, text: &str) -> Result<u64, TrajectoryError> {
    let out_of_range = || TrajectoryError::TimeOutOfRange {
        line,
        text: text.to_owned(),
    };
    if let Some(exact) = parse_decimal_ns(text) {
        return exact.ok_or_else(out_of_range);
    }
    let secs = parse_finite(line, 1, text)?;
    let ns = (secs * NS_PER_S as f64).round();
    // 2^64 is exactly representable; `as` would saturate silently instead.
    if ns < 0.0 || ns >= u64::MAX as f64 {
        return Err(out_of_range());
    }
    Ok(ns as u64)
}

/// `None` when `text` is not a plain `[+]digits[.digits]`; `Some(None)` when it is but overflows.
/// Digits past the ninth decimal round to the nearest ns (half up).
fn parse_decimal_ns(text: &str) -> Option<Option<u64>> {
    let unsigned = text.strip_prefix('+').unwrap_or(text);
    let (int, frac) = unsigned.split_once('.').unwrap_or((unsigned, ""));
    let all_digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if (int.is_empty() && frac.is_empty()) || !all_digits(int) || !all_digits(frac) {
        return None;
    }
    let frac = frac.as_bytes();
    let mut ns = 0u64;
    for k in 0..9 {
        ns = ns * 10 + frac.get(k).map_or(0, |d| u64::from(d - b'0'));
    }
    let round_up = frac.get(9).is_some_and(|d| *d >= b'5');
    // Leading zeros in a long integer part would overflow `parse` for nothing.
    let int = int.trim_start_matches('0');
    let secs: u64 = if int.is_empty() {
        0
    } else {
        match int.parse() {
            Ok(s) => s,
            Err(_) => return Some(None),
        }
    };
    Some(
        secs.checked_mul(NS_PER_S)
            .and_then(|t| t.checked_add(ns + u64::from(round_up))),
    )
}

/// One KITTI line (no newline): rows 0–2 of the 4×4 matrix, row-major, 12 numbers.
pub fn format_kitti_line(pose: &Isometry3<f64>) -> String {
    let m = pose.to_homogeneous();
    let numbers: Vec<String> = (0..3)
        .flat_map(|r| (0..4).map(move |c| format!("{:.9}", m[(r, c)])))
        .collect();
    numbers.join(" ")
}

/// The pose at `time_ns`: translation linear, rotation slerped between the neighbouring poses.
/// `None` outside `[first, last]` time (both ends included) or for an empty trajectory. Expects
/// non-decreasing times, as `parse_tum` guarantees.
pub fn interpolate(traj: &[StampedPose], time_ns: u64) -> Option<Isometry3<f64>> {
    let idx = traj.partition_point(|p| p.time_ns < time_ns);
    let b = traj.get(idx)?;
    if b.time_ns == time_ns {
        return Some(b.pose);
    }
    // `b` is later than `time_ns`: a pose before it is needed to bracket the time.
    let a = traj.get(idx.checked_sub(1)?)?;
    let s = (time_ns - a.time_ns) as f64 / (b.time_ns - a.time_ns) as f64;
    let translation = a
        .pose
        .translation
        .vector
        .lerp(&b.pose.translation.vector, s);
    Some(Isometry3::from_parts(
        Translation3::from(translation),
        slerp(&a.pose.rotation, &b.pose.rotation, s),
    ))
}

/// Slerp through the rotation vector of `a⁻¹b`: nalgebra's `slerp` recovers the angle with
/// `acos`, which loses about half the digits for the tiny steps between dense samples.
fn slerp(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>, s: f64) -> UnitQuaternion<f64> {
    a * UnitQuaternion::from_scaled_axis(rotation_vector(&(a.inverse() * b)) * s)
}

/// The rotation vector (axis × angle, angle in [0, π]) of `q`, by `atan2`, which stays exact
/// for small angles where `acos` of the scalar part does not.
pub(crate) fn rotation_vector(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    // q and −q are the same rotation; w ≥ 0 picks the angle ≤ π.
    let (w, v) = if q.scalar() < 0.0 {
        (-q.scalar(), -q.imag())
    } else {
        (q.scalar(), q.imag())
    };
    let sin_half = v.norm();
    if sin_half == 0.0 {
        return Vector3::zeros();
    }
    v * (2.0 * sin_half.atan2(w) / sin_half)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    fn pose(t: [f64; 3], yaw: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(t[0], t[1], t[2]), Vector3::z() * yaw)
    }

    fn stamped(time_ns: u64, t: [f64; 3], yaw: f64) -> StampedPose {
        StampedPose {
            time_ns,
            pose: pose(t, yaw),
        }
    }

    fn assert_pose_near(a: &Isometry3<f64>, b: &Isometry3<f64>, tol: f64) {
        let d = a.inverse() * b;
        assert!(
            d.translation.vector.norm() < tol && rotation_vector(&d.rotation).norm() < tol,
            "{a} vs {b}"
        );
    }

    #[test]
    fn tum_line_has_exact_ns_and_qx_qy_qz_qw_order() {
        let q = UnitQuaternion::from_quaternion(Quaternion::new(0.5, 0.5, -0.5, 0.5));
        let p = StampedPose {
            time_ns: 1_700_000_000_000_000_042,
            pose: Isometry3::from_parts(Translation3::new(1.0, -2.5, 0.125), q),
        };
        assert_eq!(
            format_tum_line(&p),
            "1700000000.000000042 1.000000000 -2.500000000 0.125000000 \
             0.500000000 -0.500000000 0.500000000 0.500000000"
        );
    }

    #[test]
    fn tum_round_trip_is_exact_to_the_ns() {
        let traj: Trajectory = (0..50u64)
            .map(|k| {
                let time_ns = 1_700_000_000_123_456_789 + k * 33_333_337;
                let a = k as f64 * 0.37;
                let pose = Isometry3::new(
                    Vector3::new(12.3 * a.cos(), -4.0 + a, 0.01 * a),
                    Vector3::new(0.1 * a.sin(), -0.2, a),
                );
                StampedPose { time_ns, pose }
            })
            .collect();
        let text: String = traj.iter().map(|p| format_tum_line(p) + "\n").collect();
        let back = parse_tum(&text).expect("own output parses");
        assert_eq!(back.len(), traj.len());
        for (a, b) in traj.iter().zip(&back) {
            assert_eq!(a.time_ns, b.time_ns);
            assert_pose_near(&a.pose, &b.pose, 2e-9);
        }
    }

    #[test]
    fn times_parse_exactly_or_through_f64_for_exponents() {
        let cases = [
            ("1700000000.123456789", 1_700_000_000_123_456_789),
            ("1700000000.1", 1_700_000_000_100_000_000),
            ("+12", 12_000_000_000),
            ("12.", 12_000_000_000),
            (".5", 500_000_000),
            ("0.0000000014", 1),
            ("0.0000000015", 2),
            ("0000000000000000000000003.000000001", 3_000_000_001),
            ("1e-3", 1_000_000),
            ("1.5E9", 1_500_000_000_000_000_000),
            ("18446744073.709551615", u64::MAX),
        ];
        for (text, ns) in cases {
            assert_eq!(parse_time_ns(1, text), Ok(ns), "{text}");
        }
        for text in ["18446744073.709551616", "-1", "-1e-9", "1e30"] {
            assert!(
                matches!(
                    parse_time_ns(7, text),
                    Err(TrajectoryError::TimeOutOfRange { line: 7, .. })
                ),
                "{text}"
            );
        }
    }

    #[test]
    fn comments_blank_lines_crlf_and_near_unit_quaternions_are_accepted() {
        let text =
            "# t x y z qx qy qz qw\r\n\r\n  \n1 1 2 3 0 0 0.7071 0.7071\r\n2.5 0 0 0 0 0 0 1\n";
        let traj = parse_tum(text).expect("valid");
        assert_eq!(traj.len(), 2);
        assert_eq!(traj[0].time_ns, 1_000_000_000);
        assert_eq!(traj[1].time_ns, 2_500_000_000);
        assert_eq!(traj[0].pose.translation.vector, Vector3::new(1.0, 2.0, 3.0));
        assert!((traj[0].pose.rotation.quaternion().norm() - 1.0).abs() < 1e-15);
        assert!((traj[0].pose.rotation.angle() - FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn parse_errors_name_the_line() {
        let good = "0 0 0 0 0 0 0 1\n";
        type IsExpected = fn(&TrajectoryError) -> bool;
        let cases: [(&str, IsExpected); 7] = [
            ("1 0 0 0 0 0 1", |e| {
                matches!(e, TrajectoryError::FieldCount { found: 7, .. })
            }),
            ("1 0 0 0 0 0 0 1 9", |e| {
                matches!(e, TrajectoryError::FieldCount { found: 9, .. })
            }),
            ("1 0 abc 0 0 0 0 1", |e| {
                matches!(e, TrajectoryError::NotANumber { field: 3, .. })
            }),
            ("1 0 0 NaN 0 0 0 1", |e| {
                matches!(e, TrajectoryError::NotFinite { field: 4, .. })
            }),
            ("inf 0 0 0 0 0 0 1", |e| {
                matches!(e, TrajectoryError::NotFinite { field: 1, .. })
            }),
            ("1 0 0 0 0 0 0 1.01", |e| {
                matches!(e, TrajectoryError::QuaternionNorm { .. })
            }),
            ("0 0 0 0 0 0 0 1\n-0.5 0 0 0 0 0 0 1", |e| {
                matches!(e, TrajectoryError::TimeOutOfRange { .. })
            }),
        ];
        for (bad, is_expected) in cases {
            let text = format!("# header\n\n{good}{bad}\n{good}");
            let err = parse_tum(&text).expect_err(bad);
            assert!(is_expected(&err), "{bad}: {err}");
            let line = 3 + bad.lines().count();
            assert_eq!(err.line(), line, "{bad}: {err}");
            assert!(err.to_string().starts_with(&format!("line {line}: ")));
        }
        let err = parse_tum("2 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n1.999999999 0 0 0 0 0 0 1\n")
            .expect_err("time goes back");
        assert_eq!(
            err,
            TrajectoryError::TimeGoesBack {
                line: 3,
                time_ns: 1_999_999_999,
                previous_ns: 2_000_000_000
            }
        );
    }

    #[test]
    fn kitti_line_is_the_top_three_rows() {
        assert_eq!(
            format_kitti_line(&pose([1.0, 2.0, -3.5], 0.0)),
            "1.000000000 0.000000000 0.000000000 1.000000000 \
             0.000000000 1.000000000 0.000000000 2.000000000 \
             0.000000000 0.000000000 1.000000000 -3.500000000"
        );
        let numbers: Vec<f64> = format_kitti_line(&pose([4.0, 5.0, 6.0], FRAC_PI_2))
            .split(' ')
            .map(|s| s.parse().expect("number"))
            .collect();
        let expected = [0.0, -1.0, 0.0, 4.0, 1.0, 0.0, 0.0, 5.0, 0.0, 0.0, 1.0, 6.0];
        assert_eq!(numbers.len(), 12);
        for (n, e) in numbers.iter().zip(expected) {
            assert!((n - e).abs() < 1e-9, "{numbers:?}");
        }
    }

    #[test]
    fn interpolation_is_linear_in_translation_and_slerp_in_rotation() {
        let traj = [
            stamped(1_000, [0.0, 0.0, 0.0], 0.0),
            stamped(3_000, [2.0, 4.0, -6.0], FRAC_PI_2),
            stamped(4_000, [2.0, 4.0, -6.0], PI - 0.02),
        ];
        let mid = interpolate(&traj, 2_000).expect("inside");
        assert_pose_near(&mid, &pose([1.0, 2.0, -3.0], PI / 4.0), 1e-12);
        let quarter = interpolate(&traj, 1_500).expect("inside");
        assert_pose_near(&quarter, &pose([0.5, 1.0, -1.5], PI / 8.0), 1e-12);
        // Rotation changes at a constant rate even for a large step.
        let late = interpolate(&traj, 3_500).expect("inside");
        let yaw = (FRAC_PI_2 + PI - 0.02) / 2.0;
        assert_pose_near(&late, &pose([2.0, 4.0, -6.0], yaw), 1e-12);
    }

    #[test]
    fn interpolation_takes_the_short_way_whatever_the_quaternion_sign() {
        let mut b = stamped(10, [0.0; 3], FRAC_PI_2);
        b.pose.rotation = UnitQuaternion::new_unchecked(-b.pose.rotation.into_inner());
        let traj = [stamped(0, [0.0; 3], 0.0), b];
        let mid = interpolate(&traj, 5).expect("inside");
        assert_pose_near(&mid, &pose([0.0; 3], PI / 4.0), 1e-12);
    }

    #[test]
    fn interpolation_covers_exactly_the_time_span() {
        let traj = [
            stamped(100, [1.0, 0.0, 0.0], 0.1),
            stamped(200, [2.0, 0.0, 0.0], 0.2),
            stamped(200, [3.0, 0.0, 0.0], 0.3),
            stamped(300, [4.0, 0.0, 0.0], 0.4),
        ];
        assert_eq!(interpolate(&traj, 99), None);
        assert_eq!(interpolate(&traj, 301), None);
        assert_eq!(interpolate(&traj, 100), Some(traj[0].pose));
        assert_eq!(interpolate(&traj, 300), Some(traj[3].pose));
        // At a repeated time, the first pose with that time; just after, the last.
        assert_eq!(interpolate(&traj, 200), Some(traj[1].pose));
        let after = interpolate(&traj, 250).expect("inside");
        assert_pose_near(&after, &pose([3.5, 0.0, 0.0], 0.35), 1e-12);
        assert_eq!(interpolate(&[], 0), None);
        assert_eq!(interpolate(&traj[..1], 100), Some(traj[0].pose));
        assert_eq!(interpolate(&traj[..1], 101), None);
    }

    #[test]
    fn rotation_vector_is_accurate_for_tiny_and_half_turn_angles() {
        for angle in [1e-12, 1e-7, 0.5, PI - 1e-9] {
            let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
            let q = UnitQuaternion::from_scaled_axis(axis * angle);
            let v = rotation_vector(&q);
            assert!(
                (v.norm() - angle).abs() <= 1e-15 * angle.max(1.0),
                "{angle}"
            );
            assert!((v.normalize() - axis).norm() < 1e-12, "{angle}");
        }
        assert_eq!(
            rotation_vector(&UnitQuaternion::identity()),
            Vector3::zeros()
        );
    }
}

//! SE(3) on `Isometry3<f64>`: exponential and logarithm with twists ordered [ω, υ] (rotation
//! first), and the skew matrix. Perturbations are applied on the left, in the fixed frame:
//! `T ← exp(δ)·T`, so a point `q = T·p` moves by `δq = −[q]×·ω + υ`.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

/// The skew-symmetric matrix of `v`: `skew(v)·w = v × w`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The left Jacobian of SO(3) at `omega`, which maps υ to the translation of `exp([ω, υ])`.
fn left_jacobian(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let k = skew(omega);
    if theta < 1e-6 {
        return Matrix3::identity() + 0.5 * k + k * k / 6.0;
    }
    let t2 = theta * theta;
    Matrix3::identity()
        + (1.0 - theta.cos()) / t2 * k
        + (theta - theta.sin()) / (t2 * theta) * k * k
}

/// `exp` of a twist [ω, υ].
pub fn exp(twist: &Vector6<f64>) -> Isometry3<f64> {
    let omega = Vector3::new(twist[0], twist[1], twist[2]);
    let upsilon = Vector3::new(twist[3], twist[4], twist[5]);
    let rotation = UnitQuaternion::from_scaled_axis(omega);
    Isometry3::from_parts(
        Translation3::from(left_jacobian(&omega) * upsilon),
        rotation,
    )
}

/// `log` of a pose, as a twist [ω, υ]; the inverse of [`exp`] for rotations below π.
pub fn log(pose: &Isometry3<f64>) -> Vector6<f64> {
    let omega = pose.rotation.scaled_axis();
    let upsilon = left_jacobian(&omega)
        .try_inverse()
        .unwrap_or_else(Matrix3::identity)
        * pose.translation.vector;
    Vector6::new(omega.x, omega.y, omega.z, upsilon.x, upsilon.y, upsilon.z)
}

/// The base pose and body twist from the sensor's, with `m` = `base_link` ← sensor (the
/// mounting): a frame whose origin is the sensor's first pose becomes one whose origin is the
/// base's, `T_base = M · T_sensor · M⁻¹`, and the twist is `Ad_M` of the sensor's.
pub fn to_base(
    m: &Isometry3<f64>,
    pose: &Isometry3<f64>,
    twist: &Vector6<f64>,
) -> (Isometry3<f64>, Vector6<f64>) {
    let base = m * pose * m.inverse();
    let w = m.rotation * Vector3::new(twist[0], twist[1], twist[2]);
    let v =
        m.rotation * Vector3::new(twist[3], twist[4], twist[5]) + m.translation.vector.cross(&w);
    (base, Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z))
}

/// The covariance of the published `base_link` pose, over `[x, y, z, roll, pitch, yaw]` in the
/// published frame (the wire's order, rotations about that frame's axes), from the
/// alignment's over `[δθ, δt]` in the odometry's world frame about the sensor
/// (`crate::solver::Alignment::covariance`). `frame_from_world` takes the odometry's world
/// frame to the published one, `sensor` is the sensor's pose in the world and `base` the
/// published pose. A rotation δθ about the sensor moves the base by δθ × (base − sensor) as well.
pub fn base_covariance(
    covariance: &Matrix6<f64>,
    frame_from_world: &Isometry3<f64>,
    sensor: &Isometry3<f64>,
    base: &Isometry3<f64>,
) -> Matrix6<f64> {
    let rotation = frame_from_world.rotation.to_rotation_matrix().into_inner();
    let lever = base.translation.vector - (frame_from_world * sensor).translation.vector;
    let mut jacobian = Matrix6::zeros();
    jacobian
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-lever.cross_matrix() * rotation));
    jacobian.fixed_view_mut::<3, 3>(0, 3).copy_from(&rotation);
    jacobian.fixed_view_mut::<3, 3>(3, 0).copy_from(&rotation);
    let published = jacobian * covariance * jacobian.transpose();
    // Symmetric to the last bit, as consumers may check.
    (published + published.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_and_log_are_inverse() {
        for t in [
            Vector6::new(0.1, -0.2, 0.3, 1.0, 2.0, -3.0),
            Vector6::new(0.0, 0.0, 0.0, 1.0, 0.0, 0.0),
            Vector6::new(1e-9, 0.0, 2.0, 0.0, 0.5, 0.0),
        ] {
            let back = log(&exp(&t));
            assert!((back - t).norm() < 1e-9, "{t} → {back}");
        }
    }

    #[test]
    fn left_perturbation_moves_points_as_documented() {
        let p = Vector3::new(1.0, 2.0, 3.0);
        let d = Vector6::new(1e-6, -2e-6, 3e-6, 4e-6, 5e-6, -6e-6);
        let moved = exp(&d) * nalgebra::Point3::from(p);
        let predicted =
            p - skew(&p) * Vector3::new(d[0], d[1], d[2]) + Vector3::new(d[3], d[4], d[5]);
        // Second-order terms are ~½|ω|²|p| ≈ 3e-11.
        assert!((moved.coords - predicted).norm() < 1e-10);
    }

    #[test]
    fn the_base_pose_follows_the_mounting() {
        // Sensor mounted 1 m ahead of the base, facing backwards; the sensor drives 1 m along its
        // own x (backwards for the base) while turning.
        let m = Isometry3::from_parts(
            Translation3::new(1.0, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::PI),
        );
        let twist = Vector6::new(0.0, 0.0, 0.3, 1.0, 0.0, 0.0);
        let sensor_pose = exp(&twist);
        let (base, base_twist) = to_base(&m, &sensor_pose, &twist);
        // Consistency: the base pose is the exponential of the base twist.
        let from_twist = exp(&base_twist);
        assert!((base.translation.vector - from_twist.translation.vector).norm() < 1e-9);
        assert!(base.rotation.angle_to(&from_twist.rotation) < 1e-9);
        // And the sensor, seen from the moved base, is where it was mounted.
        let sensor_in_odom = base * m;
        let expected = m * sensor_pose;
        assert!((sensor_in_odom.translation.vector - expected.translation.vector).norm() < 1e-9);
    }

    /// A base 2 m ahead of the sensor swings 2 mm sideways per mrad of yaw about the sensor.
    #[test]
    fn a_rotation_about_the_sensor_moves_the_base_by_its_lever_arm() {
        let mut c = Matrix6::zeros();
        c[(2, 2)] = 1e-6;
        let sensor = Isometry3::identity();
        let base = Isometry3::translation(2.0, 0.0, 0.0);
        let b = base_covariance(&c, &Isometry3::identity(), &sensor, &base);
        assert!((b[(1, 1)] - 4e-6).abs() < 1e-15, "{b}");
        assert!(b[(0, 0)].abs() < 1e-15, "{b}");
        // Position and yaw move together.
        assert!(
            (b[(1, 5)] - 2e-6).abs() < 1e-15 && b[(1, 5)] == b[(5, 1)],
            "{b}"
        );
    }
}

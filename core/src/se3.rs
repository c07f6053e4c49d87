//! SE(3) on `Isometry3<f64>`: exponential and logarithm with twists ordered [ω, υ] (rotation
//! first), and the skew matrix. Perturbations are applied on the left, in the fixed frame:
//! `T ← exp(δ)·T`, so a point `q = T·p` moves by `δq = −[q]×·ω + υ`.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3, Vector6};

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
}

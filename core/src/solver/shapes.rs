//! Shape fits: lines and planes through a point's map neighbours, from their covariance's
//! eigen-decomposition.

use super::*;

/// Lines: the neighbours must spread along one direction (largest eigenvalue dominant); the
/// residual is the distance to the line, its projection the line's normal space.
pub(super) fn line_model(config: &SolverConfig, covariance: &Matrix3<f64>) -> Option<Shape> {
    let (values, vectors) = eigen3(covariance);
    (values[2] >= config.line_ratio * values[1]).then_some(Shape::Line(vectors[2]))
}

/// Planes: every neighbour within the tolerance of the plane through them; the residual is the
/// distance along the normal (the smallest eigenvector, see [`plane_normal`]).
pub(super) fn plane_model(
    config: &SolverConfig,
    center: &Vector3<f64>,
    covariance: &Matrix3<f64>,
    near: &[Vector3<f32>],
) -> Option<Shape> {
    let normal = plane_normal(covariance)?;
    near.iter()
        .all(|n| (n.cast::<f64>() - center).dot(&normal).abs() <= config.plane_tolerance)
        .then_some(Shape::Plane(normal))
}

/// The unit eigenvector of the smallest eigenvalue of a symmetric 3×3 `a`, without the
/// eigenvalues: the largest column of its adjugate (λ₂λ₃·e₁e₁ᵀ + λ₁λ₃·e₂e₂ᵀ + λ₁λ₂·e₃e₃ᵀ, so e₁
/// once λ₁ ≪ λ₂), then twice more through the adjugate, which leaves (λ₁/λ₂)³ of the others:
/// for five map points on a wall with centimetres of noise, the normal within microradians,
/// without the cubic's trigonometry that [`eigen3`] needs for the eigenvalues. Points on a line
/// or in one place have none.
pub(super) fn plane_normal(a: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let (r0, r1, r2) = (
        a.row(0).transpose(),
        a.row(1).transpose(),
        a.row(2).transpose(),
    );
    let adjugate = Matrix3::from_columns(&[r1.cross(&r2), r2.cross(&r0), r0.cross(&r1)]);
    let column = adjugate
        .column_iter()
        .max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))?
        .into_owned();
    // Relative to the scale of λ₂λ₃: below it the two smallest eigenvalues are both ~0. (A NaN
    // fails the comparison too.)
    let scale = a.norm_squared();
    let spread = column.norm_squared() > 1e-18 * scale * scale;
    if !spread {
        return None;
    }
    let refined = adjugate * (adjugate * column.normalize());
    (refined.norm_squared() > 0.0).then(|| refined.normalize())
}

/// Centroid and covariance of `points`.
pub(super) fn covariance(points: &[Vector3<f32>]) -> (Vector3<f64>, Matrix3<f64>) {
    let n = points.len() as f64;
    let center = points
        .iter()
        .fold(Vector3::zeros(), |acc: Vector3<f64>, p| {
            acc + p.cast::<f64>()
        })
        / n;
    let mut cov = Matrix3::zeros();
    for p in points {
        let d = p.cast::<f64>() - center;
        cov += d * d.transpose();
    }
    (center, cov / n)
}

/// Eigen-decomposition of a symmetric 3×3 matrix in closed form (the trigonometric solution of
/// the characteristic cubic, eigenvectors from cross products of the rows of A − λI): several
/// times faster than an iterative solver, which it falls back to when eigenvalues nearly repeat.
/// Eigenvalues ascending.
pub(super) fn eigen3(a: &Matrix3<f64>) -> ([f64; 3], [Vector3<f64>; 3]) {
    let fallback = || {
        let e = SymmetricEigen::new(*a);
        let mut order = [0, 1, 2];
        order.sort_by(|&i, &j| e.eigenvalues[i].total_cmp(&e.eigenvalues[j]));
        (
            order.map(|i| e.eigenvalues[i]),
            order.map(|i| e.eigenvectors.column(i).into_owned()),
        )
    };
    let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let q = a.trace() / 3.0;
    let p2 =
        (a[(0, 0)] - q).powi(2) + (a[(1, 1)] - q).powi(2) + (a[(2, 2)] - q).powi(2) + 2.0 * off;
    let p = (p2 / 6.0).sqrt();
    if p < 1e-12 {
        return fallback();
    }
    let b = (a - Matrix3::identity() * q) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let largest = q + 2.0 * p * phi.cos();
    let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    let middle = 3.0 * q - largest - smallest;
    // Well separated from the others, or the cross products lose precision.
    if (largest - middle).min(middle - smallest) < 1e-9 * p {
        return fallback();
    }
    let vector = |lambda: f64| {
        let m = a - Matrix3::identity() * lambda;
        let (r0, r1, r2) = (
            m.row(0).transpose(),
            m.row(1).transpose(),
            m.row(2).transpose(),
        );
        [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)]
            .into_iter()
            .max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))
    };
    let (Some(v_small), Some(v_large)) = (vector(smallest), vector(largest)) else {
        return fallback();
    };
    if v_small.norm_squared() < 1e-24 || v_large.norm_squared() < 1e-24 {
        return fallback();
    }
    let v_small = v_small.normalize();
    let v_large = v_large.normalize();
    let v_middle = v_large.cross(&v_small).normalize();
    ([smallest, middle, largest], [v_small, v_middle, v_large])
}

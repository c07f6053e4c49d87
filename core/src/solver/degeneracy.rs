//! Step 5: what the plane correspondences constrain (the degeneracy measures) and the pose's
//! covariance from the final normal equations.

use super::*;

/// What the plane correspondences constrain at a pose: the degeneracy measures' sums. Read once
/// per alignment, at its end (not in every Levenberg–Marquardt trial).
pub(super) struct PlaneInformation {
    pub(super) translation: Matrix3<f64>,
    pub(super) rotation: Matrix3<f64>,
    pub(super) squared_ranges: f64,
    pub(super) planes: usize,
}

/// See [`PlaneInformation`]. The degeneracy measure reads planes only: their normals are well
/// determined, while an edge line fitted through a few noisy map points can point anywhere and
/// would count as information along a corridor's axis.
pub(super) fn plane_information(pose: &Isometry3<f64>, models: &[Model]) -> PlaneInformation {
    let mut info = PlaneInformation {
        translation: Matrix3::zeros(),
        rotation: Matrix3::zeros(),
        squared_ranges: 0.0,
        planes: 0,
    };
    for m in models {
        if let Shape::Plane(n) = m.shape {
            info.translation.ger(1.0, &n, &n, 1.0);
            // Rotation about the sensor moves a point at r from it by δθ × r.
            let r = pose.rotation * m.point;
            let lever = r.cross(&n);
            info.rotation.ger(1.0, &lever, &lever, 1.0);
            info.squared_ranges += r.norm_squared();
            info.planes += 1;
        }
    }
    info
}

/// [`Alignment::covariance`] from the system at the final pose, whose `models` it was built
/// with: the inverse of its information without the edges' in the balanced frame, with the
/// step's rule for what is held (see [`damped_step`]), then back to rad for the rotations.
pub(super) fn pose_covariance(
    system: &System,
    pose: &Isometry3<f64>,
    models: &[Model],
    weak_translation: Option<Vector3<f64>>,
    config: &SolverConfig,
) -> Matrix6<f64> {
    let (mut edges, mut planes) = (RowSums::default(), RowSums::default());
    for m in models {
        let q = (pose * Point3::from(m.point)).coords;
        match m.shape {
            Shape::Line(d) => {
                let projection = line_projection(m, &d);
                let (w, _) = huber((projection * (q - m.center)).norm(), config.huber_geometric);
                for row in &line_rows(&q, &projection) {
                    edges.add(w, row, 0.0);
                }
            }
            Shape::Plane(n) => {
                let (row, e) = plane_row(m, &n, &q);
                planes.add(huber(e.abs(), config.huber_geometric).0, &row, 0.0);
            }
        }
    }
    let (edges, planes) = (edges.normal_equations().0, planes.normal_equations().0);
    let frame = Balanced::new(system, pose);
    let eigen = SymmetricEigen::new(frame.information(&(system.hessian - edges)));
    let largest = eigen.eigenvalues.max().max(1e-12);
    let held = (largest * NULL_INFORMATION).max(config.hold_information);
    // The balanced information is per geometric correspondence: times their count, it is the
    // whole sweep's, in units of the head-on plane noise.
    let correspondences = frame.per_correspondence.recip();
    let noise = config.plane_noise * config.plane_noise;
    let mut balanced = Matrix6::zeros();
    for i in 0..6 {
        let value = eigen.eigenvalues[i];
        let variance = if system.count == 0 || value <= held {
            HELD_SIGMA * HELD_SIGMA
        } else {
            noise / (value * correspondences)
        };
        let v = eigen.eigenvectors.column(i);
        balanced += v * v.transpose() * variance;
    }
    // Balanced coordinates are [ρ·δθ, δt]: rotations back to rad.
    let rotation = 1.0 / frame.rms_range;
    let scale = Matrix6::from_diagonal(&Vector6::new(rotation, rotation, rotation, 1.0, 1.0, 1.0));
    let (angular, motion) = (config.angular_noise.powi(2), config.motion_noise.powi(2));
    let mut covariance = scale * balanced * scale
        + Matrix6::from_diagonal(&Vector6::new(
            angular, angular, angular, motion, motion, motion,
        ));
    // Along a direction the planes leave free (the sweep is degenerate), whatever information
    // they show is their fits' small biases: only the intensity residuals can measure it. If
    // theirs is below the same threshold, the direction is not measured at all.
    if let Some(w) = weak_translation {
        let intensity = system.hessian - edges - planes;
        let along = w.dot(&(intensity.fixed_view::<3, 3>(3, 3) * w)) * frame.per_correspondence;
        if along < config.degeneracy_threshold {
            let mut block = covariance.fixed_view_mut::<3, 3>(3, 3);
            block += w * w.transpose() * (HELD_SIGMA * HELD_SIGMA);
        }
    }
    covariance
}

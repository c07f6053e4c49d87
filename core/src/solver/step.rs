//! The Levenberg–Marquardt step, taken in balanced coordinates where rotation and translation
//! compare, with the directions that carry no measurement held.

use super::*;

/// The Levenberg–Marquardt step in the eigenbasis of the balanced normal equations (see
/// [`Balanced`]). Directions with less information per correspondence than `hold` (or than
/// `null`, numerically none) carry no usable measurement — a corridor's axis without intensity,
/// rotation inside a sphere of returns, anything but height and tilt over a bare floor — so a
/// step there would follow the fit's small biases, not the motion: they get none, and the pose
/// there stays at the prediction.
pub(super) fn damped_step(
    eigen: &SymmetricEigen<f64, nalgebra::U6>,
    gradient: &Vector6<f64>,
    lambda: f64,
    null: f64,
    hold: f64,
) -> Vector6<f64> {
    let mut step = Vector6::zeros();
    for i in 0..6 {
        let value = eigen.eigenvalues[i];
        if value <= null.max(hold) {
            continue;
        }
        let v = eigen.eigenvectors.column(i);
        step -= v * (v.dot(gradient) / (value * (1.0 + lambda)));
    }
    step
}

/// Coordinates in which the normal equations' directions compare: the solver's perturbation
/// rotates about the world origin, so rotations are re-expressed about the sensor and scaled by
/// the correspondences' RMS range (a rotation then reads as the displacement it causes), and
/// the information is divided by the number of geometric correspondences (1/3 per direction
/// for normals spread evenly; the degeneracy measures' scale).
pub(super) struct Balanced {
    /// δ = A·y: y's rotation part is ρ·ω about the sensor, its translation part the sensor's.
    pub(super) to_perturbation: Matrix6<f64>,
    pub(super) per_correspondence: f64,
    /// ρ, m.
    pub(super) rms_range: f64,
}

impl Balanced {
    pub(super) fn new(system: &System, pose: &Isometry3<f64>) -> Self {
        let rms_range = if system.planes > 0 {
            (system.squared_ranges / system.planes as f64)
                .sqrt()
                .max(1e-3)
        } else {
            1.0
        };
        // A rotation ω about the sensor at t, then a translation υₛ: q' = q + ω × (q − t) + υₛ,
        // which the origin-centred perturbation writes as [ω, υₛ + t × ω].
        let mut a = Matrix6::identity();
        a.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(Matrix3::identity() / rms_range));
        a.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(skew(&pose.translation.vector) / rms_range));
        Self {
            to_perturbation: a,
            per_correspondence: 1.0 / (system.count - system.intensity).max(1) as f64,
            rms_range,
        }
    }

    pub(super) fn hessian(&self, system: &System) -> Matrix6<f64> {
        self.information(&system.hessian)
    }

    /// `hessian` (origin-centred perturbation) in this frame.
    pub(super) fn information(&self, hessian: &Matrix6<f64>) -> Matrix6<f64> {
        self.to_perturbation.transpose() * hessian * self.to_perturbation * self.per_correspondence
    }

    pub(super) fn gradient(&self, system: &System) -> Vector6<f64> {
        self.to_perturbation.transpose() * system.gradient * self.per_correspondence
    }

    pub(super) fn to_perturbation(&self, step: &Vector6<f64>) -> Vector6<f64> {
        self.to_perturbation * step
    }
}

/// Information below this fraction of the strongest direction's is treated as none.
pub(super) const NULL_INFORMATION: f64 = 1e-6;

/// Trials of one Levenberg–Marquardt step, each with more damping, before it is given up.
pub(super) const TRIALS_PER_STEP: usize = 6;

/// The Levenberg–Marquardt damping λ: it scales a step by 1 / (1 + λ) in every direction (see
/// [`damped_step`]), eases after an accepted trial and grows after a rejected one.
#[derive(Debug, Clone, Copy)]
pub(super) struct Damping(f64);

impl Damping {
    /// λ at the start of an alignment.
    const INITIAL: f64 = 1e-4;
    /// λ never eases below this.
    const MIN: f64 = 1e-7;
    /// An accepted trial divides λ by this.
    const EASE: f64 = 3.0;
    /// A rejected trial multiplies λ by this ...
    const GROW: f64 = 4.0;

    pub(super) fn new() -> Self {
        Self(Self::INITIAL)
    }

    pub(super) fn lambda(&self) -> f64 {
        self.0
    }

    pub(super) fn relax(&mut self) {
        self.0 = (self.0 / Self::EASE).max(Self::MIN);
    }

    /// ... and at least halves the step: from a small λ, growing it fourfold left the step as
    /// it was, and the trial was rejected again.
    pub(super) fn stiffen(&mut self) {
        self.0 = (Self::GROW * self.0).max(2.0 * self.0 + 1.0);
    }
}

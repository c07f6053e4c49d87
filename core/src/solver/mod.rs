//! Step 4 of the method: scan-to-map matching, and step 5: degeneracy. Minimises over the pose
//! T ∈ SE(3) a robust (Huber) least-squares sum of
//! - point-to-line distances of edge points to lines fitted through their nearest map edges,
//! - point-to-plane distances of planar points to planes fitted through their nearest map planes,
//! - intensity differences `w·(η − M(T·p))` against the trilinear intensity map,
//!
//! by Levenberg–Marquardt on a left perturbation `T ← exp(δ)·T`, re-associating the geometric
//! correspondences between rounds. (The paper writes a sum of absolute values and solves least
//! squares; this is robust least squares, said plainly.) Degeneracy is read off the eigenvalues
//! of the translational block of the geometric normal equations, normalised per correspondence.

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, SymmetricEigen, Vector3, Vector6};

use crate::config::SolverConfig;
use crate::intensity_map::{Corners, IntensityMap};
use crate::local_map::LocalMap;
use crate::se3::{exp, skew};

mod association;
mod degeneracy;
mod residuals;
mod shapes;
mod step;
#[cfg(test)]
mod tests;

use association::*;
pub use association::{angular_weight, Correspondences, EarlyCorrespondences};
use degeneracy::*;
use residuals::*;
use shapes::*;
use step::*;

/// The points to align, in the sensor frame at the sweep's reference time.
#[derive(Debug, Default, Clone)]
pub struct AlignmentInput {
    /// Edge points.
    pub edges: Vec<Vector3<f64>>,
    /// Planar points.
    pub planes: Vec<Vector3<f64>>,
    /// Points with their calibrated reflectivity, for the intensity residual.
    pub intensity: Vec<IntensityPoint>,
}

/// A point for the intensity residual.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntensityPoint {
    /// Position, sensor frame at the reference time.
    pub point: Vector3<f64>,
    /// Calibrated reflectivity.
    pub eta: f64,
    /// Unit surface normal (sensor frame), or zero if unknown.
    pub normal: Vector3<f64>,
}

/// The maps to align against.
#[derive(Debug, Clone, Copy)]
pub struct MapView<'a> {
    /// Edge points.
    pub edges: &'a LocalMap,
    /// Planar points.
    pub planes: &'a LocalMap,
    /// Reflectivity.
    pub intensity: &'a IntensityMap,
}

/// What the alignment found.
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    /// The pose (sensor at the reference time → world).
    pub pose: Isometry3<f64>,
    /// Correspondences used in the last round.
    pub edges: usize,
    /// See `edges`.
    pub planes: usize,
    /// See `edges`.
    pub intensity: usize,
    /// Smallest eigenvalue of the translational information of the plane correspondences per
    /// correspondence, in [0, 1/3] (1/3: normals spread evenly over all directions; near 0:
    /// some direction of travel is unconstrained by geometry).
    pub degeneracy: f64,
    /// The direction (world frame) geometry constrains least.
    pub weakest_direction: Vector3<f64>,
    /// The same for rotation about the sensor: the smallest eigenvalue of the plane
    /// correspondences' rotational information, divided by their mean squared range, in
    /// [0, 1/3] (near 0: some rotation moves no point off its plane, as on a sphere centred on
    /// the sensor).
    pub rotational_degeneracy: f64,
    /// Whether `degeneracy` or `rotational_degeneracy` is below its configured threshold.
    pub degenerate: bool,
    /// Levenberg–Marquardt steps taken.
    pub iterations: usize,
    /// Mean robust cost per residual at the end.
    pub cost: f64,
    /// The pose's covariance from the final normal equations, over `[δθ, δt]`: a rotation δθ
    /// about the sensor's position and a translation δt of it, both along the world (map) axes,
    /// rad and m, the error of `pose` being `exp(δθ)` about the sensor then `δt`. It describes
    /// one sweep's pose against the local map, not the drift accumulated over the run: the
    /// inverse of the plane and intensity residuals' information, each counted as independent
    /// with the noise of a plane seen head-on ([`SolverConfig::plane_noise`]; the weights scale
    /// the others to it), plus the errors no count of residuals averages away
    /// ([`SolverConfig::angular_noise`] on each rotation, [`SolverConfig::motion_noise`] on each
    /// translation). A direction with less information than
    /// [`SolverConfig::hold_information`] gets [`HELD_SIGMA`]² instead, displacement at the
    /// returns' RMS range, and so does the direction a degenerate sweep's planes leave free
    /// unless the intensity residuals measure it (as much as `degeneracy_threshold` asks of
    /// planes). Edge lines are left out, as from the degeneracy measure: fitted through a few map
    /// points their direction is poorly known. In a corridor without intensity, edges and the
    /// planes' slight information along the axis made it look measured (σ 15–17 mm) while the
    /// pose moved 8–9 times that from sweep to sweep.
    pub covariance: Matrix6<f64>,
}

/// 1σ (m) given to a direction the alignment held at the prediction: it was not measured, and no
/// consumer should fuse it as if it had been. Rotations read as the displacement they cause at
/// the returns' RMS range.
pub const HELD_SIGMA: f64 = 1.0;

/// Aligns `input` to `maps` starting from `initial`.
pub fn align(
    initial: &Isometry3<f64>,
    input: &AlignmentInput,
    maps: MapView<'_>,
    config: &SolverConfig,
) -> Alignment {
    align_with(
        initial,
        input,
        maps,
        config,
        &mut Correspondences::default(),
    )
}

/// [`align`], starting from the correspondences in `kept` (empty, or from an alignment of the
/// same points against the same maps) and leaving this alignment's there.
pub fn align_with(
    initial: &Isometry3<f64>,
    input: &AlignmentInput,
    maps: MapView<'_>,
    config: &SolverConfig,
    kept: &mut Correspondences,
) -> Alignment {
    let mut pose = *initial;
    let mut models = Vec::with_capacity(input.edges.len() + input.planes.len());
    let Correspondences {
        edges: edge_links,
        planes: plane_links,
        intensity: intensity_links,
    } = kept;
    let mut neighbours = Vec::with_capacity(8);
    // A round's first system, which selects the intensity residuals its trials keep.
    let round_start_system = |pose: &Isometry3<f64>, models: &[Model], links: &mut Vec<_>| {
        build(
            pose,
            models,
            input,
            maps.intensity,
            config,
            links,
            IntensitySet::Select,
        )
    };
    let mut damping = Damping::new();
    let mut iterations = 0;
    let mut edges = 0;
    let mut planes = 0;
    // The system at `pose` with the latest models.
    let mut last = None;
    // Whether the last round's Levenberg–Marquardt converged.
    let mut settled = false;
    for _ in 0..config.outer_iterations.max(1) {
        let round_start = pose;
        let line = |_: &_, covariance: &_, _: &_| line_model(config, covariance);
        let plane =
            |center: &_, covariance: &_, near: &_| plane_model(config, center, covariance, near);
        let updated = edge_links.update(
            &pose,
            &input.edges,
            maps.edges,
            config,
            &mut neighbours,
            line,
        ) + plane_links.update(
            &pose,
            &input.planes,
            maps.planes,
            config,
            &mut neighbours,
            plane,
        );
        // Same correspondences, same system, and the solver had converged on it: another
        // round would only repeat the last one's final, negligible step.
        if updated == 0 && settled {
            break;
        }
        let mut converged = false;
        // `last` is the system at `pose` with the models in hand: unless a point was
        // re-associated, this round's would be the same, bit for bit.
        let system = match last.as_mut() {
            Some(system) if updated == 0 => system,
            _ => {
                models.clear();
                edges = edge_links.collect(&mut models);
                planes = plane_links.collect(&mut models);
                last.insert(round_start_system(&pose, &models, intensity_links))
            }
        };
        for _ in 0..config.inner_iterations.max(1) {
            if system.count == 0 {
                break;
            }
            let frame = Balanced::new(system, &pose);
            let hessian = frame.hessian(system);
            let gradient = frame.gradient(system);
            let eigen = SymmetricEigen::new(hessian);
            let largest = eigen.eigenvalues.max().max(1e-12);
            // Levenberg–Marquardt: retry with more damping until the cost drops. An accepted
            // trial's system is the next step's, so each trial costs one evaluation.
            let mut accepted = false;
            for _ in 0..TRIALS_PER_STEP {
                let step = frame.to_perturbation(&damped_step(
                    &eigen,
                    &gradient,
                    damping.lambda(),
                    largest.max(1e-12) * NULL_INFORMATION,
                    config.hold_information,
                ));
                // A step this small ends the round, taken or not: the pose it would give is
                // within the tolerance of this one, so its evaluation is saved.
                if step.norm() < config.convergence {
                    converged = true;
                    break;
                }
                let candidate = exp(&step) * pose;
                let trial = build(
                    &candidate,
                    &models,
                    input,
                    maps.intensity,
                    config,
                    intensity_links,
                    IntensitySet::Keep,
                );
                iterations += 1;
                let change = (trial.cost - system.cost).abs() / system.cost.max(f64::MIN_POSITIVE);
                if trial.cost <= system.cost {
                    pose = candidate;
                    *system = trial;
                    damping.relax();
                    accepted = true;
                    converged = step.norm() < config.convergence || change < config.cost_tolerance;
                    break;
                }
                if change < config.cost_tolerance {
                    converged = true;
                    break;
                }
                damping.stiffen();
            }
            if !accepted || converged {
                break;
            }
        }
        settled = converged;
        // Another round only if this one moved the pose: new correspondences could differ.
        if crate::se3::log(&(round_start.inverse() * pose)).norm() < config.convergence {
            break;
        }
    }
    // The last accepted trial was built at `pose` with the last round's models: it is the
    // final system (re-association happens only at the start of a round).
    let system = last.unwrap_or_else(|| round_start_system(&pose, &models, intensity_links));
    let info = plane_information(&pose, &models);
    let translational = info.translation / info.planes.max(1) as f64;
    let eigen = SymmetricEigen::new(translational);
    let (weakest, degeneracy) = eigen
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(i, &v)| (eigen.eigenvectors.column(i).into_owned(), v.max(0.0)))
        .unwrap_or((Vector3::x(), 0.0));
    let rotational_degeneracy = if info.squared_ranges > 0.0 {
        SymmetricEigen::new(info.rotation / info.squared_ranges)
            .eigenvalues
            .min()
            .max(0.0)
    } else {
        0.0
    };
    let weak_translation = (degeneracy < config.degeneracy_threshold).then_some(weakest);
    let covariance = pose_covariance(&system, &pose, &models, weak_translation, config);
    Alignment {
        pose,
        edges,
        planes,
        intensity: system.intensity,
        degeneracy,
        weakest_direction: weakest,
        rotational_degeneracy,
        degenerate: degeneracy < config.degeneracy_threshold
            || rotational_degeneracy < config.rotational_degeneracy_threshold,
        iterations,
        cost: system.cost / system.count.max(1) as f64,
        covariance,
    }
}

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

/// A geometric correspondence fixed for one round: residual `e = P·(T·p − c)`, where `P` is the
/// projection onto the line's normal space (edges) or onto the plane normal (planes).
#[derive(Debug, Clone, Copy)]
struct Model {
    point: Vector3<f64>,
    center: Vector3<f64>,
    shape: Shape,
    /// The residual's weight: its noise at a frontal surface over its noise here, squared
    /// (see [`SolverConfig::angular_noise`]).
    weight: f64,
}

/// What a neighbourhood was fitted as.
#[derive(Debug, Clone, Copy)]
enum Shape {
    /// A line with this unit direction: `P = I − d·dᵀ`.
    Line(Vector3<f64>),
    /// A plane with this unit normal: `P = n·nᵀ`, a scalar residual `n·(T·p − c)`.
    Plane(Vector3<f64>),
}

/// What an alignment found for each point — its map correspondence and where it was made, its
/// eight intensity cells (and whether its intensity residual is in the round's set, see
/// `IntensitySet`) — kept for another alignment of the same points against the same maps
/// (the same sweep deskewed again, its points moved by millimetres): each point keeps what is
/// still valid for it, by the rule of [`SolverConfig::reassociation_distance`].
#[derive(Debug, Default, Clone)]
pub struct Correspondences {
    edges: Links,
    planes: Links,
    intensity: Vec<IntensityLink>,
}

/// An intensity point's eight map cells, and whether it has a residual in the current round.
#[derive(Debug, Default, Clone, Copy)]
struct IntensityLink {
    corners: Corners,
    active: bool,
}

/// Which intensity points a [`build`] gives a residual.
#[derive(Debug, Clone, Copy, PartialEq)]
enum IntensitySet {
    /// Those the map covers at this pose (a round's first system): the set is recorded.
    Select,
    /// The recorded set (a trial within the round), so that its cost and the system's are sums
    /// over the same residuals. A point entering or leaving the map's cover as the pose moves
    /// by a millimetre would make the cost jump by its whole residual; Levenberg–Marquardt then
    /// rejected step after step for a rise no damping could remove.
    Keep,
}

impl Correspondences {
    /// Forgets everything (a new sweep, or the maps changed).
    pub fn clear(&mut self) {
        for links in [&mut self.edges, &mut self.planes] {
            links.at.clear();
            links.models.clear();
        }
        self.intensity.clear();
    }
}

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
    let mut lambda = 1e-4;
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
            for _ in 0..6 {
                let step = frame.to_perturbation(&damped_step(
                    &eigen,
                    &gradient,
                    lambda,
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
                    lambda = (lambda / 3.0).max(1e-7);
                    accepted = true;
                    converged = step.norm() < config.convergence || change < config.cost_tolerance;
                    break;
                }
                if change < config.cost_tolerance {
                    converged = true;
                    break;
                }
                // The damping scales the whole step by 1 / (1 + λ): from a small λ, growing it
                // fourfold left the step as it was, and the trial was rejected again. At least
                // halve it.
                lambda = (4.0 * lambda).max(2.0 * lambda + 1.0);
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

/// [`Alignment::covariance`] from the system at the final pose, whose `models` it was built
/// with: the inverse of its information without the edges' in the balanced frame, with the
/// step's rule for what is held (see [`damped_step`]), then back to rad for the rotations.
fn pose_covariance(
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

/// The Levenberg–Marquardt step in the eigenbasis of the balanced normal equations (see
/// [`Balanced`]). Directions with less information per correspondence than `hold` (or than
/// `null`, numerically none) carry no usable measurement — a corridor's axis without intensity,
/// rotation inside a sphere of returns, anything but height and tilt over a bare floor — so a
/// step there would follow the fit's small biases, not the motion: they get none, and the pose
/// there stays at the prediction.
fn damped_step(
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
struct Balanced {
    /// δ = A·y: y's rotation part is ρ·ω about the sensor, its translation part the sensor's.
    to_perturbation: Matrix6<f64>,
    per_correspondence: f64,
    /// ρ, m.
    rms_range: f64,
}

impl Balanced {
    fn new(system: &System, pose: &Isometry3<f64>) -> Self {
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

    fn hessian(&self, system: &System) -> Matrix6<f64> {
        self.information(&system.hessian)
    }

    /// `hessian` (origin-centred perturbation) in this frame.
    fn information(&self, hessian: &Matrix6<f64>) -> Matrix6<f64> {
        self.to_perturbation.transpose() * hessian * self.to_perturbation * self.per_correspondence
    }

    fn gradient(&self, system: &System) -> Vector6<f64> {
        self.to_perturbation.transpose() * system.gradient * self.per_correspondence
    }

    fn to_perturbation(&self, step: &Vector6<f64>) -> Vector6<f64> {
        self.to_perturbation * step
    }
}

/// Information below this fraction of the strongest direction's is treated as none.
const NULL_INFORMATION: f64 = 1e-6;

/// Each point's correspondence and where (world frame) it was made. A point that has moved less
/// than [`SolverConfig::reassociation_distance`] since keeps it: its nearest neighbours, 0.1 m
/// or more apart in the map, would be the same, and the search is most of the solver's time.
#[derive(Debug, Default, Clone)]
struct Links {
    at: Vec<Vector3<f64>>,
    models: Vec<Option<Model>>,
}

impl Links {
    /// For each point that moved enough (all of them the first time), fits a model to its nearest
    /// map neighbours at `pose`: `fit` turns the neighbourhood (centroid, covariance, the
    /// neighbours) into the residual's projection, or rejects it.
    fn update(
        &mut self,
        pose: &Isometry3<f64>,
        points: &[Vector3<f64>],
        map: &LocalMap,
        config: &SolverConfig,
        neighbours: &mut Vec<Vector3<f32>>,
        fit: impl Fn(&Vector3<f64>, &Matrix3<f64>, &[Vector3<f32>]) -> Option<Shape>,
    ) -> usize {
        let fresh = self.at.len() != points.len();
        if fresh {
            self.at.clear();
            self.at.resize(points.len(), Vector3::zeros());
            self.models.clear();
            self.models.resize(points.len(), None);
        }
        let limit_sq = config.reassociation_distance.powi(2);
        let mut updated = 0;
        for (i, p) in points.iter().enumerate() {
            let q = (pose * Point3::from(*p)).coords;
            if !fresh && (q - self.at[i]).norm_squared() <= limit_sq {
                continue;
            }
            self.at[i] = q;
            self.models[i] = associate(pose, p, &q, map, config, neighbours, &fit);
            updated += 1;
        }
        updated
    }

    /// Appends the current models to `models`; returns how many there are.
    fn collect(&self, models: &mut Vec<Model>) -> usize {
        let before = models.len();
        models.extend(self.models.iter().flatten());
        models.len() - before
    }
}

/// Fits a model for the point `p` (sensor frame), seen at `q` (world), to its nearest map
/// neighbours.
fn associate(
    pose: &Isometry3<f64>,
    p: &Vector3<f64>,
    q: &Vector3<f64>,
    map: &LocalMap,
    config: &SolverConfig,
    neighbours: &mut Vec<Vector3<f32>>,
    fit: &impl Fn(&Vector3<f64>, &Matrix3<f64>, &[Vector3<f32>]) -> Option<Shape>,
) -> Option<Model> {
    map.nearest(
        &q.cast(),
        config.neighbours,
        config.max_neighbour_distance,
        neighbours,
    );
    if neighbours.len() < config.neighbours {
        return None;
    }
    let (center, covariance) = covariance(neighbours);
    fit(&center, &covariance, neighbours).map(|shape| Model {
        point: *p,
        center,
        shape,
        weight: residual_weight(pose, p, &shape, config),
    })
}

/// A geometric residual's weight from how much an angular error of the ray moves the point off
/// its model. An angular error δ (the sweep's vibration and residual motion, the beam's width)
/// displaces a return at range r by r·δ across its ray, and a plane sees the part along its
/// normal, r·δ·sin α at incidence α: |p × n|·δ (a line, the part leaving it: |p × d|·δ). Range
/// noise σ adds along the ray (taken whole, the map's own fit included), so the residual's
/// variance is σ² + (|p × n|·δ)², and the weight σ² over that: 1 on a wall seen head-on, small
/// for ground seen far away at a grazing angle, which a tilt of the sensor lifts by metres.
fn residual_weight(
    pose: &Isometry3<f64>,
    p: &Vector3<f64>,
    shape: &Shape,
    config: &SolverConfig,
) -> f64 {
    let direction = match shape {
        Shape::Plane(n) => n,
        Shape::Line(d) => d,
    };
    let local = pose.rotation.inverse_transform_vector(direction);
    angular_weight(p.cross(&local).norm_squared(), config)
}

/// The weight σ² / (σ² + lever²·δ²) of a residual whose point (sensor frame) moves `lever` m per
/// radian of ray error: |p × n| for a plane with normal n, |p × d| for a line along d (the
/// part of an angular error that leaves the line). See [`residual_weight`].
pub fn angular_weight(lever_sq: f64, config: &SolverConfig) -> f64 {
    let noise = config.plane_noise * config.plane_noise;
    noise / (noise + lever_sq * config.angular_noise * config.angular_noise)
}

/// Lines: the neighbours must spread along one direction (largest eigenvalue dominant); the
/// residual is the distance to the line, its projection the line's normal space.
fn line_model(config: &SolverConfig, covariance: &Matrix3<f64>) -> Option<Shape> {
    let (values, vectors) = eigen3(covariance);
    (values[2] >= config.line_ratio * values[1]).then_some(Shape::Line(vectors[2]))
}

/// Planes: every neighbour within the tolerance of the plane through them; the residual is the
/// distance along the normal (the smallest eigenvector, see [`plane_normal`]).
fn plane_model(
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
fn plane_normal(a: &Matrix3<f64>) -> Option<Vector3<f64>> {
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
fn covariance(points: &[Vector3<f32>]) -> (Vector3<f64>, Matrix3<f64>) {
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
fn eigen3(a: &Matrix3<f64>) -> ([f64; 3], [Vector3<f64>; 3]) {
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

struct System {
    hessian: Matrix6<f64>,
    gradient: Vector6<f64>,
    cost: f64,
    count: usize,
    intensity: usize,
    /// Σ of the plane points' squared ranges from the sensor, and their count (for the
    /// balanced frame's RMS range).
    squared_ranges: f64,
    planes: usize,
}

/// What the plane correspondences constrain at a pose: the degeneracy measures' sums. Read once
/// per alignment, at its end (not in every Levenberg–Marquardt trial).
struct PlaneInformation {
    translation: Matrix3<f64>,
    rotation: Matrix3<f64>,
    squared_ranges: f64,
    planes: usize,
}

/// See [`PlaneInformation`]. The degeneracy measure reads planes only: their normals are well
/// determined, while an edge line fitted through a few noisy map points can point anywhere and
/// would count as information along a corridor's axis.
fn plane_information(pose: &Isometry3<f64>, models: &[Model]) -> PlaneInformation {
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

/// Huber weight and cost of a residual of norm `r` with threshold `k`.
fn huber(r: f64, k: f64) -> (f64, f64) {
    if r <= k {
        (1.0, 0.5 * r * r)
    } else {
        (k / r, k * (r - 0.5 * k))
    }
}

/// Normal equations (IRLS with Huber weights) at `pose`.
fn build(
    pose: &Isometry3<f64>,
    models: &[Model],
    input: &AlignmentInput,
    intensity: &IntensityMap,
    config: &SolverConfig,
    links: &mut Vec<IntensityLink>,
    set: IntensitySet,
) -> System {
    let mut s = System {
        hessian: Matrix6::zeros(),
        gradient: Vector6::zeros(),
        cost: 0.0,
        count: 0,
        intensity: 0,
        squared_ranges: 0.0,
        planes: 0,
    };
    let mut rows = RowSums::default();
    for m in models {
        let q = (pose * Point3::from(m.point)).coords;
        match m.shape {
            Shape::Plane(n) => {
                let (row, e) = plane_row(m, &n, &q);
                let (w, cost) = huber(e.abs(), config.huber_geometric);
                rows.add(w, &row, e);
                s.cost += cost;
                s.squared_ranges += m.point.norm_squared();
                s.planes += 1;
            }
            Shape::Line(d) => {
                let projection = line_projection(m, &d);
                let e = projection * (q - m.center);
                let (w, cost) = huber(e.norm(), config.huber_geometric);
                for (i, row) in line_rows(&q, &projection).iter().enumerate() {
                    rows.add(w, row, e[i]);
                }
                s.cost += cost;
            }
        }
        s.count += 1;
    }
    if config.use_intensity {
        let weight = config.intensity_weight;
        links.resize(input.intensity.len(), IntensityLink::default());
        for (ip, link) in input.intensity.iter().zip(links.iter_mut()) {
            let q = (pose * Point3::from(ip.point)).coords;
            let sample = match set {
                IntensitySet::Select => {
                    let sample = intensity.sample_near(&q, &mut link.corners);
                    link.active = sample.is_some();
                    sample
                }
                IntensitySet::Keep if link.active => {
                    intensity.sample_observed(&q, &mut link.corners)
                }
                IntensitySet::Keep => None,
            };
            let Some(sample) = sample else {
                continue;
            };
            let r = weight * (ip.eta - sample.value);
            let (w, cost) = huber(r.abs(), config.huber_intensity);
            // Reflectivity is a property of the surface: only its gradient along the surface
            // says where the point is. Across the surface the voxel grid's layering makes up a
            // gradient, and the position there is geometry's to decide.
            let n = pose.rotation * ip.normal;
            let along = sample.gradient - n * n.dot(&sample.gradient);
            // r = w·(η − M(q)) ⇒ ∂r/∂δ = −w·∇Mᵀ·[−[q]×, I].
            let g = -weight * along;
            let j_rot = -(g.transpose() * skew(&q));
            rows.add(w, &[j_rot[0], j_rot[1], j_rot[2], g.x, g.y, g.z], r);
            s.cost += cost;
            s.count += 1;
            s.intensity += 1;
        }
    }
    (s.hessian, s.gradient) = rows.normal_equations();
    s
}

/// A plane residual at `q` and its Jacobian's row, both scaled by the residual's weight:
/// ∂q/∂δ = [−[q]×, I], so ∂e/∂δ = nᵀ·[−[q]×, I] = [(q × n)ᵀ, nᵀ].
fn plane_row(m: &Model, n: &Vector3<f64>, q: &Vector3<f64>) -> ([f64; 6], f64) {
    let scale = m.weight.sqrt();
    let e = scale * n.dot(&(q - m.center));
    let arm = scale * q.cross(n);
    let n = scale * n;
    ([arm.x, arm.y, arm.z, n.x, n.y, n.z], e)
}

/// A line residual's projection: onto the line's normal space, scaled by the residual's weight.
fn line_projection(m: &Model, d: &Vector3<f64>) -> Matrix3<f64> {
    m.weight.sqrt() * (Matrix3::identity() - d * d.transpose())
}

/// The rows of a line residual's Jacobian at `q`: ∂q/∂δ = [−[q]×, I], so ∂e/∂δ = P·[−[q]×, I],
/// one row per axis of the residual, and row i is [(q × Pᵢ)ᵀ, Pᵢᵀ] (P symmetric).
fn line_rows(q: &Vector3<f64>, projection: &Matrix3<f64>) -> [[f64; 6]; 3] {
    std::array::from_fn(|i| {
        let row = projection.column(i).into_owned();
        let arm = q.cross(&row);
        [arm.x, arm.y, arm.z, row.x, row.y, row.z]
    })
}

/// Σ w·j·jᵀ and Σ w·e·j over the residual rows j. The matrix is symmetric, so only its upper
/// triangle is summed: 21 products a row instead of the 36 of nalgebra's `ger`, which made this
/// accumulation a fifth of the odometry's instructions.
#[derive(Default)]
struct RowSums {
    /// Row a's entries b ≥ a.
    upper: [[f64; 6]; 6],
    gradient: [f64; 6],
}

impl RowSums {
    #[inline(always)]
    fn add(&mut self, w: f64, j: &[f64; 6], e: f64) {
        for (a, (row, g)) in self.upper.iter_mut().zip(&mut self.gradient).enumerate() {
            let wj = w * j[a];
            for (h, &jb) in row[a..].iter_mut().zip(&j[a..]) {
                *h += wj * jb;
            }
            *g += wj * e;
        }
    }

    fn normal_equations(&self) -> (Matrix6<f64>, Vector6<f64>) {
        let hessian = Matrix6::from_fn(|r, c| self.upper[r.min(c)][r.max(c)]);
        (hessian, Vector6::from(self.gradient))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{IntensityMapConfig, LocalMapConfig};
    use crate::se3::log;

    /// A box room (planes at x = ±6, y = ±4, z = 0 and 3) with edges along its vertical corners.
    fn room() -> (LocalMap, LocalMap, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let mut planes = LocalMap::new(&LocalMapConfig::default());
        let mut edges = LocalMap::new(&LocalMapConfig {
            min_spacing: 0.05,
            ..LocalMapConfig::default()
        });
        let mut plane_pts = Vec::new();
        let mut edge_pts = Vec::new();
        let step = 0.25;
        for i in 0..=48 {
            for j in 0..=12 {
                let (a, b) = (-6.0 + i as f64 * step, j as f64 * step);
                for p in [Vector3::new(a, -4.0, b), Vector3::new(a, 4.0, b)] {
                    plane_pts.push(p);
                }
            }
        }
        for i in 0..=32 {
            for j in 0..=12 {
                let (a, b) = (-4.0 + i as f64 * step, j as f64 * step);
                plane_pts.push(Vector3::new(-6.0, a, b));
                plane_pts.push(Vector3::new(6.0, a, b));
            }
        }
        for i in 0..=48 {
            for j in 0..=32 {
                plane_pts.push(Vector3::new(
                    -6.0 + i as f64 * step,
                    -4.0 + j as f64 * step,
                    0.0,
                ));
            }
        }
        for k in 0..=30 {
            for (x, y) in [(-6.0, -4.0), (-6.0, 4.0), (6.0, -4.0), (6.0, 4.0)] {
                edge_pts.push(Vector3::new(x, y, k as f64 * 0.1));
            }
        }
        for p in &plane_pts {
            planes.insert(p.cast());
        }
        for p in &edge_pts {
            edges.insert(p.cast());
        }
        (edges, planes, edge_pts, plane_pts)
    }

    #[test]
    fn closed_form_eigen_matches_the_iterative_solver() {
        let mut next = crate::test_random::centred(7);
        for _ in 0..200 {
            let m = Matrix3::from_fn(|_, _| next());
            let a = m * m.transpose();
            let (values, vectors) = eigen3(&a);
            for i in 0..3 {
                assert!(
                    (a * vectors[i] - vectors[i] * values[i]).norm() < 1e-9,
                    "{a} {values:?}"
                );
            }
            assert!(values[0] <= values[1] && values[1] <= values[2]);
        }
        // Repeated eigenvalues go through the fallback.
        let (values, _) = eigen3(&Matrix3::identity());
        assert_eq!(values, [1.0, 1.0, 1.0]);
    }

    #[test]
    fn a_planar_neighbourhood_s_normal_is_its_smallest_eigenvector() {
        let mut next = crate::test_random::centred(11);
        for _ in 0..200 {
            // Five points on a tilted plane, 0.4 m across, with 1 cm of noise off it.
            let normal = Vector3::new(next(), next(), next()).normalize();
            let u = normal
                .cross(&Vector3::new(next(), next(), next()))
                .normalize();
            let v = normal.cross(&u);
            let origin = Vector3::new(next(), next(), next()) * 40.0;
            let points: Vec<Vector3<f32>> = (0..5)
                .map(|_| {
                    let p = origin + u * 0.8 * next() + v * 0.8 * next() + normal * 0.02 * next();
                    p.cast()
                })
                .collect();
            let (_, a) = covariance(&points);
            let (_, vectors) = eigen3(&a);
            let found = plane_normal(&a).expect("a plane has a normal");
            // Within 0.15 mrad, when five random points may come close to a line.
            assert!(
                found.dot(&vectors[0]).abs() > 1.0 - 1e-8,
                "{found} vs {}",
                vectors[0]
            );
        }
        // Points on a line, or all in one place, have none.
        let line: Vec<Vector3<f32>> = (0..5)
            .map(|i| Vector3::new(1.0, 2.0, 3.0) * (0.1 * i as f32))
            .collect();
        assert_eq!(plane_normal(&covariance(&line).1), None);
        assert_eq!(plane_normal(&Matrix3::zeros()), None);
    }

    #[test]
    fn recovers_a_known_offset() {
        let (edges, planes, edge_pts, plane_pts) = room();
        let intensity = IntensityMap::new(&IntensityMapConfig::default());
        let truth = exp(&Vector6::new(0.01, -0.02, 0.05, 0.3, -0.2, 0.05));
        // The scan sees the room from the true pose: its points are truth⁻¹·world.
        let inverse = truth.inverse();
        let input = AlignmentInput {
            edges: edge_pts
                .iter()
                .step_by(3)
                .map(|p| (inverse * Point3::from(*p)).coords)
                .collect(),
            planes: plane_pts
                .iter()
                .step_by(7)
                .map(|p| (inverse * Point3::from(*p)).coords)
                .collect(),
            intensity: Vec::new(),
        };
        let maps = MapView {
            edges: &edges,
            planes: &planes,
            intensity: &intensity,
        };
        let a = align(
            &Isometry3::identity(),
            &input,
            maps,
            &SolverConfig::default(),
        );
        let error = log(&(a.pose.inverse() * truth));
        assert!(error.norm() < 1e-4, "error {error}, {a:?}");
        assert!(!a.degenerate, "{}", a.degeneracy);
        // Every direction measured: the residuals add little to the floors.
        let config = SolverConfig::default();
        for i in 0..6 {
            let floor = if i < 3 {
                config.angular_noise
            } else {
                config.motion_noise
            };
            let sigma = a.covariance[(i, i)].sqrt();
            assert!(
                sigma >= floor && sigma < 1.5 * floor,
                "{i}: {}",
                a.covariance
            );
        }
        assert_eq!(a.covariance, a.covariance.transpose());
    }

    #[test]
    fn a_corridor_is_degenerate_along_its_axis() {
        // Two walls and a floor, all parallel to x.
        let mut planes = LocalMap::new(&LocalMapConfig::default());
        let mut pts = Vec::new();
        for i in 0..200 {
            for j in 0..12 {
                let x = -25.0 + i as f64 * 0.25;
                let h = j as f64 * 0.25;
                pts.extend([
                    Vector3::new(x, -1.75, h),
                    Vector3::new(x, 1.75, h),
                    Vector3::new(x, -1.75 + h, 0.0),
                ]);
            }
        }
        for p in &pts {
            planes.insert(p.cast());
        }
        let edges = LocalMap::new(&LocalMapConfig::default());
        let intensity = IntensityMap::new(&IntensityMapConfig::default());
        let input = AlignmentInput {
            edges: vec![],
            planes: pts.iter().step_by(5).copied().collect(),
            intensity: vec![],
        };
        let maps = MapView {
            edges: &edges,
            planes: &planes,
            intensity: &intensity,
        };
        let a = align(
            &Isometry3::identity(),
            &input,
            maps,
            &SolverConfig::default(),
        );
        assert!(a.degenerate, "{}", a.degeneracy);
        assert!(
            a.weakest_direction.x.abs() > 0.99,
            "{}",
            a.weakest_direction
        );
        // The covariance says which direction: the axis was held, height was measured. (Seen
        // from 15 m away on average, roll inside the corridor is weak too, and mixes with y.)
        let c = &a.covariance;
        assert!(c[(3, 3)] >= 0.5 * HELD_SIGMA * HELD_SIGMA, "{c}");
        assert!(c[(5, 5)] < 1e-3, "{c}");
        let translation = SymmetricEigen::new(c.fixed_view::<3, 3>(3, 3).into_owned());
        let widest = translation.eigenvalues.imax();
        assert!(translation.eigenvectors[(0, widest)].abs() > 0.99, "{c}");
    }

    #[test]
    fn intensity_resolves_the_corridor_axis() {
        // The same corridor, with reflectivity stripes on the walls every 2 m along x.
        let mut planes = LocalMap::new(&LocalMapConfig::default());
        let mut map = IntensityMap::new(&IntensityMapConfig::default());
        let stripe = |x: f64| if x.rem_euclid(2.0) < 0.6 { 80.0 } else { 20.0 };
        for i in 0..500 {
            for j in 0..30 {
                let x = -25.0 + i as f64 * 0.1;
                let h = 0.1 + j as f64 * 0.1;
                for y in [-1.75, 1.75] {
                    let p = Vector3::new(x, y, h);
                    planes.insert(p.cast());
                    map.insert(&p.cast(), stripe(x) as f32);
                }
            }
        }
        let edges = LocalMap::new(&LocalMapConfig::default());
        let truth = exp(&Vector6::new(0.0, 0.0, 0.0, 0.15, 0.0, 0.0));
        let inverse = truth.inverse();
        // The scan samples the walls on its own lattice, offset from the map's, as a sensor
        // would: near the stripes' edges for intensity, everywhere for planes.
        let scan: Vec<Vector3<f64>> = (0..495)
            .flat_map(|i| {
                (0..29).flat_map(move |j| {
                    [-1.75, 1.75].map(|y| {
                        Vector3::new(-24.7 + i as f64 * 0.1 + 0.037, y, 0.15 + j as f64 * 0.1)
                    })
                })
            })
            .collect();
        let input = AlignmentInput {
            edges: vec![],
            planes: scan
                .iter()
                .step_by(11)
                .map(|p| (inverse * Point3::from(*p)).coords)
                .collect(),
            intensity: scan
                .iter()
                .filter(|p| {
                    let f = p.x.rem_euclid(2.0);
                    f.min((f - 0.6).abs()).min(2.0 - f) < 0.3
                })
                .map(|p| IntensityPoint {
                    point: (inverse * Point3::from(*p)).coords,
                    eta: stripe(p.x),
                    normal: inverse.rotation * Vector3::y(),
                })
                .collect(),
        };
        let maps = MapView {
            edges: &edges,
            planes: &planes,
            intensity: &map,
        };
        let a = align(
            &Isometry3::identity(),
            &input,
            maps,
            &SolverConfig::default(),
        );
        assert!(
            (a.pose.translation.vector.x - 0.15).abs() < 0.02,
            "{}",
            a.pose.translation.vector
        );
        let geometry_only = SolverConfig {
            use_intensity: false,
            ..SolverConfig::default()
        };
        let g = align(&Isometry3::identity(), &input, maps, &geometry_only);
        assert!(
            g.pose.translation.vector.x.abs() < 0.05,
            "geometry alone cannot see the offset"
        );
        // With intensity the axis is measured (to about the floor); without, it was held.
        let (with, without) = (a.covariance[(3, 3)], g.covariance[(3, 3)]);
        assert!(with < 1e-3, "{}", a.covariance);
        assert!(without >= 0.5 * HELD_SIGMA * HELD_SIGMA, "{}", g.covariance);
        // Trilinear cells make the cost piecewise smooth: near the minimum a step can raise it
        // by a hair however it is damped. Stopping there (`cost_tolerance`) instead of retrying
        // saves trials and gives the same pose (compared with no step tolerance, which would
        // end both first).
        let stopping = SolverConfig {
            convergence: 0.0,
            ..SolverConfig::default()
        };
        let retrying = SolverConfig {
            cost_tolerance: 0.0,
            ..stopping.clone()
        };
        let s = align(&Isometry3::identity(), &input, maps, &stopping);
        let r = align(&Isometry3::identity(), &input, maps, &retrying);
        assert!(
            s.iterations < r.iterations,
            "{} trials stopping, {} retrying",
            s.iterations,
            r.iterations
        );
        for stopped in [&a, &s] {
            assert!(
                (stopped.pose.translation.vector - r.pose.translation.vector).norm() < 0.005,
                "{} against {}",
                stopped.pose.translation.vector,
                r.pose.translation.vector
            );
        }
    }
}

#[cfg(test)]
mod jacobian_tests {
    use super::*;
    use crate::config::IntensityMapConfig;
    use crate::se3::exp;

    /// The intensity residual's analytic gradient of the cost equals the finite-difference one,
    /// for rotation and translation alike.
    #[test]
    fn intensity_gradient_matches_finite_differences() {
        let mut map = IntensityMap::new(&IntensityMapConfig {
            voxel: 0.2,
            max_count: 20,
            min_weight: 0.5,
        });
        let field = |p: &Vector3<f64>| {
            50.0 + 20.0 * (1.3 * p.x).sin() + 10.0 * (0.7 * p.y + 0.4 * p.z).cos()
        };
        for i in -60..60 {
            for j in -60..60 {
                for k in -10..10 {
                    let p = Vector3::new(
                        i as f64 * 0.1 + 0.05,
                        j as f64 * 0.1 + 0.05,
                        k as f64 * 0.1 + 0.05,
                    );
                    map.insert(&p.cast(), field(&p) as f32);
                }
            }
        }
        let pose = exp(&Vector6::new(0.05, -0.03, 0.2, 0.3, -0.2, 0.1));
        let points: Vec<IntensityPoint> = (0..40)
            .map(|i| {
                let p = Vector3::new(
                    (i % 7) as f64 * 0.6 - 2.0,
                    (i % 5) as f64 * 0.5 - 1.0,
                    (i % 3) as f64 * 0.2 - 0.2,
                );
                IntensityPoint {
                    point: p,
                    eta: field(&p) + 3.0,
                    normal: Vector3::zeros(),
                }
            })
            .collect();
        let input = AlignmentInput {
            edges: vec![],
            planes: vec![],
            intensity: points,
        };
        let config = SolverConfig {
            huber_intensity: 1e9,
            intensity_weight: 0.01,
            ..SolverConfig::default()
        };
        let cost = |pose: &Isometry3<f64>| {
            build(
                pose,
                &[],
                &input,
                &map,
                &config,
                &mut Vec::new(),
                IntensitySet::Select,
            )
        };
        assert_gradient_matches(cost, &pose, 1e-3);
    }

    /// Within a round, trials keep the residuals of the round's first system: a point moved out
    /// of the map's cover by a millimetre still counts, so the costs compared are sums over the
    /// same residuals.
    #[test]
    fn trials_keep_the_rounds_intensity_residuals() {
        // The weight crosses the map's 0.5 at x = 1.
        let map = crate::intensity_map::one_cell_map(40.0);
        let input = AlignmentInput {
            edges: vec![],
            planes: vec![],
            intensity: vec![IntensityPoint {
                point: Vector3::new(0.995, 0.5, 0.5),
                eta: 60.0,
                normal: Vector3::zeros(),
            }],
        };
        let config = SolverConfig::default();
        let moved = Isometry3::translation(0.01, 0.0, 0.0);
        let mut links = Vec::new();
        let at = |pose: &Isometry3<f64>, links: &mut Vec<IntensityLink>, set| {
            build(pose, &[], &input, &map, &config, links, set)
        };
        let start = at(&Isometry3::identity(), &mut links, IntensitySet::Select);
        assert_eq!(start.intensity, 1);
        let kept = at(&moved, &mut links, IntensitySet::Keep);
        assert_eq!(kept.intensity, 1, "the trial keeps the residual");
        assert!((kept.cost - start.cost).abs() < 1e-3 * start.cost);
        let selected = at(&moved, &mut links, IntensitySet::Select);
        assert_eq!(selected.intensity, 0, "a new round selects afresh");
        // And a point the round left out stays out.
        let kept = at(&Isometry3::identity(), &mut links, IntensitySet::Keep);
        assert_eq!(kept.intensity, 0);
    }

    /// `cost`'s gradient at `pose` equals central finite differences along each axis of the
    /// perturbation, to `tolerance` relative.
    fn assert_gradient_matches(
        cost: impl Fn(&Isometry3<f64>) -> System,
        pose: &Isometry3<f64>,
        tolerance: f64,
    ) {
        let system = cost(pose);
        for axis in 0..6 {
            let mut d = Vector6::zeros();
            d[axis] = 1e-6;
            let plus = cost(&(exp(&d) * pose)).cost;
            let minus = cost(&(exp(&-d) * pose)).cost;
            let fd = (plus - minus) / 2e-6;
            assert!(
                (fd - system.gradient[axis]).abs() < tolerance * (1.0 + fd.abs()),
                "axis {axis}: fd {fd} vs {}",
                system.gradient[axis]
            );
        }
    }

    /// Both geometric residuals' analytic gradients equal the finite-difference ones.
    #[test]
    fn geometric_gradient_matches_finite_differences() {
        let direction = Vector3::new(0.3, -0.5, 0.8).normalize();
        for shape in [Shape::Plane(direction), Shape::Line(direction)] {
            let model = Model {
                point: Vector3::new(1.0, 2.0, 0.5),
                center: Vector3::new(0.8, 2.5, 0.4),
                shape,
                weight: 0.37,
            };
            let map = IntensityMap::new(&IntensityMapConfig::default());
            let input = AlignmentInput::default();
            let config = SolverConfig {
                huber_geometric: 1e9,
                ..SolverConfig::default()
            };
            let cost = |pose: &Isometry3<f64>| {
                build(
                    pose,
                    &[model],
                    &input,
                    &map,
                    &config,
                    &mut Vec::new(),
                    IntensitySet::Select,
                )
            };
            let pose = exp(&Vector6::new(0.1, 0.2, -0.3, 0.5, 0.1, -0.2));
            assert_gradient_matches(cost, &pose, 1e-6);
        }
    }

    /// A wall seen head-on keeps its full weight whatever its range; ground seen at a grazing
    /// angle loses weight with range, as r·δ outgrows the range noise; a line is weighted by the
    /// same lever.
    #[test]
    fn residual_weights_follow_the_angular_lever() {
        let config = SolverConfig::default();
        let pose = exp(&Vector6::new(0.0, 0.0, 0.7, 1.0, -2.0, 0.3));
        let world = |v: Vector3<f64>| pose.rotation * v;
        let wall = Shape::Plane(world(Vector3::x()));
        let ground = Shape::Plane(world(Vector3::z()));
        let weight = |p: Vector3<f64>, shape: &Shape| residual_weight(&pose, &p, shape, &config);
        assert!((weight(Vector3::new(40.0, 0.0, 0.0), &wall) - 1.0).abs() < 1e-12);
        let near = weight(Vector3::new(3.0, 0.0, -0.9), &ground);
        let far = weight(Vector3::new(30.0, 0.0, -0.9), &ground);
        // σ² / (σ² + (30 m · δ)²) with σ = 2 cm, δ = 2 mrad: 0.1.
        assert!((far - 0.0004 / (0.0004 + 0.0036)).abs() < 1e-3, "{far}");
        assert!(near > 0.5 && near < 1.0, "{near}");
        let pole = Shape::Line(world(Vector3::z()));
        let w = weight(Vector3::new(30.0, 0.0, 0.0), &pole);
        assert!((w - far).abs() < 1e-3, "{w}");
        let flat = SolverConfig {
            angular_noise: 0.0,
            ..SolverConfig::default()
        };
        assert_eq!(
            residual_weight(&pose, &Vector3::new(30.0, 0.0, -0.9), &ground, &flat),
            1.0
        );
    }
}

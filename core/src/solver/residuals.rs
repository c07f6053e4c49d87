//! The residuals and their normal equations: point-to-line, point-to-plane and intensity rows,
//! Huber-weighted (IRLS), summed at a pose.

use super::*;

pub(super) struct System {
    pub(super) hessian: Matrix6<f64>,
    pub(super) gradient: Vector6<f64>,
    pub(super) cost: f64,
    pub(super) count: usize,
    pub(super) intensity: usize,
    /// Σ of the plane points' squared ranges from the sensor, and their count (for the
    /// balanced frame's RMS range).
    pub(super) squared_ranges: f64,
    pub(super) planes: usize,
}

/// Huber weight and cost of a residual of norm `r` with threshold `k`.
pub(super) fn huber(r: f64, k: f64) -> (f64, f64) {
    if r <= k {
        (1.0, 0.5 * r * r)
    } else {
        (k / r, k * (r - 0.5 * k))
    }
}

/// Normal equations (IRLS with Huber weights) at `pose`.
pub(super) fn build(
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

/// A plane residual at `q` and its Jacobian's row, both scaled by [`Model::scale`]:
/// ∂q/∂δ = [−[q]×, I], so ∂e/∂δ = nᵀ·[−[q]×, I] = [(q × n)ᵀ, nᵀ].
pub(super) fn plane_row(m: &Model, n: &Vector3<f64>, q: &Vector3<f64>) -> ([f64; 6], f64) {
    let scale = m.scale;
    let e = scale * n.dot(&(q - m.center));
    let arm = scale * q.cross(n);
    let n = scale * n;
    ([arm.x, arm.y, arm.z, n.x, n.y, n.z], e)
}

/// A line residual's projection: onto the line's normal space, scaled by [`Model::scale`].
pub(super) fn line_projection(m: &Model, d: &Vector3<f64>) -> Matrix3<f64> {
    m.scale * (Matrix3::identity() - d * d.transpose())
}

/// The rows of a line residual's Jacobian at `q`: ∂q/∂δ = [−[q]×, I], so ∂e/∂δ = P·[−[q]×, I],
/// one row per axis of the residual, and row i is [(q × Pᵢ)ᵀ, Pᵢᵀ] (P symmetric).
pub(super) fn line_rows(q: &Vector3<f64>, projection: &Matrix3<f64>) -> [[f64; 6]; 3] {
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
pub(super) struct RowSums {
    /// Row a's entries b ≥ a.
    pub(super) upper: [[f64; 6]; 6],
    pub(super) gradient: [f64; 6],
}

impl RowSums {
    #[inline(always)]
    pub(super) fn add(&mut self, w: f64, j: &[f64; 6], e: f64) {
        for (a, (row, g)) in self.upper.iter_mut().zip(&mut self.gradient).enumerate() {
            let wj = w * j[a];
            for (h, &jb) in row[a..].iter_mut().zip(&j[a..]) {
                *h += wj * jb;
            }
            *g += wj * e;
        }
    }

    pub(super) fn normal_equations(&self) -> (Matrix6<f64>, Vector6<f64>) {
        let hessian = Matrix6::from_fn(|r, c| self.upper[r.min(c)][r.max(c)]);
        (hessian, Vector6::from(self.gradient))
    }
}

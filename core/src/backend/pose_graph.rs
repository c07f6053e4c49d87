//! Step 9 of the method: the pose graph. Nodes are SE(3) poses (node → world), edges relative
//! pose measurements with information matrices, and the optimiser is sparse
//! Levenberg–Marquardt over a left perturbation `T ← exp(δ)·T`, with a Cauchy kernel on the
//! edges marked robust (loop closures), so one wrong loop bends the graph less than it would
//! as a plain square.
//!
//! The residual is g2o's for `EDGE_SE3:QUAT`, so costs compare with g2o's figures: for an edge
//! i → j with measurement Z, `Δ = Z⁻¹·Tᵢ⁻¹·Tⱼ` and `e = [t(Δ), q_xyz(Δ)]` (quaternion with
//! w ≥ 0), information ordered [translation, rotation] likewise. Since q_xyz ≈ θ/2, a rotation
//! standard deviation σ (rad) is an information of 4/σ². Jacobians come from central
//! differences: exact to ~1e-9 here and far shorter than the closed forms.

use nalgebra::{Isometry3, Matrix6, Vector6};
use thiserror::Error;

use super::sparse::Symbolic;
use crate::se3::exp;

/// One relative measurement between two nodes.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// The node the measurement is expressed in.
    pub from: usize,
    /// The node measured.
    pub to: usize,
    /// `from⁻¹·to` as measured.
    pub measurement: Isometry3<f64>,
    /// Information of `e` ([translation, quaternion xyz]), symmetric positive semi-definite.
    pub information: Matrix6<f64>,
    /// Whether the robust kernel applies (loop closures).
    pub robust: bool,
}

/// Nodes and edges.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseGraph {
    /// Node → world.
    pub poses: Vec<Isometry3<f64>>,
    /// Nodes held where they are (the gauge); if none is, the first node is.
    pub fixed: Vec<bool>,
    /// Measurements.
    pub edges: Vec<Edge>,
}

/// How the optimiser runs.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseGraphConfig {
    /// Levenberg–Marquardt iterations at most (accepted or not).
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub relative_tolerance: f64,
    /// Width of the Cauchy kernel on robust edges, in units of √χ²: an edge whose χ² is c²
    /// counts half as much as a square would. 3 keeps a correct loop (χ² of a few) at
    /// nearly full weight.
    pub cauchy_width: f64,
    /// Initial damping, as a fraction of the Hessian's own diagonal (Marquardt's scaling).
    pub initial_lambda: f64,
}

impl Default for PoseGraphConfig {
    fn default() -> Self {
        Self {
            max_iterations: 50,
            relative_tolerance: 1e-9,
            cauchy_width: 3.0,
            initial_lambda: 1e-4,
        }
    }
}

/// What an optimisation did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimizationReport {
    /// Σ eᵀΩe before (robust edges through their kernel).
    pub initial_cost: f64,
    /// The same after.
    pub final_cost: f64,
    /// Plain Σ eᵀΩe before, kernel or not (g2o's χ²).
    pub initial_chi2: f64,
    /// The same after.
    pub final_chi2: f64,
    /// Iterations taken (each one linear solve).
    pub iterations: usize,
    /// Steps that lowered the cost.
    pub accepted: usize,
    /// Blocks in the Cholesky factor, a measure of fill.
    pub factor_blocks: usize,
}

/// Why a graph cannot be optimised.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PoseGraphError {
    /// An edge names a node that does not exist.
    #[error("edge {edge} joins node {node}, but the graph has {nodes} nodes")]
    MissingNode {
        /// The edge's index.
        edge: usize,
        /// The node it names.
        node: usize,
        /// Nodes in the graph.
        nodes: usize,
    },
    /// A pose or measurement is not finite.
    #[error("edge {0} has a non-finite measurement or information")]
    NotFinite(usize),
    /// `fixed` and `poses` differ in length.
    #[error("{fixed} fixed flags for {poses} poses")]
    FixedLength {
        /// Flags.
        fixed: usize,
        /// Poses.
        poses: usize,
    },
}

/// Error vector of an edge at the given poses.
pub fn edge_error(edge: &Edge, from: &Isometry3<f64>, to: &Isometry3<f64>) -> Vector6<f64> {
    let delta = edge.measurement.inverse() * from.inverse() * to;
    let q = delta.rotation.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    let t = delta.translation.vector;
    Vector6::new(t.x, t.y, t.z, s * q.i, s * q.j, s * q.k)
}

/// Cost (kernelled if robust) and IRLS weight of an edge with χ² `s`.
fn kernel(robust: bool, s: f64, width: f64) -> (f64, f64) {
    if !robust {
        return (s, 1.0);
    }
    let c2 = width * width;
    (c2 * (s / c2).ln_1p(), 1.0 / (1.0 + s / c2))
}

impl PoseGraph {
    /// Adds a node; returns its index.
    pub fn add_node(&mut self, pose: Isometry3<f64>, fixed: bool) -> usize {
        self.poses.push(pose);
        self.fixed.push(fixed);
        self.poses.len() - 1
    }

    /// Checks indices and finiteness.
    pub fn validate(&self) -> Result<(), PoseGraphError> {
        if self.fixed.len() != self.poses.len() {
            return Err(PoseGraphError::FixedLength {
                fixed: self.fixed.len(),
                poses: self.poses.len(),
            });
        }
        for (k, e) in self.edges.iter().enumerate() {
            for node in [e.from, e.to] {
                if node >= self.poses.len() {
                    return Err(PoseGraphError::MissingNode {
                        edge: k,
                        node,
                        nodes: self.poses.len(),
                    });
                }
            }
            let finite = e.information.iter().all(|v| v.is_finite())
                && e.measurement
                    .translation
                    .vector
                    .iter()
                    .all(|v| v.is_finite())
                && e.measurement.rotation.coords.iter().all(|v| v.is_finite());
            if !finite {
                return Err(PoseGraphError::NotFinite(k));
            }
        }
        Ok(())
    }

    /// (kernelled cost, plain χ²) at the current poses.
    pub fn cost(&self, width: f64) -> (f64, f64) {
        self.cost_at(&self.poses, width)
    }

    fn cost_at(&self, poses: &[Isometry3<f64>], width: f64) -> (f64, f64) {
        self.cost_of(self.edges.iter(), poses, width)
    }

    fn cost_of<'a>(
        &self,
        edges: impl Iterator<Item = &'a Edge>,
        poses: &[Isometry3<f64>],
        width: f64,
    ) -> (f64, f64) {
        let mut cost = 0.0;
        let mut chi2 = 0.0;
        for e in edges {
            let r = edge_error(e, &poses[e.from], &poses[e.to]);
            let s = (r.transpose() * e.information * r)[0];
            chi2 += s;
            cost += kernel(e.robust, s, width).0;
        }
        (cost, chi2)
    }

    /// Optimises the poses in place.
    pub fn optimize(
        &mut self,
        config: &PoseGraphConfig,
    ) -> Result<OptimizationReport, PoseGraphError> {
        self.optimize_from(config, 0)
    }

    /// Optimises the poses from node `first_free` on in place, holding the older ones where
    /// they are as if fixed: the work depends on the nodes from `first_free` and the edges that
    /// reach them, not on the whole graph. The report's costs are the whole graph's.
    pub fn optimize_from(
        &mut self,
        config: &PoseGraphConfig,
        first_free: usize,
    ) -> Result<OptimizationReport, PoseGraphError> {
        self.validate()?;
        let n = self.poses.len();
        let mut fixed = self.fixed.clone();
        for f in fixed.iter_mut().take(first_free) {
            *f = true;
        }
        if n > 0 && !fixed.iter().any(|&f| f) {
            fixed[0] = true;
        }
        // Edges between two held nodes only add a constant to the cost.
        let active: Vec<&Edge> = self
            .edges
            .iter()
            .filter(|e| !fixed[e.from] || !fixed[e.to])
            .collect();
        // Free nodes are numbered 0..m for the linear system.
        let mut variable = vec![usize::MAX; n];
        let mut m = 0;
        for (v, f) in fixed.iter().enumerate() {
            if !f {
                variable[v] = m;
                m += 1;
            }
        }
        let symbolic = Symbolic::analyse(
            m,
            active.iter().filter_map(|e| {
                let (a, b) = (variable[e.from], variable[e.to]);
                (a != usize::MAX && b != usize::MAX).then_some((a, b))
            }),
        );
        let width = config.cauchy_width;
        let (initial_cost, initial_chi2) = self.cost(width);
        let mut cost = self.cost_of(active.iter().copied(), &self.poses, width).0;
        let mut report = OptimizationReport {
            initial_cost,
            final_cost: initial_cost,
            initial_chi2,
            final_chi2: initial_chi2,
            iterations: 0,
            accepted: 0,
            factor_blocks: symbolic.factor_blocks(),
        };
        if m == 0 || active.is_empty() {
            return Ok(report);
        }
        let mut lambda = config.initial_lambda;
        let mut system = self.linearise(&active, &symbolic, &variable, m, width);
        while report.iterations < config.max_iterations {
            report.iterations += 1;
            let (matrix, gradient, diagonal) = &system;
            let largest = diagonal
                .iter()
                .flat_map(|d| d.iter())
                .fold(0.0f64, |a, &b| a.max(b))
                .max(1e-12);
            let mut damped = matrix.clone();
            for (v, d) in diagonal.iter().enumerate() {
                // Marquardt's scaling, plus a floor so that directions without information
                // still get a bounded step.
                let block = Matrix6::from_diagonal(&(d * lambda))
                    + Matrix6::identity() * (lambda * 1e-6 * largest);
                symbolic.add(&mut damped, v, v, &block);
            }
            let rhs: Vec<Vector6<f64>> = gradient.iter().map(|g| -g).collect();
            let Some(step) = symbolic.solve(&mut damped, &rhs) else {
                lambda *= 10.0;
                continue;
            };
            let candidate: Vec<Isometry3<f64>> = self
                .poses
                .iter()
                .enumerate()
                .map(|(v, p)| match variable[v] {
                    usize::MAX => *p,
                    k => exp(&step[k]) * p,
                })
                .collect();
            let (trial, _) = self.cost_of(active.iter().copied(), &candidate, width);
            if trial.is_finite() && trial < cost {
                let decrease = (cost - trial) / cost.max(1e-300);
                self.poses = candidate;
                cost = trial;
                report.accepted += 1;
                lambda = (lambda / 3.0).max(1e-12);
                if decrease < config.relative_tolerance {
                    break;
                }
                system = self.linearise(&active, &symbolic, &variable, m, width);
            } else {
                lambda *= 4.0;
                if lambda > 1e12 {
                    break;
                }
            }
        }
        let (final_cost, final_chi2) = self.cost(width);
        report.final_cost = final_cost;
        report.final_chi2 = final_chi2;
        Ok(report)
    }

    /// Normal equations at the current poses: matrix, gradient and the Hessian's diagonal per
    /// free node.
    fn linearise(
        &self,
        edges: &[&Edge],
        symbolic: &Symbolic,
        variable: &[usize],
        m: usize,
        width: f64,
    ) -> (
        super::sparse::BlockMatrix,
        Vec<Vector6<f64>>,
        Vec<Vector6<f64>>,
    ) {
        let mut matrix = symbolic.matrix();
        let mut gradient = vec![Vector6::zeros(); m];
        let mut diagonal = vec![Vector6::zeros(); m];
        const H: f64 = 1e-6;
        for e in edges {
            let (a, b) = (&self.poses[e.from], &self.poses[e.to]);
            let r = edge_error(e, a, b);
            let s = (r.transpose() * e.information * r)[0];
            let (_, w) = kernel(e.robust, s, width);
            let mut ja = Matrix6::zeros();
            let mut jb = Matrix6::zeros();
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = H;
                let (plus, minus) = (exp(&d), exp(&-d));
                let col_a =
                    (edge_error(e, &(plus * a), b) - edge_error(e, &(minus * a), b)) / (2.0 * H);
                let col_b =
                    (edge_error(e, a, &(plus * b)) - edge_error(e, a, &(minus * b))) / (2.0 * H);
                ja.set_column(k, &col_a);
                jb.set_column(k, &col_b);
            }
            let omega = e.information * w;
            let (va, vb) = (variable[e.from], variable[e.to]);
            if va != usize::MAX {
                let h = ja.transpose() * omega * ja;
                symbolic.add(&mut matrix, va, va, &h);
                diagonal[va] += h.diagonal();
                gradient[va] += ja.transpose() * omega * r;
            }
            if vb != usize::MAX {
                let h = jb.transpose() * omega * jb;
                symbolic.add(&mut matrix, vb, vb, &h);
                diagonal[vb] += h.diagonal();
                gradient[vb] += jb.transpose() * omega * r;
            }
            if va != usize::MAX && vb != usize::MAX && va != vb {
                symbolic.add(&mut matrix, va, vb, &(ja.transpose() * omega * jb));
            }
        }
        (matrix, gradient, diagonal)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se3::log;
    use nalgebra::Vector3;

    fn info(sigma_t: f64, sigma_r: f64) -> Matrix6<f64> {
        let t = 1.0 / (sigma_t * sigma_t);
        let r = 4.0 / (sigma_r * sigma_r);
        Matrix6::from_diagonal(&Vector6::new(t, t, t, r, r, r))
    }

    fn edge(graph: &PoseGraph, from: usize, to: usize, truth: &[Isometry3<f64>]) -> Edge {
        let _ = graph;
        Edge {
            from,
            to,
            measurement: truth[from].inverse() * truth[to],
            information: info(0.05, 0.01),
            robust: false,
        }
    }

    /// A square of 1 m sides driven twice, with a yaw error on every odometry edge.
    fn square(laps: usize) -> (PoseGraph, Vec<Isometry3<f64>>) {
        let mut truth = Vec::new();
        for k in 0..(8 * laps + 1) {
            let side = (k / 2) % 4;
            let along = (k % 2) as f64 * 0.5;
            let yaw = side as f64 * std::f64::consts::FRAC_PI_2;
            let corner = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)][side];
            let dir = Vector3::new(yaw.cos(), yaw.sin(), 0.0);
            let p = Vector3::new(corner.0, corner.1, 0.0) + dir * along;
            truth.push(Isometry3::new(p, Vector3::z() * yaw));
        }
        let mut graph = PoseGraph::default();
        // Odometry with a 0.5° yaw error per step (about the 1σ of its information), chained
        // into the initial guess.
        let bias = Isometry3::rotation(Vector3::z() * 0.5f64.to_radians());
        let mut pose = truth[0];
        for k in 0..truth.len() {
            if k > 0 {
                pose = pose * truth[k - 1].inverse() * truth[k] * bias;
            }
            graph.add_node(pose, k == 0);
        }
        for k in 1..truth.len() {
            let mut e = edge(&graph, k - 1, k, &truth);
            e.measurement *= bias;
            graph.edges.push(e);
        }
        (graph, truth)
    }

    #[test]
    fn a_consistent_graph_is_solved_exactly() {
        let (mut graph, truth) = square(2);
        // Replace the biased odometry by exact measurements: the optimum has zero cost, and
        // the solver must find it from the drifted start.
        for e in &mut graph.edges {
            e.measurement = truth[e.from].inverse() * truth[e.to];
        }
        let report = graph.optimize(&PoseGraphConfig::default()).expect("valid");
        assert!(report.initial_chi2 > 1.0, "{report:?}");
        assert!(report.final_chi2 < 1e-12, "{report:?}");
        for (p, t) in graph.poses.iter().zip(&truth) {
            assert!(log(&(p.inverse() * t)).norm() < 1e-6);
        }
    }

    #[test]
    fn a_window_holds_the_older_nodes_and_still_closes_the_loop() {
        let (mut graph, truth) = square(2);
        let last = truth.len() - 1;
        graph.edges.push(Edge {
            robust: true,
            ..edge(&graph, 4, last, &truth)
        });
        let held: Vec<_> = graph.poses[..8].to_vec();
        let before = (graph.poses[last].translation.vector - truth[last].translation.vector).norm();
        let whole = graph
            .clone()
            .optimize(&PoseGraphConfig::default())
            .expect("valid");
        let report = graph
            .optimize_from(&PoseGraphConfig::default(), 8)
            .expect("valid");
        assert_eq!(&graph.poses[..8], &held[..], "held nodes moved");
        let after = (graph.poses[last].translation.vector - truth[last].translation.vector).norm();
        assert!(after < 0.5 * before, "{before} → {after}");
        assert!(report.final_cost < report.initial_cost, "{report:?}");
        // Fewer nodes free: a smaller factor, a cost no lower than the whole graph's optimum.
        assert!(
            report.factor_blocks < whole.factor_blocks,
            "{report:?} vs {whole:?}"
        );
        assert!(report.final_cost >= whole.final_cost * (1.0 - 1e-9));
    }

    #[test]
    fn a_loop_closure_pulls_the_drifted_lap_back() {
        let (mut graph, truth) = square(2);
        let last = truth.len() - 1;
        // The second lap ends where the first began; so does node 8.
        for (from, to) in [(0, last), (0, 8), (4, 12)] {
            graph.edges.push(Edge {
                robust: true,
                ..edge(&graph, from, to, &truth)
            });
        }
        let before = (graph.poses[last].translation.vector - truth[last].translation.vector).norm();
        let report = graph.optimize(&PoseGraphConfig::default()).expect("valid");
        let after = (graph.poses[last].translation.vector - truth[last].translation.vector).norm();
        assert!(before > 0.05, "{before}");
        assert!(after < 0.2 * before, "{before} → {after}, {report:?}");
        // What remains is the odometry's own bias, spread over its 16 edges: each 0.5° off,
        // χ² = 4/0.01² · sin²(0.25°) ≈ 0.76.
        assert!(report.final_chi2 < 16.0 * 0.76 * 1.1, "{report:?}");
    }

    #[test]
    fn the_kernel_limits_a_wrong_loop() {
        let (mut graph, truth) = square(1);
        for e in &mut graph.edges {
            e.measurement = truth[e.from].inverse() * truth[e.to];
        }
        graph.poses.clone_from(&truth);
        // A loop claiming nodes 2 and 6 coincide (they are 1 m apart).
        let wrong = Edge {
            from: 2,
            to: 6,
            measurement: Isometry3::identity(),
            information: info(0.05, 0.01),
            robust: true,
        };
        let mut plain = graph.clone();
        plain.edges.push(Edge {
            robust: false,
            ..wrong.clone()
        });
        graph.edges.push(wrong);
        graph.optimize(&PoseGraphConfig::default()).expect("valid");
        plain.optimize(&PoseGraphConfig::default()).expect("valid");
        let moved = |g: &PoseGraph| {
            g.poses
                .iter()
                .zip(&truth)
                .map(|(p, t)| (p.translation.vector - t.translation.vector).norm())
                .fold(0.0, f64::max)
        };
        assert!(
            moved(&graph) < 0.5 * moved(&plain),
            "robust {} vs plain {}",
            moved(&graph),
            moved(&plain)
        );
    }

    #[test]
    fn bad_indices_are_errors() {
        let mut graph = PoseGraph::default();
        graph.add_node(Isometry3::identity(), true);
        graph.edges.push(Edge {
            from: 0,
            to: 3,
            measurement: Isometry3::identity(),
            information: Matrix6::identity(),
            robust: false,
        });
        assert!(matches!(
            graph.optimize(&PoseGraphConfig::default()),
            Err(PoseGraphError::MissingNode { node: 3, .. })
        ));
    }
}

//! The back end of the method, steps 6–9: keyframes, Intensity Scan Context place recognition,
//! geometric verification of loop candidates, and the pose graph, driven one keyframe at a
//! time by [`BackEnd`]. Pure and deterministic like the rest of `core`: no threads, no clocks;
//! the caller runs it on its own thread and times its stages through a hook.
//!
//! Frames: the odometry publishes sensor → `odom` poses, smooth and drifting. The back end
//! keeps every keyframe's sensor → `map` pose in the graph and exposes the correction
//! `map ← odom` of the newest keyframe, so a published map pose is `correction · odom pose`: it
//! jumps once when a loop is accepted, while the odom pose never does.

pub mod config;
pub mod g2o;
pub mod keyframe;
pub mod loop_closure;
pub mod pose_graph;
pub mod scan_context;
mod sparse;

use nalgebra::{Isometry3, Matrix6, Vector6};

use crate::trajectory::StampedPose;
use config::BackEndConfig;
use keyframe::Keyframe;
use loop_closure::{search, verify, Candidate, Placed, Verification};
use pose_graph::{Edge, OptimizationReport, PoseGraph};
use scan_context::ScanContext;

/// Stages of [`BackEnd::add_keyframe`], reported to the caller's hook as each one ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BackEndStage {
    /// The keyframe's descriptor and its node in the graph.
    Descriptor,
    /// The candidate search.
    Search,
    /// The verification of one candidate (reported once per candidate).
    Verify,
    /// The optimisation after an accepted loop.
    Optimize,
}

/// An accepted loop.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopClosure {
    /// The new keyframe's index.
    pub query: usize,
    /// The earlier keyframe it closes on.
    pub candidate: usize,
    /// ISC similarity.
    pub similarity: f64,
    /// The ISC yaw guess, rad.
    pub yaw_guess: f64,
    /// The verification's result (query → candidate and its scores).
    pub verification: Verification,
}

/// What one keyframe did in the back end.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeOutcome {
    /// The keyframe's index.
    pub index: usize,
    /// Candidates above the similarity threshold (loops found).
    pub candidates: Vec<Candidate>,
    /// Verifications run, in order, with their results.
    pub verifications: Vec<Verification>,
    /// The loop accepted, if any.
    pub accepted: Option<LoopClosure>,
    /// The optimisation it triggered.
    pub optimization: Option<OptimizationReport>,
}

/// Counts over the run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BackEndStats {
    /// Keyframes added.
    pub keyframes: usize,
    /// Candidates found above the ISC threshold.
    pub loops_found: usize,
    /// Candidates verified.
    pub verified: usize,
    /// Verified and accepted.
    pub accepted: usize,
    /// Verified and rejected.
    pub rejected: usize,
}

/// Steps 7–9 over a growing set of keyframes. See the module docs.
#[derive(Debug, Clone)]
pub struct BackEnd {
    config: BackEndConfig,
    keyframes: Vec<Keyframe>,
    descriptors: Vec<ScanContext>,
    /// Odometry path length at each keyframe, m.
    path: Vec<f64>,
    graph: PoseGraph,
    correction: Isometry3<f64>,
    loops: Vec<LoopClosure>,
    stats: BackEndStats,
    /// The first keyframe index allowed to search (cool-down).
    next_search: usize,
}

fn information(sigma_translation: f64, sigma_rotation: f64) -> Matrix6<f64> {
    let t = 1.0 / (sigma_translation * sigma_translation);
    // The residual's rotation part is a quaternion's vector part, ≈ θ/2.
    let r = 4.0 / (sigma_rotation * sigma_rotation);
    Matrix6::from_diagonal(&Vector6::new(t, t, t, r, r, r))
}

impl BackEnd {
    /// An empty back end.
    pub fn new(config: &BackEndConfig) -> Self {
        Self {
            config: config.clone(),
            keyframes: Vec::new(),
            descriptors: Vec::new(),
            path: Vec::new(),
            graph: PoseGraph::default(),
            correction: Isometry3::identity(),
            loops: Vec::new(),
            stats: BackEndStats::default(),
            next_search: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &BackEndConfig {
        &self.config
    }

    /// `map ← odom`: a map pose is `correction() * odom pose`. Changes only when a loop is
    /// accepted.
    pub fn correction(&self) -> Isometry3<f64> {
        self.correction
    }

    /// Keyframes so far.
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes
    }

    /// Each keyframe's sensor → map pose after the last optimisation.
    pub fn keyframe_poses(&self) -> &[Isometry3<f64>] {
        &self.graph.poses
    }

    /// The accepted loops.
    pub fn loops(&self) -> &[LoopClosure] {
        &self.loops
    }

    /// Counts so far.
    pub fn stats(&self) -> BackEndStats {
        self.stats
    }

    /// The pose graph (keyframe nodes, odometry and loop edges), e.g. to write as g2o.
    pub fn graph(&self) -> &PoseGraph {
        &self.graph
    }

    /// Adds a keyframe: its descriptor, a node and an odometry edge, the candidate search, the
    /// verification of the best candidates and, when one is accepted, a loop edge and an
    /// optimisation, after which [`Self::correction`] jumps. `on_stage` is called as each stage
    /// ends (for timing). The same keyframes in the same order give bit-identical results.
    pub fn add_keyframe(
        &mut self,
        keyframe: Keyframe,
        mut on_stage: impl FnMut(BackEndStage),
    ) -> KeyframeOutcome {
        let index = self.keyframes.len();
        let descriptor = ScanContext::new(
            keyframe.cloud.iter().map(|c| (c.position.into(), c.eta)),
            &self.config.scan_context,
        );
        let node = self.correction * keyframe.odom_pose;
        let first = self.graph.poses.is_empty();
        self.graph.add_node(node, first);
        let path = match self.keyframes.last() {
            Some(previous) => {
                let measurement = previous.odom_pose.inverse() * keyframe.odom_pose;
                let length = measurement.translation.vector.norm();
                let g = &self.config.graph;
                self.graph.edges.push(Edge {
                    from: index - 1,
                    to: index,
                    measurement,
                    information: information(
                        g.odometry_sigma_translation + g.odometry_sigma_per_metre * length,
                        g.odometry_sigma_rotation,
                    ),
                    robust: false,
                });
                self.path[index - 1] + length
            }
            None => 0.0,
        };
        self.path.push(path);
        self.keyframes.push(keyframe);
        self.descriptors.push(descriptor);
        self.stats.keyframes += 1;
        on_stage(BackEndStage::Descriptor);

        let sc = &self.config.scan_context;
        let here = self.graph.poses[index].translation.vector;
        if index < self.next_search {
            on_stage(BackEndStage::Search);
            return KeyframeOutcome {
                index,
                candidates: Vec::new(),
                verifications: Vec::new(),
                accepted: None,
                optimization: None,
            };
        }
        let candidates = search(
            &self.descriptors[index],
            &self.descriptors[..index],
            |j| {
                let travelled = path - self.path[j];
                travelled >= sc.exclude_recent_distance
                    && (self.graph.poses[j].translation.vector - here).norm()
                        <= sc.search_radius + sc.search_drift_fraction * travelled
            },
            sc,
        );
        self.stats.loops_found += candidates.len();
        on_stage(BackEndStage::Search);

        let mut verifications = Vec::new();
        let mut accepted = None;
        for c in candidates
            .iter()
            .take(self.config.scan_context.max_verifications)
        {
            let v = self.verify_candidate(index, c);
            on_stage(BackEndStage::Verify);
            self.stats.verified += 1;
            if v.accepted {
                self.stats.accepted += 1;
                accepted = Some(LoopClosure {
                    query: index,
                    candidate: c.index,
                    similarity: c.similarity,
                    yaw_guess: c.yaw,
                    verification: v.clone(),
                });
                verifications.push(v);
                break;
            }
            self.stats.rejected += 1;
            verifications.push(v);
        }
        let sc = &self.config.scan_context;
        if accepted.is_some() {
            self.next_search = index + 1 + sc.cooldown_after_accept;
        } else if !verifications.is_empty() {
            self.next_search = index + 1 + sc.cooldown_after_reject;
        }

        let mut optimization = None;
        if let Some(closure) = &accepted {
            let g = &self.config.graph;
            self.graph.edges.push(Edge {
                from: closure.candidate,
                to: index,
                measurement: closure.verification.relative,
                information: information(g.loop_sigma_translation, g.loop_sigma_rotation),
                robust: true,
            });
            // The graph is valid by construction (indices from our own counts, finite poses).
            if let Ok(report) = self.graph.optimize(&g.optimizer) {
                optimization = Some(report);
            }
            self.correction = self.graph.poses[index] * self.keyframes[index].odom_pose.inverse();
            self.loops.push(closure.clone());
            on_stage(BackEndStage::Optimize);
        }
        KeyframeOutcome {
            index,
            candidates,
            verifications,
            accepted,
            optimization,
        }
    }

    /// Verifies candidate `c` for keyframe `index` against a submap of the candidate and its
    /// neighbours placed with their current graph poses, from two starts: the ISC yaw with no
    /// translation (the descriptor's guess, all it knows), and the graph's own relative pose.
    fn verify_candidate(&self, index: usize, c: &Candidate) -> Verification {
        let k = self.config.verification.submap_neighbours;
        let anchor = self.graph.poses[c.index].inverse();
        let last = index.saturating_sub(1);
        let submap: Vec<Placed<'_>> = (c.index.saturating_sub(k)..=(c.index + k).min(last))
            .filter(|&j| {
                self.path[index] - self.path[j] >= self.config.scan_context.exclude_recent_distance
            })
            .map(|j| Placed {
                pose: anchor * self.graph.poses[j],
                keyframe: &self.keyframes[j],
            })
            .collect();
        let yaw_guess = Isometry3::rotation(nalgebra::Vector3::z() * c.yaw);
        let graph_guess = anchor * self.graph.poses[index];
        let mut v = verify(
            &self.keyframes[index],
            &submap,
            &[yaw_guess, graph_guess],
            &self.config.verification,
        );
        let disagreement = (graph_guess.rotation.inverse() * v.relative.rotation).angle();
        if disagreement > self.config.verification.max_rotation_disagreement {
            v.accepted = false;
        }
        v
    }

    /// The final trajectory: each sweep's odometry pose corrected through the latest keyframe
    /// at or before it (the first keyframe for sweeps before it), with the keyframes' poses of
    /// the last optimisation. `sweeps` are (time, sensor → odom) in any order; the output
    /// follows it.
    pub fn trajectory(&self, sweeps: &[StampedPose]) -> Vec<StampedPose> {
        sweeps
            .iter()
            .map(|s| {
                let k = self
                    .keyframes
                    .partition_point(|kf| kf.time_ns <= s.time_ns)
                    .saturating_sub(1);
                let pose = match self.keyframes.get(k) {
                    Some(kf) => self.graph.poses[k] * kf.odom_pose.inverse() * s.pose,
                    None => s.pose,
                };
                StampedPose {
                    time_ns: s.time_ns,
                    pose,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn keyframe(k: usize) -> Keyframe {
        Keyframe {
            time_ns: 1_000_000_000 * (k as u64 + 1),
            odom_pose: Isometry3::new(
                Vector3::new(k as f64, 0.0, 0.0),
                Vector3::z() * 0.01 * k as f64,
            ),
            edges: Vec::new(),
            planes: Vec::new(),
            cloud: Vec::new(),
        }
    }

    #[test]
    fn without_loops_the_map_is_the_odometry() {
        let mut backend = BackEnd::new(&BackEndConfig::default());
        let mut stages = Vec::new();
        for k in 0..30 {
            let outcome = backend.add_keyframe(keyframe(k), |s| stages.push(s));
            assert_eq!(outcome.index, k);
            assert!(outcome.accepted.is_none());
        }
        assert_eq!(backend.correction(), Isometry3::identity());
        assert_eq!(backend.stats().keyframes, 30);
        assert_eq!(backend.graph().edges.len(), 29);
        assert_eq!(stages.len(), 60, "descriptor and search per keyframe");
        // A sweep between keyframes 4 and 5 is corrected through keyframe 4: unchanged here.
        let sweep = StampedPose {
            time_ns: 5_500_000_000,
            pose: Isometry3::new(Vector3::new(4.5, 0.1, 0.0), Vector3::zeros()),
        };
        let out = backend.trajectory(&[sweep]);
        assert_eq!(out[0].time_ns, sweep.time_ns);
        assert!((out[0].pose.translation.vector - sweep.pose.translation.vector).norm() < 1e-12);
    }
}

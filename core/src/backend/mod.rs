//! The back end of the method, steps 6–9: keyframes, Intensity Scan Context place recognition,
//! geometric verification of loop candidates, and the pose graph, driven one keyframe at a
//! time by [`BackEnd`]. Pure and deterministic like the rest of `core`: no threads, no clocks;
//! the caller runs it on its own thread and times its stages through a hook.
//!
//! Frames: the odometry publishes sensor → `odom` poses, smooth and drifting. The back end
//! keeps every keyframe's sensor → `map` pose in the graph and exposes the correction
//! `map ← odom` of the newest keyframe, so a published map pose is `correction · odom pose`: it
//! jumps once when a loop is accepted (and in small steps as keyframes are tied
//! to the floor), while the odom pose never does.

pub mod config;
pub mod floor;
pub mod g2o;
pub mod keyframe;
pub mod loop_closure;
pub mod pose_graph;
pub mod scan_context;
mod sparse;

use nalgebra::{Isometry3, Matrix6, Vector3, Vector6};

use crate::trajectory::StampedPose;
use config::BackEndConfig;
use floor::Plane;
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
    /// Keyframes that released their points as redundant (see
    /// [`config::KeyframeConfig::redundant_within`]).
    pub released: usize,
    /// Keyframes tied to the floor (see [`floor`]).
    pub on_floor: usize,
}

/// What a site map records of the run that made it (see [`BackEnd::site_map`]).
#[derive(Debug, Clone)]
pub struct SiteMapHeader {
    /// When, ns since the Unix epoch.
    pub created_ns: u64,
    /// The sensor, e.g. "VLP-16".
    pub sensor_model: String,
    /// The mapping robot's mounting, `base_link` ← sensor.
    pub base_from_sensor: Isometry3<f64>,
}

/// Steps 7–9 over a growing set of keyframes. See the module docs.
#[derive(Debug, Clone)]
pub struct BackEnd {
    config: BackEndConfig,
    keyframes: Vec<Keyframe>,
    /// Per keyframe: it still holds its points (see [`Self::release_if_redundant`]).
    held: Vec<bool>,
    descriptors: Vec<ScanContext>,
    /// Odometry path length at each keyframe, m.
    path: Vec<f64>,
    graph: PoseGraph,
    correction: Isometry3<f64>,
    loops: Vec<LoopClosure>,
    stats: BackEndStats,
    /// The first keyframe index allowed to search (cool-down).
    next_search: usize,
    /// The run's floor in the map frame, once a keyframe has seen it.
    floor: Option<Plane>,
    /// Floor edges added since the last optimisation.
    floor_edges_pending: usize,
}

/// The information matrix of an edge with these standard deviations (m, rad).
pub(crate) fn information(sigma_translation: f64, sigma_rotation: f64) -> Matrix6<f64> {
    let t = 1.0 / (sigma_translation * sigma_translation);
    // The residual's rotation part is a quaternion's vector part, ≈ θ/2.
    let r = 4.0 / (sigma_rotation * sigma_rotation);
    Matrix6::from_diagonal(&Vector6::new(t, t, t, r, r, r))
}

/// An odometry edge `from → to`: its uncertainty grows with the distance it spans.
pub(crate) fn odometry_edge(
    g: &config::GraphConfig,
    from: usize,
    to: usize,
    measurement: Isometry3<f64>,
) -> Edge {
    let length = measurement.translation.vector.norm();
    Edge {
        from,
        to,
        measurement,
        information: information(
            g.odometry_sigma_translation + g.odometry_sigma_per_metre * length,
            g.odometry_sigma_rotation,
        ),
        robust: false,
    }
}

impl BackEnd {
    /// An empty back end.
    pub fn new(config: &BackEndConfig) -> Self {
        Self {
            config: config.clone(),
            keyframes: Vec::new(),
            held: Vec::new(),
            descriptors: Vec::new(),
            path: Vec::new(),
            graph: PoseGraph::default(),
            correction: Isometry3::identity(),
            loops: Vec::new(),
            stats: BackEndStats::default(),
            next_search: 0,
            floor: None,
            floor_edges_pending: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &BackEndConfig {
        &self.config
    }

    /// `map ← odom`: a map pose is `correction() * odom pose`. Changes only when the graph is
    /// optimised: after an accepted loop, and in small steps as keyframes are tied to the floor.
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

    /// Adds a keyframe: its descriptor, a node, an odometry edge and, if it sees the floor, a
    /// floor edge; the candidate search, the verification of the best candidates and, when one
    /// is accepted, a loop edge and an optimisation, after which [`Self::correction`] jumps (the
    /// graph is also optimised after every `floor.optimize_every` floor edges); then, if it is
    /// redundant, the keyframe releases its points. `on_stage` is called as each stage ends
    /// (for timing). The same keyframes in the same order give bit-identical results.
    pub fn add_keyframe(
        &mut self,
        keyframe: Keyframe,
        on_stage: impl FnMut(BackEndStage),
    ) -> KeyframeOutcome {
        let outcome = self.close_loops(keyframe, on_stage);
        self.release_if_redundant(outcome.index);
        outcome
    }

    /// [`Self::add_keyframe`] up to the release of redundant points.
    fn close_loops(
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
                let edge = odometry_edge(&self.config.graph, index - 1, index, measurement);
                self.graph.edges.push(edge);
                self.path[index - 1] + measurement.translation.vector.norm()
            }
            None => 0.0,
        };
        self.path.push(path);
        self.keyframes.push(keyframe);
        self.held.push(true);
        self.descriptors.push(descriptor);
        self.stats.keyframes += 1;
        self.tie_to_floor(index);
        on_stage(BackEndStage::Descriptor);

        let sc = &self.config.scan_context;
        if index < self.next_search {
            on_stage(BackEndStage::Search);
            let optimization = self.optimize_if_due(index, false, &mut on_stage);
            return KeyframeOutcome {
                index,
                candidates: Vec::new(),
                verifications: Vec::new(),
                accepted: None,
                optimization,
            };
        }
        let candidates = search(
            &self.descriptors[index],
            &self.descriptors[..index],
            |j| {
                self.earlier_place(index, j, |travelled| {
                    sc.search_radius + sc.search_drift_fraction * travelled
                })
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

        if let Some(closure) = &accepted {
            let g = &self.config.graph;
            self.graph.edges.push(Edge {
                from: closure.candidate,
                to: index,
                measurement: closure.verification.relative,
                information: information(g.loop_sigma_translation, g.loop_sigma_rotation),
                robust: true,
            });
            self.loops.push(closure.clone());
        }
        let optimization = self.optimize_if_due(index, accepted.is_some(), &mut on_stage);
        KeyframeOutcome {
            index,
            candidates,
            verifications,
            accepted,
            optimization,
        }
    }

    /// Measures the floor in keyframe `index` and, if it is the run's floor, ties the keyframe's
    /// node to it with an edge from the fixed first node. The first floor seen defines the
    /// run's: later ones are searched for where the graph expects it.
    fn tie_to_floor(&mut self, index: usize) {
        let config = &self.config.floor;
        if !config.enabled {
            return;
        }
        let pose = self.graph.poses[index];
        let expected = self.floor.map(|f| f.transformed(&pose.inverse()));
        let keyframe = &self.keyframes[index];
        let points = keyframe
            .planes
            .iter()
            .map(|p| Vector3::from(*p).cast::<f64>());
        let Some(seen) = floor::measure(points, expected.as_ref(), config) else {
            return;
        };
        let world = *self
            .floor
            .get_or_insert_with(|| seen.plane.transformed(&pose));
        self.stats.on_floor += 1;
        if index > 0 {
            let edge = seen.edge(&world, 0, &self.graph.poses[0], index, &pose, config);
            self.graph.edges.push(edge);
            self.floor_edges_pending += 1;
        }
    }

    /// Optimises the graph if a loop was just closed or enough floor edges wait, and moves
    /// [`Self::correction`] to the newest keyframe's optimised pose.
    fn optimize_if_due(
        &mut self,
        index: usize,
        loop_closed: bool,
        on_stage: &mut impl FnMut(BackEndStage),
    ) -> Option<OptimizationReport> {
        let due = loop_closed
            || (self.floor_edges_pending > 0
                && self.floor_edges_pending >= self.config.floor.optimize_every);
        if !due {
            return None;
        }
        let window = self.config.graph.optimize_window;
        let first_free = if window == 0 {
            0
        } else {
            (index + 1).saturating_sub(window)
        };
        let report = self.optimize(index, first_free);
        on_stage(BackEndStage::Optimize);
        report
    }

    /// Optimises the graph from keyframe `first_free` on and moves [`Self::correction`] to
    /// keyframe `index`'s new pose.
    fn optimize(&mut self, index: usize, first_free: usize) -> Option<OptimizationReport> {
        self.floor_edges_pending = 0;
        // The graph is valid by construction (indices from our own counts, finite poses).
        let report = self
            .graph
            .optimize_from(&self.config.graph.optimizer, first_free)
            .ok();
        self.correction = self.graph.poses[index] * self.keyframes[index].odom_pose.inverse();
        report
    }

    /// At the end of a run: optimises the whole graph once more if floor edges added since the
    /// last optimisation wait or the window held older keyframes back, so
    /// [`Self::trajectory`] has every edge's say.
    pub fn finish(&mut self) -> Option<OptimizationReport> {
        let window = self.config.graph.optimize_window;
        let held_back = window > 0 && self.keyframes.len() > window;
        if (self.floor_edges_pending == 0 && !held_back) || self.keyframes.is_empty() {
            return None;
        }
        self.optimize(self.keyframes.len() - 1, 0)
    }

    /// Whether keyframe `j` is an earlier visit of keyframe `index`'s place: it holds its points,
    /// lies farther back along the path than the loop search's recent stretch, and within
    /// `radius(path travelled since)` of it at the graph's current poses.
    fn earlier_place(&self, index: usize, j: usize, radius: impl Fn(f64) -> f64) -> bool {
        let travelled = self.path[index] - self.path[j];
        self.held[j]
            && travelled >= self.config.scan_context.exclude_recent_distance
            && (self.graph.poses[j].translation.vector - self.graph.poses[index].translation.vector)
                .norm()
                <= radius(travelled)
    }

    /// Releases the points of keyframe `index` (the newest, processed) if an earlier keyframe
    /// that holds its own lies within [`config::KeyframeConfig::redundant_within`] at the graph's
    /// current poses, farther back along the path than the loop search looks (the keyframes
    /// just behind are always this close). The earlier one is kept rather than the newer: it
    /// is the one loops have already tied into the graph, and it keeps the place's loop
    /// candidates and submaps where later passes will look for them.
    fn release_if_redundant(&mut self, index: usize) {
        let within = self.config.keyframes.redundant_within;
        if within <= 0.0 {
            return;
        }
        if (0..index).any(|j| self.earlier_place(index, j, |_| within)) {
            let keyframe = &mut self.keyframes[index];
            keyframe.edges = Vec::new();
            keyframe.planes = Vec::new();
            keyframe.cloud = Vec::new();
            self.held[index] = false;
            self.stats.released += 1;
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

    /// The site map's frame from the run's world (the first sensor pose's frame): the mapping
    /// robot's first `base_link` pose (`base_from_sensor` is its mounting), levelled so that its
    /// z axis is the floor's normal when the run saw a floor. A map anchored to one sweep's
    /// attitude would carry that sweep's tilt (vibration, a bump) to every robot localising
    /// in it: 1° is 17 cm of height 10 m away.
    pub fn site_from_world(&self, base_from_sensor: &Isometry3<f64>) -> Isometry3<f64> {
        let Some(floor) = self.floor else {
            return *base_from_sensor;
        };
        let up = base_from_sensor.rotation * floor.normal;
        let up = if up.z < 0.0 { -up } else { up };
        let level = nalgebra::UnitQuaternion::rotation_between(&up, &Vector3::z())
            .unwrap_or_else(nalgebra::UnitQuaternion::identity);
        Isometry3::from_parts(nalgebra::Translation3::identity(), level) * base_from_sensor
    }

    /// The run as a site map ([`crate::site_map`]): every keyframe at its optimised pose
    /// turned into the site's frame by `site_from_world` (the mapping robot's mounting, so the
    /// map frame is its first `base_link` pose), with its descriptor, the intensity map rebuilt
    /// from the held keyframes' returns at those poses, and the graph's edges (relative
    /// measurements, the same in any frame).
    pub fn site_map(
        &self,
        site_from_world: &Isometry3<f64>,
        intensity: &crate::config::IntensityMapConfig,
        header: SiteMapHeader,
    ) -> crate::site_map::SiteMap {
        let mut map = crate::intensity_map::IntensityMap::new(intensity);
        let keyframes = self
            .keyframes
            .iter()
            .zip(&self.graph.poses)
            .zip(&self.descriptors)
            .map(|((keyframe, pose), descriptor)| {
                let pose = site_from_world * pose;
                let placed = pose.cast::<f32>();
                for c in &keyframe.cloud {
                    let p = placed * nalgebra::Point3::from(c.position);
                    map.insert(&p.coords, c.eta);
                }
                crate::site_map::SiteKeyframe {
                    pose,
                    keyframe: keyframe.clone(),
                    descriptor: descriptor.clone(),
                }
            })
            .collect();
        crate::site_map::SiteMap {
            created_ns: header.created_ns,
            sensor_model: header.sensor_model,
            base_from_sensor: header.base_from_sensor,
            keyframes,
            intensity: map,
            edges: self.graph.edges.clone(),
        }
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
                    // A keyframe's own sweep is its node: the first keyframe's pose may have
                    // been settled in the maps after the odometry reported the sweep.
                    Some(kf) if kf.time_ns == s.time_ns => self.graph.poses[k],
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

    #[test]
    fn keyframes_that_see_the_floor_keep_the_map_level() {
        // Driving along x, 0.8 m above a level floor; the odometry pitches up by 2 mrad per
        // metre, so after 44 m it believes it climbed 1.9 m.
        let mut backend = BackEnd::new(&BackEndConfig::default());
        let floor: Vec<[f32; 3]> = (-20..=20)
            .flat_map(|i| (-20..=20).map(move |j| [0.5 * i as f32, 0.5 * j as f32, -0.8]))
            .collect();
        let mut odom = Isometry3::translation(0.0, 0.0, 0.8);
        let mut optimisations = 0;
        for k in 0..45 {
            if k > 0 {
                odom *= Isometry3::new(Vector3::x(), Vector3::y() * -0.002);
            }
            let frame = Keyframe {
                time_ns: 1_000_000_000 * (k as u64 + 1),
                odom_pose: odom,
                edges: Vec::new(),
                planes: floor.clone(),
                cloud: Vec::new(),
            };
            let outcome = backend.add_keyframe(frame, |_| {});
            optimisations += usize::from(outcome.optimization.is_some());
        }
        assert!(
            backend.finish().is_some(),
            "edges since the last optimisation"
        );
        assert_eq!(optimisations, 4, "every 10 floor edges");
        assert_eq!(backend.stats().on_floor, 45);
        let last = odom.translation.z;
        assert!(last > 1.5, "the odometry climbed to {last} m");
        for (k, pose) in backend.keyframe_poses().iter().enumerate() {
            let height = pose.translation.z;
            let tilt = (pose.rotation * Vector3::z()).angle(&Vector3::z());
            assert!((height - 0.8).abs() < 0.02, "keyframe {k}: {height} m");
            assert!(tilt < 0.003, "keyframe {k}: {tilt} rad");
        }
        // The map pose follows: the correction brings the newest keyframe down to the floor.
        let corrected = backend.correction() * odom;
        assert!((corrected.translation.z - 0.8).abs() < 0.02);
    }

    /// Out along x to 30 m and back, keyframes 1 m apart, the way back offset by 0.4 m.
    fn out_and_back(config: &BackEndConfig) -> BackEnd {
        let mut backend = BackEnd::new(config);
        let cloud = vec![
            keyframe::CloudPoint {
                position: [1.0, 2.0, 0.5],
                eta: 40.0,
            };
            3
        ];
        let places = (0..=30)
            .map(|k| (k as f64, 0.0))
            .chain((0..30).map(|i| (29.6 - i as f64, std::f64::consts::PI)));
        for (k, (x, yaw)) in places.enumerate() {
            let frame = Keyframe {
                time_ns: 1_000_000_000 * (k as u64 + 1),
                odom_pose: Isometry3::new(Vector3::new(x, 0.0, 0.0), Vector3::z() * yaw),
                edges: vec![[1.0, 0.0, 0.0]],
                planes: vec![[0.0, 1.0, 0.0]],
                cloud: cloud.clone(),
            };
            backend.add_keyframe(frame, |_| {});
        }
        backend
    }

    #[test]
    fn a_second_pass_releases_its_keyframes_points() {
        let backend = out_and_back(&BackEndConfig::default());
        // On the way back, the keyframe at x is 60 − x m along the path, and the outbound one at
        // ⌊x⌋, 0.6 m away, at ⌊x⌋ m: redundant once they are 15 m apart along it (the loop
        // search's recent stretch), from 22.6 on: 22.6, 21.6, … 0.6.
        assert_eq!(backend.stats().released, 23);
        let kept = |k: &Keyframe| !k.cloud.is_empty() && !k.edges.is_empty();
        let frames = backend.keyframes();
        assert!(
            frames[..31].iter().all(kept),
            "the first pass keeps its points"
        );
        for (k, frame) in frames.iter().enumerate().skip(31) {
            let released = frame.odom_pose.translation.x < 23.0;
            assert_eq!(kept(frame), !released, "keyframe {k}");
            assert_eq!(backend.held[k], !released);
        }
        // Every keyframe is still a node on the odometry chain.
        assert_eq!(backend.graph().poses.len(), 61);
        assert_eq!(backend.graph().edges.len(), 60);

        let keep_all = BackEndConfig {
            keyframes: config::KeyframeConfig {
                redundant_within: 0.0,
                ..config::KeyframeConfig::default()
            },
            ..BackEndConfig::default()
        };
        let all = out_and_back(&keep_all);
        assert_eq!(all.stats().released, 0);
        assert!(all.keyframes().iter().all(kept));
    }
}

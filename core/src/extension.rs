//! Extending a saved site map with what a localisation run saw beyond it (a new aisle): the
//! run's keyframes, each with the localiser's verdict, become a pose graph joined to the saved
//! one, and the keyframes in places the map does not cover are added to it.
//!
//! The saved map stays as it is: its keyframes are fixed nodes, so the map frame, the routes
//! drawn in it and every robot already localising in it keep their meaning. The run's keyframes
//! are free nodes chained by their odometry (one chain per odometry epoch) and tied to the saved
//! keyframes wherever the localiser verified them in the map (an anchor edge per registration,
//! as strict as tracking). A new aisle entered from the map and left back into it is held at
//! both ends; a dead end only at its entrance, where the odometry's drift grows with the
//! distance driven out. A chain the localiser never verified has no place in the map frame and
//! is left out. Of the placed keyframes, those farther than the back end's `redundant_within`
//! from every saved keyframe with points (and from each other) join the map.

use nalgebra::Isometry3;

use crate::backend::config::BackEndConfig;
use crate::backend::keyframe::Keyframe;
use crate::backend::pose_graph::{Edge, OptimizationReport, PoseGraph, PoseGraphError};
use crate::backend::scan_context::ScanContext;
use crate::backend::{information, odometry_edge, SiteMapHeader};
use crate::localiser::{Localisation, Registration};
use crate::site_map::{SiteKeyframe, SiteMap};

/// One keyframe of the run.
#[derive(Debug, Clone)]
struct RunKeyframe {
    epoch: u64,
    keyframe: Keyframe,
    registered: Option<Registration>,
}

/// What an extension added (see [`MapExtension::finish`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExtensionReport {
    /// Keyframes the run made.
    pub run_keyframes: usize,
    /// Of them, registered in the saved map (anchors).
    pub anchors: usize,
    /// Of them, placed in the map frame (in a chain with an anchor).
    pub placed: usize,
    /// Of them, added to the map.
    pub added: usize,
    /// The optimisation that placed them, if any keyframe was placed.
    pub optimization: Option<OptimizationReport>,
}

/// See the module docs. Fed every keyframe of a localisation run with its outcome, in order.
#[derive(Debug, Clone)]
pub struct MapExtension {
    saved: SiteMap,
    config: BackEndConfig,
    run: Vec<RunKeyframe>,
}

impl MapExtension {
    /// An extension of `saved`, whose descriptors were made with `config.scan_context`.
    pub fn new(saved: SiteMap, config: &BackEndConfig) -> Self {
        Self {
            saved,
            config: config.clone(),
            run: Vec::new(),
        }
    }

    /// Takes one keyframe of odometry epoch `epoch` with the localiser's outcome for it. A
    /// keyframe registered next to a saved keyframe with points can never join the map, so it
    /// keeps only its pose: the run's memory grows with the new ground it covers alone.
    pub fn add(&mut self, epoch: u64, keyframe: &Keyframe, outcome: &Localisation) {
        let mut keyframe = keyframe.clone();
        if let Some(r) = outcome.registered {
            if self.near_saved(&r.pose) {
                keyframe.edges = Vec::new();
                keyframe.planes = Vec::new();
                keyframe.cloud = Vec::new();
            }
        }
        self.run.push(RunKeyframe {
            epoch,
            keyframe,
            registered: outcome.registered,
        });
    }

    /// Keyframes taken so far.
    pub fn len(&self) -> usize {
        self.run.len()
    }

    /// Whether no keyframe was taken.
    pub fn is_empty(&self) -> bool {
        self.run.is_empty()
    }

    fn near_saved(&self, pose: &Isometry3<f64>) -> bool {
        let within = self.config.keyframes.redundant_within;
        self.saved.keyframes.iter().any(|k| {
            k.keyframe.holds_points()
                && (k.pose.translation.vector - pose.translation.vector).norm() <= within
        })
    }

    /// The extended map (the saved one's header fields but `created_ns` from `header`) and what
    /// was added. The saved keyframes, their edges and the map frame are unchanged.
    pub fn finish(
        self,
        header: &SiteMapHeader,
    ) -> Result<(SiteMap, ExtensionReport), PoseGraphError> {
        let mut report = ExtensionReport {
            run_keyframes: self.run.len(),
            anchors: self.run.iter().filter(|k| k.registered.is_some()).count(),
            ..ExtensionReport::default()
        };
        let placed = self.place(&mut report)?;
        // The chosen run keyframes, in run order, each with its placed pose.
        let mut chosen: Vec<(usize, Isometry3<f64>)> = Vec::new();
        let within = self.config.keyframes.redundant_within;
        for &(k, pose) in &placed {
            let covered = self.near_saved(&pose)
                || chosen.iter().any(|(_, p)| {
                    (p.translation.vector - pose.translation.vector).norm() <= within
                });
            if self.run[k].keyframe.holds_points() && !covered {
                chosen.push((k, pose));
            }
        }
        let MapExtension {
            mut saved, config, ..
        } = self;
        let saved_count = saved.keyframes.len();

        let g = &config.graph;
        let nearest_saved = |pose: &Isometry3<f64>| {
            saved
                .keyframes
                .iter()
                .enumerate()
                .min_by(|a, b| {
                    let d = |s: &SiteKeyframe| {
                        (s.pose.translation.vector - pose.translation.vector).norm()
                    };
                    d(a.1).total_cmp(&d(b.1))
                })
                .map(|(i, s)| (i, s.pose))
        };
        let mut edges = Vec::new();
        for (n, &(k, pose)) in chosen.iter().enumerate() {
            let index = saved_count + n;
            // Joined to the chosen keyframe before it in the same chain, else to the saved
            // keyframe nearest to it: the relative pose the optimisation settled on.
            let previous = n
                .checked_sub(1)
                .map(|m| (m, chosen[m]))
                .filter(|(_, (j, _))| self.run[*j].epoch == self.run[k].epoch)
                .map(|(m, (_, p))| (saved_count + m, p))
                .or_else(|| nearest_saved(&pose));
            if let Some((from, from_pose)) = previous {
                edges.push(odometry_edge(g, from, index, from_pose.inverse() * pose));
            }
        }

        for &(k, pose) in &chosen {
            let keyframe = self.run[k].keyframe.clone();
            let placed32 = pose.cast::<f32>();
            for c in &keyframe.cloud {
                let p = placed32 * nalgebra::Point3::from(c.position);
                saved.intensity.insert(&p.coords, c.eta);
            }
            let descriptor = ScanContext::new(
                keyframe.cloud.iter().map(|c| (c.position.into(), c.eta)),
                &config.scan_context,
            );
            saved.keyframes.push(SiteKeyframe {
                pose,
                keyframe,
                descriptor,
            });
        }
        saved.edges.extend(edges);
        saved.created_ns = header.created_ns;
        report.added = chosen.len();
        Ok((saved, report))
    }

    /// Places the run's keyframes of every chain with an anchor: a pose graph of the saved
    /// keyframes they registered against (fixed) and of the chain's keyframes (free, starting
    /// where the anchors' corrections put them), optimised. The placed keyframes in run order,
    /// with their poses (sensor → map).
    fn place(
        &self,
        report: &mut ExtensionReport,
    ) -> Result<Vec<(usize, Isometry3<f64>)>, PoseGraphError> {
        let anchored_epochs: std::collections::BTreeSet<u64> = self
            .run
            .iter()
            .filter(|k| k.registered.is_some())
            .map(|k| k.epoch)
            .collect();
        let members: Vec<usize> = (0..self.run.len())
            .filter(|&k| anchored_epochs.contains(&self.run[k].epoch))
            .collect();
        if members.is_empty() {
            return Ok(Vec::new());
        }
        // Each run keyframe starts where the `map ← odom` correction of its chain's nearest
        // anchor (the one before it on a tie) puts it.
        let correction = |j: usize| {
            self.run[j]
                .registered
                .map(|r| (j, r.pose * self.run[j].keyframe.odom_pose.inverse()))
        };
        let mut before = vec![None; members.len()];
        let mut last: Option<(usize, Isometry3<f64>)> = None;
        for (n, &k) in members.iter().enumerate() {
            if n > 0 && self.run[members[n - 1]].epoch != self.run[k].epoch {
                last = None;
            }
            last = correction(k).or(last);
            before[n] = last;
        }
        let mut after: Option<(usize, Isometry3<f64>)> = None;
        let mut graph = PoseGraph::default();
        let mut starts = vec![Isometry3::identity(); members.len()];
        for (n, &k) in members.iter().enumerate().rev() {
            if n + 1 < members.len() && self.run[members[n + 1]].epoch != self.run[k].epoch {
                after = None;
            }
            after = correction(k).or(after);
            let nearest = match (before[n], after) {
                (Some(b), Some(a)) if a.0 - k < k - b.0 => a.1,
                (Some(b), _) => b.1,
                (None, Some(a)) => a.1,
                // Members are of anchored chains only.
                (None, None) => Isometry3::identity(),
            };
            starts[n] = nearest * self.run[k].keyframe.odom_pose;
        }
        for start in starts {
            graph.add_node(start, false);
        }
        let g = &self.config.graph;
        for (n, pair) in members.windows(2).enumerate() {
            let (a, b) = (&self.run[pair[0]], &self.run[pair[1]]);
            if a.epoch != b.epoch {
                continue;
            }
            let measurement = a.keyframe.odom_pose.inverse() * b.keyframe.odom_pose;
            graph.edges.push(odometry_edge(g, n, n + 1, measurement));
        }
        let mut saved_nodes: Vec<(usize, usize)> = Vec::new();
        for (n, &k) in members.iter().enumerate() {
            let Some(r) = self.run[k].registered else {
                continue;
            };
            let Some(saved) = self.saved.keyframes.get(r.saved) else {
                continue;
            };
            let node = match saved_nodes.iter().find(|(s, _)| *s == r.saved) {
                Some(&(_, node)) => node,
                None => {
                    let node = graph.add_node(saved.pose, true);
                    saved_nodes.push((r.saved, node));
                    node
                }
            };
            graph.edges.push(Edge {
                from: node,
                to: n,
                measurement: saved.pose.inverse() * r.pose,
                information: information(g.loop_sigma_translation, g.loop_sigma_rotation),
                robust: true,
            });
        }
        report.optimization = Some(graph.optimize(&g.optimizer)?);
        report.placed = members.len();
        Ok(members
            .iter()
            .zip(&graph.poses)
            .map(|(&k, pose)| (k, *pose))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::backend::keyframe::CloudPoint;
    use crate::config::IntensityMapConfig;
    use crate::intensity_map::IntensityMap;
    use crate::localiser::MapState;

    fn at(x: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(x, 1.0, 0.5), Vector3::z() * 0.05)
    }

    fn keyframe(time_ns: u64, odom_pose: Isometry3<f64>) -> Keyframe {
        Keyframe {
            time_ns,
            odom_pose,
            edges: vec![[1.0, 0.0, 0.0]],
            planes: vec![[0.0, 1.0, 0.0], [0.0, 2.0, 0.0]],
            cloud: vec![CloudPoint {
                position: [3.0, 0.0, 0.0],
                eta: 50.0,
            }],
        }
    }

    /// Where the run's keyframe stamped `time_ns` is (off the saved keyframes' metre marks).
    fn run_x(time_ns: u64) -> f64 {
        0.3 + 0.4 * (time_ns - 1) as f64
    }

    /// Saved keyframes every 2 m at these positions along x.
    fn saved_map(xs: &[f64]) -> SiteMap {
        let config = BackEndConfig::default();
        let keyframes = xs
            .iter()
            .map(|&x| {
                let keyframe = keyframe(0, at(x));
                let descriptor = ScanContext::new(
                    keyframe.cloud.iter().map(|c| (c.position.into(), c.eta)),
                    &config.scan_context,
                );
                SiteKeyframe {
                    pose: at(x),
                    keyframe,
                    descriptor,
                }
            })
            .collect();
        SiteMap {
            created_ns: 1,
            sensor_model: "VLP-16".into(),
            base_from_sensor: Isometry3::identity(),
            keyframes,
            intensity: IntensityMap::new(&IntensityMapConfig::default()),
            edges: Vec::new(),
        }
    }

    fn outcome(registered: Option<Registration>) -> Localisation {
        Localisation {
            state: if registered.is_some() {
                MapState::Tracking
            } else {
                MapState::Relocalising
            },
            correction: None,
            relocalised: false,
            verifications: 1,
            registered,
        }
    }

    /// A run every 0.4 m along x from 0.3 m to `to`, its odometry in a frame of its own and
    /// stretched by `scale`; registered where `registered(x)` says, against the nearest saved
    /// keyframe. The extended map, the report and the run's true poses.
    fn extend(
        saved: &SiteMap,
        to: f64,
        scale: f64,
        registered: impl Fn(f64) -> bool,
    ) -> (SiteMap, ExtensionReport) {
        let odom_from_map = Isometry3::new(Vector3::new(3.0, -2.0, 0.1), Vector3::z() * 0.4);
        let mut extension = MapExtension::new(saved.clone(), &BackEndConfig::default());
        let steps = ((to - 0.3) / 0.4).floor() as usize + 1;
        for k in 0..steps {
            let x = run_x(k as u64 + 1);
            let truth = at(x);
            let odom = odom_from_map * at(x * scale);
            let registration = registered(x).then(|| {
                let (saved_index, _) = saved
                    .keyframes
                    .iter()
                    .enumerate()
                    .min_by(|a, b| {
                        let d = |p: &Isometry3<f64>| (p.translation.x - x).abs();
                        d(&a.1.pose).total_cmp(&d(&b.1.pose))
                    })
                    .expect("a saved keyframe");
                Registration {
                    saved: saved_index,
                    pose: truth,
                }
            });
            extension.add(0, &keyframe(k as u64 + 1, odom), &outcome(registration));
        }
        // A chain the localiser never placed: left out.
        for k in 0..5 {
            let odom = at(30.0 + k as f64);
            extension.add(1, &keyframe(100 + k, odom), &outcome(None));
        }
        let header = SiteMapHeader {
            created_ns: 7,
            sensor_model: "VLP-16".into(),
            base_from_sensor: Isometry3::identity(),
        };
        extension.finish(&header).expect("a valid graph")
    }

    #[test]
    fn a_new_aisle_joins_the_map_at_its_true_poses() {
        let saved = saved_map(&[0.0, 2.0, 4.0, 6.0]);
        let (extended, report) = extend(&saved, 15.0, 1.0, |x| x <= 6.0);
        assert_eq!(report.run_keyframes, 37 + 5);
        assert_eq!(report.anchors, 15);
        assert_eq!(report.placed, 37, "the unanchored chain is left out");
        // Beyond 1 m from the last saved keyframe and from each other.
        let xs: Vec<f64> = extended.keyframes[4..]
            .iter()
            .map(|k| k.pose.translation.x)
            .collect();
        assert_eq!(report.added, xs.len());
        let expected = [7.1, 8.3, 9.5, 10.7, 11.9, 13.1, 14.3];
        assert_eq!(xs.len(), expected.len(), "{xs:?}");
        for (k, x) in extended.keyframes[4..].iter().zip(expected) {
            let error = (k.pose.inverse() * at(x)).translation.vector.norm();
            assert!(error < 1e-6, "{x}: {error}");
            assert!(!k.keyframe.cloud.is_empty());
        }
        assert_eq!(&extended.keyframes[..4], &saved.keyframes[..]);
        assert_eq!(extended.created_ns, 7);
        // Joined: the first added keyframe to the saved one nearest, then each to the last.
        let edges: Vec<(usize, usize)> = extended.edges.iter().map(|e| (e.from, e.to)).collect();
        assert_eq!(
            edges,
            vec![(3, 4), (4, 5), (5, 6), (6, 7), (7, 8), (8, 9), (9, 10)]
        );
        let graph = extended.graph();
        assert!(graph.validate().is_ok());
        assert!(graph.cost(1.0).1 < 1e-9, "the edges hold the placed poses");
        assert!(extended.intensity.len() > saved.intensity.len());
    }

    #[test]
    fn an_aisle_between_two_mapped_ones_is_held_at_both_ends() {
        // The odometry overestimates distance by 1 %: anchored at the entrance alone, the far
        // end of a 14 m aisle is 14 cm out; anchored where the run comes back into the map too,
        // the middle is within a few centimetres.
        let saved = saved_map(&[0.0, 2.0, 4.0, 6.0, 20.0, 22.0, 24.0]);
        let worst = |extended: &SiteMap| {
            extended.keyframes[7..]
                .iter()
                .map(|k| {
                    let x = k.pose.translation.x;
                    let truth = at(run_x(k.keyframe.time_ns));
                    (
                        (k.pose.translation.vector - truth.translation.vector).norm(),
                        x,
                    )
                })
                .fold((0.0_f64, 0.0), |a, b| if b.0 > a.0 { b } else { a })
        };
        let (one_end, _) = extend(&saved, 24.0, 1.01, |x| x <= 6.0);
        let (both_ends, report) = extend(&saved, 24.0, 1.01, |x| x <= 6.0 || x >= 20.0);
        assert_eq!(report.anchors, 15 + 10);
        let (one, _) = worst(&one_end);
        let (both, x) = worst(&both_ends);
        assert!(one > 0.1, "{one}");
        assert!(both < 0.05, "{both} at {x}");
        assert!(both_ends.keyframes[7..]
            .iter()
            .all(|k| (7.0..19.0).contains(&k.pose.translation.x)));
    }

    #[test]
    fn keyframes_registered_where_the_map_has_points_keep_only_their_pose() {
        let saved = saved_map(&[0.0, 2.0]);
        let mut extension = MapExtension::new(saved, &BackEndConfig::default());
        for (k, x) in [1.5, 4.0].into_iter().enumerate() {
            let registration = Registration {
                saved: 1,
                pose: at(x),
            };
            extension.add(0, &keyframe(k as u64, at(x)), &outcome(Some(registration)));
        }
        assert_eq!(extension.len(), 2);
        assert!(extension.run[0].keyframe.cloud.is_empty());
        assert!(extension.run[0].keyframe.planes.is_empty());
        assert!(!extension.run[1].keyframe.cloud.is_empty());
    }
}

//! Localisation in a saved site map ([`SiteMap`]), one keyframe at a time, hdl_localization's
//! way: the odometry runs as usual in its own smooth frame, and each keyframe is registered
//! against the fixed map around where the current `map ← odom` correction puts it, which moves
//! the correction. With no correction yet (at boot, or after tracking was lost) it relocalises
//! globally: Intensity Scan Context candidates over every saved keyframe (the robot may boot
//! anywhere), each verified by the loop closure's registration; a fix is taken only when one
//! place verifies and no other verified place disagrees with it (a corridor's look-alike
//! stretches verify at several places: ambiguous, so no fix), and only once the next keyframe,
//! registered from that fix, agrees. Until then nothing is reported as tracked: a wrong pose
//! sends a robot into a rack, a late one only waits.

use nalgebra::{Isometry3, Vector3};

use crate::backend::config::{KeyframeConfig, ScanContextConfig, VerificationConfig};
use crate::backend::keyframe::Keyframe;
use crate::backend::loop_closure::{search, verify, Placed, Verification};
use crate::backend::scan_context::ScanContext;
use crate::site_map::SiteMap;
use crate::tracker::Correction;

/// Tuning of the localiser.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocaliserConfig {
    /// Ring-key neighbours ranked by the full descriptor when relocalising globally: more than
    /// the loop search's, since every saved keyframe is a candidate.
    pub ring_key_candidates: usize,
    /// Candidates verified per relocalisation attempt, best descriptor first.
    pub max_verifications: usize,
    /// Least ISC similarity of a candidate.
    pub similarity_threshold: f64,
    /// Saved keyframes within this of the anchor are placed into a registration submap, m.
    pub submap_radius: f64,
    /// At most this many of them (the nearest), bounding a registration's cost.
    pub submap_keyframes: usize,
    /// Two verified places farther apart than this make a relocalisation ambiguous, m.
    pub ambiguity_distance: f64,
    /// While tracking, a registration that moves the predicted pose farther than this is not
    /// trusted (the odometry does not drift so far between keyframes), m ...
    pub max_step: f64,
    /// ... or turns it by more than this, rad.
    pub max_step_angle: f64,
    /// Consecutive keyframes that fail to register while tracking before tracking is lost.
    pub lost_after: usize,
    /// With an initial-pose hint: saved keyframes within this of it are the candidates, m.
    pub hint_radius: f64,
    /// Registration of a relocalisation candidate: as strict as loop closure.
    pub relocalise: VerificationConfig,
    /// Registration while tracking, from a prediction good to centimetres: the goods that moved
    /// since the map was made lower the inlier ratio, so it asks for fewer inliers.
    pub track: VerificationConfig,
}

impl Default for LocaliserConfig {
    fn default() -> Self {
        // A keyframe of today's run against the saved keyframes near it: they were taken at
        // other spots than today's, so the residuals are larger than a loop's between two
        // keyframes of one run (simulated warehouse: the right place 0.0019–0.0021, wrong
        // places from 0.0045 up).
        let relocalise = VerificationConfig {
            max_cost: 0.003,
            ..VerificationConfig::default()
        };
        let track = VerificationConfig {
            min_inlier_ratio: 0.4,
            max_cost: 0.004,
            ..VerificationConfig::default()
        };
        Self {
            ring_key_candidates: 40,
            max_verifications: 4,
            similarity_threshold: 0.5,
            submap_radius: 20.0,
            submap_keyframes: 12,
            ambiguity_distance: 1.0,
            max_step: 0.3,
            max_step_angle: 3f64.to_radians(),
            lost_after: 3,
            hint_radius: 10.0,
            relocalise,
            track,
        }
    }
}

/// Keyframes for localisation from the mapping run's: every 0.3 m or half second, so that a
/// relocalisation (a fix and the keyframe that confirms it) takes well under a second of
/// driving or of standing still, and a pose that stopped fitting the map is caught within two
/// or three sweeps.
pub fn localisation_keyframes(mapping: &KeyframeConfig) -> KeyframeConfig {
    KeyframeConfig {
        min_distance: 0.3,
        max_interval_ns: 500_000_000,
        ..mapping.clone()
    }
}

/// Where the localiser stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapState {
    /// No verified pose in the map yet: searching.
    Relocalising,
    /// The correction is verified.
    Tracking,
    /// Tracking, but the last registration did not fit: the pose may no longer be where the
    /// correction puts it (the robot carried to a look-alike aisle is matched as usual by its
    /// odometry), so it is not verified until a registration fits again, or is lost after
    /// `lost_after` that do not.
    Checking,
    /// Tracking was just lost (the pose no longer fits the map): relocalising from the next
    /// keyframe.
    Lost,
}

/// One keyframe's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct Localisation {
    /// State after this keyframe.
    pub state: MapState,
    /// `map ← odom`, when tracking.
    pub correction: Option<Isometry3<f64>>,
    /// This keyframe (re)localised the robot: poses jump to the map here.
    pub relocalised: bool,
    /// Candidates verified (relocalisation) or registrations run (tracking).
    pub verifications: usize,
    /// The keyframe's own registration in the map, when it fitted while tracking (a
    /// relocalisation's unconfirmed fix is not one).
    pub registered: Option<Registration>,
}

/// Where one keyframe registered in the saved map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Registration {
    /// The saved keyframe whose neighbourhood it registered against.
    pub saved: usize,
    /// The keyframe's pose found, sensor → map.
    pub pose: Isometry3<f64>,
}

/// See the module docs.
#[derive(Debug, Clone)]
pub struct Localiser {
    config: LocaliserConfig,
    scan_context: ScanContextConfig,
    /// The saved keyframes: sensor → map, and the keyframe.
    keyframes: Vec<(Isometry3<f64>, Keyframe)>,
    /// Their descriptors, apart so that the global search reads them as a slice.
    descriptors: Vec<ScanContext>,
    /// Whether a keyframe holds points to register against.
    held: Vec<bool>,
    state: MapState,
    correction: Option<Isometry3<f64>>,
    /// A fix from the last keyframe, waiting for the next to agree.
    pending: Option<Isometry3<f64>>,
    failures: usize,
    /// Sensor → map, narrowing the next relocalisation.
    hint: Option<Isometry3<f64>>,
    /// The odometry's frame the correction is for (see [`Self::locate`]).
    epoch: u64,
    /// The last verified correction, carried in answers while none is verified.
    last_verified: Isometry3<f64>,
}

impl Localiser {
    /// A localiser in `map`, whose descriptors were made with `scan_context`.
    pub fn new(map: SiteMap, config: &LocaliserConfig, scan_context: &ScanContextConfig) -> Self {
        let held = map
            .keyframes
            .iter()
            .map(|k| k.keyframe.holds_points())
            .collect();
        let (keyframes, descriptors) = map
            .keyframes
            .into_iter()
            .map(|k| ((k.pose, k.keyframe), k.descriptor))
            .unzip();
        Self {
            config: config.clone(),
            scan_context: scan_context.clone(),
            keyframes,
            descriptors,
            held,
            state: MapState::Relocalising,
            correction: None,
            pending: None,
            failures: 0,
            hint: None,
            epoch: 0,
            last_verified: Isometry3::identity(),
        }
    }

    /// [`Self::locate`] as the tracker takes it: the correction to apply, with the state it is
    /// to be trusted in (unverified answers carry the last verified correction, so unverified
    /// map poses stay near the last known place rather than at the odometry's origin).
    pub fn answer(&mut self, epoch: u64, keyframe: &Keyframe) -> (Correction, Localisation) {
        let outcome = self.locate(epoch, keyframe);
        if let Some(c) = outcome.correction {
            self.last_verified = c;
        }
        let correction = Correction {
            map_from_odom: self.last_verified,
            state: outcome.state,
            relocalised: outcome.relocalised,
            epoch,
            keyframe_ns: keyframe.time_ns,
        };
        (correction, outcome)
    }

    /// The state.
    pub fn state(&self) -> MapState {
        self.state
    }

    /// Narrows the next relocalisation to the saved keyframes near `sensor_in_map`, and drops
    /// the current fix: an operator's hint says the robot is there, so a fix elsewhere is
    /// doubtful.
    pub fn hint(&mut self, sensor_in_map: Isometry3<f64>) {
        self.hint = Some(sensor_in_map);
        self.lose();
    }

    fn lose(&mut self) {
        self.state = MapState::Relocalising;
        self.correction = None;
        self.pending = None;
        self.failures = 0;
    }

    /// Locates one keyframe of the odometry. `epoch` names the odometry's frame: when it
    /// changes (the odometry restarted after being lost), any correction is void and the
    /// localiser relocalises.
    pub fn locate(&mut self, epoch: u64, keyframe: &Keyframe) -> Localisation {
        if epoch != self.epoch {
            self.epoch = epoch;
            if self.state == MapState::Tracking {
                self.lose();
            }
        }
        if self.state == MapState::Lost {
            self.state = MapState::Relocalising;
        }
        match self.correction {
            Some(correction) => self.track(keyframe, &correction),
            None => self.relocalise(keyframe),
        }
    }

    fn track(&mut self, keyframe: &Keyframe, correction: &Isometry3<f64>) -> Localisation {
        let predicted = correction * keyframe.odom_pose;
        let registered = self.register(keyframe, &predicted, &self.config.track);
        let step = registered.map(|r| predicted.inverse() * r.pose);
        let fits = step.is_some_and(|s| {
            s.translation.vector.norm() <= self.config.max_step
                && s.rotation.angle() <= self.config.max_step_angle
        });
        let registered = registered.filter(|_| fits);
        if let Some(r) = registered {
            self.failures = 0;
            self.correction = Some(r.pose * keyframe.odom_pose.inverse());
            self.hint = None;
        } else {
            self.failures += 1;
        }
        if self.failures >= self.config.lost_after.max(1) {
            self.lose();
            self.state = MapState::Lost;
            return self.outcome(false, 1);
        }
        if self.pending.take().is_some() {
            // The fix from the last keyframe, confirmed by this one's registration (or not).
            if fits {
                self.state = MapState::Tracking;
                return self.registered(self.outcome(true, 1), registered);
            }
            self.lose();
            return self.outcome(false, 1);
        }
        self.registered(self.outcome(false, 1), registered)
    }

    /// `outcome` with the keyframe's registration, which counts only once tracking is
    /// verified.
    fn registered(&self, outcome: Localisation, registered: Option<Registration>) -> Localisation {
        Localisation {
            registered: registered.filter(|_| outcome.state == MapState::Tracking),
            ..outcome
        }
    }

    fn outcome(&self, relocalised: bool, verifications: usize) -> Localisation {
        let state = match self.state {
            MapState::Tracking if self.failures > 0 => MapState::Checking,
            state => state,
        };
        Localisation {
            state,
            correction: matches!(state, MapState::Tracking | MapState::Checking)
                .then_some(self.correction)
                .flatten(),
            relocalised,
            verifications,
            registered: None,
        }
    }

    /// A global search for the keyframe's place; a fix found becomes pending, to be confirmed
    /// by the next keyframe.
    fn relocalise(&mut self, keyframe: &Keyframe) -> Localisation {
        let candidates = self.candidates(keyframe);
        let mut fixes: Vec<Isometry3<f64>> = Vec::new();
        let mut verifications = 0;
        for (index, guess) in candidates {
            let anchor = self.keyframes[index].0;
            let Some(v) = self.register_anchored(
                keyframe,
                index,
                &[anchor.inverse() * guess],
                &self.config.relocalise,
            ) else {
                continue;
            };
            verifications += 1;
            if v.accepted {
                fixes.push(anchor * v.relative);
            }
        }
        let Some(first) = fixes.first().copied() else {
            return self.outcome(false, verifications);
        };
        let ambiguous = fixes.iter().any(|f| {
            (f.translation.vector - first.translation.vector).norm()
                > self.config.ambiguity_distance
        });
        if ambiguous {
            return self.outcome(false, verifications);
        }
        self.correction = Some(first * keyframe.odom_pose.inverse());
        self.pending = Some(first);
        self.failures = 0;
        self.outcome(false, verifications)
    }

    /// The saved keyframes to verify, best first, each with a guess of the sensor's pose in the
    /// map: near the hint if there is one, else by descriptor over the whole map.
    fn candidates(&self, keyframe: &Keyframe) -> Vec<(usize, Isometry3<f64>)> {
        let descriptor = ScanContext::new(
            keyframe.cloud.iter().map(|c| (c.position.into(), c.eta)),
            &self.scan_context,
        );
        let max = self.config.max_verifications.max(1);
        if let Some(hint) = self.hint {
            return self
                .nearest(
                    &hint.translation.vector,
                    self.config.hint_radius,
                    false,
                    max,
                )
                .into_iter()
                .map(|i| (i, hint))
                .collect();
        }
        let config = ScanContextConfig {
            ring_key_candidates: self.config.ring_key_candidates,
            similarity_threshold: self.config.similarity_threshold,
            ..self.scan_context.clone()
        };
        search(&descriptor, &self.descriptors, |_| true, &config)
            .into_iter()
            .take(max)
            .map(|c| {
                // The descriptor's yaw turns the query's frame into the candidate's.
                let yaw = Isometry3::rotation(Vector3::z() * c.yaw);
                (c.index, self.keyframes[c.index].0 * yaw)
            })
            .collect()
    }

    /// Registers the keyframe against the map around `predicted` (sensor → map): where, if
    /// the registration is accepted.
    fn register(
        &self,
        keyframe: &Keyframe,
        predicted: &Isometry3<f64>,
        config: &VerificationConfig,
    ) -> Option<Registration> {
        let anchor = self.nearest_held(&predicted.translation.vector)?;
        let anchor_pose = self.keyframes[anchor].0;
        let v = self.register_anchored(
            keyframe,
            anchor,
            &[anchor_pose.inverse() * predicted],
            config,
        )?;
        v.accepted.then(|| Registration {
            saved: anchor,
            pose: anchor_pose * v.relative,
        })
    }

    /// The verification of `keyframe` against the saved keyframes around keyframe `anchor`,
    /// in the anchor's frame, from `guesses` (keyframe → anchor); None when no saved points
    /// lie near.
    fn register_anchored(
        &self,
        keyframe: &Keyframe,
        anchor: usize,
        guesses: &[Isometry3<f64>],
        config: &VerificationConfig,
    ) -> Option<Verification> {
        let centre = self.keyframes[anchor].0;
        let near = self.nearest(
            &centre.translation.vector,
            self.config.submap_radius,
            true,
            self.config.submap_keyframes.max(1),
        );
        if near.is_empty() {
            return None;
        }
        let inverse = centre.inverse();
        let submap: Vec<Placed<'_>> = near
            .iter()
            .map(|&i| Placed {
                pose: inverse * self.keyframes[i].0,
                keyframe: &self.keyframes[i].1,
            })
            .collect();
        Some(verify(keyframe, &submap, guesses, config))
    }

    /// The saved keyframe with points nearest to `position`.
    fn nearest_held(&self, position: &Vector3<f64>) -> Option<usize> {
        self.nearest(position, f64::INFINITY, true, 1)
            .first()
            .copied()
    }

    /// The indices of at most `max` saved keyframes within `radius` of `position`, nearest
    /// first (ties by index, so the choice is deterministic); with `held`, only those that
    /// hold points.
    fn nearest(&self, position: &Vector3<f64>, radius: f64, held: bool, max: usize) -> Vec<usize> {
        let mut near: Vec<(f64, usize)> = self
            .keyframes
            .iter()
            .enumerate()
            .filter(|(i, _)| !held || self.held[*i])
            .map(|(i, (pose, _))| ((pose.translation.vector - position).norm(), i))
            .filter(|(d, _)| *d <= radius)
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        near.into_iter().take(max).map(|(_, i)| i).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::config::BackEndConfig;
    use crate::config::IntensityMapConfig;
    use crate::intensity_map::IntensityMap;
    use crate::se3::{exp, log};
    use crate::site_map::SiteKeyframe;
    use crate::test_scenes::keyframe_seen;
    use nalgebra::Vector6;

    /// A map of the test room from keyframes along a line, at their true poses.
    fn room_map(config: &BackEndConfig) -> SiteMap {
        let keyframes = (0..6)
            .map(|i| {
                let pose = exp(&Vector6::new(
                    0.0,
                    0.0,
                    0.1 * i as f64,
                    -6.0 + 2.0 * i as f64,
                    0.5,
                    0.0,
                ));
                let keyframe = keyframe_seen(&pose, &pose, i as u64);
                let descriptor = ScanContext::new(
                    keyframe.cloud.iter().map(|c| (c.position.into(), c.eta)),
                    &config.scan_context,
                );
                SiteKeyframe {
                    pose,
                    keyframe,
                    descriptor,
                }
            })
            .collect();
        SiteMap {
            created_ns: 0,
            sensor_model: "VLP-16".into(),
            base_from_sensor: Isometry3::identity(),
            keyframes,
            intensity: IntensityMap::new(&IntensityMapConfig::default()),
            edges: Vec::new(),
        }
    }

    /// Keyframes of a robot driving through the room from `start` (map frame), its odometry
    /// starting at the identity: `odom_offset` = map ← odom is what the localiser must find.
    fn drive(start: &Isometry3<f64>, n: usize) -> Vec<Keyframe> {
        let odom_offset = *start;
        (0..n)
            .map(|k| {
                let step = exp(&Vector6::new(
                    0.0,
                    0.0,
                    0.02 * k as f64,
                    0.5 * k as f64,
                    0.0,
                    0.0,
                ));
                let truth = start * step;
                keyframe_seen(&truth, &(odom_offset.inverse() * truth), k as u64)
            })
            .collect()
    }

    #[test]
    fn a_robot_booted_anywhere_in_the_map_is_found_and_confirmed() {
        let config = BackEndConfig::default();
        let mut localiser = Localiser::new(
            room_map(&config),
            &LocaliserConfig::default(),
            &config.scan_context,
        );
        let start = exp(&Vector6::new(0.0, 0.0, -0.4, 1.3, -0.8, 0.0));
        let mut states = Vec::new();
        for keyframe in drive(&start, 5) {
            let (correction, outcome) = localiser.answer(0, &keyframe);
            states.push(outcome.state);
            if outcome.state == MapState::Tracking {
                let error = log(&(start.inverse() * correction.map_from_odom));
                assert!(error.norm() < 0.02, "{error}");
            }
        }
        // A fix from the first keyframe, confirmed by the second: no pose is tracked before.
        assert_eq!(states[0], MapState::Relocalising, "{states:?}");
        assert!(
            states[1..].iter().all(|s| *s == MapState::Tracking),
            "{states:?}"
        );
    }

    #[test]
    fn a_new_epoch_voids_the_fix_and_a_place_off_the_map_is_never_tracked() {
        let config = BackEndConfig::default();
        let mut localiser = Localiser::new(
            room_map(&config),
            &LocaliserConfig::default(),
            &config.scan_context,
        );
        let start = exp(&Vector6::new(0.0, 0.0, -0.4, 1.3, -0.8, 0.0));
        let states: Vec<MapState> = drive(&start, 4)
            .iter()
            .map(|k| localiser.answer(0, k).1.state)
            .collect();
        assert_eq!(localiser.state(), MapState::Tracking, "{states:?}");
        // The odometry restarted (the robot was moved): the old correction means nothing.
        let (_, outcome) = localiser.answer(1, &drive(&start, 1)[0]);
        assert_ne!(outcome.state, MapState::Tracking);
        // Keyframes of another place, whose points fit nothing in the map: never tracked.
        let elsewhere = Isometry3::translation(300.0, 0.0, 0.0);
        let (planes, _) = crate::test_scenes::room();
        let stretched: Vec<_> = planes
            .iter()
            .map(|p| Vector3::new(p.y * 1.7, p.x * 0.6, p.z))
            .collect();
        let input = crate::solver::AlignmentInput {
            edges: Vec::new(),
            planes: stretched,
            intensity: Vec::new(),
        };
        let other = Keyframe::new(9, elsewhere, &input, std::iter::empty(), &config.keyframes);
        for _ in 0..4 {
            let (_, outcome) = localiser.answer(2, &other);
            assert_ne!(outcome.state, MapState::Tracking);
        }
    }
}

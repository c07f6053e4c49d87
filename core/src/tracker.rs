//! What happens to one sweep after its features, as the daemon ships it: the odometry's
//! registration with the resume-after-gap policy, the match quality, keyframe selection and
//! the `map ← odom` correction the back end (or the localiser) hands back. [`Tracker::track`]
//! registers a sweep whole; [`Tracker::track_pose`] stops at its pose, and
//! [`Tracker::update_maps`] then grows the odometry's maps from it, which the daemon does after
//! publishing the pose (see [`crate::odometry`]). Every caller — the
//! daemon's odometry stage, `glintd bench`, the end-to-end tests — drives this one type, so
//! what the tests measure is what runs on the robot. Pure: the threads, channels and clocks
//! stay with the caller.

use nalgebra::{Isometry3, Vector3, Vector6};

use crate::backend::config::KeyframeConfig;
use crate::backend::keyframe::{Keyframe, KeyframeSelector};
use crate::config::OdometryConfig;
use crate::features::SweepFeatures;
use crate::localiser::MapState;
use crate::odometry::{Odometry, OdometryEstimate, Stage, TrackingStatus};
use crate::solver::AlignmentInput;

/// A gap between sweeps longer than this (sensor silence, lost packets) voids the constant
/// velocity: tracking restarts from the last pose, held still.
pub const RESUME_GAP_NS: u64 = 500_000_000;
/// After such a gap, a sweep whose features match worse than this (with no history to compare
/// with) is reported lost rather than trusted: the robot may have moved anywhere meanwhile.
const RESUME_MIN_QUALITY: f64 = 0.5;
/// The same, relative to the median of recent tracked sweeps: the fraction of features matched
/// must be at least this share of the usual one ...
const RESUME_QUALITY_RATIO: f64 = 0.8;
/// ... and the mean robust cost per residual at most this multiple of the usual one.
const RESUME_COST_RATIO: f64 = 2.0;
/// Localising, a sweep whose residual is this many times the usual one did not see the place
/// the odometry thinks it is at: the robot was carried off (the sweep at the jump into a
/// look-alike aisle: 6.8 times; ordinary sweeps stay within 2), and from the next sweep on its
/// odometry may match the new place to the old one as usual. So the odometry restarts and the
/// robot is relocalised globally, where look-alike places are refused as ambiguous.
const JUMP_COST_RATIO: f64 = 4.0;

/// Localising in a saved map, consecutive sweeps lost or matching unlike recent ones after
/// which the odometry restarts at its last pose and the localiser relocalises: the robot was
/// moved (kidnapped), or the sensor blinded. Half a second at 10 Hz.
const RESTART_AFTER: usize = 5;

/// Localising, the most an alignment may move a sweep off its constant-velocity prediction: an
/// AGV's speed changes by centimetres per second within a sweep (0.5 m/s² over 0.1 s moves it
/// 5 mm; a yaw acceleration of 0.8 rad/s² turns it 8 mrad), so more means the odometry matched
/// the scan to a look-alike place: the robot was carried elsewhere, and its odometry followed
/// a wrong match rather than losing it.
const MAX_INNOVATION_M: f64 = 0.2;
/// See [`MAX_INNOVATION_M`], rad (about 3°).
const MAX_INNOVATION_RAD: f64 = 0.05;

/// The fraction of the sweep's geometric features that found a correspondence.
pub fn match_quality(estimate: &OdometryEstimate, features: &SweepFeatures) -> f32 {
    match &estimate.alignment {
        Some(a) => {
            let offered = (features.edges.len() + features.planes.len()).max(1);
            ((a.edges + a.planes) as f32 / offered as f32).clamp(0.0, 1.0)
        }
        None => 0.0,
    }
}

/// The `q` quantile of `v` (nearest rank), NaN when empty.
pub fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize]
}

/// How well recent sweeps matched: the yardstick for a doubtful sweep, so the test adapts to
/// the scene and the sensor instead of fixing absolute numbers.
#[derive(Debug, Clone, Default)]
pub struct MatchHistory {
    quality: Vec<f64>,
    cost: Vec<f64>,
}

impl MatchHistory {
    /// Sweeps remembered.
    pub const LEN: usize = 50;
    /// Sweeps remembered before they are a yardstick.
    pub const WARM: usize = 5;

    /// Sweeps remembered so far.
    pub fn len(&self) -> usize {
        self.cost.len()
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.cost.is_empty()
    }

    /// Remembers one tracked sweep's match.
    pub fn push(&mut self, quality: f32, cost: f64) {
        if self.quality.len() == Self::LEN {
            self.quality.remove(0);
            self.cost.remove(0);
        }
        self.quality.push(f64::from(quality));
        self.cost.push(cost);
    }

    /// Whether a sweep's residual is [`JUMP_COST_RATIO`] times the usual one or more (false
    /// until enough sweeps are remembered).
    pub fn striking(&self, cost: f64) -> bool {
        if self.cost.len() < Self::WARM || !cost.is_finite() {
            return false;
        }
        cost >= JUMP_COST_RATIO * quantile(&mut self.cost.clone(), 0.5)
    }

    /// Whether a sweep matches the map about as well as tracked sweeps do: a wrong alignment
    /// after the robot moved in the dark still matches many features in a repetitive
    /// warehouse, but leaves residuals several times larger (measured: cost 0.023 against a
    /// median of 0.0045 when tracking).
    pub fn usual_match(&self, quality: f32, cost: f64) -> bool {
        if !cost.is_finite() {
            return false;
        }
        if self.cost.len() < Self::WARM {
            return f64::from(quality) >= RESUME_MIN_QUALITY;
        }
        let typical_quality = quantile(&mut self.quality.clone(), 0.5);
        let typical_cost = quantile(&mut self.cost.clone(), 0.5);
        f64::from(quality) >= RESUME_QUALITY_RATIO * typical_quality
            && cost <= RESUME_COST_RATIO * typical_cost
    }
}

/// Something the caller may want to log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrackerEvent {
    /// After a gap in the data the sweep matched the map as usual: tracking goes on.
    Resumed {
        /// Its match quality.
        quality: f32,
        /// Its mean robust cost per residual.
        cost: f64,
    },
    /// After a gap the sweep did not match: lost at the last good pose (reported once until
    /// tracking resumes).
    LostAfterGap {
        /// Its match quality.
        quality: f32,
        /// Its mean robust cost per residual.
        cost: f64,
    },
    /// Localising: sweeps stopped matching the odometry's own map (see [`RESTART_AFTER`]); the
    /// odometry starts afresh at its last pose in a new epoch and the robot is relocalised.
    Restarted {
        /// The new epoch.
        epoch: u64,
    },
}

/// `map ← odom` as the back end or the localiser hands it back for a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correction {
    /// `map ← odom`.
    pub map_from_odom: Isometry3<f64>,
    /// Whether it is verified in the map.
    pub state: MapState,
    /// The robot was (re)localised with this correction: map poses jump here.
    pub relocalised: bool,
    /// The odometry epoch it is for (see [`Tracker::epoch`]); a stale one is ignored.
    pub epoch: u64,
    /// The keyframe it answers, ns: a verification vouches for sweeps up to this one.
    pub keyframe_ns: u64,
}

impl Correction {
    /// The back end's correction: its map is the run's own, always tracked.
    pub fn slam(map_from_odom: Isometry3<f64>) -> Self {
        Self {
            map_from_odom,
            state: MapState::Tracking,
            relocalised: false,
            epoch: 0,
            keyframe_ns: 0,
        }
    }
}

/// How far a sweep's map pose is to be trusted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapFix {
    /// The map pose is verified: publish it as tracked.
    pub verified: bool,
    /// The first verified pose after a (re)localisation: it jumps.
    pub relocalised: bool,
    /// The localiser's state.
    pub state: MapState,
}

/// One sweep's outcome.
#[derive(Debug, Clone)]
pub struct TrackedSweep {
    /// The odometry's estimate (sensor → odom).
    pub estimate: OdometryEstimate,
    /// The fraction of its features matched.
    pub quality: f32,
    /// Its mean robust cost per residual (NaN when not aligned).
    pub cost: f64,
    /// The keyframe it became, when keyframes are taken.
    pub keyframe: Option<Keyframe>,
    /// With a known pose: how far alignment moved the sweep off it (sensor frame).
    pub departure: Option<Vector3<f64>>,
    /// What to log, if anything.
    pub event: Option<TrackerEvent>,
}

/// The per-sweep policy around the odometry. See the module docs.
#[derive(Debug, Clone)]
pub struct Tracker {
    odometry: Odometry,
    keyframes: Option<KeyframeConfig>,
    selector: KeyframeSelector,
    correction: Isometry3<f64>,
    history: MatchHistory,
    lost_after_gap: bool,
    /// With known poses: the first one's inverse, so they start at the identity as the
    /// odometry does.
    known_origin: Option<Isometry3<f64>>,
    config: OdometryConfig,
    /// Localising in a saved map: the policy of [`RESTART_AFTER`] applies.
    localising: bool,
    epoch: u64,
    map_state: MapState,
    relocalised_pending: bool,
    /// Consecutive sweeps lost or matching unusually.
    doubtful: usize,
    /// The last sweep matched as usual.
    usual: bool,
    restart_at: Option<Isometry3<f64>>,
    /// Localising: the last sweep that matched unusually; map poses wait for a verification of
    /// a keyframe at or after it (a robot carried to a look-alike aisle matches as usual again
    /// one sweep after the jump, and only the map can tell).
    doubted_at: Option<u64>,
    /// The odometry's first sweep, a keyframe waiting for the motion it was taken with.
    first_keyframe: Option<WaitingKeyframe>,
}

/// The first sweep of a run or an epoch, kept until the motion to deskew it with is known (see
/// the tracker's `keyframe`).
#[derive(Debug, Clone)]
struct WaitingKeyframe {
    time_ns: u64,
    pose: Isometry3<f64>,
    epoch: u64,
    features: SweepFeatures,
    /// Once the motion is known: the sweep deskewed by it.
    deskewed: Option<DeskewedSweep>,
    /// Sweeps matched since.
    settled: usize,
}

/// A sweep's alignment input and its calibrated returns with their reflectivity, both
/// deskewed and in its sensor frame: what a keyframe is made of.
type DeskewedSweep = (AlignmentInput, Vec<(Vector3<f32>, f32)>);

/// Mapping, the sweeps that grow the maps after the motion is known before the first keyframe
/// is placed in them: half a second at 10 Hz, a few decimetres of travel, before the keyframe
/// selector's 1 m would take the next keyframe.
const FIRST_KEYFRAME_SETTLE: usize = 5;

impl Tracker {
    /// A tracker with fresh odometry; keyframes are taken when `keyframes` is given.
    pub fn new(config: &OdometryConfig, keyframes: Option<&KeyframeConfig>) -> Self {
        Self {
            odometry: Odometry::new(config),
            keyframes: keyframes.cloned(),
            selector: KeyframeSelector::new(),
            correction: Isometry3::identity(),
            history: MatchHistory::default(),
            lost_after_gap: false,
            known_origin: None,
            config: config.clone(),
            localising: false,
            epoch: 0,
            map_state: MapState::Tracking,
            relocalised_pending: false,
            doubtful: 0,
            usual: true,
            restart_at: None,
            doubted_at: None,
            first_keyframe: None,
        }
    }

    /// A tracker for localisation in a saved map: map poses wait for the localiser's
    /// verification, and the odometry restarts when its sweeps stop matching (see
    /// [`RESTART_AFTER`]).
    pub fn localising(config: &OdometryConfig, keyframes: &KeyframeConfig) -> Self {
        Self {
            localising: true,
            map_state: MapState::Relocalising,
            ..Self::new(config, Some(keyframes))
        }
    }

    /// The odometry's epoch: it changes when the odometry restarts, and with it the odometry
    /// frame's meaning for the localiser.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Applies the back end's or the localiser's answer; returns whether `map ← odom` changed.
    /// A correction for an earlier epoch is ignored.
    pub fn apply(&mut self, correction: &Correction) -> bool {
        if correction.epoch != self.epoch {
            return false;
        }
        self.map_state = correction.state;
        self.relocalised_pending |= correction.relocalised;
        if correction.state == MapState::Tracking
            && self.doubted_at.is_some_and(|t| correction.keyframe_ns >= t)
        {
            self.doubted_at = None;
        }
        self.correct(correction.map_from_odom)
    }

    /// How far the last sweep's map pose is to be trusted, after the answers to its keyframe
    /// were applied. A relocalisation's jump is reported once, with the first verified pose.
    pub fn map_fix(&mut self, estimate: &OdometryEstimate) -> MapFix {
        let verified = self.map_state == MapState::Tracking
            && self.usual
            && self.doubted_at.is_none()
            && self.restart_at.is_none()
            && matches!(
                estimate.status,
                TrackingStatus::Tracking | TrackingStatus::Degenerate
            );
        let relocalised = verified && std::mem::take(&mut self.relocalised_pending);
        MapFix {
            verified,
            relocalised,
            state: self.map_state,
        }
    }

    /// The odometry (its maps, last pose).
    pub fn odometry(&self) -> &Odometry {
        &self.odometry
    }

    /// `map ← odom` as last set by [`Self::correct`].
    pub fn correction(&self) -> Isometry3<f64> {
        self.correction
    }

    /// Sets `map ← odom`; returns whether it changed.
    pub fn correct(&mut self, map_from_odom: Isometry3<f64>) -> bool {
        let changed = map_from_odom != self.correction;
        self.correction = map_from_odom;
        changed
    }

    /// How well recent tracked sweeps matched.
    pub fn history(&self) -> &MatchHistory {
        &self.history
    }

    /// Registers one sweep's features: [`Self::track_pose`], then [`Self::update_maps`]. With
    /// `known_pose` (ground truth in diagnostics, in any fixed frame: the first one becomes the
    /// identity) the sweep is aligned from it and the map grown at it. `on_stage` is called as
    /// each odometry stage ends (for timing).
    pub fn track(
        &mut self,
        features: &SweepFeatures,
        known_pose: Option<Isometry3<f64>>,
        on_stage: impl FnMut(Stage),
    ) -> TrackedSweep {
        let mut on_stage = on_stage;
        let tracked = self.track_pose(features, known_pose, &mut on_stage);
        self.update_maps(features);
        on_stage(Stage::MapUpdate);
        tracked
    }

    /// Grows the odometry's maps from the sweep [`Self::track_pose`] just tracked, whose
    /// `features` these are; returns whether a growth was pending. Must come before the next
    /// sweep (see [`Odometry::locate_from`]).
    pub fn update_maps(&mut self, features: &SweepFeatures) -> bool {
        self.odometry.update_maps(features)
    }

    /// Associates the open sweep's features picked before its close (see
    /// [`Odometry::associate_early`]); `sweep` is the time of its first return.
    pub fn associate_early(&mut self, sweep: u64, features: &SweepFeatures) {
        self.odometry.associate_early(sweep, features);
    }

    /// [`Self::track`] up to the sweep's pose, keyframe and events: the odometry's maps grow
    /// from it in [`Self::update_maps`], which the caller runs once the pose is on its way.
    pub fn track_pose(
        &mut self,
        features: &SweepFeatures,
        known_pose: Option<Isometry3<f64>>,
        on_stage: impl FnMut(Stage),
    ) -> TrackedSweep {
        let mut tracked = self.pose_of(features, known_pose, on_stage);
        tracked.keyframe = self.keyframe_of(features, &tracked.estimate);
        tracked
    }

    /// [`Self::track_pose`] without the keyframe (`keyframe` is None): the sweep's keyframe,
    /// if it gives one, comes from [`Self::keyframe_of`], which a caller can run once the pose
    /// is on its way, so that a keyframe sweep's pose waits for no keyframe's making.
    pub fn pose_of(
        &mut self,
        features: &SweepFeatures,
        known_pose: Option<Isometry3<f64>>,
        on_stage: impl FnMut(Stage),
    ) -> TrackedSweep {
        let reference_ns = features.reference_ns;
        let known_pose = known_pose.map(|g| *self.known_origin.get_or_insert(g.inverse()) * g);
        let after_gap = self
            .odometry
            .last_pose()
            .filter(|(t, _)| reference_ns > t + RESUME_GAP_NS);
        let mut event = None;
        let restart = self.restart_at.take();
        // The constant-velocity prediction, to judge how far alignment moved the sweep (not
        // after a gap, where the pose is predicted as held, nor before the motion is measured).
        let predicted = (self.localising
            && after_gap.is_none()
            && restart.is_none()
            && self.history.len() >= MatchHistory::WARM)
            .then(|| self.odometry.prediction(reference_ns));
        let mut estimate = match (known_pose, after_gap) {
            (None, _) if restart.is_some() => {
                self.odometry = Odometry::new(&self.config);
                let at = restart.expect("matched on is_some");
                self.odometry.locate_from(features, at, on_stage)
            }
            (Some(pose), _) => self.odometry.locate_at_known_pose(features, pose, on_stage),
            (None, Some((_, last))) => {
                // The robot may have moved anywhere while the data stopped. Try the sweep from
                // the last pose on a copy, and keep the copy's maps only if the sweep matches;
                // otherwise report lost at the last good pose and try again with the next one.
                let mut probe = self.odometry.clone();
                let e = probe.locate_from(features, last, on_stage);
                let quality = match_quality(&e, features);
                let cost = e.alignment.as_ref().map_or(f64::NAN, |a| a.cost);
                if e.status != TrackingStatus::Lost && self.history.usual_match(quality, cost) {
                    event = Some(TrackerEvent::Resumed { quality, cost });
                    self.lost_after_gap = false;
                    self.odometry = probe;
                    e
                } else {
                    if !self.lost_after_gap {
                        event = Some(TrackerEvent::LostAfterGap { quality, cost });
                        self.lost_after_gap = true;
                    }
                    OdometryEstimate {
                        time_ns: reference_ns,
                        pose: last,
                        velocity: Vector6::zeros(),
                        status: TrackingStatus::Lost,
                        alignment: e.alignment,
                    }
                }
            }
            (None, None) => self.odometry.locate(features, on_stage),
        };
        let departure = known_pose.map(|pose| (estimate.pose.inverse() * pose).translation.vector);
        let quality = match_quality(&estimate, features);
        let cost = estimate.alignment.as_ref().map_or(f64::NAN, |a| a.cost);
        if matches!(
            estimate.status,
            TrackingStatus::Tracking | TrackingStatus::Degenerate
        ) && cost.is_finite()
        {
            self.history.push(quality, cost);
        }
        if self.localising {
            let jump = predicted.filter(|p| {
                let innovation = p.inverse() * estimate.pose;
                innovation.translation.vector.norm() > MAX_INNOVATION_M
                    || innovation.rotation.angle() > MAX_INNOVATION_RAD
                    || self.history.striking(cost)
            });
            if let Some(p) = jump {
                // The match is not the robot's motion: `odom` goes on from the prediction, as
                // for any lost sweep, and the odometry restarts there.
                estimate.pose = p;
                estimate.status = TrackingStatus::Lost;
            }
            event = event.or(self.watch(&estimate, quality, cost, jump.is_some()));
        }
        TrackedSweep {
            estimate,
            quality,
            cost,
            keyframe: None,
            departure,
            event,
        }
    }

    /// The keyframe the sweep [`Self::pose_of`] just tracked as `estimate` gives, if any
    /// (see `keyframe`). Must come before [`Self::update_maps`]; a caller that takes no
    /// keyframes (none configured, or no back end to take them) may skip it.
    pub fn keyframe_of(
        &mut self,
        features: &SweepFeatures,
        estimate: &OdometryEstimate,
    ) -> Option<Keyframe> {
        if self.first_keyframe.is_some() {
            // The first keyframe may be placed in the maps as this sweep leaves them.
            self.odometry.update_maps(features);
        }
        self.keyframe(features, estimate)
    }

    /// The keyframe this sweep gives, if any. The odometry's first sweep (of a run or an epoch)
    /// waits for the motion it was taken with: taken at once, a robot already moving would put
    /// it into the graph and the saved map smeared by a sweep's travel (0.15 m at 1.5 m/s, 4°
    /// turning at 0.67 rad/s), and the map frame with it. Localising, its keyframe comes with
    /// the next sweep that measures the motion, deskewed by it. Mapping, it also waits until
    /// [`FIRST_KEYFRAME_SETTLE`] more sweeps have grown the maps, and is placed by aligning it
    /// to them: the next sweeps were matched to the first one alone, and every later pose, the
    /// whole map's heading with them, would keep the offset that left between the first sweep
    /// and the rest. No other keyframe is taken meanwhile.
    fn keyframe(
        &mut self,
        features: &SweepFeatures,
        estimate: &OdometryEstimate,
    ) -> Option<Keyframe> {
        let config = self.keyframes.as_ref()?;
        if let Some(mut waiting) = self.first_keyframe.take() {
            if waiting.epoch == self.epoch {
                if self.odometry.awaits_motion() {
                    self.first_keyframe = Some(waiting);
                    return None;
                }
                let settle = if self.localising {
                    0
                } else {
                    FIRST_KEYFRAME_SETTLE
                };
                match waiting.deskewed {
                    None => {
                        waiting.deskewed = Some((
                            self.odometry.deskewed(&waiting.features),
                            self.odometry
                                .map_points(&waiting.features, &Isometry3::identity())
                                .collect(),
                        ));
                    }
                    Some(_) if estimate.status != TrackingStatus::Lost => waiting.settled += 1,
                    Some(_) => {}
                }
                if waiting.settled < settle {
                    self.first_keyframe = Some(waiting);
                    return None;
                }
                let (input, points) = waiting.deskewed.take().expect("deskewed above");
                let pose = if settle > 0 {
                    self.settled_pose(&input, &waiting.pose)
                } else {
                    waiting.pose
                };
                return Some(Keyframe::new(waiting.time_ns, pose, &input, points, config));
            }
            // The odometry restarted before measuring the motion: that frame is void.
        }
        if estimate.status == TrackingStatus::Lost
            || !self
                .selector
                .is_keyframe(estimate.time_ns, &estimate.pose, config)
        {
            return None;
        }
        if self.odometry.awaits_motion() {
            self.first_keyframe = Some(WaitingKeyframe {
                time_ns: estimate.time_ns,
                pose: estimate.pose,
                epoch: self.epoch,
                features: features.clone(),
                deskewed: None,
                settled: 0,
            });
            return None;
        }
        let (input, points) = self.odometry.keyframe_parts(features);
        Some(Keyframe::new(
            estimate.time_ns,
            estimate.pose,
            input,
            points,
            config,
        ))
    }

    /// The first sweep's pose aligned to the maps the next sweeps grew, from `pose`, where the
    /// alignment matched enough, is well constrained and moved it as little as an AGV's
    /// prediction error may; otherwise `pose`.
    fn settled_pose(&self, input: &AlignmentInput, pose: &Isometry3<f64>) -> Isometry3<f64> {
        let a = self.odometry.place(input, pose);
        let moved = pose.inverse() * a.pose;
        let usable = a.edges + a.planes >= self.config.solver.min_correspondences
            && !a.degenerate
            && moved.translation.vector.norm() <= MAX_INNOVATION_M
            && moved.rotation.angle() <= MAX_INNOVATION_RAD;
        if usable {
            a.pose
        } else {
            *pose
        }
    }

    /// Localising: counts sweeps lost or matching unlike recent ones, and restarts the odometry
    /// after [`RESTART_AFTER`] of them in a row, or at once after an implausible `jumped` one.
    fn watch(
        &mut self,
        estimate: &OdometryEstimate,
        quality: f32,
        cost: f64,
        jumped: bool,
    ) -> Option<TrackerEvent> {
        let aligned = matches!(
            estimate.status,
            TrackingStatus::Tracking | TrackingStatus::Degenerate
        );
        self.usual = aligned && !jumped && self.history.usual_match(quality, cost);
        if !self.usual && estimate.status != TrackingStatus::Initialising {
            self.doubted_at = Some(estimate.time_ns);
        }
        match estimate.status {
            TrackingStatus::Initialising => self.doubtful = 0,
            _ if self.usual => self.doubtful = 0,
            _ => self.doubtful += 1,
        }
        // An implausible jump restarts at once: the odometry's maps now hold the scan at the
        // wrong place, and every later sweep would match them as usual.
        if self.doubtful < RESTART_AFTER && !jumped {
            return None;
        }
        self.doubtful = 0;
        self.epoch += 1;
        self.map_state = MapState::Lost;
        self.relocalised_pending = false;
        self.restart_at = Some(estimate.pose);
        self.selector = KeyframeSelector::new();
        Some(TrackerEvent::Restarted { epoch: self.epoch })
    }

    /// The last sweep's calibrated returns placed at `pose` (call right after
    /// [`Self::track`] or [`Self::track_pose`]), with their reflectivity.
    pub fn map_points<'a>(
        &'a self,
        features: &'a SweepFeatures,
        pose: &Isometry3<f64>,
    ) -> impl Iterator<Item = (Vector3<f32>, f32)> + 'a {
        self.odometry.map_points(features, pose)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_doubtful_sweep_is_judged_against_recent_ones() {
        let mut history = MatchHistory::default();
        // With no history, an absolute floor on the matched fraction.
        assert!(history.usual_match(0.6, 0.01));
        assert!(!history.usual_match(0.3, 0.01));
        assert!(!history.usual_match(0.9, f64::NAN));
        for i in 0..60 {
            history.push(0.7 + 0.001 * (i % 5) as f32, 0.0045);
        }
        assert_eq!(history.cost.len(), MatchHistory::LEN);
        assert!(history.usual_match(0.68, 0.006));
        // As many matches as usual, but five times the residual: a wrong alignment.
        assert!(!history.usual_match(0.62, 0.023));
        assert!(!history.usual_match(0.4, 0.004));
        // Localising, four times the usual residual is a jump; twice is only doubtful.
        assert!(history.striking(0.023));
        assert!(!history.striking(0.009));
        assert!(!MatchHistory::default().striking(1.0), "no yardstick yet");
    }

    #[test]
    fn quantiles_by_nearest_rank() {
        assert!(quantile(&mut [], 0.5).is_nan());
        assert_eq!(quantile(&mut [3.0, 1.0, 2.0], 0.5), 2.0);
        assert_eq!(quantile(&mut [3.0, 1.0, 2.0], 1.0), 3.0);
    }
}

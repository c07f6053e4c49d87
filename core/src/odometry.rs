//! The front end of the method, steps 0–5, one sweep at a time:
//!
//! - step 0: predict the pose by constant velocity and deskew the features to the sweep's
//!   reference time with the per-point firing times;
//! - steps 1–2 (done before, by [`crate::front_end::FrontEnd`]): intensity calibration and
//!   salient points;
//! - steps 3–4: align the features to the local edge, plane and intensity maps;
//! - step 5: read the degeneracy of the geometric constraints;
//!
//! then deskew again with the motion just estimated and grow the maps. The pose is known before
//! the maps grow: [`Odometry::locate`] returns it and leaves the growth to
//! [`Odometry::update_maps`], so a caller can publish the pose first and grow the maps while the
//! next sweep arrives; [`Odometry::register`] does both. Everything is pure: time comes with the
//! data, and stage timing is reported through a caller's hook, never a clock.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3, Vector6};

use crate::config::OdometryConfig;
use crate::features::{Feature, SweepFeatures};
use crate::intensity_map::IntensityMap;
use crate::local_map::LocalMap;
use crate::se3::{exp, log};
use crate::solver::{
    align_with, angular_weight, Alignment, AlignmentInput, Correspondences, EarlyCorrespondences,
    IntensityPoint, MapView,
};

/// Where the odometry stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackingStatus {
    /// The first sweep: it defines the map frame.
    Initialising,
    /// Aligned to the map.
    Tracking,
    /// Aligned, but geometry alone leaves a direction unconstrained (intensity may hold it).
    Degenerate,
    /// Too few correspondences, or too little of a turn (see
    /// [`crate::config::SolverConfig::min_coverage`]): the prediction is reported and the map
    /// is not grown.
    Lost,
}

/// Stages of [`Odometry::register`], reported to the caller's hook as each one ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Prediction and deskew.
    Deskew,
    /// Scan-to-map alignment.
    Align,
    /// Map update (reported by the calls that grow the maps: [`Odometry::register`] and its
    /// variants, not [`Odometry::locate`]).
    MapUpdate,
}

/// One sweep's result.
#[derive(Debug, Clone, PartialEq)]
pub struct OdometryEstimate {
    /// The instant the pose describes (the sweep's reference time), ns since the epoch.
    pub time_ns: u64,
    /// Sensor → map at `time_ns`.
    pub pose: Isometry3<f64>,
    /// Body-frame twist [ω, υ] (rad/s, m/s) over the last interval.
    pub velocity: Vector6<f64>,
    /// Tracking status.
    pub status: TrackingStatus,
    /// The alignment's details, when one ran.
    pub alignment: Option<Alignment>,
}

/// Steps 0 and 3–5, holding the local maps and the motion between sweeps. `Clone`, so a caller
/// can try a doubtful sweep on a copy and keep the maps only if it matches.
#[derive(Debug, Clone)]
pub struct Odometry {
    config: OdometryConfig,
    edges: LocalMap,
    planes: LocalMap,
    intensity: IntensityMap,
    last: Option<(u64, Isometry3<f64>)>,
    velocity: Vector6<f64>,
    input: AlignmentInput,
    /// Whether `input` still waits to be deskewed with `velocity`, the motion the sweep's
    /// alignment measured: only the maps' growth and a keyframe need it, so it is done there,
    /// after the pose is out.
    input_stale: bool,
    /// The current sweep's correspondences, for its refinement after the second deskew.
    correspondences: Correspondences,
    /// Correspondences of the open sweep's features picked before its close.
    early: EarlyCorrespondences,
    sweeps: u64,
    known_poses: bool,
    /// The pose of the last sweep that grew the maps.
    mapped_at: Option<Isometry3<f64>>,
    /// The sweep the maps were started from and its pose, until the next sweep measures the
    /// motion it was taken with (see [`Self::restart_maps`]).
    first_sweep: Option<(SweepFeatures, Isometry3<f64>)>,
    deskew_cache: DeskewCache,
    /// The last located sweep's growth of the maps, until [`Self::update_maps`].
    pending_growth: Option<PendingGrowth>,
}

/// Where a located sweep grows the maps, and whether cells far from it are evicted then.
#[derive(Debug, Clone, Copy)]
struct PendingGrowth {
    pose: Isometry3<f64>,
    evict: bool,
}

/// Sweeps between evictions of map cells far from the robot.
const EVICT_EVERY: u64 = 10;
/// Bounds on a plausible AGV twist: faster estimates are not extrapolated.
const MAX_SPEED: f64 = 5.0;
const MAX_TURN_RATE: f64 = 3.0;

impl Odometry {
    /// Odometry with empty maps.
    pub fn new(config: &OdometryConfig) -> Self {
        let (edges, planes, intensity) = empty_maps(config);
        Self {
            config: config.clone(),
            edges,
            planes,
            intensity,
            last: None,
            velocity: Vector6::zeros(),
            input: AlignmentInput::default(),
            input_stale: false,
            correspondences: Correspondences::default(),
            early: EarlyCorrespondences::default(),
            sweeps: 0,
            known_poses: false,
            mapped_at: None,
            first_sweep: None,
            deskew_cache: DeskewCache::default(),
            pending_growth: None,
        }
    }

    /// Map sizes (edge points, plane points, intensity cells), for memory reports.
    pub fn map_sizes(&self) -> (usize, usize, usize) {
        (self.edges.len(), self.planes.len(), self.intensity.len())
    }

    /// What a keyframe keeps of the last registered sweep, `features` (call right after
    /// [`Self::locate`] or [`Self::register`]): its edge, plane and intensity points deskewed
    /// with the motion just estimated, in the sensor frame at its reference time, and its
    /// calibrated returns in that frame (see [`Self::map_points`]).
    pub fn keyframe_parts<'a>(
        &'a mut self,
        features: &'a SweepFeatures,
    ) -> (
        &'a AlignmentInput,
        impl Iterator<Item = (Vector3<f32>, f32)> + 'a,
    ) {
        self.settle_input(features);
        let this = &*self;
        (
            &this.input,
            this.map_points(features, &Isometry3::identity()),
        )
    }

    /// Deskews the sweep's features with the motion its alignment measured, if not yet done.
    fn settle_input(&mut self, features: &SweepFeatures) {
        if self.input_stale {
            self.deskew(features, &self.velocity.clone());
        }
    }

    /// The last pose, if any.
    pub fn last_pose(&self) -> Option<(u64, Isometry3<f64>)> {
        self.last
    }

    /// Registers one sweep's features: [`Self::locate`], then [`Self::update_maps`]. `on_stage`
    /// is called as each stage ends (for timing).
    pub fn register(
        &mut self,
        features: &SweepFeatures,
        on_stage: impl FnMut(Stage),
    ) -> OdometryEstimate {
        let prediction = self.prediction(features.reference_ns);
        self.register_from(features, prediction, on_stage)
    }

    /// The sweep's pose from the constant-velocity prediction ([`Self::locate_from`]).
    pub fn locate(
        &mut self,
        features: &SweepFeatures,
        on_stage: impl FnMut(Stage),
    ) -> OdometryEstimate {
        let prediction = self.prediction(features.reference_ns);
        self.locate_from(features, prediction, on_stage)
    }

    /// Step 0: the pose at `time_ns` by constant velocity from the last one (the identity
    /// before the first sweep).
    pub fn prediction(&self, time_ns: u64) -> Isometry3<f64> {
        match self.last {
            Some((t, pose)) if time_ns > t => {
                let dt = (time_ns - t) as f64 * 1e-9;
                pose * exp(&(self.velocity * dt))
            }
            Some((_, pose)) => pose,
            None => Isometry3::identity(),
        }
    }

    /// Locates one sweep whose true pose is known (ground truth, in diagnostics): aligns it from
    /// that pose to measure how far the scan alone would move it, but takes the motion from the
    /// known pose, and [`Self::update_maps`] grows the maps there. The estimate's `pose` is the
    /// alignment's.
    pub fn locate_at_known_pose(
        &mut self,
        features: &SweepFeatures,
        pose: Isometry3<f64>,
        on_stage: impl FnMut(Stage),
    ) -> OdometryEstimate {
        self.known_poses = true;
        let estimate = self.locate_from(features, pose, on_stage);
        self.known_poses = false;
        estimate
    }

    /// Registers one sweep from a given prediction of its pose (another sensor's, or ground
    /// truth in tests) instead of the constant-velocity one: [`Self::locate_from`], then
    /// [`Self::update_maps`].
    pub fn register_from(
        &mut self,
        features: &SweepFeatures,
        prediction: Isometry3<f64>,
        mut on_stage: impl FnMut(Stage),
    ) -> OdometryEstimate {
        let estimate = self.locate_from(features, prediction, &mut on_stage);
        self.update_maps(features);
        on_stage(Stage::MapUpdate);
        estimate
    }

    /// The sweep's pose from a given prediction of it. The method's steps, in order: deskew by
    /// the predicted motion, align to the maps, deskew again by the motion measured and refine,
    /// restart the maps from the first sweep when it was taken in motion, and report the
    /// estimate. The maps grow from the sweep in [`Self::update_maps`], which must follow with the
    /// same features before the next sweep: a growth still pending then is dropped, and the
    /// maps miss that sweep. (The first sweep, which starts the maps, grows them here.)
    pub fn locate_from(
        &mut self,
        features: &SweepFeatures,
        prediction: Isometry3<f64>,
        mut on_stage: impl FnMut(Stage),
    ) -> OdometryEstimate {
        let time_ns = features.reference_ns;
        self.pending_growth = None;
        self.deskew(features, &self.velocity.clone());
        on_stage(Stage::Deskew);
        if features.coverage < self.config.solver.min_coverage {
            // A sliver of a turn: see `SolverConfig::min_coverage`. Before the maps exist it
            // does not start them; the next whole sweep does.
            on_stage(Stage::Align);
            if self.last.is_some() {
                self.last = Some((time_ns, prediction));
            }
            self.sweeps += 1;
            return OdometryEstimate {
                time_ns,
                pose: prediction,
                velocity: self.velocity,
                status: TrackingStatus::Lost,
                alignment: None,
            };
        }
        if self.last.is_none() || self.planes.is_empty() {
            on_stage(Stage::Align);
            return self.initialise(features, time_ns, prediction);
        }

        let mut alignment = self.align_seeded(features, &prediction);
        if alignment.edges + alignment.planes < self.config.solver.min_correspondences {
            on_stage(Stage::Align);
            // Hold the prediction; the maps do not grow from a sweep that did not match.
            self.last = Some((time_ns, prediction));
            self.sweeps += 1;
            return self.estimate(time_ns, prediction, TrackingStatus::Lost, alignment);
        }
        let interval = match self.last {
            Some((t, previous)) if time_ns > t => Some(((time_ns - t) as f64 * 1e-9, previous)),
            _ => None,
        };
        if let Some((interval, previous)) = interval {
            alignment = self.refine_with_measured_motion(features, alignment, &previous, interval);
            if let Some((first, first_pose)) = self.first_sweep.take() {
                alignment = self.restart_from_first_sweep(
                    features,
                    alignment,
                    (&first, &first_pose),
                    &previous,
                    interval,
                );
            }
        }
        on_stage(Stage::Align);

        let mapped_at = if self.known_poses {
            // Mapping with known poses: the alignment above only measures where the scan would
            // have put the sensor; the maps and the motion follow the given pose.
            if let Some((interval, previous)) = interval {
                self.velocity = motion(&previous, &prediction, interval);
            }
            self.deskew(features, &self.velocity.clone());
            prediction
        } else {
            alignment.pose
        };
        self.commit(time_ns, mapped_at, !self.known_poses);
        let status = if alignment.degenerate {
            TrackingStatus::Degenerate
        } else {
            TrackingStatus::Tracking
        };
        self.estimate(time_ns, alignment.pose, status, alignment)
    }

    /// The first sweep (or the first after the maps emptied) starts the maps at `pose`; one
    /// without features is lost.
    fn initialise(
        &mut self,
        features: &SweepFeatures,
        time_ns: u64,
        pose: Isometry3<f64>,
    ) -> OdometryEstimate {
        self.sweeps += 1;
        let status = if features.planes.is_empty() && features.edges.is_empty() {
            TrackingStatus::Lost
        } else {
            self.grow_maps(features, &pose);
            self.last = Some((time_ns, pose));
            self.first_sweep = (!self.known_poses).then(|| (features.clone(), pose));
            TrackingStatus::Initialising
        };
        OdometryEstimate {
            time_ns,
            pose,
            velocity: self.velocity,
            status,
            alignment: None,
        }
    }

    /// Associates, at the pose predicted for the sweep's first return, the edges and planes of
    /// the open sweep (`features`, with that return as their reference time, `sweep` its
    /// time) not associated yet, so that its alignment finds them associated (see
    /// [`EarlyCorrespondences`]): those picked before its close as they are, the rest with the
    /// closed sweep. What each gets depends on it, the maps and the motion so far only, so the
    /// alignment is the same however much of the sweep streamed in before its close. Only once
    /// the maps exist and between a sweep's [`Self::update_maps`] and the next sweep's
    /// alignment.
    pub fn associate_early(&mut self, sweep: u64, features: &SweepFeatures) {
        if self.last.is_none() || self.planes.is_empty() || self.pending_growth.is_some() {
            return;
        }
        let prediction = self.prediction(features.reference_ns);
        let skew = Deskew::new(&self.velocity, &self.deskew_cache);
        let maps = MapView {
            edges: &self.edges,
            planes: &self.planes,
            intensity: &self.intensity,
        };
        let edges = features.edges.iter().map(|f| (f.point, f));
        let planes = kept_planes(features, &self.config).map(|f| (f.point, f));
        self.early.associate(
            sweep,
            &prediction,
            (edges, planes),
            |f| skew.apply(f),
            maps,
            &self.config.solver,
        );
    }

    /// Correspondences made early for the open sweep so far.
    pub fn early_correspondences(&self) -> usize {
        self.early.len()
    }

    /// The sweep's first alignment from `from`, starting from the correspondences made early
    /// for its features, which it then forgets.
    fn align_seeded(&mut self, features: &SweepFeatures, from: &Isometry3<f64>) -> Alignment {
        if self.early.is_empty() {
            return self.align(from, Rounds::Full);
        }
        let edges: Vec<u32> = features.edges.iter().map(|f| f.point).collect();
        let planes: Vec<u32> = kept_planes(features, &self.config)
            .map(|f| f.point)
            .collect();
        self.early.seed(
            &mut self.correspondences,
            (&edges, &planes),
            &self.input,
            from,
            &self.config.solver,
        );
        self.early.clear();
        self.align(from, Rounds::Seeded)
    }

    /// Steps 3–5: aligns the deskewed features to the maps from `from`.
    fn align(&mut self, from: &Isometry3<f64>, rounds: Rounds) -> Alignment {
        let maps = MapView {
            edges: &self.edges,
            planes: &self.planes,
            intensity: &self.intensity,
        };
        let refine;
        let config = match rounds {
            Rounds::Full => {
                self.correspondences.clear();
                &self.config.solver
            }
            Rounds::Seeded => &self.config.solver,
            Rounds::Refine => {
                refine = crate::config::SolverConfig {
                    outer_iterations: 1,
                    ..self.config.solver.clone()
                };
                &refine
            }
        };
        align_with(from, &self.input, maps, config, &mut self.correspondences)
    }

    /// Deskews again with the motion the alignment measured and, if that moves the sweep's
    /// ends enough, refines the alignment: the prediction's deskew is off by the change in
    /// velocity over the sweep. The features are deskewed with the final motion when the maps
    /// grow from them or a keyframe takes them (see `input_stale`).
    fn refine_with_measured_motion(
        &mut self,
        features: &SweepFeatures,
        mut alignment: Alignment,
        previous: &Isometry3<f64>,
        interval: f64,
    ) -> Alignment {
        let measured = motion(previous, &alignment.pose, interval);
        if smear(&(measured - self.velocity)) > REDESKEW_THRESHOLD {
            // A sweep deskewed with a turn rate off by δ aligns between its smeared ends, so
            // the rate it measures has moved only part of δ: the re-deskew extrapolates the
            // rotation by ROTATION_EXTRAPOLATION of the change (the translation, which sparse
            // scenes constrain less, is taken as measured).
            let change = measured - self.velocity;
            let mut velocity = measured;
            let mut turn = velocity.fixed_rows_mut::<3>(0);
            turn += change.fixed_rows::<3>(0) * ROTATION_EXTRAPOLATION;
            self.deskew(features, &clamp_twist(velocity));
            // The correspondences of the first alignment still hold for points the new deskew
            // moved by millimetres: only those it moved farther are searched again.
            alignment = self.align(&alignment.pose, Rounds::Refine);
        }
        self.velocity = motion(previous, &alignment.pose, interval);
        self.input_stale = true;
        alignment
    }

    /// The second sweep measures the motion the first was taken with: the maps restart from
    /// the first sweep deskewed by it (see [`Self::restart_maps`]) and the second is aligned
    /// again. The motion measured against the smeared map is itself off (1.2 m/s for 1.5 in a
    /// room): each restart deskews the first sweep better, until the motion stops changing.
    fn restart_from_first_sweep(
        &mut self,
        features: &SweepFeatures,
        mut alignment: Alignment,
        (first, first_pose): (&SweepFeatures, &Isometry3<f64>),
        previous: &Isometry3<f64>,
        interval: f64,
    ) -> Alignment {
        let mut deskewed_with = Vector6::zeros();
        for _ in 0..MAX_RESTARTS {
            if smear(&(self.velocity - deskewed_with)) <= REDESKEW_THRESHOLD {
                break;
            }
            deskewed_with = self.velocity;
            self.restart_maps(first, first_pose);
            self.deskew(features, &self.velocity.clone());
            alignment = self.align(&alignment.pose, Rounds::Full);
            self.velocity = motion(previous, &alignment.pose, interval);
            self.deskew(features, &self.velocity.clone());
        }
        alignment
    }

    /// `pose` becomes the last one; the sweep is to grow the maps there (and to evict what lies
    /// beyond their radius now and then, with `evict`) in [`Self::update_maps`].
    fn commit(&mut self, time_ns: u64, pose: Isometry3<f64>, evict: bool) {
        self.last = Some((time_ns, pose));
        self.sweeps += 1;
        self.pending_growth = Some(PendingGrowth {
            pose,
            evict: evict && self.sweeps.is_multiple_of(EVICT_EVERY),
        });
    }

    /// Grows the maps from the sweep just located, whose `features` these are (see
    /// [`Self::locate_from`]); returns whether a growth was pending. Only the next sweep's
    /// alignment needs it, so it may run after the pose is published.
    pub fn update_maps(&mut self, features: &SweepFeatures) -> bool {
        let Some(PendingGrowth { pose, evict }) = self.pending_growth.take() else {
            return false;
        };
        self.grow_maps(features, &pose);
        if evict {
            let center = pose.translation.vector.cast::<f32>();
            let radius = self.config.local_map.radius;
            self.edges.retain_near(&center, radius);
            self.planes.retain_near(&center, radius);
            self.intensity.retain_near(&center, radius);
        }
        true
    }

    fn estimate(
        &self,
        time_ns: u64,
        pose: Isometry3<f64>,
        status: TrackingStatus,
        alignment: Alignment,
    ) -> OdometryEstimate {
        OdometryEstimate {
            time_ns,
            pose,
            velocity: self.velocity,
            status,
            alignment: Some(alignment),
        }
    }

    /// The sweep's calibrated returns in the map frame at `pose`, deskewed with the current
    /// velocity estimate (call right after [`Self::locate`] or [`Self::register`]), with their
    /// reflectivity.
    pub fn map_points<'a>(
        &'a self,
        features: &'a SweepFeatures,
        pose: &Isometry3<f64>,
    ) -> impl Iterator<Item = (Vector3<f32>, f32)> + 'a {
        place_calibrated(features, &self.velocity, pose, &self.deskew_cache)
    }

    /// Fills the alignment input with the features moved to the reference time, assuming the
    /// body twist `velocity` over the sweep.
    fn deskew(&mut self, features: &SweepFeatures, velocity: &Vector6<f64>) {
        self.input_stale = false;
        deskew_into(
            &mut self.input,
            features,
            velocity,
            &self.config,
            &self.deskew_cache,
        );
    }

    /// Whether the maps hold the first sweep as it came, smeared by whatever motion it was
    /// taken with: the next sweep that matches measures that motion and restarts them from it
    /// (see [`Self::restart_maps`]).
    pub fn awaits_motion(&self) -> bool {
        self.first_sweep.is_some()
    }

    /// An earlier sweep's features deskewed with the current velocity estimate: a keyframe of
    /// the first sweep, taken once the motion it was taken with is known.
    pub fn deskewed(&self, features: &SweepFeatures) -> AlignmentInput {
        let mut input = AlignmentInput::default();
        deskew_into(
            &mut input,
            features,
            &self.velocity,
            &self.config,
            &self.deskew_cache,
        );
        input
    }

    /// Aligns an earlier sweep's deskewed features to the maps as they are now, from `from`,
    /// leaving the odometry as it was: where the first sweep sits in the maps the next sweeps
    /// grew, rather than in the maps it alone made.
    pub fn place(&self, input: &AlignmentInput, from: &Isometry3<f64>) -> Alignment {
        let maps = MapView {
            edges: &self.edges,
            planes: &self.planes,
            intensity: &self.intensity,
        };
        align_with(
            from,
            input,
            maps,
            &self.config.solver,
            &mut Correspondences::default(),
        )
    }

    /// Starts the maps afresh from the first sweep, deskewed with the motion the second one
    /// measured. The first sweep had no motion to deskew with: taken by a robot already moving
    /// (a restart while driving, a capture started mid-run), it entered the maps smeared by a
    /// sweep's travel, 0.18 m at 1.8 m/s, and every later sweep matched to that smear kept its
    /// offset (160 s simulated yards: the return to the start 0.05–0.22 m off by odometry alone).
    fn restart_maps(&mut self, first: &SweepFeatures, pose: &Isometry3<f64>) {
        (self.edges, self.planes, self.intensity) = empty_maps(&self.config);
        self.mapped_at = None;
        self.deskew(first, &self.velocity.clone());
        self.grow_maps(first, pose);
    }

    /// Adds the sweep at `pose` to the maps if it was taken far enough from the last sweep that
    /// was (see [`crate::config::LocalMapConfig::update_distance`]); always while they are empty.
    fn grow_maps(&mut self, features: &SweepFeatures, pose: &Isometry3<f64>) {
        self.early.clear();
        let config = &self.config.local_map;
        if let Some(mapped) = self.mapped_at.filter(|_| !self.planes.is_empty()) {
            let moved = mapped.inverse() * pose;
            if moved.translation.vector.norm() < config.update_distance
                && moved.rotation.angle() < config.update_angle
            {
                return;
            }
        }
        self.mapped_at = Some(*pose);
        self.settle_input(features);
        for p in &self.input.edges {
            self.edges.insert((pose * Point3::from(*p)).coords.cast());
        }
        for p in &self.input.planes {
            self.planes.insert((pose * Point3::from(*p)).coords.cast());
        }
        self.intensity.insert_sweep(place_calibrated(
            features,
            &self.velocity,
            pose,
            &self.deskew_cache,
        ));
    }
}

/// Empty edge, plane and intensity maps (edge points at half the planes' spacing).
fn empty_maps(config: &OdometryConfig) -> (LocalMap, LocalMap, IntensityMap) {
    (
        LocalMap::new(&crate::config::LocalMapConfig {
            min_spacing: config.local_map.min_spacing * 0.5,
            ..config.local_map.clone()
        }),
        LocalMap::new(&config.local_map),
        IntensityMap::new(&config.intensity_map),
    )
}

/// Fills `input` with the features moved to the reference time, assuming the body twist
/// `velocity` over the sweep.
fn deskew_into(
    input: &mut AlignmentInput,
    features: &SweepFeatures,
    velocity: &Vector6<f64>,
    config: &OdometryConfig,
    cache: &DeskewCache,
) {
    let skew = Deskew::new(velocity, cache);
    input.edges.clear();
    input
        .edges
        .extend(features.edges.iter().map(|f| skew.apply(f)));
    // A plane point an angular error would move far off its surface (ground seen far away
    // at a grazing angle) says little about the pose, and in the map it would carry that
    // sweep's tilt to every later sweep matched to it: it is left out of both, and the
    // surface enters the map when the robot sees it closer.
    input.planes.clear();
    input
        .planes
        .extend(kept_planes(features, config).map(|f| skew.apply(f)));
    input.intensity.clear();
    if config.solver.use_intensity {
        input
            .intensity
            .extend(features.intensity.iter().map(|f| IntensityPoint {
                point: skew.apply(f),
                eta: f64::from(f.eta),
                normal: Vector3::from(f.normal).cast(),
            }));
    }
}

/// The planes of `features` an alignment takes, in order: judged at the firing position, so a
/// second deskew keeps the same points.
fn kept_planes<'a>(
    features: &'a SweepFeatures,
    config: &'a OdometryConfig,
) -> impl Iterator<Item = &'a Feature> + 'a {
    let min_weight = config.local_map.min_plane_weight;
    let solver = &config.solver;
    features.planes.iter().filter(move |f| {
        let p = Vector3::from(f.position).cast::<f64>();
        let normal = Vector3::from(f.normal).cast::<f64>();
        let lever_sq = if normal == Vector3::zeros() {
            p.norm_squared()
        } else {
            p.cross(&normal).norm_squared()
        };
        angular_weight(lever_sq, solver) >= min_weight
    })
}

/// The calibrated returns of a sweep, deskewed for the body twist `velocity` and placed in the
/// map frame at `pose`, with their reflectivity.
fn place_calibrated<'a>(
    features: &'a SweepFeatures,
    velocity: &Vector6<f64>,
    pose: &Isometry3<f64>,
    cache: &'a DeskewCache,
) -> impl Iterator<Item = (Vector3<f32>, f32)> + 'a {
    let mut place = Deskew::new(velocity, cache).into_placer(pose);
    features
        .calibrated
        .iter()
        .map(move |f| (place(f.position, f.dt), f.eta))
}

/// How far an alignment goes: from scratch, or one outer round reusing the correspondences.
#[derive(Debug, Clone, Copy)]
enum Rounds {
    Full,
    /// From scratch, but for the correspondences seeded from early ones.
    Seeded,
    Refine,
}

/// Restarts of the maps from the first sweep at most (see [`Odometry::restart_maps`]).
const MAX_RESTARTS: usize = 3;
/// A sweep lasts 0.1 s at 600 rpm: the span over which a velocity error smears it.
const SWEEP_SPAN_S: f64 = 0.1;
/// How far a sweep's ends move when its deskew's velocity changes by `delta`, m: the
/// translation over [`SWEEP_SPAN_S`], and the rotation over it at [`TYPICAL_RANGE_M`].
fn smear(delta: &Vector6<f64>) -> f64 {
    let rotation = Vector3::new(delta[0], delta[1], delta[2]).norm();
    let translation = Vector3::new(delta[3], delta[4], delta[5]).norm();
    (rotation * TYPICAL_RANGE_M + translation) * SWEEP_SPAN_S
}

/// The range of the bulk of an indoor sweep's features, m: the lever a turn rate's error acts
/// on (a rotation counted at 1 m let yaw accelerations under 60 °/s² go unrefined).
const TYPICAL_RANGE_M: f64 = 10.0;

/// The share of the turn rate's change the re-deskew extrapolates beyond the measured rate (0:
/// none; 1: the whole change again, right for a sweep that aligns exactly half-way). At 0.5, on
/// a 150 s simulated warehouse the heading error per sweep fell from 0.113° to 0.092° RMS (its
/// part proportional to yaw acceleration from 0.0047 to 0.0036 s²), and the mean drift over
/// nine runs (three scenarios) went from 0.296 % to 0.293 %; at 1, or extrapolating the
/// translation too, two 60 s yards drifted 0.32–1.1 % instead of 0.29 %.
const ROTATION_EXTRAPOLATION: f64 = 0.5;

/// Re-deskew and refine when the new velocity would move a sweep's ends by more than this
/// (metres, or radians × 1 m): half a plane residual's noise (`solver.plane_noise`). Measured
/// over nine runs (three scenarios, 60 and 160 s): at 5 mm drift averaged 0.286 %, at 1 cm
/// 0.286 % for 2 % fewer instructions, never refining 0.295 % (the warehouse's 0.244 → 0.286 %)
/// for 7 % fewer.
const REDESKEW_THRESHOLD: f64 = 0.01;

/// The body twist that takes `previous` to `pose` in `interval` s, within the bounds of a
/// plausible AGV (see [`clamp_twist`]).
fn motion(previous: &Isometry3<f64>, pose: &Isometry3<f64>, interval: f64) -> Vector6<f64> {
    clamp_twist(log(&(previous.inverse() * pose)) / interval)
}

fn clamp_twist(v: Vector6<f64>) -> Vector6<f64> {
    let omega = Vector3::new(v[0], v[1], v[2]);
    let upsilon = Vector3::new(v[3], v[4], v[5]);
    let omega = if omega.norm() > MAX_TURN_RATE {
        omega * (MAX_TURN_RATE / omega.norm())
    } else {
        omega
    };
    let upsilon = if upsilon.norm() > MAX_SPEED {
        upsilon * (MAX_SPEED / upsilon.norm())
    } else {
        upsilon
    };
    if !(omega.iter().chain(upsilon.iter()).all(|x| x.is_finite())) {
        return Vector6::zeros();
    }
    Vector6::new(omega.x, omega.y, omega.z, upsilon.x, upsilon.y, upsilon.z)
}

/// Moves a point fired `dt` from the reference time into the reference frame, for a constant
/// body twist: `p_ref = exp(dt·ξ)·p`. The exponential is cached per 0.1 ms of `dt` (a sweep has
/// at most a few thousand distinct buckets; at 1 rad/s and 2 m/s the bucketing moves a point at
/// 10 m by under 1 mm), in a [`DeskewCache`] the odometry keeps from call to call. `dt` is
/// negative for a sweep deskewed to its last return and positive for one deskewed to its first
/// (the features associated before the sweep closes): both are cached.
struct Deskew<'a> {
    twist: Vector6<f64>,
    cache: &'a DeskewCache,
    /// The last bucket looked up and its exponential: a sweep's returns come in firing order,
    /// a few dozen to a bucket, so most need no look-up in the cache.
    last: std::cell::Cell<Option<(i64, Isometry3<f64>)>>,
}

/// The exponentials of one twist per bucket of `dt`, kept between calls so that a deskew
/// neither allocates nor recomputes them while the twist is the same.
#[derive(Debug, Clone, Default)]
struct DeskewCache(std::cell::RefCell<DeskewTransforms>);

/// A twist and its exponentials `exp(ξ·b·δ)` for buckets b = 0, 1, 2, … (`ahead`) and b = 0,
/// −1, −2, … (`behind`), as far as the sweeps reach on either side of their reference time.
/// Along one twist the exponentials form a one-parameter group, `exp(ξ·(b + 1)·δ) =
/// exp(ξ·b·δ)·exp(ξ·δ)`: the table is filled outward by that product, a quaternion and a
/// vector per bucket, with an exact exponential every [`DESKEW_EXACT_EVERY`] buckets so that
/// rounding cannot build up (each product adds about 1e-16).
#[derive(Debug, Clone, Default)]
struct DeskewTransforms {
    twist: Vector6<f64>,
    ahead: Vec<Isometry3<f64>>,
    behind: Vec<Isometry3<f64>>,
}

impl DeskewTransforms {
    /// `exp(ξ·bucket·δ)` for this table's twist.
    fn at(&mut self, bucket: i64) -> Isometry3<f64> {
        let (table, sign) = if bucket >= 0 {
            (&mut self.ahead, 1.0)
        } else {
            (&mut self.behind, -1.0)
        };
        let wanted = bucket.unsigned_abs() as usize;
        while table.len() <= wanted {
            let b = table.len();
            let next = if b == 1 || b % DESKEW_EXACT_EVERY == 0 {
                exp(&(self.twist * (sign * b as f64 * DESKEW_BUCKET_S)))
            } else {
                table[b - 1] * table[1]
            };
            table.push(next);
        }
        table[wanted]
    }
}

const DESKEW_BUCKET_S: f64 = 1e-4;
/// The buckets cached on each side of the reference time: 0.4 s, a sweep at 2.5 Hz.
const DESKEW_BUCKETS: i64 = 4000;
/// See [`DeskewTransforms`].
const DESKEW_EXACT_EVERY: usize = 64;

impl<'a> Deskew<'a> {
    fn new(twist: &Vector6<f64>, cache: &'a DeskewCache) -> Self {
        Self {
            twist: *twist,
            cache,
            last: std::cell::Cell::new(None),
        }
    }

    fn apply(&self, f: &Feature) -> Vector3<f64> {
        self.apply_at(f.position, f.dt)
    }

    /// The return at `position`, fired `dt` s from the reference time.
    fn apply_at(&self, position: [f32; 3], dt: f32) -> Vector3<f64> {
        let p = Point3::new(
            f64::from(position[0]),
            f64::from(position[1]),
            f64::from(position[2]),
        );
        if self.twist == Vector6::zeros() {
            return p.coords;
        }
        (self.transform(dt) * p).coords
    }

    /// The bucket of `dt`, if the cache holds it; None for a `dt` beyond the cached buckets (or
    /// NaN), which is then left to `exp`.
    fn bucket(dt: f32) -> Option<i64> {
        let bucket = (f64::from(dt) / DESKEW_BUCKET_S).round();
        (bucket.abs() < DESKEW_BUCKETS as f64).then_some(bucket as i64)
    }

    /// The motion from `dt` s after the reference time to it (cached per bucket).
    fn transform(&self, dt: f32) -> Isometry3<f64> {
        let Some(bucket) = Self::bucket(dt) else {
            return exp(&(self.twist * f64::from(dt)));
        };
        if let Some((_, transform)) = self.last.get().filter(|&(last, _)| last == bucket) {
            return transform;
        }
        let mut cache = self.cache.0.borrow_mut();
        // Held for another twist: start over for this one.
        if cache.twist != self.twist {
            cache.twist = self.twist;
            cache.ahead.clear();
            cache.behind.clear();
        }
        let transform = cache.at(bucket);
        self.last.set(Some((bucket, transform)));
        transform
    }

    /// Returns deskewed and then placed by `to_map`, in single precision: per bucket the two
    /// motions are composed once into a matrix, so a return costs one affine product rather
    /// than two quaternion rotations (the intensity map takes tens of thousands a sweep).
    fn into_placer(
        self,
        to_map: &Isometry3<f64>,
    ) -> impl FnMut([f32; 3], f32) -> Vector3<f32> + 'a {
        let to_map = *to_map;
        let mut last: Option<(i64, Matrix3<f32>, Vector3<f32>)> = None;
        let compose = move |motion: Isometry3<f64>| {
            let placed = to_map * motion;
            (
                placed.rotation.to_rotation_matrix().matrix().cast::<f32>(),
                placed.translation.vector.cast::<f32>(),
            )
        };
        move |position, dt| {
            let bucket = Self::bucket(dt);
            let (rotation, translation) = match last {
                Some((b, r, t)) if Some(b) == bucket => (r, t),
                _ => {
                    let (r, t) = compose(self.transform(dt));
                    last = bucket.map(|b| (b, r, t));
                    (r, t)
                }
            };
            rotation * Vector3::from(position) + translation
        }
    }
}

/// Moves any return of a sweep to the sweep's reference instant for a constant body twist, as
/// the odometry moves its features (same exponential, same cache): for the points a caller
/// publishes beside the pose.
#[derive(Debug, Clone, Default)]
pub struct SweepDeskew {
    cache: DeskewCache,
}

impl SweepDeskew {
    /// The return at `position` (sensor frame at its firing), fired `dt` s from the reference
    /// time (≤ 0), in the sensor frame at the reference time, for the body twist `twist`
    /// ([ω, υ], rad/s and m/s).
    pub fn point(&self, twist: &Vector6<f64>, position: [f32; 3], dt: f32) -> Vector3<f64> {
        Deskew::new(twist, &self.cache).apply_at(position, dt)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::front_end::FrontEnd;
    use crate::scan::{Scan, ScanPoint};

    #[test]
    fn deskew_undoes_constant_motion() {
        // Moving at 1 m/s along x, turning at 0.5 rad/s: a static point seen 0.05 s before the
        // reference time, in the sensor frame of that instant, maps to where the reference frame
        // sees it.
        let twist = Vector6::new(0.0, 0.0, 0.5, 1.0, 0.0, 0.0);
        let world = Point3::new(5.0, 2.0, 0.3);
        let at = |t: f64| exp(&(twist * t));
        let seen_then = at(-0.05).inverse() * world;
        let f = Feature {
            position: [seen_then.x as f32, seen_then.y as f32, seen_then.z as f32],
            dt: -0.05,
            eta: 0.0,
            normal: [0.0; 3],
            point: 0,
        };
        let deskewed = Deskew::new(&twist, &DeskewCache::default()).apply(&f);
        let expected = at(0.0).inverse() * world;
        assert!(
            (deskewed - expected.coords).norm() < 1e-5,
            "{deskewed} vs {expected}"
        );
    }

    #[test]
    fn deskew_to_the_first_return_matches_the_exponential_both_sides() {
        // A sweep deskewed to its first return has returns fired after it (dt > 0): they go
        // through the same cache as those before a last-return reference, within its bucketing.
        let twist = Vector6::new(0.1, -0.2, 0.8, 1.5, 0.3, 0.0);
        let cache = DeskewCache::default();
        let skew = Deskew::new(&twist, &cache);
        let p = [12.0f32, -7.0, 1.5];
        for dt in [-0.0993f32, -0.031, 0.0, 0.00026, 0.047, 0.0999] {
            let exact = exp(&(twist * f64::from(dt))) * Point3::from(Vector3::from(p).cast());
            let cached = skew.apply_at(p, dt);
            assert!(
                (cached - exact.coords).norm() < 1e-3,
                "dt {dt}: {cached} vs {exact}"
            );
        }
        // Both sides were cached, each as far as its farthest bucket (−993 and 999).
        let cached = cache.0.borrow();
        assert_eq!((cached.ahead.len(), cached.behind.len()), (1000, 994));
    }

    #[test]
    fn the_table_built_by_products_is_the_exponential_at_every_bucket() {
        // A fast turn and drive, so that rounding in the products would show.
        let twist = Vector6::new(0.4, -0.3, 2.5, 3.0, -1.0, 0.2);
        let mut table = DeskewTransforms {
            twist,
            ..DeskewTransforms::default()
        };
        let p = Point3::new(60.0, -40.0, 5.0);
        let mut worst = 0f64;
        for bucket in (-3999..4000).rev() {
            let exact = exp(&(twist * (bucket as f64 * DESKEW_BUCKET_S)));
            worst = worst.max((table.at(bucket) * p - exact * p).norm());
        }
        assert!(worst < 1e-11, "{worst} m off at 72 m");
    }

    #[test]
    fn empty_sweeps_are_lost_and_hold_the_prediction() {
        let mut odometry = Odometry::new(&OdometryConfig::default());
        let empty = SweepFeatures {
            reference_ns: 1_000_000_000,
            ..SweepFeatures::default()
        };
        let e = odometry.register(&empty, |_| {});
        assert_eq!(e.status, TrackingStatus::Lost);
        assert!(e.pose.translation.vector.iter().all(|v| v.is_finite()));
    }

    /// A VLP-16 sweep (16 rings from −15° to 15°, 1800 columns, 55.296 µs apart) ending at
    /// `end_ns`, of a static scene given as the range along each ray (`None`: no return).
    fn synthetic_sweep(
        end_ns: u64,
        range: impl Fn(&Vector3<f32>) -> Option<f32>,
    ) -> Vec<ScanPoint> {
        sweep_in_motion(end_ns, |ray, _| range(ray))
    }

    /// The same for a scene that changes over the sweep: `range(ray, t)` at `t` s before
    /// `end_ns`.
    fn sweep_in_motion(
        end_ns: u64,
        range: impl Fn(&Vector3<f32>, f32) -> Option<f32>,
    ) -> Vec<ScanPoint> {
        let mut points = Vec::new();
        let start = end_ns - 1799 * 55_296;
        for c in 0..1800u64 {
            let az = -(c as f32) * 0.2f32.to_radians();
            let before_end = (1799 - c) as f32 * 55.296e-6;
            for ring in 0..16u8 {
                let el = (-15.0 + 2.0 * f32::from(ring)).to_radians();
                let ray = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
                if let Some(r) = range(&ray, before_end) {
                    let p = ray * r;
                    points.push(ScanPoint {
                        position: [p.x, p.y, p.z],
                        time_ns: start + c * 55_296,
                        reflectivity: 40,
                        ring,
                    });
                }
            }
        }
        points
    }

    /// A front end and an odometry, fed one VLP-16 sweep at a time.
    struct Rig {
        front_end: FrontEnd,
        odometry: Odometry,
        features: SweepFeatures,
    }

    impl Rig {
        fn new(config: &OdometryConfig) -> Self {
            Self {
                front_end: FrontEnd::new(config),
                odometry: Odometry::new(config),
                features: SweepFeatures::default(),
            }
        }

        fn feed(&mut self, points: &[ScanPoint], end_ns: u64) -> OdometryEstimate {
            self.select(points, end_ns);
            self.odometry.register(&self.features, |_| {})
        }

        fn select(&mut self, points: &[ScanPoint], end_ns: u64) {
            let scan = Scan {
                points,
                rings: 16,
                reference_ns: end_ns,
            };
            self.front_end.process(&scan, &mut self.features);
        }

        /// [`Self::feed`], the sweep's edges and planes not associated early associated first,
        /// as the daemon does.
        fn feed_rest(&mut self, points: &[ScanPoint], end_ns: u64) -> OdometryEstimate {
            self.select(points, end_ns);
            let mut rest = SweepFeatures::default();
            (self.front_end).features_from_start(points, &self.features, &mut rest);
            self.odometry.associate_early(points[0].time_ns, &rest);
            self.odometry.register(&self.features, |_| {})
        }
    }

    /// Runs `sweeps` copies of a static scene through the front end and the odometry.
    fn track(sweeps: usize, range: impl Fn(&Vector3<f32>) -> Option<f32>) -> Vec<OdometryEstimate> {
        let mut rig = Rig::new(&OdometryConfig::default());
        (1..=sweeps as u64)
            .map(|k| {
                let end_ns = 1_000_000_000 + k * 100_000_000;
                let points = synthetic_sweep(end_ns, &range);
                rig.feed(&points, end_ns)
            })
            .collect()
    }

    /// Finite, and not walking off: a static scene's biases may shift the pose by millimetres
    /// (a plane fitted through a curved neighbourhood), never by a runaway.
    fn assert_holds_still(estimates: &[OdometryEstimate]) {
        for e in estimates {
            let t = e.pose.translation.vector;
            let angle = e.pose.rotation.angle();
            assert!(
                t.iter().all(|v| v.is_finite()) && angle.is_finite(),
                "{e:?}"
            );
            assert!(t.norm() < 0.03 && angle < 0.002, "ran away: {e:?}");
            assert!(e.velocity.iter().all(|v| v.is_finite()), "{e:?}");
        }
    }

    /// The range along `ray` inside a 12 × 8 × 4 m box room, the sensor 1 m above its floor.
    fn room(ray: &Vector3<f32>) -> Option<f32> {
        room_from(&Vector3::zeros(), ray)
    }

    /// The same from `origin`, relative to the room's centre at the sensor's height.
    fn room_from(origin: &Vector3<f32>, ray: &Vector3<f32>) -> Option<f32> {
        let t = |d: f32, c: f32| (c.abs() > 1e-6 && d / c > 0.0).then_some(d / c);
        [
            t(6.0 - origin.x, ray.x),
            t(-6.0 - origin.x, ray.x),
            t(4.0 - origin.y, ray.y),
            t(-4.0 - origin.y, ray.y),
            t(-1.0 - origin.z, ray.z),
            t(3.0 - origin.z, ray.z),
        ]
        .into_iter()
        .flatten()
        .min_by(f32::total_cmp)
    }

    #[test]
    fn a_parked_sensor_does_not_map_what_moves_around_it() {
        // The room, and from the fourth sweep on the face of a crate (2 m wide, 1.5 m tall)
        // 2.5 m ahead: something moving past a robot that stands still.
        let with_crate = |ray: &Vector3<f32>| {
            let wall = room(ray)?;
            let hit = (ray.x > 1e-6).then(|| 2.5 / ray.x).filter(|&r| {
                let q = ray * r;
                q.y.abs() < 1.0 && q.z < 0.5 && r < wall
            });
            Some(hit.unwrap_or(wall))
        };
        let run = |config: OdometryConfig| {
            let mut rig = Rig::new(&config);
            let mut sizes = Vec::new();
            for k in 1..=6u64 {
                let end_ns = 1_000_000_000 + k * 100_000_000;
                let points = if k < 4 {
                    synthetic_sweep(end_ns, room)
                } else {
                    synthetic_sweep(end_ns, with_crate)
                };
                let e = rig.feed(&points, end_ns);
                assert_ne!(e.status, TrackingStatus::Lost, "{e:?}");
                sizes.push(rig.odometry.map_sizes());
            }
            sizes
        };
        let gated = run(OdometryConfig::default());
        assert!(gated.iter().all(|s| *s == gated[0]), "{gated:?}");
        // Without the gate the crate's face enters the maps: the test would notice.
        let mut ungated = OdometryConfig::default();
        ungated.local_map.update_distance = 0.0;
        ungated.local_map.update_angle = 0.0;
        let ungated = run(ungated);
        assert!(ungated[5].1 > ungated[2].1, "{ungated:?}");
    }

    #[test]
    fn a_sliver_of_a_turn_is_lost_at_the_prediction_and_leaves_the_maps_alone() {
        // Driving at 1.5 m/s along the room; after six whole sweeps the stream stops 18° into
        // the seventh (a sensor falling silent, a capture's end), then a whole sweep follows.
        let speed = 1.5f32;
        let sweep_at = |k: u64| {
            let end_ns = 1_000_000_000 + k * 100_000_000;
            let end_x = -2.0 + speed * 0.1 * k as f32;
            let points = sweep_in_motion(end_ns, |ray, before_end| {
                room_from(&Vector3::new(end_x - speed * before_end, 0.0, 0.0), ray)
            });
            (end_ns, points)
        };
        let run = |config: &OdometryConfig| {
            let mut rig = Rig::new(config);
            for k in 0..6u64 {
                let (end_ns, points) = sweep_at(k);
                assert_ne!(rig.feed(&points, end_ns).status, TrackingStatus::Lost);
            }
            let maps = rig.odometry.map_sizes();
            let (_, whole) = sweep_at(6);
            let sliver: Vec<ScanPoint> = whole.iter().copied().take(90 * 16).collect();
            let end_ns = sliver.last().expect("returns").time_ns;
            let sliver_estimate = rig.feed(&sliver, end_ns);
            assert!(
                (rig.features.coverage - 0.05).abs() < 0.001,
                "{}",
                rig.features.coverage
            );
            let maps_after = rig.odometry.map_sizes();
            let (end_ns, points) = sweep_at(7);
            let next = rig.feed(&points, end_ns);
            (sliver_estimate, maps == maps_after, next)
        };
        let (sliver, maps_kept, next) = run(&OdometryConfig::default());
        assert_eq!(sliver.status, TrackingStatus::Lost, "{sliver:?}");
        assert!(sliver.alignment.is_none());
        assert!(maps_kept);
        // The prediction at the sliver's last return: where the robot was.
        let truth_x = |t_ns: u64| f64::from(speed) * (t_ns - 1_000_000_000) as f64 * 1e-9;
        assert!(
            (sliver.pose.translation.x - truth_x(sliver.time_ns)).abs() < 0.01,
            "{sliver:?}"
        );
        // The next whole sweep tracks on from there.
        assert_ne!(next.status, TrackingStatus::Lost, "{next:?}");
        assert!(
            (next.pose.translation.x - truth_x(next.time_ns)).abs() < 0.02,
            "{next:?}"
        );
        // Without the rule the sliver is aligned (and grows the maps).
        let mut ungated = OdometryConfig::default();
        ungated.solver.min_coverage = 0.0;
        let (sliver, _, _) = run(&ungated);
        assert_ne!(sliver.status, TrackingStatus::Lost, "{sliver:?}");
    }

    #[test]
    fn a_sensor_started_in_motion_maps_its_first_sweep_unsmeared() {
        // Already driving at 1.5 m/s along the room when the odometry starts: its first sweep
        // is smeared by 0.15 m until the second measures the motion.
        let speed = 1.5f32;
        let mut rig = Rig::new(&OdometryConfig::default());
        let mut errors = Vec::new();
        for k in 0..8u64 {
            let end_ns = 1_000_000_000 + k * 100_000_000;
            let end_x = -2.0 + speed * 0.1 * k as f32;
            let points = sweep_in_motion(end_ns, |ray, before_end| {
                room_from(&Vector3::new(end_x - speed * before_end, 0.0, 0.0), ray)
            });
            let e = rig.feed(&points, end_ns);
            // The odometry's frame is the first sweep's sensor frame at its end.
            let truth = f64::from(speed) * 0.1 * k as f64;
            errors.push((e.pose.translation.x - truth).abs());
        }
        // Without the restart: 3–7 cm off from the second sweep on.
        assert!(errors.iter().all(|e| *e < 0.02), "{errors:?}");
    }

    /// The features of sweep `k` (0.1 s apart) of a sensor driving along the room's x axis at
    /// `speed` m/s from `start_x`.
    fn driving_through_the_room(
        front_end: &mut FrontEnd,
        k: u64,
        start_x: f32,
        speed: f32,
        out: &mut SweepFeatures,
    ) {
        let (points, end_ns) = sweep_through_the_room(k, start_x, speed);
        let scan = Scan {
            points: &points,
            rings: 16,
            reference_ns: end_ns,
        };
        front_end.process(&scan, out);
    }

    /// Sweep `k` (and its end) of a sensor driving along +x through the room at `speed`, from
    /// `start_x` at the end of sweep 0.
    fn sweep_through_the_room(k: u64, start_x: f32, speed: f32) -> (Vec<ScanPoint>, u64) {
        let end_ns = 1_000_000_000 + k * 100_000_000;
        let end_x = start_x + speed * 0.1 * k as f32;
        let points = sweep_in_motion(end_ns, |ray, before_end| {
            room_from(&Vector3::new(end_x - speed * before_end, 0.0, 0.0), ray)
        });
        (points, end_ns)
    }

    #[test]
    fn correspondences_made_before_the_close_track_as_those_made_after() {
        // One odometry gets each sweep's early picks associated as the sweep streams in, a
        // packet's worth at a time, and the rest at the close; another all of them at the
        // close: the same poses, bit for bit. A third associates at the close as it aligns:
        // the early correspondences are made at another reference time (the sweep's first
        // return), so the poses may differ in the last bits, not more.
        let config = OdometryConfig::default();
        let mut plain = Rig::new(&config);
        let mut closed = Rig::new(&config);
        let mut early = Rig::new(&config);
        let mut picked = SweepFeatures::default();
        for k in 0..12u64 {
            let (points, end_ns) = sweep_through_the_room(k, -3.0, 1.5);
            let expected = plain.feed(&points, end_ns);
            let at_close = closed.feed_rest(&points, end_ns);

            early.front_end.begin(16);
            let mut sectors = 0;
            for end in (384..points.len() - 384).step_by(384) {
                early.front_end.stream(&points[end - 384..end]);
                if early.front_end.sectors_picked() > sectors {
                    sectors = early.front_end.sectors_picked();
                    early.front_end.early_features(&points[..end], &mut picked);
                    early.odometry.associate_early(points[0].time_ns, &picked);
                }
            }
            let made = early.odometry.early_correspondences();
            let got = early.feed_rest(&points, end_ns);
            if k >= 2 {
                assert!(made > 100, "sweep {k}: {made} made early");
            }
            assert_eq!(got.pose, at_close.pose, "sweep {k}");
            let apart = got.pose.inverse() * expected.pose;
            assert!(
                apart.translation.vector.norm() < 1e-3 && apart.rotation.angle() < 1e-4,
                "sweep {k}: {apart}"
            );
            assert_eq!(got.status, expected.status, "sweep {k}");
        }
    }

    #[test]
    fn the_first_keyframe_waits_for_the_motion_and_enters_unsmeared() {
        // The tracker's side of the start in motion: localising, the first sweep's keyframe
        // comes with the second sweep, deskewed by the motion the second measured; mapping,
        // five sweeps later, placed in the maps they grew.
        use crate::backend::config::KeyframeConfig;
        use crate::tracker::Tracker;
        let speed = 1.5f32;
        let config = OdometryConfig::default();
        let keyframes = KeyframeConfig::default();
        for (mut tracker, given_with) in [
            (Tracker::localising(&config, &keyframes), 1),
            (Tracker::new(&config, Some(&keyframes)), 6),
        ] {
            let mut front_end = FrontEnd::new(&config);
            let mut features = SweepFeatures::default();
            let mut taken = Vec::new();
            for k in 0..8u64 {
                driving_through_the_room(&mut front_end, k, -2.0, speed, &mut features);
                taken.push(tracker.track(&features, None, |_| {}).keyframe);
            }
            let given: Vec<usize> = (0..taken.len()).filter(|&k| taken[k].is_some()).collect();
            assert_eq!(given[0], given_with, "{given:?}");
            let first = taken[given_with].as_ref().expect("given");
            assert_eq!(first.time_ns, 1_000_000_000);
            // The odometry's frame is the first sweep's sensor frame at its end.
            let moved = log(&first.odom_pose);
            assert!(moved.norm() < 0.01, "{}", first.odom_pose);
            // The room's −x wall, 4 m behind the sensor at the sweep's end, seen half a sweep
            // earlier from 7.5 cm further back: smeared it would sit at −3.925 m.
            let wall: Vec<f32> = first
                .planes
                .iter()
                .filter(|p| p[0] < -3.5 && p[1].abs() < 3.0 && p[2].abs() < 0.8)
                .map(|p| p[0])
                .collect();
            assert!(wall.len() > 20, "{}", wall.len());
            let mean = wall.iter().sum::<f32>() / wall.len() as f32;
            assert!((mean + 4.0).abs() < 0.02, "{mean}");
        }
    }

    #[test]
    fn the_pose_comes_before_the_map_update_and_changes_nothing() {
        // The tracker stops at each sweep's pose and grows the maps after: its estimates are
        // those of the odometry registering each sweep whole, and the first keyframe is placed
        // in the maps as the sweep that places it leaves them.
        use crate::backend::config::KeyframeConfig;
        use crate::tracker::Tracker;
        let speed = 1.5f32;
        // Every sweep grows the maps.
        let mut config = OdometryConfig::default();
        config.local_map.update_distance = 0.0;
        config.local_map.update_angle = 0.0;
        let mut tracker = Tracker::new(&config, Some(&KeyframeConfig::default()));
        let mut reference = Odometry::new(&config);
        let mut front_end = FrontEnd::new(&config);
        let sweep = |k: u64, front_end: &mut FrontEnd| {
            let mut features = SweepFeatures::default();
            driving_through_the_room(front_end, k, -3.0, speed, &mut features);
            features
        };
        let first = sweep(0, &mut front_end);
        let mut first_deskewed = None;
        let mut keyframes = Vec::new();
        for k in 0..24u64 {
            let features = if k == 0 {
                first.clone()
            } else {
                sweep(k, &mut front_end)
            };
            let tracked = tracker.track_pose(&features, None, |_| {});
            let expected = reference.register(&features, |_| {});
            assert_eq!(tracked.estimate, expected, "sweep {k}");
            if let Some(keyframe) = tracked.keyframe {
                keyframes.push((k, keyframe));
            }
            tracker.update_maps(&features);
            assert!(!tracker.update_maps(&features), "grown twice");
            if k == 1 {
                // The first sweep deskewed by the motion the second measured, as the tracker
                // keeps it.
                first_deskewed = Some(reference.deskewed(&first));
            }
            if keyframes.len() == 1 && keyframes[0].0 == k {
                let input = first_deskewed.as_ref().expect("after the second sweep");
                let placed = reference.place(input, &Isometry3::identity());
                assert_eq!(keyframes[0].1.odom_pose, placed.pose, "sweep {k}");
            }
        }
        assert!(keyframes.len() >= 2, "{}", keyframes.len());
        // A growth left out is dropped with the next sweep, which still tracks.
        let features = sweep(24, &mut front_end);
        tracker.track_pose(&features, None, |_| {});
        let features = sweep(25, &mut front_end);
        let e = tracker.track_pose(&features, None, |_| {}).estimate;
        assert_ne!(e.status, TrackingStatus::Lost, "{e:?}");
        assert!(tracker.update_maps(&features));
    }

    #[test]
    fn an_empty_sweep_after_tracking_is_lost_and_holds_the_prediction() {
        // A room, then nothing: the sensor is blinded.
        let config = OdometryConfig::default();
        let mut rig = Rig::new(&config);
        let mut estimates: Vec<OdometryEstimate> = Vec::new();
        for k in 1..=6u64 {
            let end_ns = 1_000_000_000 + k * 100_000_000;
            let points = if k < 5 {
                synthetic_sweep(end_ns, room)
            } else {
                Vec::new()
            };
            let e = rig.feed(&points, end_ns);
            if k < 5 {
                assert_ne!(e.status, TrackingStatus::Lost, "{e:?}");
            } else {
                assert_eq!(e.status, TrackingStatus::Lost, "{e:?}");
                // The pose is the constant-velocity prediction, the velocity unchanged.
                let before = &estimates[estimates.len() - 1];
                let predicted = before.pose * exp(&(before.velocity * 0.1));
                assert!(
                    log(&(predicted.inverse() * e.pose)).norm() < 1e-9,
                    "{e:?} vs {predicted}"
                );
                assert_eq!(e.velocity, before.velocity);
            }
            estimates.push(e);
        }
        assert_holds_still(&estimates);
    }

    /// A static scene geometry cannot pin down: after the first sweep every one is reported
    /// degenerate (or lost), and the pose stays put.
    fn assert_reported_and_held(range: impl Fn(&Vector3<f32>) -> Option<f32>) {
        let estimates = track(8, range);
        assert_eq!(estimates[0].status, TrackingStatus::Initialising);
        for e in &estimates[1..] {
            assert!(
                matches!(e.status, TrackingStatus::Degenerate | TrackingStatus::Lost),
                "{e:?}"
            );
        }
        assert_holds_still(&estimates);
    }

    #[test]
    fn a_sweep_of_one_plane_is_degenerate_and_holds_the_prediction() {
        // Only a floor 1.5 m below: height, roll and pitch are seen, x, y and yaw are not.
        assert_reported_and_held(|ray| (ray.z < -0.05).then(|| -1.5 / ray.z));
    }

    #[test]
    fn a_sweep_at_one_range_is_degenerate_and_holds_the_prediction() {
        // Every return 5 m away: a sphere about the sensor, on which any rotation fits.
        assert_reported_and_held(|_| Some(5.0));
    }

    #[test]
    fn clamp_rejects_nonsense_twists() {
        assert_eq!(clamp_twist(Vector6::repeat(f64::NAN)), Vector6::zeros());
        let fast = clamp_twist(Vector6::new(0.0, 0.0, 10.0, 100.0, 0.0, 0.0));
        assert!((fast[2] - MAX_TURN_RATE).abs() < 1e-12 && (fast[3] - MAX_SPEED).abs() < 1e-12);
    }
}

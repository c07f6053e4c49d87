//! The odometry stage: each sweep's features registered by core's `Tracker`, keyframes handed
//! to the back end (or the localiser) and its corrections applied, the run's map grown when no
//! back end rebuilds it, and the estimate passed on to the publishing end with its timing.

use std::time::Instant;

use crossbeam_channel::{Receiver, Sender};
use glint_core::odometry::{OdometryEstimate, Stage as OdometryStep, TrackingStatus};
use glint_core::tracker::{MapFix, Tracker, TrackerEvent};
use glint_core::trajectory::{interpolate, StampedPose};
use glint_core::world_map::WorldMap;
use nalgebra::{Isometry3, Vector3};

use super::backend_link::{BackEndLink, Lockstep};
use super::front_end::ToOdometry;
use super::health::{recv_beating, send_beating, Heartbeats, Stage};
use super::sweeps::LabelledSweep;

/// A sweep's estimate on its way to the publisher.
pub(super) struct Estimated {
    /// On sensor time (see `glint_driver::clock`): differences are the sensor's own.
    pub(super) estimate: OdometryEstimate,
    /// What turns the estimate's sensor time into its stamp.
    pub(super) stamp_offset_ns: i64,
    pub(super) quality: f32,
    pub(super) received: Instant,
    pub(super) stage_ms: StageTimes,
    pub(super) counts: FeatureCounts,
    pub(super) departure: Option<Vector3<f64>>,
    /// `map ← odom` as of this sweep.
    pub(super) map_from_odom: Isometry3<f64>,
    /// The correction changed with this sweep.
    pub(super) loop_closed: bool,
    /// How far the map pose is to be trusted.
    pub(super) map_fix: MapFix,
    /// Every return, labelled, when the `sweep` service is on.
    pub(super) returns: Option<LabelledSweep>,
}

/// Time one sweep spent in each step, ms.
#[derive(Debug, Clone, Copy)]
pub(super) struct StageTimes {
    /// Calibration and features.
    pub(super) front_end: f64,
    /// Prediction and deskew.
    pub(super) deskew: f64,
    /// Scan-to-map alignment.
    pub(super) align: f64,
    /// Map update, of the sweep before: it runs after that sweep's pose is sent on, off the
    /// latency path.
    pub(super) map_update: f64,
}

impl StageTimes {
    /// Front end and odometry together.
    pub(super) fn total(&self) -> f64 {
        self.front_end + self.deskew + self.align + self.map_update
    }
}

/// One sweep's features.
#[derive(Debug, Clone, Copy)]
pub(super) struct FeatureCounts {
    pub(super) edges: usize,
    pub(super) planes: usize,
    pub(super) intensity: usize,
}

/// What the odometry leaves at the end of a run.
pub(super) struct OdometryOutcome {
    /// The run's map grown from the odometry's poses, when asked for and no back end rebuilds
    /// it.
    pub(super) world: Option<WorldMap>,
    /// Local map sizes (edge points, plane points, intensity cells).
    pub(super) map_sizes: (usize, usize, usize),
    /// Keyframes the back end could not take in time (live).
    pub(super) keyframes_dropped: u64,
}

/// The odometry's thread: registers each sweep until the front end is gone.
pub(super) fn run_odometry(
    mut tracker: Tracker,
    known: Option<Vec<StampedPose>>,
    map_voxel: Option<f32>,
    mut back_end: Option<BackEndLink>,
    input: &Receiver<ToOdometry>,
    output: &Sender<Estimated>,
    heartbeats: &Heartbeats,
) -> OdometryOutcome {
    let mut world = map_voxel.map(WorldMap::new);
    // The last sweep's map update, ms: reported with the next sweep, as it runs after the pose.
    let mut map_update_ms = 0.0;
    while let Some(message) = recv_beating(input, heartbeats, Stage::Odometry) {
        let mut featured = match message {
            ToOdometry::Picked { sweep, features } => {
                tracker.associate_early(sweep, &features);
                continue;
            }
            ToOdometry::Closed(featured) => featured,
        };
        let returns = featured.returns.take();
        let features = &featured.features;
        let start = Instant::now();
        // When each step ended.
        let (mut deskewed, mut aligned) = (start, start);
        let hook = |step| match step {
            OdometryStep::Deskew => deskewed = Instant::now(),
            OdometryStep::Align => aligned = Instant::now(),
            OdometryStep::MapUpdate => {}
        };
        let known_pose = known
            .as_deref()
            .and_then(|gt| interpolate(gt, features.reference_ns));
        let tracked = tracker.pose_of(features, known_pose, hook);
        match tracked.event {
            Some(TrackerEvent::Resumed { quality, cost }) => {
                tracing::info!(quality, cost, "tracking resumed after a gap in the data");
            }
            Some(TrackerEvent::Restarted { epoch }) => tracing::warn!(
                epoch,
                "sweeps stopped matching the odometry's map (moved, or blinded): \
                 odometry restarted, relocalising"
            ),
            Some(TrackerEvent::LostAfterGap { quality, cost }) => tracing::warn!(
                quality,
                cost,
                "after a gap in the data the scan does not match the map: lost \
                 (trying each sweep from the last good pose)"
            ),
            None => {}
        }
        let estimate = tracked.estimate;
        tracing::debug!(
            quality = tracked.quality,
            cost = tracked.cost,
            "sweep registered"
        );
        let previous_correction = tracker.correction();
        // Live, a keyframe is made and handed over once the pose is on its way (below); in
        // lockstep before, as the answer it brings back applies from this sweep.
        let keyframe_after = back_end
            .as_ref()
            .is_some_and(|link| link.lockstep == Lockstep::Off)
            .then_some(estimate.clone());
        if let Some(link) = back_end.as_mut() {
            if link.lockstep == Lockstep::Off {
                for c in link.arrived() {
                    tracker.apply(&c);
                }
            } else if let Some(keyframe) = tracker.keyframe_of(features, &estimate) {
                if let Some(c) = link.offer(tracker.epoch(), keyframe, heartbeats) {
                    tracker.apply(&c);
                }
            }
        }
        let map_fix = tracker.map_fix(&estimate);
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        let (status, pose) = (estimate.status, estimate.pose);
        let message = Estimated {
            stamp_offset_ns: featured.stamp_offset_ns,
            map_from_odom: tracker.correction(),
            loop_closed: tracker.correction() != previous_correction,
            map_fix,
            quality: tracked.quality,
            received: featured.received,
            stage_ms: StageTimes {
                front_end: featured.front_end_ms,
                deskew: ms(start, deskewed),
                align: ms(deskewed, aligned),
                map_update: map_update_ms,
            },
            counts: FeatureCounts {
                edges: features.edges.len(),
                planes: features.planes.len(),
                intensity: features.intensity.len(),
            },
            departure: tracked.departure,
            estimate,
            returns,
        };
        if send_beating(output, message, heartbeats, Stage::Odometry).is_err() {
            break;
        }
        // The pose is on its way; what only the next sweep needs follows.
        if let (Some(link), Some(estimate)) = (back_end.as_mut(), keyframe_after) {
            if let Some(keyframe) = tracker.keyframe_of(features, &estimate) {
                link.offer(tracker.epoch(), keyframe, heartbeats);
            }
        }
        let grown = Instant::now();
        tracker.update_maps(features);
        map_update_ms = grown.elapsed().as_secs_f64() * 1e3;
        if let Some(map) = world.as_mut() {
            if status != TrackingStatus::Lost {
                for (p, eta) in tracker.map_points(features, &pose) {
                    map.insert(&p, eta);
                }
            }
        }
    }
    OdometryOutcome {
        world,
        map_sizes: tracker.odometry().map_sizes(),
        keyframes_dropped: back_end.map_or(0, |l| l.dropped),
    }
}

//! The link between the odometry and the back end (loop closure and pose-graph optimisation)
//! or, localising in a saved site map, the localiser in its place: keyframes one way, `map ←
//! odom` corrections the other, and the two threads that answer. In a replay the odometry takes
//! the answers in lockstep, so a correction applies from a sweep fixed by the data; live it never
//! waits.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};
use glint_core::backend::config::BackEndConfig;
use glint_core::backend::keyframe::Keyframe;
use glint_core::backend::{BackEnd, BackEndStage, SiteMapHeader};
use glint_core::config::IntensityMapConfig;
use glint_core::extension::{ExtensionReport, MapExtension};
use glint_core::localiser::{Localiser, MapState};
use glint_core::tracker::Correction;
use glint_ipc::InitialPoseSubscriber;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::health::{recv_beating, send_beating, Heartbeats, Stage};
use super::map_updates::MapOutlet;
use super::SlamSummary;

/// Keyframes allowed to wait for the back end (live: more are dropped, counted).
pub(super) const BACK_END_QUEUE: usize = 8;

/// How the odometry waits for the back end's (or the localiser's) answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Lockstep {
    /// Live: never; the answers that arrived apply, in order, from whichever sweep follows.
    Off,
    /// Replays: each keyframe's answer is awaited when the next keyframe is handed over, so a
    /// correction applies from a sweep fixed by the data while the back end works in parallel
    /// with the odometry for a keyframe interval (about 1 m of travel).
    NextKeyframe,
    /// Replays localising: each keyframe's answer is awaited at once, so a (re)localisation
    /// applies from the keyframe that made it.
    Immediate,
}

/// The odometry's end of the back end or the localiser.
pub(super) struct BackEndLink {
    keyframes: Sender<(u64, Keyframe)>,
    corrections: Receiver<Correction>,
    pub(super) lockstep: Lockstep,
    /// A keyframe was handed over and its answer not yet taken (`NextKeyframe`).
    pending: bool,
    /// Keyframes the back end could not take in time (live).
    pub(super) dropped: u64,
}

impl BackEndLink {
    pub(super) fn new(
        keyframes: Sender<(u64, Keyframe)>,
        corrections: Receiver<Correction>,
        lockstep: Lockstep,
    ) -> Self {
        Self {
            keyframes,
            corrections,
            lockstep,
            pending: false,
            dropped: 0,
        }
    }

    /// Hands a keyframe of odometry epoch `epoch` over. In lockstep, returns the answer due.
    pub(super) fn offer(
        &mut self,
        epoch: u64,
        keyframe: Keyframe,
        heartbeats: &Heartbeats,
    ) -> Option<Correction> {
        match self.lockstep {
            Lockstep::NextKeyframe => {
                let mut answer = None;
                if self.pending {
                    answer = Some(recv_beating(
                        &self.corrections,
                        heartbeats,
                        Stage::Odometry,
                    )?);
                }
                self.pending = send_beating(
                    &self.keyframes,
                    (epoch, keyframe),
                    heartbeats,
                    Stage::Odometry,
                )
                .is_ok();
                answer
            }
            Lockstep::Immediate => {
                send_beating(
                    &self.keyframes,
                    (epoch, keyframe),
                    heartbeats,
                    Stage::Odometry,
                )
                .ok()?;
                recv_beating(&self.corrections, heartbeats, Stage::Odometry)
            }
            Lockstep::Off => {
                if let Err(TrySendError::Full(_)) = self.keyframes.try_send((epoch, keyframe)) {
                    self.dropped += 1;
                    tracing::warn!(
                        dropped = self.dropped,
                        "the back end is behind: keyframe dropped"
                    );
                }
                None
            }
        }
    }

    /// The answers sent since the last call, in order (live): each is applied, so a
    /// relocalisation's jump is not lost behind a later answer.
    pub(super) fn arrived(&self) -> impl Iterator<Item = Correction> + '_ {
        self.corrections.try_iter()
    }
}

/// Writes the back end's site map (mapping).
#[derive(Clone)]
pub(super) struct MapSaver {
    pub(super) path: PathBuf,
    /// Live: also this often while running.
    pub(super) every: Option<Duration>,
    pub(super) header: SiteMapHeader,
    pub(super) intensity: IntensityMapConfig,
}

impl MapSaver {
    /// Saves `backend`'s map crash-safely; its size in bytes.
    pub(super) fn save(&self, backend: &BackEnd) -> Result<u64> {
        let site_from_world = backend.site_from_world(&self.header.base_from_sensor);
        let map = backend.site_map(&site_from_world, &self.intensity, self.header.clone());
        let report = glint_map::save(&self.path, &map)
            .with_context(|| format!("cannot save the site map {}", self.path.display()))?;
        Ok(report.bytes)
    }

    /// Saves the saved map extended by a localisation run crash-safely: its size in bytes and
    /// what the run added.
    pub(super) fn save_extension(&self, extension: MapExtension) -> Result<(u64, ExtensionReport)> {
        let (map, added) = extension
            .finish(&self.header)
            .context("cannot place the run's keyframes in the saved map")?;
        let report = glint_map::save(&self.path, &map)
            .with_context(|| format!("cannot save the site map {}", self.path.display()))?;
        Ok((report.bytes, added))
    }
}

/// Initial-pose hints from consumers (`glint/<domain>/initial_pose`), for the localiser.
pub(super) struct HintSource {
    pub(super) subscriber: InitialPoseSubscriber,
    /// The robot's mounting: hints are `base_link` poses, the localiser takes the sensor's.
    pub(super) base_from_sensor: Isometry3<f64>,
}

impl HintSource {
    /// The newest hint since the last call, as the sensor's pose in the map.
    fn take(&self) -> Option<Isometry3<f64>> {
        match self.subscriber.try_latest() {
            Ok(Some(hint)) => {
                let [x, y, z] = hint.position;
                let [qx, qy, qz, qw] = hint.orientation;
                let base = Isometry3::from_parts(
                    Translation3::new(x, y, z),
                    UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz)),
                );
                tracing::info!(x, y, "initial-pose hint received: relocalising near it");
                Some(base * self.base_from_sensor)
            }
            Ok(None) => None,
            Err(e) => {
                tracing::warn!("initial-pose hints cannot be read: {e}");
                None
            }
        }
    }
}

/// How often the localiser looks for a hint while no keyframe comes (the service keeps a
/// sender's hint only while the subscriber polls: see `glint_ipc::settings`).
const HINT_POLL: Duration = Duration::from_millis(50);

/// The localiser's thread: locates each keyframe in the saved map and answers with the
/// correction and how far it is verified, taking initial-pose hints as they come; until the
/// odometry is gone. Extending the map, each keyframe also goes to `extension` (after the
/// answer: the pose path does not wait for it), which is returned.
pub(super) fn run_localiser(
    mut localiser: Localiser,
    hints: Option<HintSource>,
    mut extension: Option<MapExtension>,
    input: &Receiver<(u64, Keyframe)>,
    output: &Sender<Correction>,
    heartbeats: &Heartbeats,
) -> Option<MapExtension> {
    loop {
        heartbeats.beat(Stage::BackEnd);
        if let Some(hint) = hints.as_ref().and_then(HintSource::take) {
            localiser.hint(hint);
        }
        let (epoch, keyframe) = match input.recv_timeout(HINT_POLL) {
            Ok(message) => message,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        let (answer, outcome) = localiser.answer(epoch, &keyframe);
        tracing::debug!(
            epoch,
            state = ?outcome.state,
            verifications = outcome.verifications,
            "keyframe located"
        );
        match outcome.state {
            MapState::Lost => {
                tracing::warn!("the scan no longer fits the saved map: lost, relocalising");
            }
            MapState::Tracking if outcome.relocalised => {
                tracing::info!(epoch, "relocalised in the saved map");
            }
            _ => {}
        }
        if output.send(answer).is_err() {
            break;
        }
        if let Some(e) = extension.as_mut() {
            e.add(epoch, &keyframe, &outcome);
        }
    }
    extension
}

/// The back end's thread: adds each keyframe to the pose graph (closing loops, saving the site
/// map now and then when live) and answers with the correction, until the odometry is gone; then
/// the back end itself and its report. Each keyframe and each optimisation also goes to `map`,
/// after the answer.
pub(super) fn run_backend(
    config: &BackEndConfig,
    saver: Option<&MapSaver>,
    mut map: Option<MapOutlet>,
    input: &Receiver<(u64, Keyframe)>,
    output: &Sender<Correction>,
    heartbeats: &Heartbeats,
) -> (BackEnd, SlamSummary) {
    let mut backend = BackEnd::new(config);
    let mut report = SlamSummary::default();
    let mut saved = Instant::now();
    while let Some((_, keyframe)) = recv_beating(input, heartbeats, Stage::BackEnd) {
        let mut last = Instant::now();
        let outcome = backend.add_keyframe(keyframe, |stage| {
            let now = Instant::now();
            let ms = (now - last).as_secs_f64() * 1e3;
            last = now;
            heartbeats.beat(Stage::BackEnd);
            match stage {
                BackEndStage::Descriptor => report.descriptor_ms.push(ms),
                BackEndStage::Search => report.search_ms.push(ms),
                BackEndStage::Verify => report.verify_ms.push(ms),
                BackEndStage::Optimize => report.optimize_ms.push(ms),
            }
        });
        if let Some(l) = &outcome.accepted {
            tracing::info!(
                keyframe = l.query,
                closes_on = l.candidate,
                similarity = l.similarity,
                "loop closed"
            );
        }
        if output.send(Correction::slam(backend.correction())).is_err() {
            break;
        }
        if let Some(map) = map.as_mut() {
            map.keyframe_added(&backend, outcome.index);
            if outcome.optimization.is_some() {
                map.optimised(&backend);
            }
        }
        // Periodic saves happen here, between keyframes, off the pose path: the odometry never
        // waits for the back end live.
        if let Some(s) = saver.filter(|s| s.every.is_some_and(|e| saved.elapsed() >= e)) {
            heartbeats.beat(Stage::BackEnd);
            match s.save(&backend) {
                Ok(bytes) => tracing::info!(path = %s.path.display(), bytes, "site map saved"),
                Err(e) => tracing::error!("{e:#}"),
            }
            saved = Instant::now();
        }
    }
    // Floor edges since the last optimisation: into the final trajectory too.
    let start = Instant::now();
    if backend.finish().is_some() {
        report.optimize_ms.push(start.elapsed().as_secs_f64() * 1e3);
        if let Some(map) = map.as_mut() {
            map.optimised(&backend);
        }
    }
    report.stats = backend.stats();
    (backend, report)
}

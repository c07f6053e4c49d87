//! The publishing end, on the calling thread: each estimate turned into the base's `odom` and
//! `map` poses and published, the predicted stream between sweeps, the trajectory files written
//! as the poses come (or, with a back end in a replay, its optimised trajectory at the end), and
//! the run's final outputs: the site map, the exported map and the summary.

use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::Result;
use glint_core::backend::BackEnd;
use glint_core::extension::MapExtension;
use glint_core::localiser::MapState;
use glint_core::odometry::TrackingStatus;
use glint_core::se3::{base_covariance, exp, to_base};
use glint_core::tracker::RESUME_GAP_NS;
use glint_core::trajectory::StampedPose;
use glint_core::world_map::WorldMap;
use glint_driver::clock::stamp;
use glint_ipc::StatusFlags;
use nalgebra::Isometry3;

use super::backend_link::MapSaver;
use super::odometry::Estimated;
use super::receive::ReceiveCounters;
use super::report::{ReportWindow, Samples, SweepFigures, SweepWatcher, Timings};
use super::sweeps::{PublishedSweep, SweepOutlet};
use super::{Options, Relocalisation, SiteMapMode, SlamSummary, Summary};
use crate::outputs::{write_map, TrajectoryWriter};
use crate::publish::{PoseBus, PoseSample};

/// The publishing end: poses, predictions, status, trajectory files and the report.
pub(super) struct Sink {
    base_from_sensor: Isometry3<f64>,
    /// The published `map` frame from the odometry's corrected world: the mounting (the map
    /// frame is the first `base_link` pose) unless localising, where the world is the saved
    /// map's frame already.
    site_from_world: Isometry3<f64>,
    /// The trajectory files' frame from the same: the map frame with a site map; without,
    /// none (the files are in the world itself, the first sensor pose's frame).
    trajectory_from_world: Option<Isometry3<f64>>,
    mode: SiteMapMode,
    /// Localising: since when (sensor time) the map pose has not been verified.
    searching_since: Option<u64>,
    /// Localising: the localiser's state at the last sweep.
    last_map_state: Option<MapState>,
    /// Written as the poses come (map frame), unless `final_trajectory`.
    trajectory: Option<TrajectoryWriter>,
    kitti: Option<TrajectoryWriter>,
    odom_trajectory: Option<TrajectoryWriter>,
    /// With a back end in a replay, `trajectory` and `kitti` hold the final optimised poses,
    /// written at the end.
    final_trajectory: bool,
    keep_estimates: bool,
    /// Every pose on sensor time with its stamp offset (when `keep_estimates`), for the back
    /// end's final trajectory, whose keyframes are on sensor time.
    sensor_estimates: Vec<(StampedPose, i64)>,
    summary: Summary,
    /// The last estimate's sensor time.
    last_sensor_ns: Option<u64>,
    /// The latest base pose and when its sweep was received.
    latest: Option<(PoseSample, Instant)>,
    /// Sweep period measured from consecutive poses, ns.
    period_ns: u64,
    window: ReportWindow,
    sweeps: u64,
    /// Shown every sweep's figures (`Options::on_sweep`).
    pub(super) on_sweep: Option<SweepWatcher>,
    /// Where published sweeps' returns go, when the `sweep` service is on.
    pub(super) sweep_outlet: Option<SweepOutlet>,
}

impl Sink {
    pub(super) fn new(options: &Options, mode: SiteMapMode) -> Result<Self> {
        let trajectory = options
            .trajectory
            .as_deref()
            .map(|p| TrajectoryWriter::create(p, false, options.trajectory_max_bytes))
            .transpose()?;
        let kitti = options
            .kitti
            .as_deref()
            .map(|p| TrajectoryWriter::create(p, true, None))
            .transpose()?;
        let odom_trajectory = options
            .odom_trajectory
            .as_deref()
            .map(|p| TrajectoryWriter::create(p, false, options.trajectory_max_bytes))
            .transpose()?;
        let site_from_world = match mode {
            SiteMapMode::Localising => Isometry3::identity(),
            _ => options.base_from_sensor,
        };
        Ok(Self {
            base_from_sensor: options.base_from_sensor,
            site_from_world,
            trajectory_from_world: (mode != SiteMapMode::Off).then_some(site_from_world),
            mode,
            searching_since: None,
            last_map_state: None,
            trajectory,
            kitti,
            odom_trajectory,
            final_trajectory: options.backend.is_some()
                && mode != SiteMapMode::Localising
                && options.keep_estimates,
            keep_estimates: options.keep_estimates,
            sensor_estimates: Vec::new(),
            summary: Summary {
                // A live run reports its latest half hour; a replay, every sweep it can hold.
                timings: if options.keep_estimates {
                    Timings::default()
                } else {
                    Timings::bounded(Samples::LIVE)
                },
                ..Summary::default()
            },
            last_sensor_ns: None,
            latest: None,
            period_ns: 100_000_000,
            window: ReportWindow::new(),
            sweeps: 0,
            on_sweep: None,
            sweep_outlet: None,
        })
    }

    /// One sweep's estimate: published, written and counted.
    pub(super) fn take(
        &mut self,
        mut e: Estimated,
        bus: Option<&mut PoseBus>,
        counters: &ReceiveCounters,
    ) {
        let estimate = &e.estimate;
        let mut flags = match estimate.status {
            TrackingStatus::Initialising => StatusFlags::INITIALISING,
            TrackingStatus::Tracking => StatusFlags::TRACKING,
            TrackingStatus::Degenerate => StatusFlags::TRACKING.with(StatusFlags::DEGENERATE),
            TrackingStatus::Lost => StatusFlags::LOST,
        };
        if counters.silent.load(Ordering::Relaxed) {
            flags = flags.with(StatusFlags::SENSOR_SILENT);
        }
        if counters.foreign_active.load(Ordering::Relaxed) {
            flags = flags.with(StatusFlags::FOREIGN_SENSOR);
        }
        let (pose, twist) = to_base(&self.base_from_sensor, &estimate.pose, &estimate.velocity);
        if let Some(last) = self.last_sensor_ns {
            let dt = estimate.time_ns.saturating_sub(last);
            if dt > 0 && dt < RESUME_GAP_NS {
                self.period_ns = dt;
            }
        }
        self.last_sensor_ns = Some(estimate.time_ns);
        // Published and written on the stamp: the sensor time as the clock now stands.
        let stamp_ns = stamp(estimate.time_ns, e.stamp_offset_ns);
        // The published frames are the odometry's world turned by the mounting (odom), and by
        // the back end's correction as well (map).
        let covariance = |frame_from_world: &Isometry3<f64>, base: &Isometry3<f64>| {
            estimate
                .alignment
                .as_ref()
                .map(|a| base_covariance(&a.covariance, frame_from_world, &estimate.pose, base))
        };
        let sample = PoseSample {
            time_ns: stamp_ns,
            pose,
            velocity: twist,
            flags,
            quality: e.quality,
            covariance: covariance(&self.base_from_sensor, &pose),
        };
        let map_pose = e.map_from_odom * estimate.pose;
        let site_pose = self.site_from_world * map_pose;
        let map_base = site_pose * self.base_from_sensor.inverse();
        let map_flags = self.map_flags(flags, &e, estimate.time_ns);
        let map_sample = PoseSample {
            pose: map_base,
            flags: map_flags,
            covariance: covariance(&(self.site_from_world * e.map_from_odom), &map_base),
            ..sample
        };
        if let Some(b) = bus {
            if let Err(err) = b.publish(&sample, &map_sample) {
                tracing::warn!("{err:#}");
            }
        }
        let latency = e.received.elapsed().as_secs_f64() * 1e3;
        // The pose is out: now the returns, on the sweep thread.
        if let (Some(outlet), Some(sweep)) = (self.sweep_outlet.as_mut(), e.returns.take()) {
            outlet.offer(PublishedSweep {
                sweep,
                twist: estimate.velocity,
                timestamp_ns: stamp_ns,
                sensor_time_ns: estimate.time_ns,
                flags,
            });
        }
        self.latest = Some((sample, e.received));
        self.sweeps += 1;
        self.window.add_sweep(latency);

        let stamped = StampedPose {
            time_ns: stamp_ns,
            pose: estimate.pose,
        };
        let corrected = StampedPose {
            time_ns: stamp_ns,
            pose: self
                .trajectory_from_world
                .map_or(map_pose, |t| t * map_pose),
        };
        // With a final trajectory, the corrected files are written at the end instead;
        // localising, they hold only poses verified in the map.
        let corrected_now =
            !self.final_trajectory && (self.mode != SiteMapMode::Localising || e.map_fix.verified);
        let streamed: [(&str, &mut Option<TrajectoryWriter>, &StampedPose, bool); 3] = [
            (
                "trajectory",
                &mut self.trajectory,
                &corrected,
                corrected_now,
            ),
            (
                "KITTI trajectory",
                &mut self.kitti,
                &corrected,
                corrected_now,
            ),
            (
                "odometry trajectory",
                &mut self.odom_trajectory,
                &stamped,
                true,
            ),
        ];
        for (name, writer, pose, now) in streamed {
            if !now {
                continue;
            }
            if let Some(w) = writer.as_mut() {
                if let Err(err) = w.write(pose) {
                    // A full disk must not stop the poses: stop writing this file, say so once.
                    tracing::error!("{name} no longer written: {err:#}");
                    self.summary.output_errors.push(format!("{err:#}"));
                    *writer = None;
                }
            }
        }
        if let Some(on_sweep) = self.on_sweep.as_mut() {
            on_sweep(&SweepFigures {
                time_ns: estimate.time_ns,
                compute_ms: e.stage_ms.total(),
                latency_ms: latency,
                status: estimate.status,
                verified: self.mode != SiteMapMode::Localising || e.map_fix.verified,
                odom_position: pose.translation.vector.into(),
            });
        }
        let s = &mut self.summary;
        s.statuses.count(estimate.status);
        let t = &mut s.timings;
        t.total.push(e.stage_ms.total());
        t.front_end.push(e.stage_ms.front_end);
        t.deskew.push(e.stage_ms.deskew);
        t.align.push(e.stage_ms.align);
        t.map.push(e.stage_ms.map_update);
        t.latency.push(latency);
        t.edges.push(e.counts.edges as f64);
        t.planes.push(e.counts.planes as f64);
        t.intensity.push(e.counts.intensity as f64);
        if let Some(a) = &estimate.alignment {
            t.iterations.push(a.iterations as f64);
            t.degeneracy.push(a.degeneracy);
        }
        if let Some(d) = e.departure {
            s.departures.push(d);
        }
        if self.keep_estimates {
            s.estimates.push(stamped);
            let on_sensor_time = StampedPose {
                time_ns: estimate.time_ns,
                pose: estimate.pose,
            };
            self.sensor_estimates
                .push((on_sensor_time, e.stamp_offset_ns));
        }
    }

    /// The `map` pose's flags. Off and mapping, the odometry's, with `LOOP_CLOSED` when the
    /// correction changed. Localising, the odometry's only when the pose is verified in the saved
    /// map (`LOOP_CLOSED` on the first after a relocalisation); otherwise `RELOCALISING`, with
    /// `LOST` when tracking in the map was just lost, never `TRACKING`.
    fn map_flags(&mut self, flags: StatusFlags, e: &Estimated, time_ns: u64) -> StatusFlags {
        if self.mode != SiteMapMode::Localising {
            return if e.loop_closed {
                flags.with(StatusFlags::LOOP_CLOSED)
            } else {
                flags
            };
        }
        let fix = e.map_fix;
        if fix.state == MapState::Lost && self.last_map_state != Some(MapState::Lost) {
            self.summary.map_lost.push(time_ns);
        }
        self.last_map_state = Some(fix.state);
        if fix.verified {
            self.summary.map_verified += 1;
            let since = self.searching_since.take();
            if fix.relocalised {
                let searched_s = since.map_or(0.0, |t| time_ns.saturating_sub(t) as f64 * 1e-9);
                self.summary.relocalisations.push(Relocalisation {
                    time_ns,
                    searched_s,
                });
                return flags.with(StatusFlags::LOOP_CLOSED);
            }
            return flags;
        }
        self.searching_since.get_or_insert(time_ns);
        let unverified = flags
            .without(StatusFlags::TRACKING)
            .without(StatusFlags::DEGENERATE)
            .with(StatusFlags::RELOCALISING);
        if fix.state == MapState::Lost {
            unverified.with(StatusFlags::LOST)
        } else {
            unverified
        }
    }

    /// Publishes the predicted pose: the latest estimate carried forward at its velocity to
    /// now, never more than one sweep period past it (after that the sensor is late and a
    /// prediction would be a guess).
    pub(super) fn predict(&mut self, bus: &mut PoseBus) {
        let Some((last, received)) = self.latest else {
            return;
        };
        let ahead = received.elapsed().as_nanos() as u64;
        if ahead > self.period_ns {
            return;
        }
        let dt = ahead as f64 * 1e-9;
        let sample = PoseSample {
            time_ns: last.time_ns + ahead,
            pose: last.pose * exp(&(last.velocity * dt)),
            flags: last.flags.with(StatusFlags::PREDICTED),
            quality: 0.0,
            ..last
        };
        if let Err(err) = bus.publish_predicted(&sample) {
            tracing::warn!("{err:#}");
        }
    }

    /// Once a second: the status message, one log line, flushed trajectory files.
    pub(super) fn report(&mut self, bus: Option<&mut PoseBus>, counters: &ReceiveCounters) {
        let silent = counters.silent.load(Ordering::Relaxed);
        let mut flags = self
            .latest
            .map_or(StatusFlags::INITIALISING, |(last, _)| last.flags);
        if self.mode == SiteMapMode::Localising && self.last_map_state != Some(MapState::Tracking) {
            // The status speaks for the `map` stream too: not yet (or no longer) in the map.
            flags = flags.with(StatusFlags::RELOCALISING);
        }
        if silent {
            flags = flags.with(StatusFlags::SENSOR_SILENT);
        }
        // Now, not as of the latest pose: another sensor may have started or stopped since.
        flags = flags.without(StatusFlags::FOREIGN_SENSOR);
        if counters.foreign_active.load(Ordering::Relaxed) {
            flags = flags.with(StatusFlags::FOREIGN_SENSOR);
        }
        self.window
            .report(bus, counters, self.sweeps, flags, silent);
        for writer in [
            &mut self.trajectory,
            &mut self.kitti,
            &mut self.odom_trajectory,
        ] {
            if let Some(w) = writer.as_mut() {
                if let Err(err) = w.flush() {
                    tracing::error!("{err:#}");
                    self.summary.output_errors.push(format!("{err:#}"));
                    *writer = None;
                }
            }
        }
    }

    /// The end of the run: the back end's site map saved and its optimised trajectory written,
    /// the files closed, the map exported; the run's summary.
    pub(super) fn finish(
        mut self,
        world: Option<WorldMap>,
        backend: Option<(BackEnd, SlamSummary)>,
        extension: Option<MapExtension>,
        saver: Option<&MapSaver>,
        options: &Options,
    ) -> Result<Summary> {
        self.summary.sweeps_unpublished = self.sweep_outlet.take().map_or(0, |s| s.dropped);
        let mut world = world;
        if let (Some(extension), Some(saver)) = (extension, saver) {
            match saver.save_extension(extension) {
                Ok((bytes, added)) => {
                    self.summary.site_map_saved = Some((saver.path.clone(), bytes));
                    self.summary.site_map_extension = Some(added);
                }
                Err(err) => self.summary.output_errors.push(format!("{err:#}")),
            }
        }
        if let Some((backend, mut report)) = backend {
            if let Some(saver) = saver {
                // The trajectory written at the end is in the saved map's (levelled) frame.
                self.trajectory_from_world = Some(backend.site_from_world(&self.base_from_sensor));
                match saver.save(&backend) {
                    Ok(bytes) => self.summary.site_map_saved = Some((saver.path.clone(), bytes)),
                    Err(err) => self.summary.output_errors.push(format!("{err:#}")),
                }
            }
            if self.keep_estimates {
                let (sensor, offsets): (Vec<StampedPose>, Vec<i64>) =
                    self.sensor_estimates.iter().copied().unzip();
                report.trajectory = backend
                    .trajectory(&sensor)
                    .into_iter()
                    .zip(offsets)
                    .map(|(p, offset)| StampedPose {
                        time_ns: stamp(p.time_ns, offset),
                        pose: p.pose,
                    })
                    .collect();
            }
            if self.final_trajectory {
                for writer in [self.trajectory.as_mut(), self.kitti.as_mut()]
                    .into_iter()
                    .flatten()
                {
                    for pose in &report.trajectory {
                        let pose = StampedPose {
                            time_ns: pose.time_ns,
                            pose: self
                                .trajectory_from_world
                                .map_or(pose.pose, |t| t * pose.pose),
                        };
                        if let Err(err) = writer.write(&pose) {
                            self.summary.output_errors.push(format!("{err:#}"));
                            break;
                        }
                    }
                }
            }
            // The map from the keyframes at their optimised poses: consistent after loops,
            // where one grown sweep by sweep from odometry poses would hold both sides of the
            // drift.
            if let Some((_, voxel)) = options.map.as_ref() {
                let mut map = WorldMap::new(*voxel);
                for (keyframe, pose) in backend.keyframes().iter().zip(backend.keyframe_poses()) {
                    let pose = pose.cast::<f32>();
                    for point in &keyframe.cloud {
                        let p = pose * nalgebra::Point3::from(point.position);
                        map.insert(&p.coords, point.eta);
                    }
                }
                world = Some(map);
            }
            self.summary.slam = Some(report);
        }
        for writer in [
            self.trajectory.take(),
            self.kitti.take(),
            self.odom_trajectory.take(),
        ]
        .into_iter()
        .flatten()
        {
            if let Err(err) = writer.finish() {
                self.summary.output_errors.push(format!("{err:#}"));
            }
        }
        if let (Some(map), Some((path, _))) = (world, options.map.as_ref()) {
            if let Err(err) = write_map(path, &map.points()) {
                self.summary.output_errors.push(format!("{err:#}"));
            }
        }
        Ok(self.summary)
    }
}

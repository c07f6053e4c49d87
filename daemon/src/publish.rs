//! Poses on the bus: odometry estimates turned into the iceoryx2 contract (`glint-ipc`) and
//! published. Until the back end exists, the `map` stream carries the odometry pose (REP-105:
//! map = odom before any correction). The mounting transform is the identity (sensor =
//! `base_link`) until the configuration provides one.

use anyhow::{Context, Result};
use glint_core::odometry::{OdometryEstimate, TrackingStatus};
use glint_ipc::{Domain, Frame, Pose, PosePublisher, Status, StatusFlags};

/// Nominal 1σ of a tracked position (m) and heading (rad) for the covariance's diagonal: a
/// placeholder scale, inflated when degenerate or lost, until it comes from the normal
/// equations.
const NOMINAL_POSITION_SIGMA: f64 = 0.02;
const NOMINAL_ANGLE_SIGMA: f64 = 0.002;

/// Publishes the daemon's poses and status.
pub struct PoseBus {
    publisher: PosePublisher,
    sequence: u64,
    status_sequence: u64,
}

impl PoseBus {
    /// Creates the services of `domain` (cleaning a crashed daemon's resources first).
    pub fn create(domain: &str) -> Result<Self> {
        let domain = Domain::new(domain).with_context(|| format!("invalid --domain {domain:?}"))?;
        let publisher = PosePublisher::create(&domain)
            .with_context(|| format!("cannot create the pose services of domain {domain:?}"))?;
        let cleaned = publisher.dead_node_cleanup();
        tracing::info!(domain = domain.as_str(), ?cleaned, "pose services ready");
        Ok(Self {
            publisher,
            sequence: 0,
            status_sequence: 0,
        })
    }

    /// Publishes one estimate on `odom` and `map`. `quality` is in 0..=1.
    pub fn publish(&mut self, estimate: &OdometryEstimate, quality: f32) -> Result<()> {
        let flags = match estimate.status {
            TrackingStatus::Initialising => StatusFlags::INITIALISING,
            TrackingStatus::Tracking => StatusFlags::TRACKING,
            TrackingStatus::Degenerate => StatusFlags::TRACKING.with(StatusFlags::DEGENERATE),
            TrackingStatus::Lost => StatusFlags::LOST,
        };
        let inflation = match estimate.status {
            TrackingStatus::Tracking => 1.0,
            TrackingStatus::Degenerate => 10.0,
            TrackingStatus::Initialising | TrackingStatus::Lost => 100.0,
        };
        let mut pose = Pose::new(self.sequence, estimate.time_ns, Frame::ODOM);
        let t = estimate.pose.translation.vector;
        let q = estimate.pose.rotation.coords; // x, y, z, w
        pose.position = [t.x, t.y, t.z];
        pose.orientation = [q.x, q.y, q.z, q.w];
        let v = estimate.velocity;
        pose.angular_velocity = [v[0], v[1], v[2]];
        pose.linear_velocity = [v[3], v[4], v[5]];
        for i in 0..6 {
            let sigma = if i < 3 {
                NOMINAL_POSITION_SIGMA
            } else {
                NOMINAL_ANGLE_SIGMA
            } * inflation;
            pose.covariance[i * 6 + i] = sigma * sigma;
        }
        pose.quality = quality.clamp(0.0, 1.0);
        pose.status = flags;
        self.publisher
            .publish_odom(&pose)
            .context("cannot publish the odom pose")?;
        pose.frame = Frame::MAP;
        self.publisher
            .publish_map(&pose)
            .context("cannot publish the map pose")?;
        self.sequence += 1;
        Ok(())
    }

    /// Publishes a status message.
    pub fn publish_status(&mut self, mut status: Status) -> Result<()> {
        status.sequence = self.status_sequence;
        self.status_sequence += 1;
        self.publisher
            .publish_status(&status)
            .context("cannot publish the status")?;
        Ok(())
    }
}

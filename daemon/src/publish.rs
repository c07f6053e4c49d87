//! Poses on the bus: the pipeline's base poses turned into the iceoryx2 contract (`glint-ipc`)
//! and published on `odom`, `map` and `predicted`, with the status. REP-105: `odom` is smooth
//! and drifts; `map` is `odom` corrected by the back end, and jumps once per closed loop.

use anyhow::{Context, Result};
use glint_ipc::{Domain, Frame, Pose, PosePublisher, Status, StatusFlags};
use nalgebra::{Isometry3, Vector6};

/// Nominal 1σ of a tracked position (m) and heading (rad) for the covariance's diagonal: a
/// placeholder scale, inflated when degenerate or lost, until it comes from the normal
/// equations.
const NOMINAL_POSITION_SIGMA: f64 = 0.02;
const NOMINAL_ANGLE_SIGMA: f64 = 0.002;

/// One pose of the base, ready to publish.
#[derive(Debug, Clone, Copy)]
pub struct PoseSample {
    /// The instant it describes, ns since the epoch.
    pub time_ns: u64,
    /// `base_link` → odom.
    pub pose: Isometry3<f64>,
    /// Body twist [ω, υ] of `base_link` (rad/s, m/s).
    pub velocity: Vector6<f64>,
    /// Status bits.
    pub flags: StatusFlags,
    /// Match quality, 0..=1.
    pub quality: f32,
}

/// Publishes the daemon's poses and status.
pub struct PoseBus {
    publisher: PosePublisher,
    sequence: u64,
    predicted_sequence: u64,
    status_sequence: u64,
}

impl PoseBus {
    /// Creates the services of `domain` (cleaning a crashed daemon's resources first).
    pub fn create(domain: &str) -> Result<Self> {
        let domain = Domain::new(domain).with_context(|| format!("invalid domain {domain:?}"))?;
        let publisher = PosePublisher::create(&domain)
            .with_context(|| format!("cannot create the pose services of domain {domain:?}"))?;
        let cleaned = publisher.dead_node_cleanup();
        tracing::info!(domain = domain.as_str(), ?cleaned, "pose services ready");
        Ok(Self {
            publisher,
            sequence: 0,
            predicted_sequence: 0,
            status_sequence: 0,
        })
    }

    /// Publishes one sweep's pose on `odom` and, corrected by the back end, on `map`.
    pub fn publish(&mut self, odom: &PoseSample, map: &PoseSample) -> Result<()> {
        let pose = to_wire(odom, self.sequence, Frame::ODOM);
        self.publisher
            .publish_odom(&pose)
            .context("cannot publish the odom pose")?;
        let pose = to_wire(map, self.sequence, Frame::MAP);
        self.publisher
            .publish_map(&pose)
            .context("cannot publish the map pose")?;
        self.sequence += 1;
        Ok(())
    }

    /// Publishes an extrapolated pose on `predicted` (in the odom frame).
    pub fn publish_predicted(&mut self, sample: &PoseSample) -> Result<()> {
        let pose = to_wire(sample, self.predicted_sequence, Frame::ODOM);
        self.publisher
            .publish_predicted(&pose)
            .context("cannot publish the predicted pose")?;
        self.predicted_sequence += 1;
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

fn to_wire(sample: &PoseSample, sequence: u64, frame: Frame) -> Pose {
    let flags = sample.flags;
    let inflation = if flags.intersects(StatusFlags::LOST.with(StatusFlags::INITIALISING)) {
        100.0
    } else if flags.contains(StatusFlags::DEGENERATE) {
        10.0
    } else {
        1.0
    };
    let mut pose = Pose::new(sequence, sample.time_ns, frame);
    let t = sample.pose.translation.vector;
    let q = sample.pose.rotation.coords; // x, y, z, w
    pose.position = [t.x, t.y, t.z];
    pose.orientation = [q.x, q.y, q.z, q.w];
    let v = sample.velocity;
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
    pose.quality = sample.quality.clamp(0.0, 1.0);
    pose.status = flags;
    pose
}

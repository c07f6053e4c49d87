//! Poses on the bus: the pipeline's base poses turned into the iceoryx2 contract (`glint-ipc`)
//! and published on `odom`, `map` and `predicted`, with the status. REP-105: `odom` is smooth
//! and drifts; `map` is `odom` corrected by the back end, and jumps once per closed loop.

use anyhow::{Context, Result};
use glint_ipc::{Domain, Frame, Pose, PosePublisher, Status, StatusFlags};
use nalgebra::{Isometry3, Matrix6, Vector6};

/// 1σ of a position (m) and an angle (rad) for a pose without an alignment's covariance (the
/// first sweep, a lost sweep's prediction): large, so no consumer fuses it as a measurement.
const UNMEASURED_POSITION_SIGMA: f64 = 2.0;
const UNMEASURED_ANGLE_SIGMA: f64 = 0.2;

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
    /// The pose's covariance over `[x, y, z, roll, pitch, yaw]` of `base_link` in the pose's
    /// frame (see `glint_core::se3::base_covariance`), when the sweep was aligned.
    pub covariance: Option<Matrix6<f64>>,
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
    let mut pose = Pose::new(sequence, sample.time_ns, frame);
    let t = sample.pose.translation.vector;
    let q = sample.pose.rotation.coords; // x, y, z, w
    pose.position = [t.x, t.y, t.z];
    pose.orientation = [q.x, q.y, q.z, q.w];
    let v = sample.velocity;
    pose.angular_velocity = [v[0], v[1], v[2]];
    pose.linear_velocity = [v[3], v[4], v[5]];
    let measured = sample
        .covariance
        .filter(|c| c.iter().all(|v| v.is_finite()))
        .filter(|_| !flags.intersects(StatusFlags::LOST.with(StatusFlags::INITIALISING)));
    match measured {
        Some(c) => {
            for (i, v) in pose.covariance.iter_mut().enumerate() {
                *v = c[(i / 6, i % 6)];
            }
        }
        None => {
            for i in 0..6 {
                let sigma = if i < 3 {
                    UNMEASURED_POSITION_SIGMA
                } else {
                    UNMEASURED_ANGLE_SIGMA
                };
                pose.covariance[i * 6 + i] = sigma * sigma;
            }
        }
    }
    pose.quality = sample.quality.clamp(0.0, 1.0);
    pose.status = flags;
    pose
}

#[cfg(test)]
mod tests {
    use super::*;
    use glint_core::se3::base_covariance;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn sample(covariance: Option<Matrix6<f64>>, flags: StatusFlags) -> PoseSample {
        PoseSample {
            time_ns: 1,
            pose: Isometry3::identity(),
            velocity: Vector6::zeros(),
            flags,
            quality: 1.0,
            covariance,
        }
    }

    /// [δθ, δt] becomes [x, y, z, roll, pitch, yaw], row-major, turned with the frame.
    #[test]
    fn the_covariance_is_reordered_and_turned_into_the_published_frame() {
        // δt along world x only (1 cm), δθ about world z only (1 mrad).
        let mut c = Matrix6::zeros();
        c[(3, 3)] = 1e-4;
        c[(2, 2)] = 1e-6;
        let identity = Isometry3::identity();
        let same = base_covariance(&c, &identity, &identity, &identity);
        assert_eq!(same[(0, 0)], 1e-4);
        assert_eq!(same[(5, 5)], 1e-6);
        // A frame turned 90° about z: world x is the frame's y.
        let turned = Isometry3::from_parts(
            Translation3::new(5.0, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2),
        );
        let sensor = Isometry3::identity();
        let base = turned * sensor;
        let t = base_covariance(&c, &turned, &sensor, &base);
        assert!(
            (t[(1, 1)] - 1e-4).abs() < 1e-12 && t[(0, 0)].abs() < 1e-12,
            "{t}"
        );
        assert!((t[(5, 5)] - 1e-6).abs() < 1e-12, "{t}");
        let wire = to_wire(&sample(Some(t), StatusFlags::TRACKING), 0, Frame::ODOM);
        assert_eq!(wire.covariance[7], t[(1, 1)]);
        assert_eq!(wire.covariance[35], t[(5, 5)]);
    }

    /// Without an alignment, or lost, the covariance is the nominal one inflated: never a
    /// measurement, never NaN.
    #[test]
    fn an_unmeasured_pose_gets_an_inflated_nominal_covariance() {
        let mut nan = Matrix6::identity() * 1e-6;
        nan[(0, 0)] = f64::NAN;
        for s in [
            sample(None, StatusFlags::TRACKING),
            sample(Some(Matrix6::identity() * 1e-6), StatusFlags::LOST),
            sample(Some(nan), StatusFlags::TRACKING),
        ] {
            let wire = to_wire(&s, 0, Frame::ODOM);
            // (2 m)² and (0.2 rad)².
            let c = wire.covariance;
            assert!(
                (c[0] - 4.0).abs() < 1e-9 && (c[35] - 0.04).abs() < 1e-9,
                "{c:?}"
            );
            assert!(wire.first_non_finite_field().is_none());
        }
    }
}

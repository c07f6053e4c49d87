//! The wire payloads: [`Pose`] and [`Status`] (published by the daemon), [`InitialPose`] (sent to
//! it), the [`StatusFlags`] bitfield and the [`Frame`] code.
//!
//! These structs *are* the shared-memory contract with every consumer, in any language. Each is
//! `#[repr(C)]`, fixed-size, pointer-free, with every padding byte an explicit field, so Rust, C and
//! Python ctypes compute the same layout; `ipc/README.md` tables the offsets and `tests/layout.rs`
//! pins them. The iceoryx2 type name carries a version suffix: a layout change must come with a new
//! name (`glint::PoseV2`), so an old consumer is refused with `IncompatibleTypes` instead of
//! misreading bytes.
//!
//! Enumerated and bitfield values are newtypes over `u32`, never Rust enums: a subscriber reads the
//! struct straight from memory another process wrote, and every bit pattern must be a valid value.
//! The newtypes are `#[repr(C)]` (iceoryx2's derive demands it), which for one `u32` field is the
//! layout of a `u32`.

use core::fmt;
use core::ops::{BitOr, BitOrAssign};

use iceoryx2::prelude::ZeroCopySend;
use thiserror::Error;

/// Status bits shared by [`Pose::status`] and [`Status::flags`].
///
/// Bits 9..=31 are reserved: the publisher writes 0, consumers must ignore them (new bits may be
/// added without a new type name; their absence must stay safe to assume).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Hash, ZeroCopySend)]
pub struct StatusFlags(pub u32);

impl StatusFlags {
    /// No bit set.
    pub const NONE: Self = Self(0);
    /// Bit 0: the estimator is starting up (first sweeps, no local map yet); do not steer by it.
    pub const INITIALISING: Self = Self(1 << 0);
    /// Bit 1: scan matching converged on this sweep; the pose is a measurement.
    pub const TRACKING: Self = Self(1 << 1);
    /// Bit 2: the scene constrains some direction poorly (a long corridor); the covariance
    /// says which.
    pub const DEGENERATE: Self = Self(1 << 2);
    /// Bit 3: tracking is lost; the pose was not measured: the last good one, or its
    /// constant-velocity prediction to this sweep's time (a sweep that did not match, or too
    /// short a part of a turn to align). Not the robot's measured pose: do not steer by it.
    pub const LOST: Self = Self(1 << 3);
    /// Bit 4: the `map` pose jumped: a loop closure corrected the map frame, or (localising in
    /// a saved map) this is the first verified pose after a (re)localisation. Set on the first
    /// `map` pose after the jump only.
    pub const LOOP_CLOSED: Self = Self(1 << 4);
    /// Bit 5: the pose is extrapolated (constant velocity) rather than measured; always set on
    /// the `predicted` stream.
    pub const PREDICTED: Self = Self(1 << 5);
    /// Bit 6: no packets arrived from the sensor recently (cable, power or network).
    pub const SENSOR_SILENT: Self = Self(1 << 6);
    /// Bit 7: localising in a saved map, and the pose is not verified in it (at boot, after
    /// tracking was lost, after a kidnap): the `map` pose is not to be steered by. Never set
    /// together with `TRACKING` on `map`.
    pub const RELOCALISING: Self = Self(1 << 7);
    /// Bit 8: packets from another sensor (another source address) reach the sensor's ports
    /// and are being refused: a shared network; set `[sensor] source` to name ours.
    pub const FOREIGN_SENSOR: Self = Self(1 << 8);

    /// All bits this version defines.
    pub const KNOWN: Self = Self((1 << 9) - 1);

    /// The raw bits, as on the wire.
    pub const fn bits(self) -> u32 {
        self.0
    }

    /// Whether every bit of `other` is set in `self`.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    /// Whether any bit of `other` is set in `self`.
    pub const fn intersects(self, other: Self) -> bool {
        self.0 & other.0 != 0
    }

    /// `self` with the bits of `other` set.
    pub const fn with(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }

    /// `self` with the bits of `other` cleared.
    pub const fn without(self, other: Self) -> Self {
        Self(self.0 & !other.0)
    }
}

impl BitOr for StatusFlags {
    type Output = Self;

    fn bitor(self, rhs: Self) -> Self {
        self.with(rhs)
    }
}

impl BitOrAssign for StatusFlags {
    fn bitor_assign(&mut self, rhs: Self) {
        *self = self.with(rhs);
    }
}

impl fmt::Display for StatusFlags {
    /// `TRACKING|LOOP_CLOSED`, `-` for none; unknown bits as hex so nothing is hidden.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        const NAMES: [(StatusFlags, &str); 9] = [
            (StatusFlags::INITIALISING, "INITIALISING"),
            (StatusFlags::TRACKING, "TRACKING"),
            (StatusFlags::DEGENERATE, "DEGENERATE"),
            (StatusFlags::LOST, "LOST"),
            (StatusFlags::LOOP_CLOSED, "LOOP_CLOSED"),
            (StatusFlags::PREDICTED, "PREDICTED"),
            (StatusFlags::SENSOR_SILENT, "SENSOR_SILENT"),
            (StatusFlags::RELOCALISING, "RELOCALISING"),
            (StatusFlags::FOREIGN_SENSOR, "FOREIGN_SENSOR"),
        ];
        let mut first = true;
        let mut sep = |f: &mut fmt::Formatter<'_>| {
            let s = if first { "" } else { "|" };
            first = false;
            f.write_str(s)
        };
        for (flag, name) in NAMES {
            if self.contains(flag) {
                sep(f)?;
                f.write_str(name)?;
            }
        }
        let unknown = self.0 & !Self::KNOWN.0;
        if unknown != 0 {
            sep(f)?;
            write!(f, "{unknown:#x}")?;
        }
        if self.0 == 0 {
            f.write_str("-")?;
        }
        Ok(())
    }
}

/// The frame a [`Pose`] is expressed in (REP-105), as a `u32` code.
///
/// A newtype rather than an enum so that an unknown code written by a newer publisher is a value
/// to report, not undefined behaviour.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Hash, ZeroCopySend)]
pub struct Frame(pub u32);

impl Frame {
    /// 0: `odom` — continuous and smooth, never jumps, drifts without bound.
    pub const ODOM: Self = Self(0);
    /// 1: `map` — globally consistent; may jump once after a loop closure
    /// ([`StatusFlags::LOOP_CLOSED`]).
    pub const MAP: Self = Self(1);

    /// The name used in ROS (`odom`, `map`), or `None` for a code this version does not know.
    pub const fn name(self) -> Option<&'static str> {
        match self {
            Self::ODOM => Some("odom"),
            Self::MAP => Some("map"),
            _ => None,
        }
    }
}

impl fmt::Display for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.name() {
            Some(name) => f.write_str(name),
            None => write!(f, "frame#{}", self.0),
        }
    }
}

/// One pose of the robot base (`base_link`) in [`Frame::ODOM`] or [`Frame::MAP`]: 424 bytes,
/// alignment 8, iceoryx2 type name `glint::PoseV1`.
///
/// Units are SI. Sequence numbers are the publisher's and increase by one per message on each
/// stream; a gap means the consumer missed messages (its buffer overflowed).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("glint::PoseV1")]
pub struct Pose {
    /// Per-stream message counter, set by the publisher.
    pub sequence: u64,
    /// The instant the pose describes (the sweep's reference time after deskew), ns since the
    /// Unix epoch — not the time it was computed or published.
    pub timestamp_ns: u64,
    /// Position of `base_link` in `frame`, metres.
    pub position: [f64; 3],
    /// Orientation of `base_link` in `frame`: a unit Hamilton quaternion stored **x, y, z, w**
    /// (the ROS/Eigen-coefficients order, scalar last).
    pub orientation: [f64; 4],
    /// Linear velocity of `base_link`, m/s, in the body frame (`base_link` axes).
    pub linear_velocity: [f64; 3],
    /// Angular velocity of `base_link`, rad/s, in the body frame.
    pub angular_velocity: [f64; 3],
    /// Pose covariance, 6×6 row-major over `[x, y, z, roll, pitch, yaw]` (m², rad², m·rad), the
    /// same convention as ROS `PoseWithCovariance`, rotations about the axes of `frame`. Never
    /// NaN. `glintd` publishes the sweep's registration covariance (how well it pins the pose
    /// against the local map, not the drift since the start); a direction nothing measured (held
    /// at the prediction, or a degenerate sweep's free axis without intensity) reads (1 m)² (a
    /// rotation: 1 m of displacement at the returns' RMS range). A diagonal-only estimate (zeros
    /// off the diagonal) is allowed.
    pub covariance: [f64; 36],
    /// Match quality in `0..=1` (1 = every feature matched within tolerance).
    pub quality: f32,
    /// The frame the pose is expressed in.
    pub frame: Frame,
    /// What the estimator knew when it produced this pose.
    pub status: StatusFlags,
    /// Explicit padding to a multiple of 8 bytes; always 0.
    _pad0: u32,
}

impl Pose {
    /// The iceoryx2 type name, as other languages must spell it.
    pub const TYPE_NAME: &'static str = "glint::PoseV1";

    /// A pose at the origin with identity orientation, zero velocity and covariance, quality 0
    /// and no status bits, for the caller to fill in.
    pub const fn new(sequence: u64, timestamp_ns: u64, frame: Frame) -> Self {
        Self {
            sequence,
            timestamp_ns,
            position: [0.0; 3],
            orientation: [0.0, 0.0, 0.0, 1.0],
            linear_velocity: [0.0; 3],
            angular_velocity: [0.0; 3],
            covariance: [0.0; 36],
            quality: 0.0,
            frame,
            status: StatusFlags::NONE,
            _pad0: 0,
        }
    }

    /// The name of the first field holding a NaN or infinity, if any; the publisher refuses such
    /// poses so consumers may rely on finite numbers.
    pub fn first_non_finite_field(&self) -> Option<&'static str> {
        let fields: [(&'static str, &[f64]); 5] = [
            ("position", &self.position),
            ("orientation", &self.orientation),
            ("linear_velocity", &self.linear_velocity),
            ("angular_velocity", &self.angular_velocity),
            ("covariance", &self.covariance),
        ];
        fields
            .into_iter()
            .find(|(_, values)| values.iter().any(|v| !v.is_finite()))
            .map(|(name, _)| name)
            .or_else(|| (!self.quality.is_finite()).then_some("quality"))
    }
}

/// Daemon health, published about once a second: 80 bytes, alignment 8, iceoryx2 type name
/// `glint::StatusV1`.
///
/// Counters are totals since the daemon started (they restart from 0 with it); rates and
/// latencies are over the daemon's last reporting window.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("glint::StatusV1")]
pub struct Status {
    /// Message counter of the status stream, set by the publisher.
    pub sequence: u64,
    /// When the status was taken, ns since the Unix epoch.
    pub timestamp_ns: u64,
    /// Sweeps that went through the whole pipeline.
    pub sweeps_processed: u64,
    /// Whole sweeps dropped because a stage fell behind.
    pub sweeps_dropped: u64,
    /// Sensor packets received.
    pub packets_received: u64,
    /// Sensor packets lost (gaps in the sensor's timing) or dropped by the receiver.
    pub packets_dropped: u64,
    /// Sensor packets refused as truncated or corrupt.
    pub packets_malformed: u64,
    /// Sweeps per second processed.
    pub sweep_rate_hz: f32,
    /// Packets per second received.
    pub packet_rate_hz: f32,
    /// Median latency, last packet of a sweep received → pose published, ms.
    pub latency_median_ms: f32,
    /// 99th-percentile of the same latency, ms.
    pub latency_p99_ms: f32,
    /// The same bits as the latest pose's [`Pose::status`].
    pub flags: StatusFlags,
    /// Explicit padding to a multiple of 8 bytes; always 0.
    _pad0: u32,
}

impl Status {
    /// The iceoryx2 type name, as other languages must spell it.
    pub const TYPE_NAME: &'static str = "glint::StatusV1";

    /// A status with every counter, rate and flag zero, for the caller to fill in.
    pub const fn new(sequence: u64, timestamp_ns: u64) -> Self {
        Self {
            sequence,
            timestamp_ns,
            sweeps_processed: 0,
            sweeps_dropped: 0,
            packets_received: 0,
            packets_dropped: 0,
            packets_malformed: 0,
            sweep_rate_hz: 0.0,
            packet_rate_hz: 0.0,
            latency_median_ms: 0.0,
            latency_p99_ms: 0.0,
            flags: StatusFlags::NONE,
            _pad0: 0,
        }
    }
}

/// An initial-pose hint: roughly where `base_link` is in the saved site map, sent by an operator
/// or a fleet manager so the daemon searches near it instead of the whole map. 80 bytes,
/// alignment 8, iceoryx2 type name `glint::InitialPoseV1`.
///
/// Consumers publish it on `glint/<domain>/initial_pose`; the daemon subscribes. The daemon
/// checks every hint with [`InitialPose::validate`] and ignores (and counts) those that fail, so
/// a sender's bug cannot steer the localiser with NaN.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("glint::InitialPoseV1")]
pub struct InitialPose {
    /// When the consumer sent the hint, ns since the Unix epoch (lets the daemon ignore a hint
    /// that waited too long).
    pub timestamp_ns: u64,
    /// Position of `base_link` in the map frame, metres.
    pub position: [f64; 3],
    /// Orientation of `base_link` in the map frame: a unit Hamilton quaternion stored
    /// **x, y, z, w**, as in [`Pose::orientation`].
    pub orientation: [f64; 4],
    /// How far off the position may be, metres (one standard deviation); 0 = unknown.
    pub position_sigma: f64,
    /// Must be [`Frame::MAP`]: the hint is a pose in the saved site map.
    pub frame: Frame,
    /// Explicit padding to a multiple of 8 bytes; always 0.
    _pad0: u32,
}

/// Why an [`InitialPose`] is not a usable hint.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum InitialPoseError {
    /// A field holds NaN or infinity.
    #[error("the initial pose's {field} is not finite")]
    NonFinite {
        /// The first offending field.
        field: &'static str,
    },
    /// The orientation is not a unit quaternion (its norm is off 1 by more than
    /// [`InitialPose::UNIT_TOLERANCE`]).
    #[error("the initial pose's orientation has norm {norm}; a unit quaternion (x, y, z, w) is required")]
    NotUnitQuaternion {
        /// The quaternion's norm.
        norm: f64,
    },
    /// The frame is not [`Frame::MAP`].
    #[error("the initial pose is in frame {frame}; it must be in map")]
    NotMapFrame {
        /// The frame given.
        frame: Frame,
    },
    /// `position_sigma` is negative (0 means unknown).
    #[error("the initial pose's position_sigma is {sigma} m; it must be >= 0 (0 = unknown)")]
    NegativeSigma {
        /// The value given.
        sigma: f64,
    },
}

impl InitialPose {
    /// The iceoryx2 type name, as other languages must spell it.
    pub const TYPE_NAME: &'static str = "glint::InitialPoseV1";

    /// How far the orientation's norm may be from 1.
    pub const UNIT_TOLERANCE: f64 = 1e-6;

    /// A hint in [`Frame::MAP`]. Not validated; see [`validate`](Self::validate).
    pub const fn new(
        timestamp_ns: u64,
        position: [f64; 3],
        orientation: [f64; 4],
        position_sigma: f64,
    ) -> Self {
        Self {
            timestamp_ns,
            position,
            orientation,
            position_sigma,
            frame: Frame::MAP,
            _pad0: 0,
        }
    }

    /// A hint for a robot on the floor: `base_link` at (`x`, `y`, 0), turned `yaw` radians
    /// about the map's z axis.
    pub fn on_floor(timestamp_ns: u64, x: f64, y: f64, yaw: f64, position_sigma: f64) -> Self {
        let (s, c) = (yaw / 2.0).sin_cos();
        Self::new(timestamp_ns, [x, y, 0.0], [0.0, 0.0, s, c], position_sigma)
    }

    /// Checks that every number is finite, the orientation a unit quaternion, `position_sigma`
    /// not negative and the frame [`Frame::MAP`].
    pub fn validate(&self) -> Result<(), InitialPoseError> {
        let fields: [(&'static str, &[f64]); 3] = [
            ("position", &self.position),
            ("orientation", &self.orientation),
            (
                "position_sigma",
                core::slice::from_ref(&self.position_sigma),
            ),
        ];
        if let Some((field, _)) = fields
            .into_iter()
            .find(|(_, values)| values.iter().any(|v| !v.is_finite()))
        {
            return Err(InitialPoseError::NonFinite { field });
        }
        let norm = self.orientation.iter().map(|v| v * v).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > Self::UNIT_TOLERANCE {
            return Err(InitialPoseError::NotUnitQuaternion { norm });
        }
        if self.position_sigma < 0.0 {
            return Err(InitialPoseError::NegativeSigma {
                sigma: self.position_sigma,
            });
        }
        if self.frame != Frame::MAP {
            return Err(InitialPoseError::NotMapFrame { frame: self.frame });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_display_names_bits_and_keeps_unknown_ones_visible() {
        assert_eq!(StatusFlags::NONE.to_string(), "-");
        assert_eq!(
            (StatusFlags::TRACKING | StatusFlags::LOOP_CLOSED).to_string(),
            "TRACKING|LOOP_CLOSED"
        );
        assert_eq!(
            StatusFlags(StatusFlags::LOST.0 | 1 << 20).to_string(),
            "LOST|0x100000"
        );
        assert_eq!(
            (StatusFlags::TRACKING | StatusFlags::FOREIGN_SENSOR).to_string(),
            "TRACKING|FOREIGN_SENSOR"
        );
        assert_eq!(StatusFlags(1 << 9).to_string(), "0x200");
    }

    #[test]
    fn flags_set_and_clear() {
        let f = StatusFlags::TRACKING.with(StatusFlags::DEGENERATE);
        assert!(f.contains(StatusFlags::TRACKING));
        assert!(!f.contains(StatusFlags::TRACKING | StatusFlags::LOST));
        assert!(f.intersects(StatusFlags::TRACKING | StatusFlags::LOST));
        assert_eq!(f.without(StatusFlags::DEGENERATE), StatusFlags::TRACKING);
        assert_eq!(StatusFlags::KNOWN.bits(), 0x1ff);
    }

    #[test]
    fn unknown_frame_code_is_a_value_not_an_error() {
        assert_eq!(Frame::ODOM.to_string(), "odom");
        assert_eq!(Frame::MAP.to_string(), "map");
        assert_eq!(Frame(7).to_string(), "frame#7");
    }

    #[test]
    fn non_finite_fields_are_named() {
        let mut p = Pose::new(1, 2, Frame::ODOM);
        assert_eq!(p.first_non_finite_field(), None);
        p.covariance[35] = f64::NAN;
        assert_eq!(p.first_non_finite_field(), Some("covariance"));
        p.covariance[35] = 0.0;
        p.quality = f32::INFINITY;
        assert_eq!(p.first_non_finite_field(), Some("quality"));
    }

    #[test]
    fn initial_pose_on_the_floor_is_valid_and_turns_about_z() {
        let h = InitialPose::on_floor(5, 1.0, -2.0, core::f64::consts::FRAC_PI_2, 0.5);
        assert_eq!(h.validate(), Ok(()));
        assert_eq!(h.position, [1.0, -2.0, 0.0]);
        let [x, y, z, w] = h.orientation;
        assert_eq!((x, y), (0.0, 0.0));
        assert!((z - w).abs() < 1e-12 && (w - 0.5f64.sqrt()).abs() < 1e-12);
        assert_eq!(h.frame, Frame::MAP);
    }

    #[test]
    fn invalid_initial_poses_say_why() {
        let good = InitialPose::on_floor(0, 0.0, 0.0, 0.3, 0.0);
        let mut h = good;
        h.position[1] = f64::NAN;
        assert_eq!(
            h.validate(),
            Err(InitialPoseError::NonFinite { field: "position" })
        );
        let mut h = good;
        h.position_sigma = f64::INFINITY;
        assert_eq!(
            h.validate(),
            Err(InitialPoseError::NonFinite {
                field: "position_sigma"
            })
        );
        let mut h = good;
        h.orientation = [0.0, 0.0, 0.0, 1.00001];
        assert!(matches!(
            h.validate(),
            Err(InitialPoseError::NotUnitQuaternion { .. })
        ));
        let mut h = good;
        h.position_sigma = -1.0;
        assert_eq!(
            h.validate(),
            Err(InitialPoseError::NegativeSigma { sigma: -1.0 })
        );
        let mut h = good;
        h.frame = Frame::ODOM;
        assert_eq!(
            h.validate(),
            Err(InitialPoseError::NotMapFrame { frame: Frame::ODOM })
        );
        assert!(h.validate().unwrap_err().to_string().contains("odom"));
    }
}

//! Service naming: the validated [`Domain`] and the service names derived from it.
//!
//! Every service lives under `glint/<domain>/`, so two daemons on one host (or tests running in
//! parallel) never share a service by accident. Names are built here and nowhere else; the README
//! lists them for consumers in other languages.

use core::fmt;

use thiserror::Error;

/// The first component of every service name.
pub const SERVICE_ROOT: &str = "glint";

/// The suffix of the event service that accompanies each data service.
pub const EVENT_SUFFIX: &str = "event";

/// Why a string is not a valid [`Domain`].
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum DomainError {
    /// The domain is the empty string.
    #[error("the domain is empty")]
    Empty,
    /// The domain is longer than [`Domain::MAX_LEN`] bytes.
    #[error("the domain is {len} bytes long; at most {max} are allowed", max = Domain::MAX_LEN)]
    TooLong {
        /// Length of the rejected domain in bytes.
        len: usize,
    },
    /// The domain holds a character outside `[A-Za-z0-9_-]` (a `/` would add a level to every
    /// service name).
    #[error(
        "the domain holds {ch:?} at byte {index}; only A-Z, a-z, 0-9, '_' and '-' are allowed"
    )]
    InvalidCharacter {
        /// The first offending character.
        ch: char,
        /// Its byte offset in the domain.
        index: usize,
    },
}

/// A validated domain: 1 to [`Domain::MAX_LEN`] characters from `[A-Za-z0-9_-]`.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Domain(String);

impl Domain {
    /// Longest accepted domain, in bytes; keeps every derived name well inside iceoryx2's limits
    /// (255 for service names, 128 for node names).
    pub const MAX_LEN: usize = 64;

    /// Validates `domain`.
    pub fn new(domain: &str) -> Result<Self, DomainError> {
        if domain.is_empty() {
            return Err(DomainError::Empty);
        }
        if let Some((index, ch)) = domain
            .char_indices()
            .find(|(_, c)| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
        {
            return Err(DomainError::InvalidCharacter { ch, index });
        }
        if domain.len() > Self::MAX_LEN {
            return Err(DomainError::TooLong { len: domain.len() });
        }
        Ok(Self(domain.to_owned()))
    }

    /// The domain as given.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// `glint/<domain>/<stream>`, the publish-subscribe service of `stream`.
    pub fn service_name(&self, stream: Stream) -> String {
        format!("{SERVICE_ROOT}/{}/{}", self.0, stream.as_str())
    }

    /// `glint/<domain>/<stream>/event`, the event service notified after each message on
    /// `stream`.
    pub fn event_service_name(&self, stream: Stream) -> String {
        format!("{}/{EVENT_SUFFIX}", self.service_name(stream))
    }
}

impl fmt::Display for Domain {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl core::str::FromStr for Domain {
    type Err = DomainError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::new(s)
    }
}

/// The pose streams, one service each; all carry [`Pose`](crate::Pose).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PoseStream {
    /// `odom`: smooth, never jumps, drifts (REP-105).
    Odom,
    /// `map`: globally corrected, may jump after a loop closure.
    Map,
    /// `predicted`: the latest pose extrapolated at constant velocity, flag `PREDICTED` set.
    Predicted,
}

impl PoseStream {
    /// Every pose stream, in service-name order.
    pub const ALL: [Self; 3] = [Self::Odom, Self::Map, Self::Predicted];
}

/// Every stream of a domain: the three pose streams and the status stream, which the daemon
/// publishes, and `initial_pose`, which it subscribes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stream {
    /// A pose stream.
    Pose(PoseStream),
    /// `status`: daemon health, [`Status`](crate::Status).
    Status,
    /// `initial_pose`: hints of where the robot is in the site map,
    /// [`InitialPose`](crate::InitialPose); consumers publish, the daemon subscribes.
    InitialPose,
    /// `sweep`: every sweep's points in `base_link`, [`SweepPoint`](crate::SweepPoint)s under a
    /// [`SweepHeader`](crate::SweepHeader).
    Sweep,
    /// `map_update`: the map as keyframes — points, poses and loop edges — under a
    /// [`MapUpdateHeader`](crate::MapUpdateHeader).
    MapUpdate,
}

impl Stream {
    /// Every stream the daemon publishes (not [`Stream::InitialPose`], which it receives).
    pub const ALL: [Self; 4] = [
        Self::Pose(PoseStream::Odom),
        Self::Pose(PoseStream::Map),
        Self::Pose(PoseStream::Predicted),
        Self::Status,
    ];

    /// The last component of the service name.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Pose(PoseStream::Odom) => "odom",
            Self::Pose(PoseStream::Map) => "map",
            Self::Pose(PoseStream::Predicted) => "predicted",
            Self::Status => "status",
            Self::InitialPose => "initial_pose",
            Self::Sweep => "sweep",
            Self::MapUpdate => "map_update",
        }
    }
}

impl From<PoseStream> for Stream {
    fn from(stream: PoseStream) -> Self {
        Self::Pose(stream)
    }
}

impl fmt::Display for Stream {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_the_documented_scheme() {
        let d = Domain::new("agv-07_a").expect("valid domain");
        assert_eq!(
            d.service_name(PoseStream::Odom.into()),
            "glint/agv-07_a/odom"
        );
        assert_eq!(d.service_name(Stream::Status), "glint/agv-07_a/status");
        assert_eq!(d.service_name(Stream::Sweep), "glint/agv-07_a/sweep");
        assert_eq!(
            d.service_name(Stream::MapUpdate),
            "glint/agv-07_a/map_update"
        );
        assert_eq!(
            d.service_name(Stream::InitialPose),
            "glint/agv-07_a/initial_pose"
        );
        assert_eq!(
            d.event_service_name(Stream::InitialPose),
            "glint/agv-07_a/initial_pose/event"
        );
        assert_eq!(
            d.event_service_name(PoseStream::Predicted.into()),
            "glint/agv-07_a/predicted/event"
        );
    }

    #[test]
    fn domain_validation() {
        assert_eq!(Domain::new(""), Err(DomainError::Empty));
        assert_eq!(
            Domain::new("a/b"),
            Err(DomainError::InvalidCharacter { ch: '/', index: 1 })
        );
        assert_eq!(
            Domain::new("é"),
            Err(DomainError::InvalidCharacter { ch: 'é', index: 0 })
        );
        assert_eq!(
            Domain::new(&"x".repeat(65)),
            Err(DomainError::TooLong { len: 65 })
        );
        assert!(Domain::new(&"x".repeat(64)).is_ok());
    }
}

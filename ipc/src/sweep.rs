//! The `sweep` service: every sweep's points, deskewed to one instant and expressed in
//! `base_link`, with calibrated intensity, ring, time offset and feature label, for consumers
//! that need what the sensor sees (an obstacle layer, a viewer) without a second driver.
//!
//! The payload is a slice of [`SweepPoint`] with a [`SweepHeader`] as iceoryx2's user header,
//! loaned in shared memory sized for the largest sweep ([`settings::SWEEP_MAX_POINTS`]) and
//! written in place: zero copy from the daemon to every subscriber. Both types are `#[repr(C)]`
//! without padding, like the pose contract (`ipc/README.md` tables them). The service
//! keeps its own, smaller limits (see [`settings`]), so its memory is bounded and stated; a
//! subscriber that stalls loses sweeps, never slows the daemon.

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::LoanError;
use iceoryx2::prelude::{AllocationStrategy, BackpressureStrategy, Node, ZeroCopySend};
use thiserror::Error;

use crate::names::{Domain, Stream};
use crate::payload::StatusFlags;
use crate::publisher::{publisher_create_error, service_name, PublisherError};
use crate::subscriber::{open_error, subscriber_service_name, ReceiveError, SubscribeError};
use crate::{node_builder, settings, Transport};

/// What a sweep point was chosen as by the front end: bits, since a return can be a plane
/// point and an intensity point at once. No bit set: not a feature.
///
/// Bits 3..=7 are reserved: the publisher writes 0, consumers must ignore them.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Hash, ZeroCopySend)]
pub struct PointLabel(pub u8);

impl PointLabel {
    /// Not a feature.
    pub const NONE: Self = Self(0);
    /// Bit 0: an edge (a geometric corner or an intensity boundary).
    pub const EDGE: Self = Self(1 << 0);
    /// Bit 1: a plane point.
    pub const PLANE: Self = Self(1 << 1);
    /// Bit 2: an intensity point (a strong reflectivity gradient).
    pub const INTENSITY: Self = Self(1 << 2);

    /// Whether every bit of `other` is set.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0 && other.0 != 0
    }

    /// `self` with the bits of `other` set.
    pub const fn with(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
}

/// One return of a sweep, in `base_link` at the header's `timestamp_ns` (24 bytes).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("glint::SweepPointV1")]
pub struct SweepPoint {
    /// Position in `base_link` at the sweep's instant (deskewed with the estimated motion), m.
    pub position: [f32; 3],
    /// Calibrated reflectivity η (incidence-corrected, about 0–1; see `docs/odometry.md`), or
    /// NaN where it could not be calibrated (no surface normal, a weak return).
    pub intensity: f32,
    /// Firing time minus the header's `sensor_time_ns`, ns (≤ 0 within a sweep).
    pub time_offset_ns: i32,
    /// Laser ring, 0 = lowest beam.
    pub ring: u16,
    /// The sensor's raw reflectivity byte (0–100 diffuse, 101–255 retro-reflective).
    pub reflectivity: u8,
    /// What the front end chose it as.
    pub label: PointLabel,
}

/// The sweep's header, iceoryx2's user header of the `sweep` service (136 bytes).
///
/// A point's `position` is `M · exp(dt·ξ) · p`, where `p` is the return in the sensor frame at
/// its firing (what `glintd decode` prints), `dt = time_offset_ns · 10⁻⁹` s, `ξ` is
/// [`sensor_twist`](Self::sensor_twist) and `M` the mounting
/// ([`sensor_position`](Self::sensor_position), [`sensor_orientation`](Self::sensor_orientation)):
/// with both in the header, a consumer can undo either step.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("glint::SweepHeaderV1")]
pub struct SweepHeader {
    /// The instant the points are deskewed to (the sweep's last firing), on the time base of the
    /// poses (`PoseV1::timestamp_ns`): the `odom` pose with the same stamp is where
    /// `base_link` was, ns since the Unix epoch.
    pub timestamp_ns: u64,
    /// The same instant on the sensor's own clock (see `glint_driver::clock`), ns; the points'
    /// `time_offset_ns` count from it.
    pub sensor_time_ns: u64,
    /// Sweeps published since the daemon started, from 0; a gap means sweeps not published.
    pub sequence: u64,
    /// Points in the payload (its slice length).
    pub point_count: u32,
    /// The status flags of the sweep's `odom` pose.
    pub flags: StatusFlags,
    /// The body twist the points were deskewed with, sensor frame: angular (rad/s) then linear
    /// (m/s), as `SE(3)`'s exponential takes it (`ξ = [ω; υ]`).
    pub sensor_twist: [f64; 6],
    /// The mounting, `base_link ← sensor`: translation, m.
    pub sensor_position: [f64; 3],
    /// The mounting's rotation, unit quaternion `[x, y, z, w]` as in `PoseV1`.
    pub sensor_orientation: [f64; 4],
}

impl SweepPoint {
    /// The iceoryx2 type name of the payload's elements, as other languages must spell it.
    pub const TYPE_NAME: &'static str = "glint::SweepPointV1";
}

impl SweepHeader {
    /// The iceoryx2 type name of the user header, as other languages must spell it.
    pub const TYPE_NAME: &'static str = "glint::SweepHeaderV1";
}

/// Why a sweep could not be published. The publisher stays usable.
#[derive(Debug, Error)]
pub enum SweepPublishError {
    /// The sweep holds more points than the service's samples ([`settings::SWEEP_MAX_POINTS`]).
    #[error("a sweep of {points} points exceeds the sweep service's {max}")]
    TooManyPoints {
        /// The sweep's points.
        points: usize,
        /// The limit.
        max: usize,
    },
    /// No sample could be loaned (every sample held by slow subscribers and in history).
    #[error("cannot loan a sweep sample")]
    Loan(#[source] LoanError),
    /// The sample could not be delivered.
    #[error("cannot send on sweep")]
    Send(#[source] iceoryx2::port::SendError),
}

/// The daemon's side of the `sweep` service: its own iceoryx2 node, so it can live on a thread
/// of its own, off the pose path.
#[derive(Debug)]
pub struct SweepPublisher {
    publisher: Publisher<Transport, [SweepPoint], SweepHeader>,
    sequence: u64,
    // Declared last so the port above is dropped before the node that owns its resources.
    _node: Node<Transport>,
}

impl SweepPublisher {
    /// Creates (or re-opens) `glint/<domain>/sweep` with the sweep settings of [`settings`].
    pub fn create(domain: &Domain) -> Result<Self, PublisherError> {
        let node = node_builder(&format!("glintd-sweep/{domain}"))
            .create::<Transport>()
            .map_err(PublisherError::Node)?;
        let name = domain.service_name(Stream::Sweep);
        let service = node
            .service_builder(&service_name(&name)?)
            .publish_subscribe::<[SweepPoint]>()
            .user_header::<SweepHeader>()
            .history_size(settings::SWEEP_HISTORY_SIZE)
            .subscriber_max_buffer_size(settings::SWEEP_SUBSCRIBER_BUFFER_SIZE)
            .subscriber_max_borrowed_samples(settings::SWEEP_MAX_BORROWED_SAMPLES)
            .max_subscribers(settings::SWEEP_MAX_SUBSCRIBERS)
            .max_publishers(settings::MAX_PUBLISHERS)
            .max_nodes(settings::MAX_NODES)
            .enable_safe_overflow(settings::SAFE_OVERFLOW)
            .open_or_create()
            .map_err(|source| PublisherError::Service {
                service: name.clone(),
                source,
            })?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(settings::SWEEP_MAX_POINTS)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(publisher_create_error(domain, &name))?;
        Ok(Self {
            publisher,
            sequence: 0,
            _node: node,
        })
    }

    /// Publishes one sweep of `count` points, writing point `i` as `point(i)` straight into
    /// shared memory; the header's `point_count` and `sequence` are filled in here.
    pub fn publish(
        &mut self,
        header: SweepHeader,
        count: usize,
        point: impl FnMut(usize) -> SweepPoint,
    ) -> Result<(), SweepPublishError> {
        if count > settings::SWEEP_MAX_POINTS {
            return Err(SweepPublishError::TooManyPoints {
                points: count,
                max: settings::SWEEP_MAX_POINTS,
            });
        }
        let mut sample = self
            .publisher
            .loan_slice_uninit(count)
            .map_err(SweepPublishError::Loan)?;
        *sample.user_header_mut() = SweepHeader {
            sequence: self.sequence,
            point_count: count as u32,
            ..header
        };
        let sample = sample.write_from_fn(point);
        sample.send().map_err(SweepPublishError::Send)?;
        self.sequence += 1;
        Ok(())
    }

    /// Connects subscribers that arrived since the last publish (they get the last sweep).
    pub fn update_connections(
        &self,
    ) -> Result<(), iceoryx2::port::update_connections::ConnectionFailure> {
        use iceoryx2::port::update_connections::UpdateConnections;
        self.publisher.update_connections()
    }
}

/// A consumer of a domain's `sweep` service. Sweeps come at the sensor's rate; poll with
/// [`try_next`](Self::try_next) (there is no event service beside it). A subscriber keeps
/// [`settings::SWEEP_SUBSCRIBER_BUFFER_SIZE`] sweeps; older ones are overwritten.
#[derive(Debug)]
pub struct SweepSubscriber {
    subscriber: Subscriber<Transport, [SweepPoint], SweepHeader>,
    // Declared last so the port above is dropped before the node that owns its resources.
    _node: Node<Transport>,
}

impl SweepSubscriber {
    /// Opens `glint/<domain>/sweep`.
    pub fn open(domain: &Domain) -> Result<Self, SubscribeError> {
        let node = node_builder(&format!("glint-subscriber/{domain}/sweep"))
            .create::<Transport>()
            .map_err(SubscribeError::Node)?;
        let name = domain.service_name(Stream::Sweep);
        let service = node
            .service_builder(&subscriber_service_name(&name)?)
            .publish_subscribe::<[SweepPoint]>()
            .user_header::<SweepHeader>()
            .open()
            .map_err(open_error(&name))?;
        let subscriber =
            service
                .subscriber_builder()
                .create()
                .map_err(|source| SubscribeError::Subscriber {
                    service: name.clone(),
                    source,
                })?;
        Ok(Self {
            subscriber,
            _node: node,
        })
    }

    /// The oldest unread sweep, shown to `visit` in shared memory (no copy) and released when
    /// it returns; `None` when there is none.
    pub fn try_next<R>(
        &self,
        visit: impl FnOnce(&SweepHeader, &[SweepPoint]) -> R,
    ) -> Result<Option<R>, ReceiveError> {
        let sample = self
            .subscriber
            .receive()
            .map_err(|source| ReceiveError::Receive {
                stream: Stream::Sweep,
                source,
            })?;
        Ok(sample.map(|s| visit(s.user_header(), s.payload())))
    }
}

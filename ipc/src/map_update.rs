//! The `map_update` service: the map the daemon localises in, as keyframes — each keyframe's
//! points in its own sensor frame, the keyframes' poses in the map frame and the pose graph's
//! loop edges — so a consumer (a viewer, a planner's costmap) can hold the map and move each
//! keyframe's points when an optimisation moves its pose, without a copy of the map file.
//!
//! A sample is one message under a [`MapUpdateHeader`]: its `kind` says which records the byte
//! payload holds ([`MapPoint`], [`KeyframePose`] or [`MapEdge`], little-endian `#[repr(C)]`
//! layouts tabled in `ipc/README.md`). Messages are idempotent: a keyframe's cloud or pose
//! replaces what the consumer held for that keyframe, so the full map sent again for a new
//! subscriber (flag [`MapUpdateFlags::REPLAY`]) is harmless to those that have it. Large
//! messages are split into parts of at most [`settings::MAP_UPDATE_MAX_BYTES`]; the service's
//! own limits (see [`settings`]) bound its shared memory, and a stalled subscriber loses
//! messages, never slows the daemon.

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::LoanError;
use iceoryx2::prelude::{
    Alignment, AllocationStrategy, BackpressureStrategy, CallbackProgression, Node, PortFactory,
    ZeroCopySend,
};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use thiserror::Error;

use crate::names::{Domain, Stream};
use crate::publisher::{publisher_create_error, service_name, PublisherError};
use crate::subscriber::{open_error, subscriber_service_name, ReceiveError, SubscribeError};
use crate::{node_builder, settings, Transport};

/// What a message's payload holds (the header's `kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum MapUpdateKind {
    /// 1: one keyframe's points ([`MapPoint`]s) in its sensor frame.
    Cloud = 1,
    /// 2: keyframes' poses ([`KeyframePose`]s) in the map frame.
    KeyframePoses = 2,
    /// 3: the pose graph's edges other than consecutive keyframes' ([`MapEdge`]s): loops.
    Edges = 3,
}

impl MapUpdateKind {
    /// The kind of a header's `kind` field; `None` for one this version does not know
    /// (consumers skip it).
    pub const fn from_u32(kind: u32) -> Option<Self> {
        match kind {
            1 => Some(Self::Cloud),
            2 => Some(Self::KeyframePoses),
            3 => Some(Self::Edges),
            _ => None,
        }
    }

    /// Bytes per record of this kind.
    pub const fn record_size(self) -> usize {
        match self {
            Self::Cloud => MapPoint::SIZE,
            Self::KeyframePoses => KeyframePose::SIZE,
            Self::Edges => MapEdge::SIZE,
        }
    }
}

/// Bits of the header's `flags`. Bits 2..=31 are reserved: 0 from the daemon, ignored by
/// consumers.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Hash, ZeroCopySend)]
pub struct MapUpdateFlags(pub u32);

impl MapUpdateFlags {
    /// Bit 0: the map is a saved site map the daemon localises in; it does not change.
    pub const SAVED_MAP: Self = Self(1 << 0);
    /// Bit 1: part of the whole map sent again because a subscriber connected.
    pub const REPLAY: Self = Self(1 << 1);

    /// Whether every bit of `other` is set.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0 && other.0 != 0
    }

    /// `self` with the bits of `other` set.
    pub const fn with(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
}

/// A `map_update` message's header, iceoryx2's user header of the service (48 bytes).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("glint::MapUpdateHeaderV1")]
pub struct MapUpdateHeader {
    /// The newest keyframe the message reflects: its sweep's time on the sensor's clock, as
    /// `SweepHeader::sensor_time_ns` (a `Cloud`: its own keyframe's), ns.
    pub sensor_time_ns: u64,
    /// Messages (parts) published since the daemon started, from 0; a gap means messages lost.
    pub sequence: u64,
    /// Which map: the saved map's creation time, or the run's start when mapping (ns). A new
    /// value means a new map: drop what was held.
    pub map_id: u64,
    /// [`MapUpdateKind`] as a number.
    pub kind: u32,
    /// `Cloud`: the keyframe the points belong to (its index in the map, from 0); else 0.
    pub keyframe: u32,
    /// Records in the payload.
    pub count: u32,
    /// This part's index, from 0.
    pub part: u16,
    /// Parts of the message; a consumer applies a `Cloud` once it holds them all.
    pub parts: u16,
    /// Keyframes in the map when the message was sent.
    pub keyframes: u32,
    /// [`MapUpdateFlags`].
    pub flags: MapUpdateFlags,
}

impl MapUpdateHeader {
    /// The iceoryx2 type name of the user header, as other languages must spell it.
    pub const TYPE_NAME: &'static str = "glint::MapUpdateHeaderV1";
}

/// A record of a `map_update` payload: its size and little-endian layout.
pub trait MapRecord: Sized + Copy {
    /// The kind of message made of these records.
    const KIND: MapUpdateKind;
    /// Bytes per record.
    const SIZE: usize;
    /// Writes the record into `out` (`SIZE` bytes).
    fn write(&self, out: &mut [u8]);
    /// Reads a record from `bytes` (`SIZE` bytes).
    fn read(bytes: &[u8]) -> Self;
}

/// A point of a keyframe's cloud (16 bytes).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// In the keyframe's sensor frame, m.
    pub position: [f32; 3],
    /// Calibrated reflectivity η, as in `SweepPointV1`.
    pub intensity: f32,
}

/// A keyframe's pose (72 bytes): the sensor's, `map ← sensor`, in the frame of the `map`
/// stream.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct KeyframePose {
    /// The keyframe's index in the map, from 0.
    pub keyframe: u32,
    /// Reserved, 0.
    pub reserved: u32,
    /// The keyframe's sweep time on the sensor's clock, as `SweepHeader::sensor_time_ns`, ns.
    pub sensor_time_ns: u64,
    /// Translation, m.
    pub position: [f64; 3],
    /// Rotation, unit quaternion `[x, y, z, w]` as in `PoseV1`.
    pub orientation: [f64; 4],
}

/// An edge of the pose graph between keyframes that are not consecutive: a loop closure
/// (8 bytes). Consecutive keyframes are always joined by odometry and are not sent.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MapEdge {
    /// The earlier keyframe's index.
    pub from: u32,
    /// The later keyframe's index.
    pub to: u32,
}

fn f32_at(bytes: &[u8], at: usize) -> f32 {
    f32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(b)
}

fn f64_at(bytes: &[u8], at: usize) -> f64 {
    f64::from_bits(u64_at(bytes, at))
}

impl MapRecord for MapPoint {
    const KIND: MapUpdateKind = MapUpdateKind::Cloud;
    const SIZE: usize = 16;

    fn write(&self, out: &mut [u8]) {
        for (i, v) in self.position.iter().chain([&self.intensity]).enumerate() {
            out[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
        }
    }

    fn read(bytes: &[u8]) -> Self {
        Self {
            position: [f32_at(bytes, 0), f32_at(bytes, 4), f32_at(bytes, 8)],
            intensity: f32_at(bytes, 12),
        }
    }
}

impl MapRecord for KeyframePose {
    const KIND: MapUpdateKind = MapUpdateKind::KeyframePoses;
    const SIZE: usize = 72;

    fn write(&self, out: &mut [u8]) {
        out[0..4].copy_from_slice(&self.keyframe.to_le_bytes());
        out[4..8].copy_from_slice(&self.reserved.to_le_bytes());
        out[8..16].copy_from_slice(&self.sensor_time_ns.to_le_bytes());
        for (i, v) in self.position.iter().chain(&self.orientation).enumerate() {
            out[16 + 8 * i..24 + 8 * i].copy_from_slice(&v.to_le_bytes());
        }
    }

    fn read(bytes: &[u8]) -> Self {
        let f = |i: usize| f64_at(bytes, 16 + 8 * i);
        Self {
            keyframe: u32_at(bytes, 0),
            reserved: u32_at(bytes, 4),
            sensor_time_ns: u64_at(bytes, 8),
            position: [f(0), f(1), f(2)],
            orientation: [f(3), f(4), f(5), f(6)],
        }
    }
}

impl MapRecord for MapEdge {
    const KIND: MapUpdateKind = MapUpdateKind::Edges;
    const SIZE: usize = 8;

    fn write(&self, out: &mut [u8]) {
        out[0..4].copy_from_slice(&self.from.to_le_bytes());
        out[4..8].copy_from_slice(&self.to.to_le_bytes());
    }

    fn read(bytes: &[u8]) -> Self {
        Self {
            from: u32_at(bytes, 0),
            to: u32_at(bytes, 4),
        }
    }
}

/// The records of a message, read from its payload.
#[derive(Debug, Clone, PartialEq)]
pub enum MapContent {
    /// A keyframe's points (the header's `keyframe`).
    Cloud(Vec<MapPoint>),
    /// Keyframes' poses.
    KeyframePoses(Vec<KeyframePose>),
    /// Loop edges.
    Edges(Vec<MapEdge>),
    /// A kind this version does not know, or a payload shorter than `count` records of its
    /// kind: skipped.
    Unreadable,
}

/// One received message (one part).
#[derive(Debug, Clone, PartialEq)]
pub struct MapUpdate {
    /// Its header.
    pub header: MapUpdateHeader,
    /// Its records.
    pub content: MapContent,
}

fn read_records<R: MapRecord>(payload: &[u8], count: usize) -> Option<Vec<R>> {
    let bytes = payload.get(..count.checked_mul(R::SIZE)?)?;
    Some(bytes.chunks_exact(R::SIZE).map(R::read).collect())
}

impl MapUpdate {
    /// Reads a message's payload as its header says.
    pub fn read(header: &MapUpdateHeader, payload: &[u8]) -> Self {
        let count = header.count as usize;
        let content = match MapUpdateKind::from_u32(header.kind) {
            Some(MapUpdateKind::Cloud) => read_records(payload, count).map(MapContent::Cloud),
            Some(MapUpdateKind::KeyframePoses) => {
                read_records(payload, count).map(MapContent::KeyframePoses)
            }
            Some(MapUpdateKind::Edges) => read_records(payload, count).map(MapContent::Edges),
            None => None,
        };
        Self {
            header: *header,
            content: content.unwrap_or(MapContent::Unreadable),
        }
    }
}

/// Why a message could not be published. The publisher stays usable.
#[derive(Debug, Error)]
pub enum MapUpdatePublishError {
    /// More parts than the header can count.
    #[error("a map message of {records} records needs more than {max} parts", max = u16::MAX)]
    TooLarge {
        /// The message's records.
        records: usize,
    },
    /// No sample could be loaned (every sample held by slow subscribers).
    #[error("cannot loan a map_update sample")]
    Loan(#[source] LoanError),
    /// The sample could not be delivered.
    #[error("cannot send on map_update")]
    Send(#[source] iceoryx2::port::SendError),
}

/// The daemon's side of the `map_update` service: its own iceoryx2 node, so it can live on a
/// thread of its own, off the pose path. It also watches who subscribes, so the whole map can
/// be sent to each new subscriber.
#[derive(Debug)]
pub struct MapUpdatePublisher {
    publisher: Publisher<Transport, [u8], MapUpdateHeader>,
    service: PubSubFactory<Transport, [u8], MapUpdateHeader>,
    sequence: u64,
    /// A part's bytes before they are copied into the sample.
    scratch: Vec<u8>,
    /// The subscribers seen at the last [`Self::new_subscribers`], sorted.
    known: Vec<String>,
    // Declared last so the ports above are dropped before the node that owns their resources.
    _node: Node<Transport>,
}

impl MapUpdatePublisher {
    /// Records of type `R` that fit one part.
    pub const fn records_per_part<R: MapRecord>() -> usize {
        settings::MAP_UPDATE_MAX_BYTES / R::SIZE
    }

    /// Creates (or re-opens) `glint/<domain>/map_update` with the settings of [`settings`].
    pub fn create(domain: &Domain) -> Result<Self, PublisherError> {
        let node = node_builder(&format!("glintd-map/{domain}"))
            .create::<Transport>()
            .map_err(PublisherError::Node)?;
        let name = domain.service_name(Stream::MapUpdate);
        let alignment = Alignment::new(8).expect("8 is a power of two");
        let service = node
            .service_builder(&service_name(&name)?)
            .publish_subscribe::<[u8]>()
            .user_header::<MapUpdateHeader>()
            .payload_alignment(alignment)
            .history_size(0)
            .subscriber_max_buffer_size(settings::MAP_UPDATE_SUBSCRIBER_BUFFER_SIZE)
            .subscriber_max_borrowed_samples(1)
            .max_subscribers(settings::MAP_UPDATE_MAX_SUBSCRIBERS)
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
            .initial_max_slice_len(settings::MAP_UPDATE_MAX_BYTES)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(publisher_create_error(domain, &name))?;
        Ok(Self {
            publisher,
            service,
            sequence: 0,
            scratch: Vec::with_capacity(settings::MAP_UPDATE_MAX_BYTES),
            known: Vec::new(),
            _node: node,
        })
    }

    /// Whether a subscriber connected since the last call; connects it (a sample sent before
    /// this would not reach it).
    pub fn new_subscribers(
        &mut self,
    ) -> Result<bool, iceoryx2::port::update_connections::ConnectionFailure> {
        use iceoryx2::port::update_connections::UpdateConnections;
        let mut now = Vec::new();
        self.service.dynamic_config().list_subscribers(|details| {
            now.push(details.subscriber_id.to_string());
            CallbackProgression::Continue
        });
        now.sort_unstable();
        let arrived = now.iter().any(|id| self.known.binary_search(id).is_err());
        self.known = now;
        if arrived {
            self.publisher.update_connections()?;
        }
        Ok(arrived)
    }

    /// Subscribers connected at the last [`Self::new_subscribers`].
    pub fn subscribers(&self) -> usize {
        self.known.len()
    }

    /// Publishes `records` as one message, in as many parts as it takes; `header`'s
    /// `kind`, `count`, `part`, `parts` and `sequence` are filled in here. Returns the parts
    /// sent.
    pub fn publish<R: MapRecord>(
        &mut self,
        header: MapUpdateHeader,
        records: &[R],
    ) -> Result<usize, MapUpdatePublishError> {
        let per_part = Self::records_per_part::<R>();
        let parts = records.len().div_ceil(per_part).max(1);
        let parts = u16::try_from(parts).map_err(|_| MapUpdatePublishError::TooLarge {
            records: records.len(),
        })?;
        for part in 0..parts {
            let start = usize::from(part) * per_part;
            let chunk = &records[start.min(records.len())..(start + per_part).min(records.len())];
            let mut sample = self
                .publisher
                .loan_slice_uninit(chunk.len() * R::SIZE)
                .map_err(MapUpdatePublishError::Loan)?;
            *sample.user_header_mut() = MapUpdateHeader {
                kind: R::KIND as u32,
                count: chunk.len() as u32,
                part,
                parts,
                sequence: self.sequence,
                ..header
            };
            self.scratch.clear();
            self.scratch.resize(chunk.len() * R::SIZE, 0);
            for (record, out) in chunk.iter().zip(self.scratch.chunks_exact_mut(R::SIZE)) {
                record.write(out);
            }
            let sample = sample.write_from_slice(&self.scratch);
            sample.send().map_err(MapUpdatePublishError::Send)?;
            self.sequence += 1;
        }
        Ok(usize::from(parts))
    }
}

/// A consumer of a domain's `map_update` service; poll with [`try_next`](Self::try_next). A
/// subscriber keeps [`settings::MAP_UPDATE_SUBSCRIBER_BUFFER_SIZE`] messages; older ones are
/// overwritten, so a consumer reads at least as often as the daemon sends a new subscriber's
/// map (see [`settings::MAP_UPDATE_REPLAY_RATE`]).
#[derive(Debug)]
pub struct MapUpdateSubscriber {
    subscriber: Subscriber<Transport, [u8], MapUpdateHeader>,
    // Declared last so the port above is dropped before the node that owns its resources.
    _node: Node<Transport>,
}

impl MapUpdateSubscriber {
    /// Opens `glint/<domain>/map_update`.
    pub fn open(domain: &Domain) -> Result<Self, SubscribeError> {
        let node = node_builder(&format!("glint-subscriber/{domain}/map_update"))
            .create::<Transport>()
            .map_err(SubscribeError::Node)?;
        let name = domain.service_name(Stream::MapUpdate);
        let alignment = Alignment::new(8).expect("8 is a power of two");
        let service = node
            .service_builder(&subscriber_service_name(&name)?)
            .publish_subscribe::<[u8]>()
            .user_header::<MapUpdateHeader>()
            .payload_alignment(alignment)
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

    /// The oldest unread message, read out of shared memory; `None` when there is none.
    pub fn try_next(&self) -> Result<Option<MapUpdate>, ReceiveError> {
        let sample = self
            .subscriber
            .receive()
            .map_err(|source| ReceiveError::Receive {
                stream: Stream::MapUpdate,
                source,
            })?;
        Ok(sample.map(|s| MapUpdate::read(s.user_header(), s.payload())))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round_trip<R: MapRecord + PartialEq + core::fmt::Debug>(record: R) {
        let mut bytes = vec![0xAA; R::SIZE];
        record.write(&mut bytes);
        assert_eq!(R::read(&bytes), record);
    }

    #[test]
    fn records_round_trip_through_their_bytes() {
        round_trip(MapPoint {
            position: [1.5, -2.25, 3.0e-3],
            intensity: 0.625,
        });
        round_trip(KeyframePose {
            keyframe: 77,
            reserved: 0,
            sensor_time_ns: 1_700_000_000_123_456_789,
            position: [10.5, -3.25, 0.125],
            orientation: [0.0, 0.0, 0.6, 0.8],
        });
        round_trip(MapEdge { from: 3, to: 900 });
    }

    #[test]
    fn the_layout_is_little_endian_as_documented() {
        let mut bytes = [0u8; 72];
        KeyframePose {
            keyframe: 1,
            reserved: 0,
            sensor_time_ns: 2,
            position: [1.0, 0.0, 0.0],
            orientation: [0.0, 0.0, 0.0, 1.0],
        }
        .write(&mut bytes);
        assert_eq!(bytes[0], 1);
        assert_eq!(bytes[8], 2);
        assert_eq!(&bytes[16..24], &1.0f64.to_le_bytes());
        assert_eq!(&bytes[64..72], &1.0f64.to_le_bytes());
        assert_eq!(core::mem::size_of::<MapUpdateHeader>(), 48);
    }

    #[test]
    fn short_or_unknown_payloads_are_unreadable() {
        let header = MapUpdateHeader {
            kind: MapUpdateKind::Edges as u32,
            count: 2,
            ..Default::default()
        };
        assert_eq!(
            MapUpdate::read(&header, &[0; 12]).content,
            MapContent::Unreadable
        );
        assert_eq!(
            MapUpdate::read(&header, &[1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 4, 0, 0, 0]).content,
            MapContent::Edges(vec![MapEdge { from: 1, to: 2 }, MapEdge { from: 3, to: 4 }])
        );
        let unknown = MapUpdateHeader { kind: 9, ..header };
        assert_eq!(
            MapUpdate::read(&unknown, &[0; 64]).content,
            MapContent::Unreadable
        );
    }
}

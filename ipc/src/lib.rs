//! Glint's shared-memory pose contract: the payload types, the service names, and publisher and
//! subscriber wrappers over iceoryx2 (exactly 0.10.0).
//!
//! The daemon creates one [`PosePublisher`] per domain at start; consumers open a
//! [`PoseSubscriber`] or [`StatusSubscriber`]. Initial-pose hints flow the other way: the daemon
//! creates an [`InitialPoseSubscriber`], consumers open an [`InitialPosePublisher`]. Consumers in
//! other languages read the same bytes: `ipc/README.md` states the byte layout, names and
//! settings once, and `tests/layout.rs` checks the layout against it.
//!
//! | module | owns |
//! | --- | --- |
//! | [`payload`] | [`Pose`], [`Status`], [`InitialPose`], [`StatusFlags`], [`Frame`] — the wire structs |
//! | [`bytes`] | [`Pose`] and [`Status`] as little-endian bytes for byte-string transports (the fleet link) |
//! | [`names`] | [`Domain`] validation and the `glint/<domain>/<stream>[/event]` names |
//! | [`settings`] | history, buffer, overflow and port limits of the services |
//! | [`publisher`] | [`PosePublisher`] (the daemon's side) |
//! | [`subscriber`] | [`PoseSubscriber`], [`StatusSubscriber`] (the consumers' side) |
//! | [`sweep`] | the `sweep` service: [`SweepPoint`], [`SweepHeader`], [`SweepPublisher`], [`SweepSubscriber`] |
//! | [`map_update`] | the `map_update` service: [`MapUpdateHeader`], its records, [`MapUpdatePublisher`], [`MapUpdateSubscriber`] |
//! | [`initial_pose`] | hints, roles reversed: [`InitialPoseSubscriber`] (the daemon's side), [`InitialPosePublisher`], [`send_initial_pose`] |

pub mod bytes;
pub mod initial_pose;
pub mod map_update;
pub mod names;
pub mod payload;
pub mod publisher;
pub mod settings;
pub mod subscriber;
pub mod sweep;

pub use bytes::BytesError;
pub use initial_pose::{
    send_initial_pose, InitialPoseCreateError, InitialPoseOpenError, InitialPosePublisher,
    InitialPoseSendError, InitialPoseSubscriber, SendInitialPoseError,
};
pub use map_update::{
    KeyframePose, MapContent, MapEdge, MapPoint, MapRecord, MapUpdate, MapUpdateFlags,
    MapUpdateHeader, MapUpdateKind, MapUpdatePublishError, MapUpdatePublisher, MapUpdateSubscriber,
};
pub use names::{Domain, DomainError, PoseStream, Stream};
pub use payload::{Frame, InitialPose, InitialPoseError, Pose, Status, StatusFlags};
pub use publisher::{
    DeadNodeCleanup, PosePublisher, PublishError, PublisherError, UpdateConnectionsError,
};
pub use subscriber::{PoseSubscriber, ReceiveError, StatusSubscriber, SubscribeError, WaitError};
pub use sweep::{
    PointLabel, SweepHeader, SweepPoint, SweepPublishError, SweepPublisher, SweepSubscriber,
};

/// The iceoryx2 this crate is built on, re-exported so callers match on its error types with
/// the very same version.
pub use iceoryx2;

/// The exact iceoryx2 version of the contract; every process on the bus must use this one.
pub const ICEORYX2_VERSION: &str = "0.10.0";

/// The iceoryx2 service flavour used throughout: inter-process, with ports that are `Send` and
/// `Sync` (mutex-protected). It shares memory layout and files with `ipc::Service` (and Python's
/// `ServiceType.Ipc`), differing only in in-process locking.
type Transport = iceoryx2::service::ipc_threadsafe::Service;

/// A node builder for every port of this crate: signal handling off (the process owns SIGINT and
/// SIGTERM; iceoryx2 must not install handlers of its own) and named `name` when that is a
/// valid node name (it only labels the node in `iox2 node list`).
fn node_builder(name: &str) -> iceoryx2::prelude::NodeBuilder {
    use iceoryx2::prelude::{NodeBuilder, NodeName, SignalHandlingMode};
    let builder = NodeBuilder::new().signal_handling_mode(SignalHandlingMode::Disabled);
    match NodeName::new(name) {
        Ok(name) => builder.name(&name),
        Err(_) => builder,
    }
}

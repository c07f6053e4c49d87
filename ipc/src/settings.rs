//! The service settings the daemon creates its services with, in one place.
//!
//! iceoryx2 lets the *creator* of a service fix its settings for good; openers can only require
//! minimums. The daemon therefore creates every service with the values below (all set
//! explicitly, so a local `iceoryx2.toml` cannot change them behind our back) and consumers only
//! `open()`.

use core::time::Duration;

/// Samples a late subscriber receives on connecting: the last pose, so a controller that starts
/// after the daemon has a pose at once (delivered on the publisher's next send or
/// [`PosePublisher::update_connections`](crate::PosePublisher::update_connections)).
pub const HISTORY_SIZE: usize = 1;

/// Samples each subscriber can queue before the oldest is overwritten: 1.6 s of poses at 10 Hz.
pub const SUBSCRIBER_BUFFER_SIZE: usize = 16;

/// Samples a subscriber may hold at once. Our wrappers copy the payload out and release the
/// sample at once; 2 is iceoryx2's default and what the Python binding assumes.
pub const SUBSCRIBER_MAX_BORROWED_SAMPLES: usize = 2;

/// Subscribers per stream.
pub const MAX_SUBSCRIBERS: usize = 16;

/// Publishers per stream: one. A second daemon started on the same domain is refused
/// ([`PublisherError::DomainInUse`](crate::PublisherError::DomainInUse)) instead of interleaving
/// two pose sources; a crashed daemon's slot is freed by the dead-node cleanup at start.
pub const MAX_PUBLISHERS: usize = 1;

/// Nodes (processes, roughly) that may have one service open: every subscriber, the daemon, and
/// room for monitoring tools such as `iox2`.
pub const MAX_NODES: usize = 32;

/// Overwrite the oldest sample of a full subscriber instead of waiting for it: a stalled, crashed
/// or never-reading consumer must never slow the daemon.
pub const SAFE_OVERFLOW: bool = true;

/// Listeners per event service, one per waiting subscriber.
pub const MAX_LISTENERS: usize = MAX_SUBSCRIBERS;

/// Notifiers per event service: the daemon's, as for [`MAX_PUBLISHERS`].
pub const MAX_NOTIFIERS: usize = MAX_PUBLISHERS;

/// How long the daemon waits, per dead node, for another process already cleaning it up.
pub const DEAD_NODE_CLEANUP_TIMEOUT: Duration = Duration::from_secs(1);

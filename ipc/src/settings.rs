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

/// `initial_pose` history: none. A hint is about the robot's pose now; a daemon that subscribes
/// later (a restart) must not act on an old one.
pub const INITIAL_POSE_HISTORY_SIZE: usize = 0;

/// `initial_pose` hints the daemon's subscriber queues before the oldest is overwritten. Hints are
/// rare; the newest is the one that counts.
pub const INITIAL_POSE_BUFFER_SIZE: usize = 8;

/// `initial_pose` senders at once (each an operator tool or a fleet manager holding the service
/// open), and notifiers on its event service.
pub const INITIAL_POSE_MAX_PUBLISHERS: usize = 8;

/// `initial_pose` subscribers: the daemon's only, so a second daemon on the domain is refused
/// here as well and no other process takes hints meant for the daemon.
pub const INITIAL_POSE_MAX_SUBSCRIBERS: usize = 1;

/// How often, at the least, the daemon must poll its
/// [`InitialPoseSubscriber`](crate::InitialPoseSubscriber). Polling connects the subscriber to
/// new senders; a hint whose sender leaves before that is lost (iceoryx2 keeps undelivered
/// samples only for connections both sides have opened).
pub const INITIAL_POSE_MAX_POLL_INTERVAL: Duration = Duration::from_millis(100);

/// How long a one-shot sender ([`send_initial_pose`](crate::send_initial_pose), `glintd
/// initial-pose`, `glint_send_initial_pose`, the Python example) keeps its port open after
/// sending: five times [`INITIAL_POSE_MAX_POLL_INTERVAL`], so the daemon has connected and holds
/// the hint when the sender goes.
pub const INITIAL_POSE_SENDER_LINGER: Duration = Duration::from_millis(500);

/// Points a `sweep` sample holds: a VLP-16's or Puck Hi-Res's largest sweep with margin (dual
/// return at 300 rpm gives 115,712; at 600 rpm, 57,856), and an HDL-32E's except dual return
/// below 600 rpm; a larger sweep is not published (counted and logged). A sample is
/// 24 B × 131,072 = 3 MiB of address space; only the points written are ever touched.
pub const SWEEP_MAX_POINTS: usize = 1 << 17;

/// `sweep` history: the last sweep, so a viewer that starts has a picture at once.
pub const SWEEP_HISTORY_SIZE: usize = 1;

/// `sweep` samples each subscriber queues: two sweeps (0.2 s at 10 Hz); a consumer that wants
/// every sweep must keep up with the sensor.
pub const SWEEP_SUBSCRIBER_BUFFER_SIZE: usize = 2;

/// `sweep` samples a subscriber may hold at once: one (read it, then release it).
pub const SWEEP_MAX_BORROWED_SAMPLES: usize = 1;

/// `sweep` subscribers: an obstacle layer, a viewer, a recorder and one to spare. With
/// [`SWEEP_HISTORY_SIZE`] and the publisher's one loan, this bounds the service's samples, and
/// so its shared memory (see the README for the measured size).
pub const SWEEP_MAX_SUBSCRIBERS: usize = 4;

/// Payload bytes a `map_update` sample holds: 4,096 map points, 910 keyframe poses or 8,192
/// edges; a larger message goes in several parts. 64 KiB each.
pub const MAP_UPDATE_MAX_BYTES: usize = 64 << 10;

/// `map_update` messages each subscriber queues: 32 parts, 2 MiB. The daemon sends a new
/// subscriber's map at [`MAP_UPDATE_REPLAY_RATE`], so a consumer that reads every 100 ms loses
/// none.
pub const MAP_UPDATE_SUBSCRIBER_BUFFER_SIZE: usize = 32;

/// Parts per second, at most, of the whole map sent again for a new subscriber: 160, 10 MiB/s
/// at most, half a subscriber's buffer per 100 ms.
pub const MAP_UPDATE_REPLAY_RATE: usize = 160;

/// `map_update` subscribers: a viewer, a planner, a recorder and one to spare. With the
/// buffer above and the publisher's one loan this bounds the service's samples: 4 × (32 + 1) +
/// 1 = 133 of 64 KiB, 8.3 MiB of address space, touched only as written.
pub const MAP_UPDATE_MAX_SUBSCRIBERS: usize = 4;

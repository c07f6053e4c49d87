//! [`PoseSubscriber`] and [`StatusSubscriber`]: the consumer's side of the bus.
//!
//! Each subscriber is its own iceoryx2 node with a subscriber port on the data service and a
//! listener on its event service. Services are only ever *opened* here — the daemon creates them
//! with the settings it documents — so a missing service means the daemon is not running (or
//! runs with another domain). Payloads are copied out and the sample released at once, so a
//! consumer never holds shared memory and never hits iceoryx2's borrow limit.
//!
//! A subscriber survives a daemon restart: its ports and the services stay alive while it holds
//! them, the restarted daemon re-opens the same services, and messages simply resume (after a
//! gap in sequence numbers and timestamps). A crashed daemon shows only as silence; judge
//! liveness by the age of `timestamp_ns`, not by errors.

use core::fmt::Debug;
use std::time::{Duration, Instant};

use iceoryx2::node::NodeCreationFailure;
use iceoryx2::port::listener::{Listener, ListenerCreateError, ListenerWaitError};
use iceoryx2::port::subscriber::{Subscriber, SubscriberCreateError};
use iceoryx2::port::ReceiveError as PortReceiveError;
use iceoryx2::prelude::{Node, ServiceName, ZeroCopySend};
use iceoryx2::service::builder::event::EventOpenError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
use iceoryx2::service::service_name::ServiceNameError;
use thiserror::Error;

use crate::names::{Domain, PoseStream, Stream};
use crate::payload::{Pose, Status};
use crate::{node_builder, Transport};

/// Why opening a [`PoseSubscriber`] or [`StatusSubscriber`] failed.
#[derive(Debug, Error)]
pub enum SubscribeError {
    /// iceoryx2 refused a derived service name (cannot happen for a validated [`Domain`]).
    #[error("invalid service name {service:?}")]
    InvalidServiceName {
        /// The refused name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: ServiceNameError,
    },
    /// The iceoryx2 node could not be created (permissions on `/tmp/iceoryx2` or `/dev/shm`).
    #[error("cannot create the iceoryx2 node")]
    Node(#[source] NodeCreationFailure),
    /// The service does not exist: the daemon is not running, runs with another domain, or
    /// runs with another iceoryx2 root path or prefix (see the README on systemd).
    #[error("service {service} does not exist: is glintd running with this domain?")]
    NotRunning {
        /// The missing service.
        service: String,
    },
    /// The service exists but cannot be opened as Glint's: `IncompatibleTypes` means another
    /// payload version, `VersionMismatch` another iceoryx2 version.
    #[error("cannot open service {service}")]
    Service {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: PublishSubscribeOpenError,
    },
    /// The event service exists but cannot be opened.
    #[error("cannot open event service {service}")]
    EventService {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: EventOpenError,
    },
    /// The subscriber port could not be created; `ExceedsMaxSupportedSubscribers` means all
    /// [`settings::MAX_SUBSCRIBERS`](crate::settings::MAX_SUBSCRIBERS) slots are taken.
    #[error("cannot subscribe to {service}")]
    Subscriber {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: SubscriberCreateError,
    },
    /// The listener port could not be created.
    #[error("cannot listen on {service}")]
    Listener {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: ListenerCreateError,
    },
}

/// Why `try_next` or `try_latest` failed.
#[derive(Debug, Error)]
pub enum ReceiveError {
    /// iceoryx2 could not take a sample (a publisher's memory could not be mapped).
    #[error("cannot receive on {stream}")]
    Receive {
        /// The stream.
        stream: Stream,
        /// iceoryx2's reason.
        #[source]
        source: PortReceiveError,
    },
}

/// Why `wait_next` failed.
#[derive(Debug, Error)]
pub enum WaitError {
    /// Taking a sample failed.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// Waiting on the event service failed; `InterruptSignal` means a signal (Ctrl-C) arrived.
    #[error("cannot wait for {stream}")]
    Wait {
        /// The stream.
        stream: Stream,
        /// iceoryx2's reason.
        #[source]
        source: ListenerWaitError,
    },
}

/// The ports shared by both subscriber kinds.
#[derive(Debug)]
struct Inlet<T: Debug + ZeroCopySend + 'static> {
    stream: Stream,
    subscriber: Subscriber<Transport, T, ()>,
    listener: Listener<Transport>,
    // Declared last so the ports above are dropped before the node that owns their resources.
    _node: Node<Transport>,
}

impl<T: Debug + ZeroCopySend + Copy + 'static> Inlet<T> {
    fn open(domain: &Domain, stream: Stream) -> Result<Self, SubscribeError> {
        let node = node_builder(&format!("glint-subscriber/{domain}/{stream}"))
            .create::<Transport>()
            .map_err(SubscribeError::Node)?;

        let name = domain.service_name(stream);
        let service = node
            .service_builder(&subscriber_service_name(&name)?)
            .publish_subscribe::<T>()
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

        let event_name = domain.event_service_name(stream);
        let event = node
            .service_builder(&subscriber_service_name(&event_name)?)
            .event()
            .open()
            .map_err(|source| match source {
                EventOpenError::DoesNotExist => SubscribeError::NotRunning {
                    service: event_name.clone(),
                },
                source => SubscribeError::EventService {
                    service: event_name.clone(),
                    source,
                },
            })?;
        let listener =
            event
                .listener_builder()
                .create()
                .map_err(|source| SubscribeError::Listener {
                    service: event_name.clone(),
                    source,
                })?;

        Ok(Self {
            stream,
            subscriber,
            listener,
            _node: node,
        })
    }

    fn try_next(&self) -> Result<Option<T>, ReceiveError> {
        let stream = self.stream;
        let sample = self
            .subscriber
            .receive()
            .map_err(|source| ReceiveError::Receive { stream, source })?;
        // Copy out; the sample is released when it goes out of scope here.
        Ok(sample.map(|sample| *sample.payload()))
    }

    fn try_latest(&self) -> Result<Option<T>, ReceiveError> {
        let mut latest = None;
        while let Some(value) = self.try_next()? {
            latest = Some(value);
        }
        Ok(latest)
    }

    fn wait_next(&self, timeout: Duration) -> Result<Option<T>, WaitError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(value) = self.try_next()? {
                return Ok(Some(value));
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            // A notification follows every send, so a sample arriving between `try_next` and
            // here still ends the wait at once. A stale notification (for a sample already
            // taken) only costs one more turn of the loop.
            self.listener
                .timed_wait(|_| {}, remaining)
                .map_err(|source| WaitError::Wait {
                    stream: self.stream,
                    source,
                })?;
        }
    }
}

/// Turns iceoryx2's refusal to open service `name` into ours: a missing service means the
/// daemon is not running.
pub(crate) fn open_error(name: &str) -> impl Fn(PublishSubscribeOpenError) -> SubscribeError + '_ {
    move |source| match source {
        PublishSubscribeOpenError::DoesNotExist => SubscribeError::NotRunning {
            service: name.to_owned(),
        },
        source => SubscribeError::Service {
            service: name.to_owned(),
            source,
        },
    }
}

pub(crate) fn subscriber_service_name(name: &str) -> Result<ServiceName, SubscribeError> {
    ServiceName::new(name).map_err(|source| SubscribeError::InvalidServiceName {
        service: name.to_owned(),
        source,
    })
}

/// A consumer of one pose stream (`odom`, `map` or `predicted`) of a domain.
///
/// Messages queue up to [`settings::SUBSCRIBER_BUFFER_SIZE`](crate::settings::SUBSCRIBER_BUFFER_SIZE)
/// deep; beyond that the oldest are overwritten (see the gap in `sequence`). A controller that
/// only wants the current pose calls [`try_latest`](Self::try_latest).
///
/// ```no_run
/// use std::time::Duration;
/// use glint_ipc::{Domain, PoseStream, PoseSubscriber};
///
/// let odom = PoseSubscriber::open(&Domain::new("agv7")?, PoseStream::Odom)?;
/// while let Some(pose) = odom.wait_next(Duration::from_secs(1))? {
///     println!("{} {:?} {}", pose.sequence, pose.position, pose.status);
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct PoseSubscriber {
    inlet: Inlet<Pose>,
}

impl PoseSubscriber {
    /// Opens `glint/<domain>/<stream>` and its event service. Fails with
    /// [`SubscribeError::NotRunning`] when the daemon has not created them.
    pub fn open(domain: &Domain, stream: PoseStream) -> Result<Self, SubscribeError> {
        Ok(Self {
            inlet: Inlet::open(domain, stream.into())?,
        })
    }

    /// The oldest unread pose, or `None` if there is none. Never blocks.
    pub fn try_next(&self) -> Result<Option<Pose>, ReceiveError> {
        self.inlet.try_next()
    }

    /// The newest pose, discarding older unread ones, or `None` if there is none. Never blocks.
    pub fn try_latest(&self) -> Result<Option<Pose>, ReceiveError> {
        self.inlet.try_latest()
    }

    /// The oldest unread pose, sleeping on the event service until one arrives or `timeout`
    /// passes (`None`).
    pub fn wait_next(&self, timeout: Duration) -> Result<Option<Pose>, WaitError> {
        self.inlet.wait_next(timeout)
    }
}

/// A consumer of the `status` stream of a domain; see [`PoseSubscriber`].
#[derive(Debug)]
pub struct StatusSubscriber {
    inlet: Inlet<Status>,
}

impl StatusSubscriber {
    /// Opens `glint/<domain>/status` and its event service. Fails with
    /// [`SubscribeError::NotRunning`] when the daemon has not created them.
    pub fn open(domain: &Domain) -> Result<Self, SubscribeError> {
        Ok(Self {
            inlet: Inlet::open(domain, Stream::Status)?,
        })
    }

    /// The oldest unread status, or `None`. Never blocks.
    pub fn try_next(&self) -> Result<Option<Status>, ReceiveError> {
        self.inlet.try_next()
    }

    /// The newest status, discarding older unread ones, or `None`. Never blocks.
    pub fn try_latest(&self) -> Result<Option<Status>, ReceiveError> {
        self.inlet.try_latest()
    }

    /// The oldest unread status, sleeping on the event service until one arrives or `timeout`
    /// passes (`None`).
    pub fn wait_next(&self, timeout: Duration) -> Result<Option<Status>, WaitError> {
        self.inlet.wait_next(timeout)
    }
}

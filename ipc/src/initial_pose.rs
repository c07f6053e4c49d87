//! The `initial_pose` service, where the roles of the pose streams are reversed: consumers (an
//! operator's tool, a fleet manager) publish [`InitialPose`] hints with an
//! [`InitialPosePublisher`], and the daemon receives them with its [`InitialPoseSubscriber`].
//!
//! The daemon still creates the service, at start, with the settings in [`settings`] (history 0,
//! up to 8 senders, one subscriber), so a sender only ever *opens* it and a missing service means
//! no daemon runs. Both sides validate: a sender refuses to send an invalid hint, and the daemon
//! skips and counts any that arrive anyway (from a sender in another language).
//!
//! Delivery. iceoryx2 keeps a sample for a subscriber only once the subscriber has opened the
//! connection to its sender, which it does when polled. A sender that goes away before the
//! daemon's next poll loses its hint; hence the daemon polls at least every
//! [`settings::INITIAL_POSE_MAX_POLL_INTERVAL`] and one-shot senders
//! ([`send_initial_pose`]) keep their port open for [`settings::INITIAL_POSE_SENDER_LINGER`].

use core::sync::atomic::{AtomicU64, Ordering};
use core::time::Duration;
use std::sync::{Mutex, PoisonError};

use iceoryx2::node::NodeCreationFailure;
use iceoryx2::port::listener::{Listener, ListenerCreateError};
use iceoryx2::port::notifier::{Notifier, NotifierCreateError, NotifierNotifyError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::{Subscriber, SubscriberCreateError};
use iceoryx2::port::SendError;
use iceoryx2::prelude::{BackpressureStrategy, Node, ServiceName};
use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::service_name::ServiceNameError;
use thiserror::Error;

use crate::names::{Domain, Stream};
use crate::payload::{InitialPose, InitialPoseError};
use crate::subscriber::{ReceiveError, WaitError};
use crate::{node_builder, settings, Transport};

/// Why [`InitialPoseSubscriber::create`] failed.
#[derive(Debug, Error)]
pub enum InitialPoseCreateError {
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
    /// Another live daemon already receives this domain's hints.
    #[error("domain {domain:?} already has a daemon receiving initial poses ({service})")]
    DomainInUse {
        /// The contested domain.
        domain: String,
        /// The service whose only subscriber slot is taken.
        service: String,
    },
    /// The service could not be created or opened; `DoesNotSupportRequested…` or
    /// `IncompatibleTypes` when senders still hold a service made with other settings or
    /// another payload version.
    #[error("cannot create or open service {service}")]
    Service {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: PublishSubscribeOpenOrCreateError,
    },
    /// The event service could not be created or opened.
    #[error("cannot create or open event service {service}")]
    EventService {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: EventOpenOrCreateError,
    },
    /// The subscriber port could not be created.
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

/// Why [`InitialPosePublisher::open`] failed.
#[derive(Debug, Error)]
pub enum InitialPoseOpenError {
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
    /// The service does not exist: no daemon runs with this domain (or it runs with another
    /// iceoryx2 root path or prefix).
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
    /// Every sender slot is taken.
    #[error(
        "all {max} sender slots of {service} are taken; close an idle sender",
        max = settings::INITIAL_POSE_MAX_PUBLISHERS
    )]
    TooManySenders {
        /// The service name.
        service: String,
    },
    /// The publisher port could not be created.
    #[error("cannot publish on {service}")]
    Publisher {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: PublisherCreateError,
    },
    /// The notifier port could not be created.
    #[error("cannot notify on {service}")]
    Notifier {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: NotifierCreateError,
    },
}

/// Why [`InitialPosePublisher::send`] failed. The publisher stays usable.
#[derive(Debug, Error)]
pub enum InitialPoseSendError {
    /// The hint is invalid; nothing was sent.
    #[error("refusing to send the hint")]
    Invalid(#[from] InitialPoseError),
    /// The sample could not be loaned or delivered.
    #[error("cannot send on {}", Stream::InitialPose)]
    Send(#[source] SendError),
    /// The hint was delivered but the daemon could not be woken; it sees the hint on its next
    /// poll.
    #[error("sent on {} but could not notify the daemon", Stream::InitialPose)]
    Notify(#[source] NotifierNotifyError),
}

/// Why [`send_initial_pose`] failed.
#[derive(Debug, Error)]
pub enum SendInitialPoseError {
    /// Opening the service failed.
    #[error(transparent)]
    Open(#[from] InitialPoseOpenError),
    /// Sending failed.
    #[error(transparent)]
    Send(#[from] InitialPoseSendError),
}

/// The daemon's side of `glint/<domain>/initial_pose`: creates the service and its event service
/// and receives validated hints.
///
/// Poll [`try_next`](Self::try_next) or [`try_latest`](Self::try_latest) at least every
/// [`settings::INITIAL_POSE_MAX_POLL_INTERVAL`] (each poll also connects new senders), or sleep
/// in [`wait_next`](Self::wait_next). Invalid hints are skipped and counted
/// ([`rejected`](Self::rejected), [`last_rejection`](Self::last_rejection)).
///
/// ```no_run
/// use glint_ipc::{Domain, InitialPoseSubscriber};
///
/// let hints = InitialPoseSubscriber::create(&Domain::new("agv7")?)?;
/// // In the localiser's loop, once per sweep:
/// if let Some(hint) = hints.try_latest()? {
///     println!("search near {:?} (σ {} m)", hint.position, hint.position_sigma);
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct InitialPoseSubscriber {
    subscriber: Subscriber<Transport, InitialPose, ()>,
    listener: Listener<Transport>,
    // Atomic and a mutex (uncontended) rather than cells, so the subscriber stays `Sync` like
    // the daemon's other ports.
    rejected: AtomicU64,
    last_rejection: Mutex<Option<InitialPoseError>>,
    // Declared last so the ports above are dropped before the node that owns their resources.
    _node: Node<Transport>,
}

impl InitialPoseSubscriber {
    /// Creates (or, after a daemon restart while senders hold it, re-opens) the services
    /// `glint/<domain>/initial_pose` and `…/initial_pose/event` with the settings in
    /// [`settings`], with a subscriber and a listener on them.
    pub fn create(domain: &Domain) -> Result<Self, InitialPoseCreateError> {
        use InitialPoseCreateError as E;
        let stream = Stream::InitialPose;
        let node = node_builder(&format!("glintd/{domain}/{stream}"))
            .create::<Transport>()
            .map_err(E::Node)?;

        let name = domain.service_name(stream);
        let service = node
            .service_builder(
                &service_name(&name)
                    .map_err(|(service, source)| E::InvalidServiceName { service, source })?,
            )
            .publish_subscribe::<InitialPose>()
            .history_size(settings::INITIAL_POSE_HISTORY_SIZE)
            .subscriber_max_buffer_size(settings::INITIAL_POSE_BUFFER_SIZE)
            .subscriber_max_borrowed_samples(settings::SUBSCRIBER_MAX_BORROWED_SAMPLES)
            .max_subscribers(settings::INITIAL_POSE_MAX_SUBSCRIBERS)
            .max_publishers(settings::INITIAL_POSE_MAX_PUBLISHERS)
            .max_nodes(settings::MAX_NODES)
            // A daemon that stops reading must never block a sender.
            .enable_safe_overflow(settings::SAFE_OVERFLOW)
            .open_or_create()
            .map_err(|source| E::Service {
                service: name.clone(),
                source,
            })?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(settings::INITIAL_POSE_BUFFER_SIZE)
            .create()
            .map_err(|source| match source {
                SubscriberCreateError::ExceedsMaxSupportedSubscribers => E::DomainInUse {
                    domain: domain.to_string(),
                    service: name.clone(),
                },
                source => E::Subscriber {
                    service: name.clone(),
                    source,
                },
            })?;

        let event_name = domain.event_service_name(stream);
        let event = node
            .service_builder(
                &service_name(&event_name)
                    .map_err(|(service, source)| E::InvalidServiceName { service, source })?,
            )
            .event()
            .max_listeners(settings::INITIAL_POSE_MAX_SUBSCRIBERS)
            .max_notifiers(settings::INITIAL_POSE_MAX_PUBLISHERS)
            .max_nodes(settings::MAX_NODES)
            .disable_deadline()
            .disable_notifier_created_event()
            .disable_notifier_dropped_event()
            .disable_notifier_dead_event()
            .open_or_create()
            .map_err(|source| E::EventService {
                service: event_name.clone(),
                source,
            })?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|source| E::Listener {
                service: event_name.clone(),
                source,
            })?;
        Ok(Self {
            subscriber,
            listener,
            rejected: AtomicU64::new(0),
            last_rejection: Mutex::new(None),
            _node: node,
        })
    }

    /// The oldest unread valid hint, or `None`. Never blocks; invalid hints on the way are
    /// skipped and counted.
    pub fn try_next(&self) -> Result<Option<InitialPose>, ReceiveError> {
        loop {
            let sample = self
                .subscriber
                .receive()
                .map_err(|source| ReceiveError::Receive {
                    stream: Stream::InitialPose,
                    source,
                })?;
            // Copy out; the sample is released at the end of this statement.
            let Some(hint) = sample.map(|s| *s.payload()) else {
                return Ok(None);
            };
            match hint.validate() {
                Ok(()) => return Ok(Some(hint)),
                Err(e) => {
                    self.rejected.fetch_add(1, Ordering::Relaxed);
                    *self
                        .last_rejection
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner) = Some(e);
                }
            }
        }
    }

    /// The newest unread valid hint, discarding older ones, or `None`. Never blocks.
    pub fn try_latest(&self) -> Result<Option<InitialPose>, ReceiveError> {
        let mut latest = None;
        while let Some(hint) = self.try_next()? {
            latest = Some(hint);
        }
        Ok(latest)
    }

    /// The oldest unread valid hint, sleeping on the event service (senders notify after each
    /// hint) until one arrives or `timeout` passes (`None`).
    pub fn wait_next(&self, timeout: Duration) -> Result<Option<InitialPose>, WaitError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if let Some(hint) = self.try_next()? {
                return Ok(Some(hint));
            }
            let remaining = deadline.saturating_duration_since(std::time::Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            self.listener
                .timed_wait(|_| {}, remaining)
                .map_err(|source| WaitError::Wait {
                    stream: Stream::InitialPose,
                    source,
                })?;
        }
    }

    /// Invalid hints received and skipped since creation.
    pub fn rejected(&self) -> u64 {
        self.rejected.load(Ordering::Relaxed)
    }

    /// Why the latest skipped hint was invalid, for the log.
    pub fn last_rejection(&self) -> Option<InitialPoseError> {
        self.last_rejection
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }
}

/// A consumer's sender of hints on `glint/<domain>/initial_pose`. Opens, never creates: the
/// daemon must be running.
///
/// Keep it open while hints may follow (a fleet manager); a one-shot tool uses
/// [`send_initial_pose`], which keeps the port open long enough for the daemon to take the hint.
#[derive(Debug)]
pub struct InitialPosePublisher {
    publisher: Publisher<Transport, InitialPose, ()>,
    notifier: Notifier<Transport>,
    // Declared last so the ports above are dropped before the node that owns their resources.
    _node: Node<Transport>,
}

impl InitialPosePublisher {
    /// Opens `glint/<domain>/initial_pose` and its event service with a publisher and a
    /// notifier. Fails with [`InitialPoseOpenError::NotRunning`] when no daemon created them.
    pub fn open(domain: &Domain) -> Result<Self, InitialPoseOpenError> {
        use InitialPoseOpenError as E;
        let stream = Stream::InitialPose;
        let node = node_builder(&format!("glint-initial-pose/{domain}"))
            .create::<Transport>()
            .map_err(E::Node)?;

        let name = domain.service_name(stream);
        let service = node
            .service_builder(
                &service_name(&name)
                    .map_err(|(service, source)| E::InvalidServiceName { service, source })?,
            )
            .publish_subscribe::<InitialPose>()
            .open()
            .map_err(|source| match source {
                PublishSubscribeOpenError::DoesNotExist => E::NotRunning {
                    service: name.clone(),
                },
                source => E::Service {
                    service: name.clone(),
                    source,
                },
            })?;
        let publisher = service
            .publisher_builder()
            // Only consulted should a service without safe overflow ever be met: never wait for
            // the daemon.
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|source| match source {
                PublisherCreateError::ExceedsMaxSupportedPublishers => E::TooManySenders {
                    service: name.clone(),
                },
                source => E::Publisher {
                    service: name.clone(),
                    source,
                },
            })?;

        let event_name = domain.event_service_name(stream);
        let event = node
            .service_builder(
                &service_name(&event_name)
                    .map_err(|(service, source)| E::InvalidServiceName { service, source })?,
            )
            .event()
            .open()
            .map_err(|source| match source {
                EventOpenError::DoesNotExist => E::NotRunning {
                    service: event_name.clone(),
                },
                source => E::EventService {
                    service: event_name.clone(),
                    source,
                },
            })?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|source| E::Notifier {
                service: event_name.clone(),
                source,
            })?;
        Ok(Self {
            publisher,
            notifier,
            _node: node,
        })
    }

    /// Validates `hint`, sends it and wakes the daemon. Returns how many subscribers it was
    /// delivered to (1 while the daemon runs). Never blocks.
    pub fn send(&self, hint: &InitialPose) -> Result<usize, InitialPoseSendError> {
        hint.validate()?;
        let delivered = self
            .publisher
            .send_copy(*hint)
            .map_err(InitialPoseSendError::Send)?;
        self.notifier
            .notify()
            .map_err(InitialPoseSendError::Notify)?;
        Ok(delivered)
    }
}

/// Sends one hint as a one-shot tool does: opens an [`InitialPosePublisher`], sends, keeps the
/// port open for [`settings::INITIAL_POSE_SENDER_LINGER`] so the daemon takes the hint, and
/// closes. Returns how many subscribers it was delivered to.
pub fn send_initial_pose(
    domain: &Domain,
    hint: &InitialPose,
) -> Result<usize, SendInitialPoseError> {
    // Refuse before touching shared memory: no node, no port, no linger for a bad hint.
    hint.validate().map_err(InitialPoseSendError::from)?;
    let publisher = InitialPosePublisher::open(domain)?;
    let delivered = publisher.send(hint)?;
    std::thread::sleep(settings::INITIAL_POSE_SENDER_LINGER);
    drop(publisher);
    Ok(delivered)
}

fn service_name(name: &str) -> Result<ServiceName, (String, ServiceNameError)> {
    ServiceName::new(name).map_err(|source| (name.to_owned(), source))
}

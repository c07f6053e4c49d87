//! [`PosePublisher`]: the daemon's side of the bus — one iceoryx2 node that creates every service
//! of its domain and publishes on them.
//!
//! Publishing is a copy into shared memory plus one notification, never a wait: the services
//! overwrite a full subscriber's oldest sample ([`settings::SAFE_OVERFLOW`]) and the publisher
//! discards rather than blocks should it ever meet a service without overflow. Nothing here
//! allocates after [`PosePublisher::create`] except on error paths.

use iceoryx2::node::{CleanupState, NodeCreationFailure};
use iceoryx2::port::notifier::{NotifierCreateError, NotifierNotifyError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::update_connections::{ConnectionFailure, UpdateConnections};
use iceoryx2::port::SendError;
use iceoryx2::prelude::{BackpressureStrategy, Config, Node, PortName, ServiceName, ZeroCopySend};
use iceoryx2::service::builder::event::EventOpenOrCreateError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenOrCreateError;
use iceoryx2::service::service_name::ServiceNameError;
use thiserror::Error;

use crate::names::{Domain, PoseStream, Stream};
use crate::payload::{Pose, Status};
use crate::settings;
use crate::{node_builder, Transport};

/// Why [`PosePublisher::create`] failed.
#[derive(Debug, Error)]
pub enum PublisherError {
    /// iceoryx2 refused a derived service name (cannot happen for a validated [`Domain`]; kept
    /// so that a change of iceoryx2's limits surfaces as an error, not a panic).
    #[error("invalid service name {service:?}")]
    InvalidServiceName {
        /// The refused name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: ServiceNameError,
    },
    /// The iceoryx2 node could not be created (permissions on `/tmp/iceoryx2` or `/dev/shm`,
    /// or a corrupted iceoryx2 directory).
    #[error("cannot create the iceoryx2 node")]
    Node(#[source] NodeCreationFailure),
    /// Another live publisher already serves this domain (a second daemon with the same domain).
    #[error("domain {domain:?} is already served by another publisher ({service})")]
    DomainInUse {
        /// The contested domain.
        domain: String,
        /// The first service found taken.
        service: String,
    },
    /// The publish-subscribe service could not be created or opened. Opening fails with
    /// `DoesNotSupportRequested…` or `IncompatibleTypes` when consumers still hold a service made
    /// by a daemon with other settings or another payload version: stop them and start again.
    #[error("cannot create or open service {service}")]
    Service {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: PublishSubscribeOpenOrCreateError,
    },
    /// The event service beside a publish-subscribe service could not be created or opened.
    #[error("cannot create or open event service {service}")]
    EventService {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: EventOpenOrCreateError,
    },
    /// The publisher port could not be created (shared memory exhausted, for example).
    #[error("cannot create the publisher of {service}")]
    Publisher {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: PublisherCreateError,
    },
    /// The notifier port could not be created.
    #[error("cannot create the notifier of {service}")]
    Notifier {
        /// The service name.
        service: String,
        /// iceoryx2's reason.
        #[source]
        source: NotifierCreateError,
    },
}

/// Why a `publish_*` call failed. The publisher stays usable; the next call may succeed.
#[derive(Debug, Error)]
pub enum PublishError {
    /// A pose field holds NaN or infinity; nothing was sent, so consumers may rely on finite
    /// numbers.
    #[error("refusing to publish a {stream} pose with a non-finite {field}")]
    NonFinite {
        /// The stream it was meant for.
        stream: Stream,
        /// The first offending field.
        field: &'static str,
    },
    /// The sample could not be loaned or delivered.
    #[error("cannot send on {stream}")]
    Send {
        /// The stream.
        stream: Stream,
        /// iceoryx2's reason.
        #[source]
        source: SendError,
    },
    /// The sample was delivered but waiting consumers could not be woken; they see it on their
    /// next wake-up or timeout.
    #[error("sent on {stream} but could not notify waiting consumers")]
    Notify {
        /// The stream.
        stream: Stream,
        /// iceoryx2's reason.
        #[source]
        source: NotifierNotifyError,
    },
}

/// Why [`PosePublisher::update_connections`] failed.
#[derive(Debug, Error)]
pub enum UpdateConnectionsError {
    /// A new subscriber could not be connected (its memory could not be mapped).
    #[error("cannot connect new subscribers of {stream}")]
    Connect {
        /// The stream.
        stream: Stream,
        /// iceoryx2's reason.
        #[source]
        source: ConnectionFailure,
    },
    /// Waiting consumers could not be woken.
    #[error("cannot notify consumers of {stream}")]
    Notify {
        /// The stream.
        stream: Stream,
        /// iceoryx2's reason.
        #[source]
        source: NotifierNotifyError,
    },
}

/// What the dead-node cleanup at start found (nodes of any iceoryx2 application on this host,
/// not only Glint's).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DeadNodeCleanup {
    /// Dead nodes whose stale resources were removed.
    pub cleaned: u64,
    /// Dead nodes that could not be cleaned (owned by another user, or busy beyond the
    /// timeout).
    pub failed: u64,
}

impl From<CleanupState> for DeadNodeCleanup {
    fn from(state: CleanupState) -> Self {
        Self {
            cleaned: state.cleanups,
            failed: state.failed_cleanups,
        }
    }
}

/// One stream's ports: the publisher and the notifier of its event service.
#[derive(Debug)]
struct Outlet<T: core::fmt::Debug + ZeroCopySend + 'static> {
    stream: Stream,
    publisher: Publisher<Transport, T, ()>,
    notifier: iceoryx2::port::notifier::Notifier<Transport>,
}

impl<T: core::fmt::Debug + ZeroCopySend + Copy + 'static> Outlet<T> {
    fn create(
        node: &Node<Transport>,
        domain: &Domain,
        stream: Stream,
    ) -> Result<Self, PublisherError> {
        let name = domain.service_name(stream);
        let service = node
            .service_builder(&service_name(&name)?)
            .publish_subscribe::<T>()
            .history_size(settings::HISTORY_SIZE)
            .subscriber_max_buffer_size(settings::SUBSCRIBER_BUFFER_SIZE)
            .subscriber_max_borrowed_samples(settings::SUBSCRIBER_MAX_BORROWED_SAMPLES)
            .max_subscribers(settings::MAX_SUBSCRIBERS)
            .max_publishers(settings::MAX_PUBLISHERS)
            .max_nodes(settings::MAX_NODES)
            .enable_safe_overflow(settings::SAFE_OVERFLOW)
            .open_or_create()
            .map_err(|source| PublisherError::Service {
                service: name.clone(),
                source,
            })?;
        let mut builder = service
            .publisher_builder()
            // Only consulted if a service without safe overflow were ever opened: drop the
            // sample for that subscriber rather than wait for it.
            .backpressure_strategy(BackpressureStrategy::DiscardData);
        if let Ok(port) = PortName::new(stream.as_str()) {
            builder = builder.name(&port);
        }
        let publisher = builder
            .create()
            .map_err(publisher_create_error(domain, &name))?;

        let event_name = domain.event_service_name(stream);
        let event = node
            .service_builder(&service_name(&event_name)?)
            .event()
            .max_listeners(settings::MAX_LISTENERS)
            .max_notifiers(settings::MAX_NOTIFIERS)
            .max_nodes(settings::MAX_NODES)
            .disable_deadline()
            .disable_notifier_created_event()
            .disable_notifier_dropped_event()
            .disable_notifier_dead_event()
            .open_or_create()
            .map_err(|source| PublisherError::EventService {
                service: event_name.clone(),
                source,
            })?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|source| match source {
                NotifierCreateError::ExceedsMaxSupportedNotifiers => PublisherError::DomainInUse {
                    domain: domain.to_string(),
                    service: event_name.clone(),
                },
                source => PublisherError::Notifier {
                    service: event_name.clone(),
                    source,
                },
            })?;
        Ok(Self {
            stream,
            publisher,
            notifier,
        })
    }

    fn publish(&self, value: &T) -> Result<(), PublishError> {
        let stream = self.stream;
        self.publisher
            .send_copy(*value)
            .map_err(|source| PublishError::Send { stream, source })?;
        // Notify even when no subscriber is connected yet: the notification is coalesced and
        // non-blocking, and skipping it would save nothing measurable.
        self.notifier
            .notify()
            .map_err(|source| PublishError::Notify { stream, source })?;
        Ok(())
    }

    fn update_connections(&self) -> Result<(), UpdateConnectionsError> {
        let stream = self.stream;
        self.publisher
            .update_connections()
            .map_err(|source| UpdateConnectionsError::Connect { stream, source })?;
        // The history may just have been delivered; wake consumers waiting for it.
        self.notifier
            .notify()
            .map_err(|source| UpdateConnectionsError::Notify { stream, source })?;
        Ok(())
    }
}

/// Turns iceoryx2's refusal of a publisher port on service `name` into ours: a second
/// publisher means another daemon serves the domain.
pub(crate) fn publisher_create_error<'a>(
    domain: &'a Domain,
    name: &'a str,
) -> impl Fn(PublisherCreateError) -> PublisherError + 'a {
    move |source| match source {
        PublisherCreateError::ExceedsMaxSupportedPublishers => PublisherError::DomainInUse {
            domain: domain.to_string(),
            service: name.to_owned(),
        },
        source => PublisherError::Publisher {
            service: name.to_owned(),
            source,
        },
    }
}

pub(crate) fn service_name(name: &str) -> Result<ServiceName, PublisherError> {
    ServiceName::new(name).map_err(|source| PublisherError::InvalidServiceName {
        service: name.to_owned(),
        source,
    })
}

/// The daemon's publisher: creates (or re-opens) every service of a domain with the settings in
/// [`settings`] and publishes poses and status on them.
///
/// `Send + Sync`: the odometry and back-end threads may share one behind an `Arc`. Dropping it
/// removes the daemon's ports; the services themselves live on while consumers hold them open,
/// so a restarted daemon re-opens them and consumers keep receiving without reopening.
///
/// ```no_run
/// use glint_ipc::{Domain, Frame, Pose, PosePublisher, StatusFlags};
///
/// let publisher = PosePublisher::create(&Domain::new("agv7")?)?;
/// let mut pose = Pose::new(1, 1_700_000_000_000_000_000, Frame::ODOM);
/// pose.position = [1.0, 2.0, 0.0];
/// pose.status = StatusFlags::TRACKING;
/// publisher.publish_odom(&pose)?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct PosePublisher {
    odom: Outlet<Pose>,
    map: Outlet<Pose>,
    predicted: Outlet<Pose>,
    status: Outlet<Status>,
    domain: Domain,
    cleanup: DeadNodeCleanup,
    // Declared last so the ports above are dropped before the node that owns their resources.
    _node: Node<Transport>,
}

impl PosePublisher {
    /// Cleans up stale resources of dead iceoryx2 nodes (a crashed earlier daemon), then creates
    /// or re-opens the services `glint/<domain>/{odom,map,predicted,status}` and their `…/event`
    /// services, with a publisher and a notifier on each.
    ///
    /// Uses iceoryx2's global configuration (`./config/iceoryx2.toml`, then
    /// `~/.config/iceoryx2/`, then `/etc/iceoryx2/`, else defaults).
    pub fn create(domain: &Domain) -> Result<Self, PublisherError> {
        let mut config: Config = Config::global_config().clone();
        // Clean up explicitly below, waiting for other cleaners, and keep the count for the log.
        config.global.node.cleanup_dead_nodes_on_creation = false;
        let node = node_builder(&format!("glintd/{domain}"))
            .config(&config)
            .create::<Transport>()
            .map_err(PublisherError::Node)?;
        let cleanup = node
            .blocking_cleanup_dead_nodes(settings::DEAD_NODE_CLEANUP_TIMEOUT)
            .into();

        Ok(Self {
            odom: Outlet::create(&node, domain, PoseStream::Odom.into())?,
            map: Outlet::create(&node, domain, PoseStream::Map.into())?,
            predicted: Outlet::create(&node, domain, PoseStream::Predicted.into())?,
            status: Outlet::create(&node, domain, Stream::Status)?,
            domain: domain.clone(),
            cleanup,
            _node: node,
        })
    }

    /// The domain this publisher serves.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// What the dead-node cleanup at creation removed; worth a log line when non-zero.
    pub fn dead_node_cleanup(&self) -> DeadNodeCleanup {
        self.cleanup
    }

    /// Publishes on `glint/<domain>/odom`. Non-blocking; refuses non-finite poses.
    pub fn publish_odom(&self, pose: &Pose) -> Result<(), PublishError> {
        publish_pose(&self.odom, pose)
    }

    /// Publishes on `glint/<domain>/map`. Non-blocking; refuses non-finite poses.
    pub fn publish_map(&self, pose: &Pose) -> Result<(), PublishError> {
        publish_pose(&self.map, pose)
    }

    /// Publishes on `glint/<domain>/predicted`. Non-blocking; refuses non-finite poses. The
    /// caller sets [`StatusFlags::PREDICTED`](crate::StatusFlags::PREDICTED).
    pub fn publish_predicted(&self, pose: &Pose) -> Result<(), PublishError> {
        publish_pose(&self.predicted, pose)
    }

    /// Publishes on `glint/<domain>/status`. Non-blocking.
    pub fn publish_status(&self, status: &Status) -> Result<(), PublishError> {
        self.status.publish(status)
    }

    /// Connects subscribers that appeared since the last send, hands them the history (the last
    /// message of each stream) and wakes them. Sends do this anyway; call it periodically (the
    /// status tick is a good place) so a consumer that starts while no poses flow — tracking
    /// lost, sensor silent — still gets the last pose.
    pub fn update_connections(&self) -> Result<(), UpdateConnectionsError> {
        self.odom.update_connections()?;
        self.map.update_connections()?;
        self.predicted.update_connections()?;
        self.status.update_connections()
    }
}

fn publish_pose(outlet: &Outlet<Pose>, pose: &Pose) -> Result<(), PublishError> {
    if let Some(field) = pose.first_non_finite_field() {
        return Err(PublishError::NonFinite {
            stream: outlet.stream,
            field,
        });
    }
    outlet.publish(pose)
}

//! Glint's fleet link: a robot's poses, status and saved site maps over Zenoh, for fleet
//! management, traffic control and other robots on other machines. The shared-memory contract
//! (`glint-ipc`) stays the only interface on the robot; this crate carries the same payload
//! bytes between machines. `docs/fleet.md` states the key expressions, the encoding, the map
//! transfer and the security set-up.
//!
//! | module | owns |
//! | --- | --- |
//! | [`keys`] | [`FleetKeys`]: `glint/<site>/<robot>/{odom,map,status}` and `glint/<site>/maps/<name>`, and the attachments naming the payload type |
//! | [`link`] | [`LinkConfig`], [`TlsConfig`]: endpoints, TLS, mutual TLS and access control → an open Zenoh session |
//! | [`forward`] | [`Forwarder`]: one stream's latest payload, its rate limit and what it dropped |
//! | [`maps`] | [`MapServer`] (a queryable serving map files in chunks) and [`fetch_map`] |
//!
//! Every call blocks (Zenoh's `Wait`); Zenoh runs its own network threads, so no async runtime
//! is needed by the caller.

pub mod forward;
pub mod keys;
pub mod link;
pub mod maps;

pub use forward::{ForwardCounts, Forwarder};
pub use keys::{FleetKeys, KeyError, PayloadType};
pub use link::{open, LinkConfig, LinkError, Mode, TlsConfig};
pub use maps::{fetch_map, FetchError, FetchReport, MapServer, MAP_CHUNK_BYTES};

/// The Zenoh release the link is built on; the Python fleet examples pin the same
/// `eclipse-zenoh` version.
pub const ZENOH_VERSION: &str = "1.10.2";

/// Zenoh's error type (a boxed error), re-exported for callers that match on it.
pub use zenoh::Error as ZenohError;

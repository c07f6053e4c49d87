//! Glint's Velodyne driver: what the sensor puts on the wire, turned into timed points and
//! whole-rotation sweeps.
//!
//! - [`wire`]: checked views over the data and position payloads (byte layout only).
//! - [`model`]: laser tables, firing timing, and model detection that does not trust the
//!   product-id byte alone.
//! - [`calibration`]: ROS `VLP16db.yaml` laser tables.
//! - [`clock`] and [`nmea`]: the time base (GPS or receive time, counter wraps and jumps).
//! - [`decode`]: packets to points with exact firing times and REP-103 coordinates.
//! - [`sweep`]: rotations cut at a configurable azimuth, gaps counted.
//! - [`stream`]: the above wired together for a stream of UDP payloads.
//! - [`pcap`] and [`udp`]: where payloads come from (captures, the network) and pcap writing.
//! - [`source_filter`]: one sensor's packets on a network shared with others.
//!
//! Knows nothing about SLAM.

pub mod calibration;
pub mod clock;
pub mod decode;
pub mod model;
pub mod nmea;
pub mod pcap;
pub mod source;
pub mod source_filter;
pub mod stream;
pub mod sweep;
pub mod udp;
pub mod wire;

pub use decode::{Decoder, Point, ReturnKind};
pub use model::{Detection, Model};
pub use source::{PacketKind, PcapSource, Ports, SensorPayload};
pub use source_filter::{Admitted, SourceFilter, Verdict};
pub use stream::{SensorStream, StreamConfig, StreamError, StreamStats};
pub use sweep::{Sweep, SweepConfig, SweepRecycler};
pub use wire::{DataPacket, PacketError, PositionPacket, ReturnMode};

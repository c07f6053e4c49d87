//! Where sensor payloads come from in replay: a capture file, with datagrams routed to the data
//! or position stream by destination port and everything else counted.

use std::net::Ipv4Addr;
use std::path::Path;

use crate::pcap::{CaptureError, CaptureReader, CaptureStats};

/// The sensor's UDP ports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ports {
    /// Data packets (factory default 2368).
    pub data: u16,
    /// Position packets (factory default 8308).
    pub position: u16,
}

impl Default for Ports {
    fn default() -> Self {
        Self {
            data: 2368,
            position: 8308,
        }
    }
}

/// Which stream a payload belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PacketKind {
    /// A data packet.
    Data,
    /// A position packet.
    Position,
}

/// One sensor payload with its receive time.
#[derive(Debug, Clone, Copy)]
pub struct SensorPayload<'a> {
    /// Data or position.
    pub kind: PacketKind,
    /// The sender's IPv4 address.
    pub source: Ipv4Addr,
    /// The UDP payload.
    pub payload: &'a [u8],
    /// When it was received, ns since the epoch (here: the capture's record time).
    pub receive_ns: u64,
}

/// Sensor payloads from a capture file.
#[derive(Debug)]
pub struct PcapSource {
    reader: CaptureReader,
    ports: Ports,
    data: u64,
    position: u64,
    other_ports: u64,
}

impl PcapSource {
    /// Opens a capture.
    pub fn open(path: &Path, ports: Ports) -> Result<Self, CaptureError> {
        Ok(Self::from_reader(CaptureReader::open(path)?, ports))
    }

    /// Wraps an open reader.
    pub fn from_reader(reader: CaptureReader, ports: Ports) -> Self {
        Self {
            reader,
            ports,
            data: 0,
            position: 0,
            other_ports: 0,
        }
    }

    /// The next payload for the sensor's ports, `Ok(None)` at the end, or the error that ends
    /// the capture early (the payloads before it have all been returned).
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> Result<Option<SensorPayload<'_>>, CaptureError> {
        let (kind, receive_ns, source) = loop {
            let Some(d) = self.reader.next()? else {
                return Ok(None);
            };
            if d.destination_port == self.ports.data {
                self.data += 1;
                break (PacketKind::Data, d.time_ns, d.source);
            } else if d.destination_port == self.ports.position {
                self.position += 1;
                break (PacketKind::Position, d.time_ns, d.source);
            }
            self.other_ports += 1;
        };
        Ok(Some(SensorPayload {
            kind,
            source,
            payload: self.reader.payload(),
            receive_ns,
        }))
    }

    /// Datagrams to the data port, to the position port, and to other ports.
    pub fn port_counts(&self) -> (u64, u64, u64) {
        (self.data, self.position, self.other_ports)
    }

    /// What the capture reader skipped.
    pub fn capture_stats(&self) -> CaptureStats {
        self.reader.stats()
    }
}

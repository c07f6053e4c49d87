//! Live UDP: the same packets, sent at real-time pace from an ephemeral local port, data to one
//! port (2368) and position packets to another (8308), so the daemon's live path can be tested
//! on one machine without hardware. The local address may be chosen, so several simulated
//! sensors on loopback (127.0.0.2, 127.0.0.3, …) send from addresses of their own.
//!
//! Pacing follows the packets' send times: the first packet defines the epoch, each later one
//! waits until its offset from the first has elapsed on the monotonic clock. A run that falls
//! behind sends at once rather than skipping packets.

use std::net::{IpAddr, SocketAddr, ToSocketAddrs, UdpSocket};
use std::time::{Duration, Instant};

use crate::error::SimError;
use crate::simulation::{PacketKind, PacketRef, DATA_PORT, POSITION_PORT};

/// Where to stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UdpTarget {
    /// Host name or address (e.g. `127.0.0.1`, `255.255.255.255`, `::1`).
    pub host: String,
    /// Destination port of data packets.
    pub data_port: u16,
    /// Destination port of position packets.
    pub position_port: u16,
    /// Local address to send from (None: the unspecified address of the destination's family,
    /// the kernel's choice).
    pub bind: Option<IpAddr>,
}

impl UdpTarget {
    /// A target with the sensor's default ports.
    pub fn new(host: impl Into<String>) -> UdpTarget {
        UdpTarget {
            host: host.into(),
            data_port: DATA_PORT,
            position_port: POSITION_PORT,
            bind: None,
        }
    }
}

/// Sends packets to a [`UdpTarget`] at the pace of their send times.
#[derive(Debug)]
pub struct UdpStreamer {
    socket: UdpSocket,
    data: SocketAddr,
    position: SocketAddr,
    epoch: Option<(Instant, u64)>,
    sent: u64,
    refused: u64,
}

impl UdpStreamer {
    /// Resolves the destination and binds an ephemeral local port of the same family.
    pub fn connect(target: &UdpTarget) -> Result<UdpStreamer, SimError> {
        let err = |source| SimError::Udp {
            target: target.host.clone(),
            source,
        };
        let resolve = |port: u16| -> Result<SocketAddr, SimError> {
            let mut addrs: Vec<SocketAddr> = (target.host.as_str(), port)
                .to_socket_addrs()
                .map_err(err)?
                .collect();
            // The bound address's family, else IPv4: the sensor speaks IPv4.
            let v4 = target.bind.is_none_or(|b| b.is_ipv4());
            addrs.sort_by_key(|a| a.is_ipv4() != v4);
            addrs.into_iter().next().ok_or_else(|| {
                err(std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "the host has no address",
                ))
            })
        };
        let data = resolve(target.data_port)?;
        let position = resolve(target.position_port)?;
        let local: SocketAddr = match target.bind {
            Some(ip) => (ip, 0).into(),
            None if data.is_ipv4() => ([0, 0, 0, 0], 0).into(),
            None => ([0u16; 8], 0).into(),
        };
        let socket = UdpSocket::bind(local).map_err(|source| SimError::Udp {
            target: format!("{} (binding {local})", target.host),
            source,
        })?;
        if let SocketAddr::V4(v4) = data {
            if v4.ip().is_broadcast() || v4.ip().octets()[3] == 255 {
                socket.set_broadcast(true).map_err(err)?;
            }
        }
        Ok(UdpStreamer {
            socket,
            data,
            position,
            epoch: None,
            sent: 0,
            refused: 0,
        })
    }

    /// The local address packets leave from.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.socket.local_addr().ok()
    }

    /// Packets sent.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Waits until the packet's time has come, then sends it.
    pub fn send(&mut self, packet: &PacketRef<'_>) -> Result<(), SimError> {
        let (epoch, t0) = *self.epoch.get_or_insert((Instant::now(), packet.time_ns));
        let due = epoch + Duration::from_nanos(packet.time_ns.saturating_sub(t0));
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        let to = match packet.kind {
            PacketKind::Data => self.data,
            PacketKind::Position => self.position,
        };
        match self.socket.send_to(packet.payload, to) {
            Ok(_) => {
                self.sent += 1;
                Ok(())
            }
            // An ICMP "port unreachable" from an earlier datagram surfaces here on some
            // systems; nobody listening is not an error for a sensor.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                self.refused += 1;
                Ok(())
            }
            Err(source) => Err(SimError::Udp {
                target: to.to_string(),
                source,
            }),
        }
    }
}

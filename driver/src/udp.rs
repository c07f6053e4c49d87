//! The live source: the sensor's data and position ports bound with `socket2` (large receive
//! buffer, optional multicast), each drained by a dedicated thread that never waits for
//! downstream work. A full channel drops the datagram and counts it.

use std::io;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crossbeam_channel::{Sender, TrySendError};
use socket2::{Domain, Protocol, Socket, Type};
use thiserror::Error;

use crate::source::{PacketKind, Ports};
use crate::wire::{DATA_PAYLOAD_LEN, POSITION_PAYLOAD_LEN};

/// Largest payload kept: anything longer is not a sensor packet and is counted as malformed.
pub const MAX_DATAGRAM: usize = DATA_PAYLOAD_LEN;

/// Socket settings.
#[derive(Debug, Clone, PartialEq)]
pub struct UdpConfig {
    /// Local address to bind (0.0.0.0 for all interfaces).
    pub bind: IpAddr,
    /// Ports to bind.
    pub ports: Ports,
    /// A multicast group to join, if the sensor sends to one.
    pub multicast_group: Option<Ipv4Addr>,
    /// Interface address for the multicast join (0.0.0.0: the kernel's choice).
    pub multicast_interface: Ipv4Addr,
    /// Requested `SO_RCVBUF`, bytes.
    pub receive_buffer: usize,
    /// Where receive times come from.
    pub clock: ReceiveClock,
}

/// Where receive times come from: the host clock, optionally shifted by an amount the caller
/// may change at any time, which is how tests step the clock under a running daemon without
/// root.
#[derive(Clone, Default)]
pub struct ReceiveClock {
    shift_ns: Option<Arc<AtomicI64>>,
}

impl ReceiveClock {
    /// The host clock.
    pub fn host() -> Self {
        Self::default()
    }

    /// The host clock plus `shift_ns` as it stands at each reading.
    pub fn shifted(shift_ns: Arc<AtomicI64>) -> Self {
        Self {
            shift_ns: Some(shift_ns),
        }
    }

    /// Now, ns since the epoch.
    pub fn now_ns(&self) -> u64 {
        let shift = self
            .shift_ns
            .as_ref()
            .map_or(0, |s| s.load(Ordering::Relaxed));
        crate::clock::stamp(host_now_ns(), shift)
    }
}

impl std::fmt::Debug for ReceiveClock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.shift_ns {
            None => f.write_str("ReceiveClock::host"),
            Some(s) => write!(f, "ReceiveClock::shifted({} ns)", s.load(Ordering::Relaxed)),
        }
    }
}

impl PartialEq for ReceiveClock {
    fn eq(&self, other: &Self) -> bool {
        match (&self.shift_ns, &other.shift_ns) {
            (None, None) => true,
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

impl Default for UdpConfig {
    fn default() -> Self {
        Self {
            bind: IpAddr::V4(Ipv4Addr::UNSPECIFIED),
            ports: Ports::default(),
            multicast_group: None,
            multicast_interface: Ipv4Addr::UNSPECIFIED,
            // ~1 s of single-return data.
            receive_buffer: 1 << 20,
            clock: ReceiveClock::host(),
        }
    }
}

/// A received datagram, copied into a fixed buffer so the channel carries no allocation.
#[derive(Clone)]
pub struct Datagram {
    /// Data or position.
    pub kind: PacketKind,
    /// Host clock at receipt, ns since the epoch.
    pub receive_ns: u64,
    /// The sender's address (which sensor, on a network shared by several).
    pub source: IpAddr,
    len: usize,
    bytes: [u8; MAX_DATAGRAM],
}

impl std::fmt::Debug for Datagram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Datagram")
            .field("kind", &self.kind)
            .field("receive_ns", &self.receive_ns)
            .field("source", &self.source)
            .field("len", &self.len)
            .finish()
    }
}

impl Datagram {
    /// The payload.
    pub fn payload(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Counters of the receive threads (shared, lock-free).
#[derive(Debug, Default)]
pub struct UdpCounters {
    /// Datagrams received on the data port.
    pub data: AtomicU64,
    /// Datagrams received on the position port.
    pub position: AtomicU64,
    /// Datagrams of a length no sensor packet has (garbage on the port).
    pub wrong_length: AtomicU64,
    /// Datagrams dropped because the pipeline was full.
    pub dropped: AtomicU64,
    /// Receive errors other than time-outs.
    pub errors: AtomicU64,
}

/// Binding failed.
#[derive(Debug, Error)]
pub enum UdpError {
    /// A socket call failed.
    #[error("cannot {what} {addr}: {source}")]
    Socket {
        what: &'static str,
        addr: SocketAddr,
        source: io::Error,
    },
    /// A thread could not be started.
    #[error("cannot start the receive thread: {0}")]
    Thread(io::Error),
}

/// The running receiver. Dropping it stops the threads.
#[derive(Debug)]
pub struct UdpSource {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    counters: Arc<UdpCounters>,
    granted_buffer: usize,
    local_ports: Ports,
}

/// Host clock, ns since the epoch.
pub fn host_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

impl UdpSource {
    /// Binds both ports and starts one receive thread per port, sending into `out`.
    pub fn start(config: &UdpConfig, out: Sender<Datagram>) -> Result<Self, UdpError> {
        let stop = Arc::new(AtomicBool::new(false));
        let counters = Arc::new(UdpCounters::default());
        let mut threads = Vec::new();
        let mut granted_buffer = usize::MAX;
        let mut local = [0u16; 2];
        for (i, (kind, port)) in [
            (PacketKind::Data, config.ports.data),
            (PacketKind::Position, config.ports.position),
        ]
        .into_iter()
        .enumerate()
        {
            let (socket, granted) = bind(config, port)?;
            granted_buffer = granted_buffer.min(granted);
            local[i] = socket.local_addr().map(|a| a.port()).unwrap_or(port);
            let (stop, counters, out) = (stop.clone(), counters.clone(), out.clone());
            let clock = config.clock.clone();
            let handle = std::thread::Builder::new()
                .name(format!("glint-rx-{port}"))
                .spawn(move || receive_loop(socket, kind, &clock, &stop, &counters, &out))
                .map_err(UdpError::Thread)?;
            threads.push(handle);
        }
        Ok(Self {
            stop,
            threads,
            counters,
            granted_buffer,
            local_ports: Ports {
                data: local[0],
                position: local[1],
            },
        })
    }

    /// The receive buffer the kernel granted, bytes (Linux reports twice the request, capped by
    /// `net.core.rmem_max`).
    pub fn granted_buffer(&self) -> usize {
        self.granted_buffer
    }

    /// The ports actually bound (differs from the configuration when it asked for port 0).
    pub fn local_ports(&self) -> Ports {
        self.local_ports
    }

    /// Counters, shared with the threads.
    pub fn counters(&self) -> Arc<UdpCounters> {
        self.counters.clone()
    }

    /// Stops the threads and waits for them.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for UdpSource {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn bind(config: &UdpConfig, port: u16) -> Result<(UdpSocket, usize), UdpError> {
    let addr = SocketAddr::new(config.bind, port);
    let err = |what| move |source| UdpError::Socket { what, addr, source };
    let socket = Socket::new(Domain::for_address(addr), Type::DGRAM, Some(Protocol::UDP))
        .map_err(err("open a socket for"))?;
    socket
        .set_reuse_address(true)
        .map_err(err("set SO_REUSEADDR on"))?;
    // The kernel may grant less than asked (rmem_max); what it granted is reported, not assumed.
    let _ = socket.set_recv_buffer_size(config.receive_buffer);
    let granted = socket
        .recv_buffer_size()
        .map_err(err("read SO_RCVBUF of"))?;
    socket.bind(&addr.into()).map_err(err("bind"))?;
    if let Some(group) = config.multicast_group {
        socket
            .join_multicast_v4(&group, &config.multicast_interface)
            .map_err(err("join the multicast group on"))?;
    }
    // A short timeout lets the thread notice a stop request during sensor silence.
    socket
        .set_read_timeout(Some(Duration::from_millis(100)))
        .map_err(err("set a timeout on"))?;
    Ok((socket.into(), granted))
}

fn receive_loop(
    socket: UdpSocket,
    kind: PacketKind,
    clock: &ReceiveClock,
    stop: &AtomicBool,
    counters: &UdpCounters,
    out: &Sender<Datagram>,
) {
    let expected = match kind {
        PacketKind::Data => DATA_PAYLOAD_LEN,
        PacketKind::Position => POSITION_PAYLOAD_LEN,
    };
    let mut buf = [0u8; 2048];
    while !stop.load(Ordering::Relaxed) {
        let (len, from) = match socket.recv_from(&mut buf) {
            Ok(received) => received,
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock
                        | io::ErrorKind::TimedOut
                        | io::ErrorKind::Interrupted
                ) =>
            {
                continue
            }
            Err(_) => {
                counters.errors.fetch_add(1, Ordering::Relaxed);
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        let receive_ns = clock.now_ns();
        match kind {
            PacketKind::Data => counters.data.fetch_add(1, Ordering::Relaxed),
            PacketKind::Position => counters.position.fetch_add(1, Ordering::Relaxed),
        };
        if len != expected {
            counters.wrong_length.fetch_add(1, Ordering::Relaxed);
            continue;
        }
        let mut d = Datagram {
            kind,
            receive_ns,
            source: from.ip(),
            len,
            bytes: [0; MAX_DATAGRAM],
        };
        d.bytes[..len].copy_from_slice(&buf[..len]);
        match out.try_send(d) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                counters.dropped.fetch_add(1, Ordering::Relaxed);
            }
            // The consumer is gone: nothing left to receive for.
            Err(TrySendError::Disconnected(_)) => break,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn receives_counts_and_drops_without_blocking() {
        let config = UdpConfig {
            bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
            ports: Ports {
                data: 0,
                position: 0,
            },
            ..UdpConfig::default()
        };
        let (tx, rx) = crossbeam_channel::bounded(2);
        let source = UdpSource::start(&config, tx).unwrap();
        assert!(source.granted_buffer() > 0);
        let ports = source.local_ports();
        let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
        let to = SocketAddr::from((Ipv4Addr::LOCALHOST, ports.data));
        for _ in 0..5 {
            sender.send_to(&[0u8; DATA_PAYLOAD_LEN], to).unwrap();
        }
        sender.send_to(b"garbage", to).unwrap();
        sender
            .send_to(
                &[0u8; POSITION_PAYLOAD_LEN],
                (Ipv4Addr::LOCALHOST, ports.position),
            )
            .unwrap();
        let counters = source.counters();
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        while counters.data.load(Ordering::Relaxed) < 6 && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(counters.data.load(Ordering::Relaxed), 6);
        assert_eq!(counters.wrong_length.load(Ordering::Relaxed), 1);
        // The channel holds 2: the rest were dropped and counted, and the thread kept going.
        assert!(counters.dropped.load(Ordering::Relaxed) >= 2);
        // Which datagrams made it into the channel is a race between the two threads; each
        // must carry its own kind's length.
        while let Ok(d) = rx.try_recv() {
            let expected = if d.kind == PacketKind::Data {
                DATA_PAYLOAD_LEN
            } else {
                POSITION_PAYLOAD_LEN
            };
            assert_eq!(d.payload().len(), expected);
            assert_eq!(d.source, IpAddr::V4(Ipv4Addr::LOCALHOST));
        }
        source.stop();
    }
}

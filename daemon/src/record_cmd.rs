//! `glintd record`: the sensor's packets, as received, into a pcap for later replay — the same
//! sockets and options as `glintd run`, no processing. Stops after `--seconds` or on SIGTERM or
//! SIGINT, and always leaves a readable file.

use std::net::Ipv4Addr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use crossbeam_channel::{bounded, RecvTimeoutError};
use glint_driver::pcap::{CaptureWriter, UdpEndpoints};
use glint_driver::udp::{Datagram, UdpSource};
use glint_driver::PacketKind;

use crate::config::DaemonConfig;

/// Arguments of `glintd record`.
#[derive(Args, Debug)]
pub struct RecordArgs {
    /// The capture to write (classic pcap).
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many seconds (default: until SIGINT or SIGTERM).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Sensor options (address, ports, multicast) from this configuration.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override the data port.
    #[arg(long)]
    pub data_port: Option<u16>,
    /// Override the position port.
    #[arg(long)]
    pub position_port: Option<u16>,
}

/// The source written for a sender with no IPv4 address (an IPv6 socket's peer): the VLP-16's
/// factory address.
const SENSOR_ADDRESS: Ipv4Addr = Ipv4Addr::new(192, 168, 1, 201);

/// Runs the command.
pub fn run(args: RecordArgs) -> Result<()> {
    let config = match &args.config {
        Some(path) => DaemonConfig::load(path)?,
        None => DaemonConfig::parse("")?,
    };
    if let Some(s) = args.seconds {
        anyhow::ensure!(s.is_finite() && s > 0.0, "--seconds must be > 0, got {s}");
    }
    let mut udp = config.udp_config();
    if let Some(p) = args.data_port {
        udp.ports.data = p;
    }
    if let Some(p) = args.position_port {
        udp.ports.position = p;
    }
    let stop = Arc::new(AtomicBool::new(false));
    crate::signals::stop_on_signals(&stop)?;
    let mut writer = CaptureWriter::create(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let (tx, rx) = bounded::<Datagram>(4096);
    let source = UdpSource::start(&udp, tx).context("cannot listen for the sensor")?;
    let ports = source.local_ports();
    say!(
        "recording ports {} (data) and {} (position) into {} …",
        ports.data,
        ports.position,
        args.out.display()
    );
    let deadline = args
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    let destination = match udp.bind {
        std::net::IpAddr::V4(a) => a,
        std::net::IpAddr::V6(_) => Ipv4Addr::UNSPECIFIED,
    };
    let (mut data, mut position) = (0u64, 0u64);
    while !stop.load(Ordering::Relaxed) && deadline.is_none_or(|d| Instant::now() < d) {
        let d = match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(d) => d,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        let port = match d.kind {
            PacketKind::Data => {
                data += 1;
                ports.data
            }
            PacketKind::Position => {
                position += 1;
                ports.position
            }
        };
        writer
            .write_udp(
                d.receive_ns,
                UdpEndpoints {
                    // The sender's own address, so a capture of a shared network tells the
                    // sensors apart (`glintd info`).
                    source: (sender_v4(d.source), port),
                    destination: (destination, port),
                },
                d.payload(),
            )
            .with_context(|| format!("cannot write {}", args.out.display()))?;
    }
    let counters = source.counters();
    source.stop();
    writer
        .finish()
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    say!(
        "recorded {data} data and {position} position packets; {} dropped, {} of a wrong length",
        counters.dropped.load(Ordering::Relaxed),
        counters.wrong_length.load(Ordering::Relaxed)
    );
    Ok(())
}

fn sender_v4(address: std::net::IpAddr) -> Ipv4Addr {
    match address.to_canonical() {
        std::net::IpAddr::V4(a) => a,
        std::net::IpAddr::V6(_) => SENSOR_ADDRESS,
    }
}

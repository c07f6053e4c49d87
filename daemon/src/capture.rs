//! Replaying a capture through the driver for the inspection commands: the sensor options they
//! share, and one loop from file to sweeps with everything counted, one sensor's packets
//! admitted and any other's refused.

use std::net::{IpAddr, Ipv4Addr};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use glint_driver::calibration::load_calibration;
use glint_driver::pcap::{CaptureError, CaptureStats};
use glint_driver::{
    Admitted, Model, PacketKind, PcapSource, Ports, SensorPayload, SensorStream, SourceFilter,
    StreamConfig, StreamError, Sweep, SweepConfig, Verdict,
};

/// Options that say how to read the sensor's packets.
#[derive(Args, Debug, Clone)]
pub struct SensorArgs {
    /// Sensor model (vlp16, puck-hires, hdl32e). Overrides detection; by default the packets'
    /// timing decides, checked against the product-id byte.
    #[arg(long)]
    pub model: Option<Model>,
    /// Laser calibration file in the ROS VLP16db.yaml layout.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// UDP port of data packets.
    #[arg(long, default_value_t = 2368)]
    pub data_port: u16,
    /// UDP port of position packets.
    #[arg(long, default_value_t = 8308)]
    pub position_port: u16,
    /// Azimuth where sweeps are cut, degrees clockwise from the sensor's +x axis.
    #[arg(long, default_value_t = 0.0)]
    pub cut_azimuth: f64,
    /// Read only the packets sent from this IPv4 address (the sensor's). By default the first
    /// source to send a valid data packet is read and any other is refused and counted.
    #[arg(long, value_name = "ADDR")]
    pub source: Option<Ipv4Addr>,
}

impl SensorArgs {
    /// The stream configuration these options describe.
    pub fn stream_config(&self) -> Result<StreamConfig> {
        let calibration = match &self.calibration {
            Some(path) => Some(load_calibration(path)?),
            None => None,
        };
        anyhow::ensure!(
            self.cut_azimuth.is_finite() && (0.0..360.0).contains(&self.cut_azimuth),
            "--cut-azimuth must be in [0, 360) degrees, got {}",
            self.cut_azimuth
        );
        Ok(StreamConfig {
            model: self.model,
            calibration,
            sweep: SweepConfig {
                cut_azimuth: self.cut_azimuth.to_radians(),
                ..SweepConfig::default()
            },
        })
    }

    /// The ports to read.
    pub fn ports(&self) -> Ports {
        Ports {
            data: self.data_port,
            position: self.position_port,
        }
    }
}

/// What a replay saw.
#[derive(Debug)]
pub struct CaptureReport {
    /// The stream, for its detection and counters.
    pub stream: SensorStream,
    /// Datagrams to the data port, the position port and other ports.
    pub port_counts: (u64, u64, u64),
    /// Records the capture reader skipped.
    pub capture: CaptureStats,
    /// Which source was read, packets per source, and what was refused.
    pub sources: SourceFilter,
    /// The error that ended the capture early, if any (everything before it was decoded).
    pub damage: Option<CaptureError>,
}

/// Replays `path` through a fresh stream, calling `on_sweep` for every sweep in order.
pub fn replay(
    path: &Path,
    sensor: &SensorArgs,
    mut on_sweep: impl FnMut(&Sweep) -> Result<()>,
) -> Result<CaptureReport> {
    replay_stream(
        path,
        sensor.ports(),
        sensor.stream_config()?,
        sensor.source,
        |_, _, _| true,
        |sweep, stream| {
            on_sweep(&sweep)?;
            if let Some(r) = stream.recycler() {
                r.recycle(sweep);
            }
            Ok(())
        },
    )
}

/// Replays `path` through a fresh stream configured by `config`, reading the packets of
/// `source` (None: of the first source to send valid data). `on_packet` sees each sensor
/// packet's record time, the stream and the filter before the packet is judged and decoded (for
/// pacing and counters) and returns false to stop early; `on_sweep` takes each sweep as it is
/// closed.
pub fn replay_stream(
    path: &Path,
    ports: Ports,
    config: StreamConfig,
    source: Option<Ipv4Addr>,
    on_packet: impl FnMut(u64, &SensorStream, &SourceFilter) -> bool,
    on_sweep: impl FnMut(Sweep, &SensorStream) -> Result<()>,
) -> Result<CaptureReport> {
    let mut payloads = PcapSource::open(path, ports)
        .with_context(|| format!("cannot replay {}", path.display()))?;
    replay_payloads(
        &mut payloads,
        &path.display().to_string(),
        config,
        source,
        on_packet,
        on_sweep,
    )
}

/// Sensor payloads in the order they were received: a capture file, or a simulated sensor
/// run in process (`glintd soak`).
pub trait PayloadSource {
    /// The next payload for the sensor's ports, `Ok(None)` at the end, or the error that ends
    /// the input early.
    fn next_payload(&mut self) -> Result<Option<SensorPayload<'_>>, CaptureError>;
    /// Datagrams to the data port, to the position port, and to other ports.
    fn port_counts(&self) -> (u64, u64, u64);
    /// Records the reader skipped.
    fn capture_stats(&self) -> CaptureStats;
}

impl PayloadSource for PcapSource {
    fn next_payload(&mut self) -> Result<Option<SensorPayload<'_>>, CaptureError> {
        self.next()
    }
    fn port_counts(&self) -> (u64, u64, u64) {
        PcapSource::port_counts(self)
    }
    fn capture_stats(&self) -> CaptureStats {
        PcapSource::capture_stats(self)
    }
}

/// [`replay_stream`] from any [`PayloadSource`]; `label` names the input in errors.
pub fn replay_payloads(
    payloads: &mut impl PayloadSource,
    label: &str,
    config: StreamConfig,
    source: Option<Ipv4Addr>,
    mut on_packet: impl FnMut(u64, &SensorStream, &SourceFilter) -> bool,
    mut on_sweep: impl FnMut(Sweep, &SensorStream) -> Result<()>,
) -> Result<CaptureReport> {
    let mut filter = SourceFilter::new(source.map(IpAddr::V4));
    let mut foreign_log = ForeignLog::default();
    let mut stream = SensorStream::new(config);
    let mut dropped_logged = 0u32;
    let mut handle = |stream: &mut SensorStream, result: Result<(), StreamError>| -> Result<()> {
        match result {
            Ok(()) => {}
            Err(e) if e.is_recoverable() => {
                if dropped_logged < 10 {
                    tracing::warn!("{e}");
                    dropped_logged += 1;
                }
            }
            Err(e) => return Err(e).context(format!("cannot decode {label}")),
        }
        while let Some(sweep) = stream.take_sweep() {
            on_sweep(sweep, stream)?;
        }
        Ok(())
    };
    let damage = loop {
        match payloads.next_payload() {
            Ok(Some(p)) => {
                if !on_packet(p.receive_ns, &stream, &filter) {
                    break None;
                }
                let from = IpAddr::V4(p.source);
                let verdict = filter.judge(p.kind, from, p.payload, p.receive_ns);
                while let Some(held) = filter.take_released() {
                    let result = stream.push_position(held.payload());
                    handle(&mut stream, result)?;
                }
                let result = match (verdict, p.kind) {
                    (Verdict::Accept, PacketKind::Data) => {
                        stream.push_data(p.payload, p.receive_ns)
                    }
                    (Verdict::Accept, PacketKind::Position) => stream.push_position(p.payload),
                    (Verdict::Foreign, _) => {
                        foreign_log.note(&filter, from, p.receive_ns);
                        Ok(())
                    }
                    (Verdict::Held, _) => Ok(()),
                };
                handle(&mut stream, result)?;
            }
            Ok(None) => break None,
            Err(e) => break Some(e),
        }
    };
    let result = stream.finish();
    handle(&mut stream, result)?;
    Ok(CaptureReport {
        port_counts: payloads.port_counts(),
        capture: payloads.capture_stats(),
        sources: filter,
        stream,
        damage,
    })
}

/// How long after the last refused packet a run still flags another sensor, ns.
pub const FOREIGN_WINDOW_NS: u64 = 2_000_000_000;

/// Refused packets logged sparingly: the first from each source, then one line at most every
/// `EVERY_NS` with the count so far.
#[derive(Debug, Default)]
pub struct ForeignLog {
    sources: Vec<IpAddr>,
    last_ns: Option<u64>,
}

impl ForeignLog {
    const EVERY_NS: u64 = 10_000_000_000;

    /// A packet from `from` was refused at `now_ns`.
    pub fn note(&mut self, filter: &SourceFilter, from: IpAddr, now_ns: u64) {
        let new_source = !self.sources.contains(&from)
            && self.sources.len() < glint_driver::source_filter::MAX_TRACKED_SOURCES;
        let due = self
            .last_ns
            .is_none_or(|t| now_ns.saturating_sub(t) >= Self::EVERY_NS);
        if !new_source && !due {
            return;
        }
        let reading = match filter.admitted() {
            Admitted::Configured(a) => format!("{a} (configured)"),
            Admitted::Locked(a) => format!("{a} (the first to send valid data)"),
            Admitted::Undecided => "none yet".into(),
        };
        let refused = filter.stats().foreign();
        if new_source {
            self.sources.push(from);
            tracing::warn!(
                refused,
                "packets from {from} refused: another sensor on the network? reading {reading}"
            );
        } else {
            tracing::warn!(
                refused,
                sources = self.sources.len(),
                "packets from other sources still refused; reading {reading}"
            );
        }
        self.last_ns = Some(now_ns);
    }
}

/// Whether a packet from another source was refused within [`FOREIGN_WINDOW_NS`] of `now_ns`.
pub fn foreign_active(filter: &SourceFilter, now_ns: u64) -> bool {
    filter
        .stats()
        .last_foreign_ns
        .is_some_and(|t| now_ns.saturating_sub(t) < FOREIGN_WINDOW_NS)
}

/// Lines describing the sources of a capture: one per source address with its packets, and
/// which one was read (for `info` and `replay`).
pub fn describe_sources(filter: &SourceFilter) -> Vec<String> {
    let admitted = filter.admitted();
    let mut lines = vec![match admitted {
        Admitted::Configured(a) => format!("source: {a} (--source); other sources refused"),
        Admitted::Locked(a) => {
            format!("source: {a} (the first to send valid data); other sources refused")
        }
        Admitted::Undecided => "source: none (no valid data packet)".into(),
    }];
    for s in filter.sources() {
        let read = if Some(s.address) == admitted.address() {
            "read"
        } else {
            "refused"
        };
        lines.push(format!(
            "  from {}: {} data, {} position packets ({read})",
            s.address, s.data, s.position
        ));
    }
    let st = filter.stats();
    if st.untracked > 0 {
        lines.push(format!(
            "  from further sources: {} packets (refused)",
            st.untracked
        ));
    }
    lines
}

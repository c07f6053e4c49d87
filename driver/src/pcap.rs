//! Captures: reading UDP datagrams out of pcap and pcapng files, and writing classic pcap.
//!
//! Reading uses `pcap-parser` for the file format and our own code for the link, IPv4 and UDP
//! headers: Ethernet (with 802.1Q / 802.1ad tags), Linux cooked SLL and SLL2, raw IPv4 and BSD
//! loopback; IPv4 with options. Anything else is skipped and counted. A truncated or corrupt
//! file yields every packet before the damage, then an error naming the byte offset.
//!
//! The writer holds only byte layouts (pcap, Ethernet, IPv4, UDP): no sensor constants.

use std::fs::File;
use std::io::{self, BufWriter, Read, Write};
use std::net::Ipv4Addr;
use std::path::Path;

use pcap_parser::{
    create_reader, traits::PcapReaderIterator, Block, Linktype, PcapBlockOwned, PcapError,
};
use thiserror::Error;

/// Why a capture could not be read (further).
#[derive(Debug, Error)]
pub enum CaptureError {
    /// The file could not be opened or read.
    #[error("cannot read {path}: {source}")]
    Io { path: String, source: io::Error },
    /// The file is neither pcap nor pcapng.
    #[error("not a pcap or pcapng file (unrecognised header at byte 0)")]
    NotACapture,
    /// The file ends inside a record.
    #[error("capture truncated: the record at byte {offset} is cut off by the end of the file")]
    Truncated { offset: u64 },
    /// The bytes at `offset` are not a valid record.
    #[error("capture corrupt at byte {offset}: {reason}")]
    Corrupt { offset: u64, reason: String },
}

/// A UDP datagram found in a capture.
#[derive(Debug, Clone, Copy)]
pub struct CapturedDatagram<'a> {
    /// The record's capture time, ns since the Unix epoch.
    pub time_ns: u64,
    /// Source IPv4 address.
    pub source: Ipv4Addr,
    /// Source UDP port.
    pub source_port: u16,
    /// Destination UDP port.
    pub destination_port: u16,
    /// The UDP payload (as captured; may be shorter than sent if the snap length cut it).
    pub payload: &'a [u8],
    /// The UDP payload length the header announced.
    pub announced_len: usize,
}

/// Counts of records that were not UDP over IPv4.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CaptureStats {
    /// Records read.
    pub records: u64,
    /// UDP datagrams returned.
    pub datagrams: u64,
    /// Records of a link type Glint does not read.
    pub unsupported_link: u64,
    /// Frames that are not IPv4 (ARP, IPv6, …).
    pub not_ipv4: u64,
    /// IPv4 packets that are not UDP.
    pub not_udp: u64,
    /// IPv4 fragments (a VLP-16 never fragments; skipped).
    pub fragments: u64,
    /// Frames whose headers are cut off or inconsistent.
    pub malformed: u64,
}

impl CaptureStats {
    /// Records skipped for any reason.
    pub fn skipped(&self) -> u64 {
        self.unsupported_link + self.not_ipv4 + self.not_udp + self.fragments + self.malformed
    }
}

const READ_BUFFER: usize = 1 << 20;
/// Smallest read buffer: a 65,535-byte record with its header and then some.
pub const MIN_BUFFER: usize = 1 << 17;

#[derive(Debug, Clone, Copy)]
struct Interface {
    linktype: Linktype,
    /// Ticks per second.
    resolution: u64,
    offset_s: i64,
}

/// Reads UDP datagrams from a pcap or pcapng stream.
pub struct CaptureReader {
    reader: Box<dyn PcapReaderIterator + Send>,
    /// Legacy pcap: the one link type and whether times are in ns.
    legacy: Option<(Linktype, bool)>,
    interfaces: Vec<Interface>,
    /// Bytes of the file consumed before the current buffer position.
    offset: u64,
    pending_consume: usize,
    stats: CaptureStats,
    failed: bool,
    payload: Vec<u8>,
}

impl std::fmt::Debug for CaptureReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CaptureReader")
            .field("offset", &self.offset)
            .field("stats", &self.stats)
            .finish()
    }
}

impl CaptureReader {
    /// Opens a capture file.
    pub fn open(path: &Path) -> Result<Self, CaptureError> {
        let file = File::open(path).map_err(|source| CaptureError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_reader(file)
    }

    /// Reads a capture from any byte stream.
    pub fn from_reader(reader: impl Read + Send + 'static) -> Result<Self, CaptureError> {
        Self::with_buffer(reader, READ_BUFFER)
    }

    /// Reads a capture with a read buffer of `capacity` bytes (at least [`MIN_BUFFER`], enough
    /// for the largest record a 64 KiB snap length allows).
    pub fn with_buffer(
        reader: impl Read + Send + 'static,
        capacity: usize,
    ) -> Result<Self, CaptureError> {
        let reader = match create_reader(capacity.max(MIN_BUFFER), reader) {
            Ok(r) => r,
            Err(PcapError::Eof) | Err(PcapError::Incomplete(_)) | Err(PcapError::UnexpectedEof) => {
                return Err(CaptureError::Truncated { offset: 0 })
            }
            Err(PcapError::ReadError) => {
                return Err(CaptureError::Corrupt {
                    offset: 0,
                    reason: "read error".into(),
                })
            }
            Err(_) => return Err(CaptureError::NotACapture),
        };
        Ok(Self {
            reader,
            legacy: None,
            interfaces: Vec::new(),
            offset: 0,
            pending_consume: 0,
            stats: CaptureStats::default(),
            failed: false,
            payload: Vec::with_capacity(2048),
        })
    }

    /// The payload of the datagram last returned by [`Self::next`].
    pub fn payload(&self) -> &[u8] {
        &self.payload
    }

    /// Counts so far.
    pub fn stats(&self) -> CaptureStats {
        self.stats
    }

    /// The next UDP datagram, `Ok(None)` at the end of the capture, or the error that stops
    /// reading (after which every call returns `Ok(None)`).
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> Result<Option<CapturedDatagram<'_>>, CaptureError> {
        if self.failed {
            return Ok(None);
        }
        loop {
            if self.pending_consume > 0 {
                self.reader.consume(self.pending_consume);
                self.offset += self.pending_consume as u64;
                self.pending_consume = 0;
            }
            // Two-phase so that the borrow of the reader's buffer ends before we refill it.
            let step = match self.reader.next() {
                Ok((size, block)) => {
                    let found = match block {
                        PcapBlockOwned::LegacyHeader(h) => {
                            self.legacy = Some((h.network, h.is_nanosecond_precision()));
                            None
                        }
                        PcapBlockOwned::Legacy(b) => {
                            self.stats.records += 1;
                            let (linktype, nanos) =
                                self.legacy.unwrap_or((Linktype::ETHERNET, false));
                            let frac = if nanos {
                                u64::from(b.ts_usec)
                            } else {
                                u64::from(b.ts_usec) * 1000
                            };
                            let time_ns = u64::from(b.ts_sec) * 1_000_000_000 + frac;
                            Some((linktype, time_ns, b.data))
                        }
                        PcapBlockOwned::NG(Block::SectionHeader(_)) => {
                            self.interfaces.clear();
                            None
                        }
                        PcapBlockOwned::NG(Block::InterfaceDescription(idb)) => {
                            self.interfaces.push(Interface {
                                linktype: idb.linktype,
                                resolution: idb.ts_resolution().unwrap_or(1_000_000),
                                offset_s: idb.ts_offset(),
                            });
                            None
                        }
                        PcapBlockOwned::NG(Block::EnhancedPacket(epb)) => {
                            self.stats.records += 1;
                            match self.interfaces.get(epb.if_id as usize) {
                                Some(iface) => {
                                    let ticks =
                                        (u64::from(epb.ts_high) << 32) | u64::from(epb.ts_low);
                                    let ns = (u128::from(ticks) * 1_000_000_000
                                        / u128::from(iface.resolution.max(1)))
                                        as i128
                                        + i128::from(iface.offset_s) * 1_000_000_000;
                                    let data: &[u8] = epb.data;
                                    let frame = &data[..(epb.caplen as usize).min(data.len())];
                                    Some((iface.linktype, ns.max(0) as u64, frame))
                                }
                                None => {
                                    self.stats.malformed += 1;
                                    None
                                }
                            }
                        }
                        PcapBlockOwned::NG(Block::SimplePacket(spb)) => {
                            self.stats.records += 1;
                            match self.interfaces.first() {
                                // Simple packets carry no time.
                                Some(iface) => {
                                    let data: &[u8] = spb.data;
                                    let frame = &data[..(spb.origlen as usize).min(data.len())];
                                    Some((iface.linktype, 0, frame))
                                }
                                None => {
                                    self.stats.malformed += 1;
                                    None
                                }
                            }
                        }
                        PcapBlockOwned::NG(_) => None,
                    };
                    self.pending_consume = size;
                    match found {
                        Some((linktype, time_ns, frame)) => match parse_frame(linktype, frame) {
                            Ok(udp) => {
                                // Copied out so the datagram outlives the reader's buffer
                                // shifts (1.2 kB per packet; cheap next to the decode).
                                self.payload.clear();
                                self.payload.extend_from_slice(udp.payload);
                                Step::Datagram(Header {
                                    time_ns,
                                    source: udp.source,
                                    source_port: udp.source_port,
                                    destination_port: udp.destination_port,
                                    announced_len: udp.announced_len,
                                })
                            }
                            Err(skip) => Step::Skip(skip),
                        },
                        None => Step::Continue,
                    }
                }
                Err(PcapError::Eof) => return Ok(None),
                Err(PcapError::Incomplete(_)) => Step::Refill,
                Err(PcapError::UnexpectedEof) => Step::Fail(CaptureError::Truncated {
                    offset: self.offset,
                }),
                Err(PcapError::BufferTooSmall) => Step::Fail(CaptureError::Corrupt {
                    offset: self.offset,
                    reason: "a record claims to be larger than any packet".into(),
                }),
                Err(PcapError::ReadError) => Step::Fail(CaptureError::Corrupt {
                    offset: self.offset,
                    reason: "read error".into(),
                }),
                Err(e) => Step::Fail(CaptureError::Corrupt {
                    offset: self.offset,
                    reason: format!("{e:?}"),
                }),
            };
            match step {
                Step::Datagram(h) => {
                    self.stats.datagrams += 1;
                    return Ok(Some(CapturedDatagram {
                        time_ns: h.time_ns,
                        source: h.source,
                        source_port: h.source_port,
                        destination_port: h.destination_port,
                        payload: &self.payload,
                        announced_len: h.announced_len,
                    }));
                }
                Step::Skip(skip) => self.count_skip(skip),
                Step::Continue => {}
                Step::Refill => {
                    if let Err(e) = self.reader.refill() {
                        self.failed = true;
                        return Err(CaptureError::Corrupt {
                            offset: self.offset,
                            reason: format!("{e:?}"),
                        });
                    }
                }
                Step::Fail(e) => {
                    self.failed = true;
                    return Err(e);
                }
            }
        }
    }

    fn count_skip(&mut self, skip: Skip) {
        let s = &mut self.stats;
        match skip {
            Skip::UnsupportedLink => s.unsupported_link += 1,
            Skip::NotIpv4 => s.not_ipv4 += 1,
            Skip::NotUdp => s.not_udp += 1,
            Skip::Fragment => s.fragments += 1,
            Skip::Malformed => s.malformed += 1,
        }
    }
}

struct Header {
    time_ns: u64,
    source: Ipv4Addr,
    source_port: u16,
    destination_port: u16,
    announced_len: usize,
}

enum Step {
    Datagram(Header),
    Skip(Skip),
    Continue,
    Refill,
    Fail(CaptureError),
}

/// Why a frame was not a UDP/IPv4 datagram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Skip {
    /// A link type Glint does not read.
    UnsupportedLink,
    /// Not IPv4.
    NotIpv4,
    /// Not UDP.
    NotUdp,
    /// An IPv4 fragment.
    Fragment,
    /// Headers cut off or inconsistent.
    Malformed,
}

const ETHERTYPE_IPV4: u16 = 0x0800;
const ETHERTYPE_VLAN: u16 = 0x8100;
const ETHERTYPE_QINQ: u16 = 0x88A8;
const IPPROTO_UDP: u8 = 17;

fn be16(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_be_bytes([*b.get(at)?, *b.get(at + 1)?]))
}

/// Finds the UDP datagram in a link-layer frame. The returned time is 0 (the caller sets it).
pub fn parse_frame(linktype: Linktype, frame: &[u8]) -> Result<CapturedDatagram<'_>, Skip> {
    let ip = match linktype {
        Linktype::ETHERNET => {
            let mut at = 12;
            let mut ethertype = be16(frame, at).ok_or(Skip::Malformed)?;
            while ethertype == ETHERTYPE_VLAN || ethertype == ETHERTYPE_QINQ {
                at += 4;
                ethertype = be16(frame, at).ok_or(Skip::Malformed)?;
            }
            if ethertype != ETHERTYPE_IPV4 {
                return Err(Skip::NotIpv4);
            }
            &frame[at + 2..]
        }
        Linktype::LINUX_SLL => {
            if be16(frame, 14).ok_or(Skip::Malformed)? != ETHERTYPE_IPV4 {
                return Err(Skip::NotIpv4);
            }
            &frame[16..]
        }
        Linktype::LINUX_SLL2 => {
            if be16(frame, 0).ok_or(Skip::Malformed)? != ETHERTYPE_IPV4 || frame.len() < 20 {
                return Err(Skip::NotIpv4);
            }
            &frame[20..]
        }
        Linktype::RAW | Linktype::IPV4 => frame,
        Linktype::NULL | Linktype::LOOP => {
            let family = frame.get(..4).ok_or(Skip::Malformed)?;
            // AF_INET is 2 in either byte order.
            if u32::from_le_bytes(family.try_into().expect("4 bytes")) != 2
                && u32::from_be_bytes(family.try_into().expect("4 bytes")) != 2
            {
                return Err(Skip::NotIpv4);
            }
            &frame[4..]
        }
        _ => return Err(Skip::UnsupportedLink),
    };
    parse_ipv4_udp(ip)
}

fn parse_ipv4_udp(ip: &[u8]) -> Result<CapturedDatagram<'_>, Skip> {
    let first = *ip.first().ok_or(Skip::Malformed)?;
    if first >> 4 != 4 {
        return Err(Skip::NotIpv4);
    }
    let header_len = usize::from(first & 0x0F) * 4;
    if header_len < 20 || ip.len() < header_len {
        return Err(Skip::Malformed);
    }
    let total_len = usize::from(be16(ip, 2).ok_or(Skip::Malformed)?);
    if total_len < header_len {
        return Err(Skip::Malformed);
    }
    let flags_fragment = be16(ip, 6).ok_or(Skip::Malformed)?;
    let more_fragments = flags_fragment & 0x2000 != 0;
    if more_fragments || flags_fragment & 0x1FFF != 0 {
        return Err(Skip::Fragment);
    }
    if ip[9] != IPPROTO_UDP {
        return Err(Skip::NotUdp);
    }
    let source = Ipv4Addr::new(ip[12], ip[13], ip[14], ip[15]);
    // Ethernet pads short frames: the IP total length, not the frame, bounds the datagram.
    let ip = &ip[..total_len.min(ip.len())];
    let udp = &ip[header_len..];
    if udp.len() < 8 {
        return Err(Skip::Malformed);
    }
    let source_port = be16(udp, 0).ok_or(Skip::Malformed)?;
    let destination_port = be16(udp, 2).ok_or(Skip::Malformed)?;
    let udp_len = usize::from(be16(udp, 4).ok_or(Skip::Malformed)?);
    if udp_len < 8 {
        return Err(Skip::Malformed);
    }
    let announced_len = udp_len - 8;
    let payload = &udp[8..udp.len().min(udp_len)];
    Ok(CapturedDatagram {
        time_ns: 0,
        source,
        source_port,
        destination_port,
        payload,
        announced_len,
    })
}

/// Addresses of a datagram to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UdpEndpoints {
    /// Source address and port.
    pub source: (Ipv4Addr, u16),
    /// Destination address and port.
    pub destination: (Ipv4Addr, u16),
}

/// Writes a classic pcap (µs timestamps, Ethernet link type) of UDP/IPv4 datagrams, with valid
/// IPv4 and UDP checksums, as tcpdump would record them.
pub struct CaptureWriter<W: Write> {
    out: W,
    frame: Vec<u8>,
    ip_id: u16,
    source_mac: [u8; 6],
}

impl CaptureWriter<BufWriter<File>> {
    /// Creates a capture file.
    pub fn create(path: &Path) -> io::Result<Self> {
        Self::new(BufWriter::new(File::create(path)?))
    }
}

impl<W: Write> CaptureWriter<W> {
    /// Writes the file header.
    pub fn new(mut out: W) -> io::Result<Self> {
        let mut header = Vec::with_capacity(24);
        header.extend_from_slice(&0xA1B2_C3D4u32.to_le_bytes());
        header.extend_from_slice(&2u16.to_le_bytes());
        header.extend_from_slice(&4u16.to_le_bytes());
        header.extend_from_slice(&0i32.to_le_bytes());
        header.extend_from_slice(&0u32.to_le_bytes());
        header.extend_from_slice(&65_535u32.to_le_bytes());
        header.extend_from_slice(&1u32.to_le_bytes()); // LINKTYPE_ETHERNET
        out.write_all(&header)?;
        // Velodyne's OUI; the sensor's MAC starts with it.
        Ok(Self {
            out,
            frame: Vec::with_capacity(1600),
            ip_id: 0,
            source_mac: [0x60, 0x76, 0x88, 0x00, 0x00, 0x01],
        })
    }

    /// Appends one datagram captured at `time_ns`. The destination MAC is broadcast.
    pub fn write_udp(
        &mut self,
        time_ns: u64,
        endpoints: UdpEndpoints,
        payload: &[u8],
    ) -> io::Result<()> {
        let udp_len = 8 + payload.len();
        let ip_len = 20 + udp_len;
        if ip_len > usize::from(u16::MAX) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "datagram too large",
            ));
        }
        let f = &mut self.frame;
        f.clear();
        f.extend_from_slice(&[0xFF; 6]);
        f.extend_from_slice(&self.source_mac);
        f.extend_from_slice(&ETHERTYPE_IPV4.to_be_bytes());
        let ip_start = f.len();
        f.extend_from_slice(&[0x45, 0x00]);
        f.extend_from_slice(&(ip_len as u16).to_be_bytes());
        f.extend_from_slice(&self.ip_id.to_be_bytes());
        f.extend_from_slice(&[0x40, 0x00, 64, IPPROTO_UDP, 0, 0]); // don't fragment, TTL 64
        f.extend_from_slice(&endpoints.source.0.octets());
        f.extend_from_slice(&endpoints.destination.0.octets());
        let ip_checksum = internet_checksum(&[&f[ip_start..ip_start + 20]]);
        f[ip_start + 10..ip_start + 12].copy_from_slice(&ip_checksum.to_be_bytes());
        self.ip_id = self.ip_id.wrapping_add(1);
        let udp_start = f.len();
        f.extend_from_slice(&endpoints.source.1.to_be_bytes());
        f.extend_from_slice(&endpoints.destination.1.to_be_bytes());
        f.extend_from_slice(&(udp_len as u16).to_be_bytes());
        f.extend_from_slice(&[0, 0]);
        f.extend_from_slice(payload);
        let mut pseudo = [0u8; 12];
        pseudo[..4].copy_from_slice(&endpoints.source.0.octets());
        pseudo[4..8].copy_from_slice(&endpoints.destination.0.octets());
        pseudo[9] = IPPROTO_UDP;
        pseudo[10..12].copy_from_slice(&(udp_len as u16).to_be_bytes());
        let mut udp_checksum = internet_checksum(&[&pseudo, &f[udp_start..]]);
        if udp_checksum == 0 {
            udp_checksum = 0xFFFF;
        }
        f[udp_start + 6..udp_start + 8].copy_from_slice(&udp_checksum.to_be_bytes());

        let secs = (time_ns / 1_000_000_000) as u32;
        let micros = ((time_ns % 1_000_000_000) / 1000) as u32;
        let mut record = [0u8; 16];
        record[0..4].copy_from_slice(&secs.to_le_bytes());
        record[4..8].copy_from_slice(&micros.to_le_bytes());
        record[8..12].copy_from_slice(&(f.len() as u32).to_le_bytes());
        record[12..16].copy_from_slice(&(f.len() as u32).to_le_bytes());
        self.out.write_all(&record)?;
        self.out.write_all(f)
    }

    /// Flushes and returns the underlying writer.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}

/// The ones'-complement sum of RFC 1071 over the concatenation of `parts` (each even-length
/// except possibly the last).
fn internet_checksum(parts: &[&[u8]]) -> u16 {
    let mut sum: u32 = 0;
    for part in parts {
        let mut chunks = part.chunks_exact(2);
        for c in &mut chunks {
            sum += u32::from(u16::from_be_bytes([c[0], c[1]]));
        }
        if let [last] = chunks.remainder() {
            sum += u32::from(*last) << 8;
        }
    }
    while sum >> 16 != 0 {
        sum = (sum & 0xFFFF) + (sum >> 16);
    }
    !(sum as u16)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn endpoints(port: u16) -> UdpEndpoints {
        UdpEndpoints {
            source: (Ipv4Addr::new(192, 168, 1, 201), 2368),
            destination: (Ipv4Addr::BROADCAST, port),
        }
    }

    fn sample_capture() -> Vec<u8> {
        let mut w = CaptureWriter::new(Vec::new()).unwrap();
        w.write_udp(1_700_000_000_123_456_000, endpoints(2368), &[7u8; 1206])
            .unwrap();
        w.write_udp(1_700_000_000_124_000_000, endpoints(8308), &[1u8; 512])
            .unwrap();
        w.finish().unwrap()
    }

    #[test]
    fn written_captures_read_back() {
        let bytes = sample_capture();
        let mut r = CaptureReader::from_reader(std::io::Cursor::new(bytes)).unwrap();
        let d = r.next().unwrap().unwrap();
        assert_eq!(
            (d.time_ns, d.destination_port, d.payload.len()),
            (1_700_000_000_123_456_000, 2368, 1206)
        );
        assert_eq!(d.source, Ipv4Addr::new(192, 168, 1, 201));
        let d = r.next().unwrap().unwrap();
        assert_eq!((d.destination_port, d.payload.len()), (8308, 512));
        assert!(r.next().unwrap().is_none());
        assert_eq!(r.stats().datagrams, 2);
    }

    #[test]
    fn checksums_verify() {
        let bytes = sample_capture();
        let frame = &bytes[24 + 16..24 + 16 + 14 + 20 + 8 + 1206];
        assert_eq!(
            internet_checksum(&[&frame[14..34]]),
            0,
            "IPv4 header checksum"
        );
        let mut pseudo = [0u8; 12];
        pseudo[..4].copy_from_slice(&frame[26..30]);
        pseudo[4..8].copy_from_slice(&frame[30..34]);
        pseudo[9] = 17;
        pseudo[10..12].copy_from_slice(&frame[38..40]);
        assert_eq!(
            internet_checksum(&[&pseudo, &frame[34..]]),
            0,
            "UDP checksum"
        );
    }

    #[test]
    fn truncated_file_yields_what_came_before_and_names_the_offset() {
        let bytes = sample_capture();
        let cut = bytes.len() - 100;
        let mut r =
            CaptureReader::from_reader(std::io::Cursor::new(bytes[..cut].to_vec())).unwrap();
        assert!(r.next().unwrap().is_some());
        let second_record = 24 + 16 + 14 + 20 + 8 + 1206;
        match r.next() {
            Err(CaptureError::Truncated { offset }) => assert_eq!(offset, second_record as u64),
            other => panic!("expected truncation, got {other:?}"),
        }
        assert!(r.next().unwrap().is_none());
    }

    #[test]
    fn foreign_files_are_refused() {
        assert!(matches!(
            CaptureReader::from_reader(std::io::Cursor::new(
                b"hello, this is not a capture file".to_vec()
            )),
            Err(CaptureError::NotACapture)
        ));
        assert!(CaptureReader::from_reader(std::io::Cursor::new(Vec::new())).is_err());
    }

    /// A pcapng built by hand: section header, an interface (Linux SLL2, nanosecond resolution
    /// via `if_tsresol`), and two enhanced packets, one of them not UDP.
    fn pcapng(payload: &[u8]) -> Vec<u8> {
        fn block(kind: u32, body: &[u8]) -> Vec<u8> {
            let len = 12 + body.len().div_ceil(4) * 4;
            let mut b = Vec::new();
            b.extend_from_slice(&kind.to_le_bytes());
            b.extend_from_slice(&(len as u32).to_le_bytes());
            b.extend_from_slice(body);
            b.resize(len - 4, 0);
            b.extend_from_slice(&(len as u32).to_le_bytes());
            b
        }
        let mut shb = Vec::new();
        shb.extend_from_slice(&0x1A2B_3C4Du32.to_le_bytes());
        shb.extend_from_slice(&1u16.to_le_bytes());
        shb.extend_from_slice(&0u16.to_le_bytes());
        shb.extend_from_slice(&(-1i64).to_le_bytes());
        let mut idb = Vec::new();
        idb.extend_from_slice(&276u16.to_le_bytes()); // LINKTYPE_LINUX_SLL2
        idb.extend_from_slice(&0u16.to_le_bytes());
        idb.extend_from_slice(&0u32.to_le_bytes());
        idb.extend_from_slice(&[9, 0, 1, 0, 9, 0, 0, 0]); // if_tsresol = 10⁻⁹
        idb.extend_from_slice(&[0, 0, 0, 0]); // opt_endofopt
        let frame = |ip_payload_protocol: u8| {
            let mut f = vec![0x08, 0x00];
            f.extend_from_slice(&[0u8; 18]);
            let total = 20 + 8 + payload.len();
            f.extend_from_slice(&[
                0x45,
                0,
                (total >> 8) as u8,
                total as u8,
                0,
                0,
                0x40,
                0,
                64,
                ip_payload_protocol,
                0,
                0,
            ]);
            f.extend_from_slice(&[192, 168, 1, 201, 255, 255, 255, 255]);
            f.extend_from_slice(&2368u16.to_be_bytes());
            f.extend_from_slice(&2368u16.to_be_bytes());
            f.extend_from_slice(&((8 + payload.len()) as u16).to_be_bytes());
            f.extend_from_slice(&[0, 0]);
            f.extend_from_slice(payload);
            f
        };
        let epb = |ts: u64, f: &[u8]| {
            let mut b = Vec::new();
            b.extend_from_slice(&0u32.to_le_bytes());
            b.extend_from_slice(&((ts >> 32) as u32).to_le_bytes());
            b.extend_from_slice(&(ts as u32).to_le_bytes());
            b.extend_from_slice(&(f.len() as u32).to_le_bytes());
            b.extend_from_slice(&(f.len() as u32).to_le_bytes());
            b.extend_from_slice(f);
            b.resize(20 + f.len().div_ceil(4) * 4, 0);
            block(6, &b)
        };
        let mut out = block(0x0A0D_0D0A, &shb);
        out.extend(block(1, &idb));
        out.extend(epb(1_700_000_000_123_456_789, &frame(6)));
        out.extend(epb(1_700_000_000_123_456_790, &frame(17)));
        out
    }

    #[test]
    fn pcapng_with_sll2_and_nanosecond_times() {
        let bytes = pcapng(&[5u8; 1206]);
        let mut r = CaptureReader::from_reader(std::io::Cursor::new(bytes.clone())).unwrap();
        let d = r.next().unwrap().unwrap();
        assert_eq!(d.time_ns, 1_700_000_000_123_456_790);
        assert_eq!((d.destination_port, d.payload.len()), (2368, 1206));
        assert!(r.next().unwrap().is_none());
        assert_eq!(r.stats().not_udp, 1);
        // Cut inside the last block: the first packets still come, then the offset.
        let mut r =
            CaptureReader::from_reader(std::io::Cursor::new(bytes[..bytes.len() - 10].to_vec()))
                .unwrap();
        assert!(matches!(r.next(), Err(CaptureError::Truncated { .. })));
    }

    #[test]
    fn vlan_sll_and_options() {
        // An IPv4 header with one 4-byte option (IHL 6), UDP to 2368 with a 3-byte payload.
        let mut ip = vec![
            0x46, 0, 0, 0, 0, 0, 0, 0, 64, 17, 0, 0, 10, 0, 0, 1, 10, 0, 0, 2, 1, 1, 1, 1,
        ];
        ip.extend_from_slice(&[0x09, 0x40, 0x09, 0x40, 0, 11, 0, 0, 1, 2, 3]);
        let total = ip.len() as u16;
        ip[2..4].copy_from_slice(&total.to_be_bytes());
        let mut eth = vec![0xFF; 12];
        eth.extend_from_slice(&[0x81, 0x00, 0x00, 0x05, 0x08, 0x00]);
        eth.extend_from_slice(&ip);
        eth.extend_from_slice(&[0; 6]); // Ethernet padding
        let d = parse_frame(Linktype::ETHERNET, &eth).unwrap();
        assert_eq!((d.destination_port, d.payload), (2368, &[1u8, 2, 3][..]));
        let mut sll = vec![0u8; 14];
        sll.extend_from_slice(&[0x08, 0x00]);
        sll.extend_from_slice(&ip);
        assert_eq!(
            parse_frame(Linktype::LINUX_SLL, &sll).unwrap().payload,
            &[1, 2, 3]
        );
        let mut sll2 = vec![0x08, 0x00];
        sll2.extend_from_slice(&[0u8; 18]);
        sll2.extend_from_slice(&ip);
        assert_eq!(
            parse_frame(Linktype::LINUX_SLL2, &sll2).unwrap().payload,
            &[1, 2, 3]
        );
        let mut frag = ip.clone();
        frag[6] = 0x20;
        assert_eq!(
            parse_frame(Linktype::RAW, &frag).unwrap_err(),
            Skip::Fragment
        );
        let mut arp = vec![0xFF; 12];
        arp.extend_from_slice(&[0x08, 0x06, 0, 0]);
        assert_eq!(
            parse_frame(Linktype::ETHERNET, &arp).unwrap_err(),
            Skip::NotIpv4
        );
    }
}

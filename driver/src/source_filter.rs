//! Which sensor a packet is from. A VLP-16 sends to the broadcast address by default, so on a
//! shared network every unit's packets reach the data and position ports; decoded together they
//! make one sweep of two sensors. The filter admits one source address: the configured one, or
//! the first to send a valid data packet. Everything else is counted per source and refused.
//!
//! Until the lock, position packets are held (a few ms of them: data packets come 754 a second)
//! and released in order once their source turns out to be the one locked onto, so a capture of
//! one sensor is decoded exactly as without the filter.

use std::net::IpAddr;

use crate::source::PacketKind;
use crate::wire::{DataPacket, PacketError, AZIMUTH_LIMIT, POSITION_PAYLOAD_LEN};

/// Position packets held before the lock (~50 ms of them).
const HOLD_POSITIONS: usize = 8;

/// Distinct sources counted one by one; any beyond are counted together.
pub const MAX_TRACKED_SOURCES: usize = 32;

/// What to do with a packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Decode it (after any [`SourceFilter::take_released`] packets).
    Accept,
    /// From another sensor (or anything else): refused and counted.
    Foreign,
    /// A position packet before the lock: held until its source is known to be ours.
    Held,
}

/// Why the filter admits the source it admits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admitted {
    /// Configured.
    Configured(IpAddr),
    /// The first source that sent a valid data packet.
    Locked(IpAddr),
    /// Nothing valid seen yet.
    Undecided,
}

impl Admitted {
    /// The admitted address, once known.
    pub fn address(self) -> Option<IpAddr> {
        match self {
            Admitted::Configured(a) | Admitted::Locked(a) => Some(a),
            Admitted::Undecided => None,
        }
    }
}

/// Packets seen from one source address (admitted or not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SourceCount {
    /// The address.
    pub address: IpAddr,
    /// Datagrams to the data port.
    pub data: u64,
    /// Datagrams to the position port.
    pub position: u64,
}

/// Counters of the filter.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FilterStats {
    /// Data packets refused as foreign.
    pub foreign_data: u64,
    /// Position packets refused as foreign (including held ones from a source not locked onto).
    pub foreign_position: u64,
    /// Position packets dropped from a full hold before any valid data packet came.
    pub unattributed_position: u64,
    /// Packets from sources beyond [`MAX_TRACKED_SOURCES`] (also in the foreign counts).
    pub untracked: u64,
    /// Receive time of the last foreign packet, ns.
    pub last_foreign_ns: Option<u64>,
}

impl FilterStats {
    /// Every packet refused as foreign.
    pub fn foreign(&self) -> u64 {
        self.foreign_data + self.foreign_position
    }
}

/// A position packet held before the lock.
#[derive(Debug, Clone)]
pub struct HeldPosition {
    /// Where it came from.
    pub source: IpAddr,
    /// When it was received, ns.
    pub receive_ns: u64,
    len: usize,
    bytes: [u8; POSITION_PAYLOAD_LEN],
}

impl HeldPosition {
    /// The payload.
    pub fn payload(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Admits one sensor's packets. See the module docs.
#[derive(Debug)]
pub struct SourceFilter {
    admitted: Admitted,
    held: Vec<HeldPosition>,
    released: std::collections::VecDeque<HeldPosition>,
    sources: Vec<SourceCount>,
    stats: FilterStats,
}

/// The address as the sensor has it: an IPv4-mapped IPv6 address (a dual-stack socket) is the
/// IPv4 address.
fn canonical(address: IpAddr) -> IpAddr {
    address.to_canonical()
}

/// Whether `payload` is a data packet the stream decodes (a block azimuth of exactly a full turn
/// is firmware's way of writing 0, not damage).
pub fn is_valid_data(payload: &[u8]) -> bool {
    match DataPacket::new_checked(payload) {
        Ok(_) => true,
        Err(PacketError::AzimuthOutOfRange { value, .. }) if value == AZIMUTH_LIMIT => {
            let mut fixed = payload.to_vec();
            let mut view = DataPacket::new_unchecked(&mut fixed[..]);
            for block in 0..crate::wire::BLOCKS_PER_PACKET {
                if view.azimuth(block) == AZIMUTH_LIMIT {
                    view.set_azimuth(block, 0);
                }
            }
            DataPacket::new_checked(&fixed[..]).is_ok()
        }
        Err(_) => false,
    }
}

impl SourceFilter {
    /// A filter admitting only `source`, or (None) the first source of a valid data packet.
    pub fn new(source: Option<IpAddr>) -> Self {
        Self {
            admitted: source.map_or(Admitted::Undecided, |a| Admitted::Configured(canonical(a))),
            held: Vec::with_capacity(HOLD_POSITIONS),
            released: std::collections::VecDeque::new(),
            sources: Vec::new(),
            stats: FilterStats::default(),
        }
    }

    /// The source admitted, and why.
    pub fn admitted(&self) -> Admitted {
        self.admitted
    }

    /// Packets per source address, in the order the sources were first seen.
    pub fn sources(&self) -> &[SourceCount] {
        &self.sources
    }

    /// Counters so far.
    pub fn stats(&self) -> FilterStats {
        self.stats
    }

    /// Judges a packet from `source` received at `receive_ns`. A data packet that locks the
    /// filter may release held position packets: take them with [`Self::take_released`] and
    /// decode them before this one.
    pub fn judge(
        &mut self,
        kind: PacketKind,
        source: IpAddr,
        payload: &[u8],
        receive_ns: u64,
    ) -> Verdict {
        let source = canonical(source);
        let first_seen = self.count(kind, source);
        let verdict = match (self.admitted, kind) {
            (Admitted::Configured(a) | Admitted::Locked(a), _) if a == source => Verdict::Accept,
            (Admitted::Configured(_) | Admitted::Locked(_), _) => Verdict::Foreign,
            (Admitted::Undecided, PacketKind::Data) => {
                if is_valid_data(payload) {
                    self.lock(source);
                }
                // Damaged data before the lock goes on to be counted where damage is.
                Verdict::Accept
            }
            (Admitted::Undecided, PacketKind::Position) => {
                self.hold(source, payload, receive_ns);
                Verdict::Held
            }
        };
        if verdict == Verdict::Foreign {
            self.count_foreign(kind, receive_ns, first_seen);
        }
        verdict
    }

    /// The next held position packet of the source just locked onto, oldest first.
    pub fn take_released(&mut self) -> Option<HeldPosition> {
        self.released.pop_front()
    }

    /// Counts a packet from `source`; false when the source is beyond the tracked ones.
    fn count(&mut self, kind: PacketKind, source: IpAddr) -> bool {
        let index = match self.sources.iter().position(|s| s.address == source) {
            Some(i) => i,
            None if self.sources.len() < MAX_TRACKED_SOURCES => {
                self.sources.push(SourceCount {
                    address: source,
                    data: 0,
                    position: 0,
                });
                self.sources.len() - 1
            }
            None => return false,
        };
        let entry = &mut self.sources[index];
        match kind {
            PacketKind::Data => entry.data += 1,
            PacketKind::Position => entry.position += 1,
        }
        true
    }

    fn count_foreign(&mut self, kind: PacketKind, receive_ns: u64, tracked: bool) {
        match kind {
            PacketKind::Data => self.stats.foreign_data += 1,
            PacketKind::Position => self.stats.foreign_position += 1,
        }
        self.stats.untracked += u64::from(!tracked);
        self.stats.last_foreign_ns = Some(
            self.stats
                .last_foreign_ns
                .map_or(receive_ns, |t| t.max(receive_ns)),
        );
    }

    fn hold(&mut self, source: IpAddr, payload: &[u8], receive_ns: u64) {
        if self.held.len() == HOLD_POSITIONS {
            self.held.remove(0);
            self.stats.unattributed_position += 1;
        }
        let len = payload.len().min(POSITION_PAYLOAD_LEN);
        let mut bytes = [0u8; POSITION_PAYLOAD_LEN];
        bytes[..len].copy_from_slice(&payload[..len]);
        self.held.push(HeldPosition {
            source,
            receive_ns,
            len,
            bytes,
        });
    }

    fn lock(&mut self, source: IpAddr) {
        self.admitted = Admitted::Locked(source);
        for held in std::mem::take(&mut self.held) {
            if held.source == source {
                self.released.push_back(held);
            } else {
                let tracked = self.sources.iter().any(|s| s.address == held.source);
                self.count_foreign(PacketKind::Position, held.receive_ns, tracked);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{ReturnMode, BLOCKS_PER_PACKET, BLOCK_FLAG, DATA_PAYLOAD_LEN};
    use std::net::{Ipv4Addr, Ipv6Addr};

    const OURS: IpAddr = IpAddr::V4(Ipv4Addr::new(192, 168, 1, 201));
    const OTHER: IpAddr = IpAddr::V4(Ipv4Addr::new(192, 168, 1, 202));

    fn data(azimuth: u16) -> [u8; DATA_PAYLOAD_LEN] {
        let mut buf = [0u8; DATA_PAYLOAD_LEN];
        let mut p = DataPacket::new_unchecked(&mut buf[..]);
        for b in 0..BLOCKS_PER_PACKET {
            p.set_block_flag(b, BLOCK_FLAG);
            p.set_azimuth(b, azimuth);
        }
        p.set_return_mode(ReturnMode::Strongest);
        p.set_product_id(0x22);
        buf
    }

    fn position(tag: u8) -> [u8; POSITION_PAYLOAD_LEN] {
        [tag; POSITION_PAYLOAD_LEN]
    }

    #[test]
    fn a_configured_source_is_the_only_one_admitted() {
        let mut f = SourceFilter::new(Some(OURS));
        assert_eq!(
            f.judge(PacketKind::Data, OTHER, &data(0), 1),
            Verdict::Foreign
        );
        assert_eq!(
            f.judge(PacketKind::Data, OURS, &data(0), 2),
            Verdict::Accept
        );
        assert_eq!(
            f.judge(PacketKind::Position, OTHER, &position(1), 3),
            Verdict::Foreign
        );
        assert_eq!(
            f.judge(PacketKind::Position, OURS, &position(1), 4),
            Verdict::Accept
        );
        assert_eq!(f.admitted(), Admitted::Configured(OURS));
        let s = f.stats();
        assert_eq!((s.foreign_data, s.foreign_position), (1, 1));
        assert_eq!(s.last_foreign_ns, Some(3));
        assert_eq!(
            f.sources(),
            &[
                SourceCount {
                    address: OTHER,
                    data: 1,
                    position: 1
                },
                SourceCount {
                    address: OURS,
                    data: 1,
                    position: 1
                }
            ]
        );
    }

    #[test]
    fn locks_onto_the_first_valid_data_not_the_first_packet() {
        let mut f = SourceFilter::new(None);
        // Garbage of the right length from a third address does not lock.
        let garbage = [0x55u8; DATA_PAYLOAD_LEN];
        let third = IpAddr::V4(Ipv4Addr::new(10, 0, 0, 9));
        assert_eq!(
            f.judge(PacketKind::Data, third, &garbage, 1),
            Verdict::Accept
        );
        assert_eq!(f.admitted(), Admitted::Undecided);
        assert_eq!(
            f.judge(PacketKind::Data, OTHER, &data(100), 2),
            Verdict::Accept
        );
        assert_eq!(f.admitted(), Admitted::Locked(OTHER));
        assert_eq!(
            f.judge(PacketKind::Data, OURS, &data(100), 3),
            Verdict::Foreign
        );
        assert_eq!(
            f.judge(PacketKind::Data, third, &garbage, 4),
            Verdict::Foreign
        );
        assert_eq!(
            f.judge(PacketKind::Data, OTHER, &data(200), 5),
            Verdict::Accept
        );
        assert_eq!(f.stats().foreign_data, 2);
    }

    #[test]
    fn a_full_turn_azimuth_is_valid_data() {
        let mut f = SourceFilter::new(None);
        f.judge(PacketKind::Data, OURS, &data(AZIMUTH_LIMIT), 1);
        assert_eq!(f.admitted(), Admitted::Locked(OURS));
        assert!(!is_valid_data(&data(AZIMUTH_LIMIT + 1)));
        assert!(!is_valid_data(&data(0)[..100]));
    }

    #[test]
    fn position_packets_before_the_lock_are_released_only_for_the_source_locked_onto() {
        let mut f = SourceFilter::new(None);
        assert_eq!(
            f.judge(PacketKind::Position, OTHER, &position(1), 1),
            Verdict::Held
        );
        assert_eq!(
            f.judge(PacketKind::Position, OURS, &position(2), 2),
            Verdict::Held
        );
        assert_eq!(
            f.judge(PacketKind::Position, OURS, &position(3), 3),
            Verdict::Held
        );
        assert!(f.take_released().is_none());
        assert_eq!(
            f.judge(PacketKind::Data, OURS, &data(0), 4),
            Verdict::Accept
        );
        let released: Vec<(u8, u64)> = std::iter::from_fn(|| f.take_released())
            .map(|p| (p.payload()[0], p.receive_ns))
            .collect();
        assert_eq!(released, [(2, 2), (3, 3)], "ours, in order");
        assert_eq!(f.stats().foreign_position, 1);
        assert_eq!(f.stats().last_foreign_ns, Some(1));
    }

    #[test]
    fn the_hold_is_bounded() {
        let mut f = SourceFilter::new(None);
        for i in 0..(HOLD_POSITIONS as u64 + 5) {
            f.judge(PacketKind::Position, OURS, &position(i as u8), i);
        }
        assert_eq!(f.stats().unattributed_position, 5);
        f.judge(PacketKind::Data, OURS, &data(0), 100);
        let first = f.take_released().unwrap();
        assert_eq!(first.payload()[0], 5, "the oldest were dropped");
        assert_eq!(std::iter::from_fn(|| f.take_released()).count(), 7);
        // A short position payload is held as it came, not padded.
        let mut g = SourceFilter::new(None);
        g.judge(PacketKind::Position, OURS, &[1, 2, 3], 0);
        g.judge(PacketKind::Data, OURS, &data(0), 1);
        assert_eq!(g.take_released().unwrap().payload(), &[1, 2, 3]);
    }

    #[test]
    fn an_ipv4_mapped_address_is_the_ipv4_address() {
        let mapped = IpAddr::V6(Ipv4Addr::new(192, 168, 1, 201).to_ipv6_mapped());
        let mut f = SourceFilter::new(Some(OURS));
        assert_eq!(
            f.judge(PacketKind::Data, mapped, &data(0), 1),
            Verdict::Accept
        );
        let v6 = IpAddr::V6(Ipv6Addr::LOCALHOST);
        assert_eq!(f.judge(PacketKind::Data, v6, &data(0), 2), Verdict::Foreign);
    }

    #[test]
    fn sources_beyond_the_tracked_ones_are_counted_together() {
        let mut f = SourceFilter::new(Some(OURS));
        for i in 0..(MAX_TRACKED_SOURCES as u32 + 3) {
            let a = IpAddr::V4(Ipv4Addr::from(0x0A00_0000 + i));
            f.judge(PacketKind::Data, a, &data(0), u64::from(i));
        }
        assert_eq!(f.sources().len(), MAX_TRACKED_SOURCES);
        assert_eq!(f.stats().untracked, 3);
        assert_eq!(f.stats().foreign(), MAX_TRACKED_SOURCES as u64 + 3);
    }
}

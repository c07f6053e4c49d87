//! Checked, zero-copy views over the two UDP payloads a VLP-16 sends: the 1206-byte data packet
//! (port 2368) and the 512-byte position packet (port 8308).
//!
//! Shape (after smoltcp's `wire`): a view generic over its byte buffer, a module of named byte
//! ranges, a checked constructor for untrusted input and setters for writing. The contract:
//! once `new_checked` succeeds, no getter panics (indices are bounded by the documented counts).
//! This module knows the byte layout only — no firing times, no elevation angles — so the
//! simulator can use the setters without borrowing the constants it is meant to check.

use thiserror::Error;

/// Length of a data packet's UDP payload.
pub const DATA_PAYLOAD_LEN: usize = 1206;
/// Length of a position packet's UDP payload.
pub const POSITION_PAYLOAD_LEN: usize = 512;
/// Data blocks per data packet.
pub const BLOCKS_PER_PACKET: usize = 12;
/// Channel records (distance + reflectivity) per data block.
pub const RECORDS_PER_BLOCK: usize = 32;
/// Bytes per data block.
pub const BLOCK_LEN: usize = 100;
/// The block flag, `FF EE` on the wire, read as a little-endian u16.
pub const BLOCK_FLAG: u16 = 0xEEFF;
/// Azimuths are in hundredths of a degree and must be below this.
pub const AZIMUTH_LIMIT: u16 = 36_000;
/// Distance unit of a channel record, in metres (2 mm).
pub const DISTANCE_UNIT_M: f64 = 0.002;

mod field {
    use core::ops::Range;
    pub const BLOCK_FLAG: Range<usize> = 0..2;
    pub const BLOCK_AZIMUTH: Range<usize> = 2..4;
    pub const BLOCK_RECORDS: usize = 4;
    pub const RECORD_LEN: usize = 3;
    pub const TIMESTAMP: Range<usize> = 1200..1204;
    pub const RETURN_MODE: usize = 1204;
    pub const PRODUCT_ID: usize = 1205;

    pub const POS_TIMESTAMP: Range<usize> = 198..202;
    pub const POS_PPS_STATUS: usize = 202;
    pub const POS_NMEA: Range<usize> = 206..334;
}

/// Why a payload is not a valid packet. `Truncated` means "need more bytes"; every other
/// variant means the bytes are there but wrong.
#[derive(Debug, Error, Clone, Copy, PartialEq, Eq)]
pub enum PacketError {
    /// The payload is shorter than the packet: it was cut off (snap length, short read).
    #[error("truncated packet: {actual} bytes, a whole one has {expected}")]
    Truncated { expected: usize, actual: usize },
    /// The payload is longer than any packet of this kind: not this kind of packet.
    #[error("wrong packet length: {actual} bytes, expected {expected}")]
    WrongLength { expected: usize, actual: usize },
    /// A data block does not start with `FF EE`.
    #[error("block {block}: flag {found:#06x}, expected 0xeeff")]
    BadBlockFlag { block: usize, found: u16 },
    /// A block's azimuth is not below 36000 hundredths of a degree.
    #[error("block {block}: azimuth {value} is not below 36000")]
    AzimuthOutOfRange { block: usize, value: u16 },
    /// The return-mode byte is none of 0x37, 0x38, 0x39.
    #[error("unknown return mode byte {0:#04x}")]
    UnknownReturnMode(u8),
}

/// The return mode announced by byte 1204 of a data packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ReturnMode {
    /// 0x37: one return per firing, the strongest.
    Strongest,
    /// 0x38: one return per firing, the last.
    Last,
    /// 0x39: two returns per firing in paired blocks (even = last, odd = strongest).
    Dual,
}

impl ReturnMode {
    /// Reads the wire byte.
    pub fn from_byte(byte: u8) -> Result<Self, PacketError> {
        match byte {
            0x37 => Ok(Self::Strongest),
            0x38 => Ok(Self::Last),
            0x39 => Ok(Self::Dual),
            other => Err(PacketError::UnknownReturnMode(other)),
        }
    }

    /// The wire byte.
    pub fn byte(self) -> u8 {
        match self {
            Self::Strongest => 0x37,
            Self::Last => 0x38,
            Self::Dual => 0x39,
        }
    }

    /// A lower-case name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Strongest => "strongest",
            Self::Last => "last",
            Self::Dual => "dual",
        }
    }
}

fn check_length(actual: usize, expected: usize) -> Result<(), PacketError> {
    use core::cmp::Ordering;
    match actual.cmp(&expected) {
        Ordering::Less => Err(PacketError::Truncated { expected, actual }),
        Ordering::Greater => Err(PacketError::WrongLength { expected, actual }),
        Ordering::Equal => Ok(()),
    }
}

fn read_u16(bytes: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([bytes[at], bytes[at + 1]])
}

/// A view over a 1206-byte data packet payload.
#[derive(Debug, Clone, Copy)]
pub struct DataPacket<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> DataPacket<T> {
    /// Wraps a buffer without checking it. Getters may panic if the buffer is shorter than
    /// [`DATA_PAYLOAD_LEN`]; use [`DataPacket::new_checked`] for untrusted input.
    pub fn new_unchecked(buffer: T) -> Self {
        Self { buffer }
    }

    /// Wraps a buffer after checking its length, every block flag and azimuth, and the
    /// return-mode byte. The product-id byte is not judged here: see [`crate::model`].
    pub fn new_checked(buffer: T) -> Result<Self, PacketError> {
        let packet = Self::new_unchecked(buffer);
        packet.check()?;
        Ok(packet)
    }

    /// The validation `new_checked` performs.
    pub fn check(&self) -> Result<(), PacketError> {
        let bytes = self.buffer.as_ref();
        check_length(bytes.len(), DATA_PAYLOAD_LEN)?;
        for block in 0..BLOCKS_PER_PACKET {
            let flag = self.block_flag(block);
            if flag != BLOCK_FLAG {
                return Err(PacketError::BadBlockFlag { block, found: flag });
            }
            let value = self.azimuth(block);
            if value >= AZIMUTH_LIMIT {
                return Err(PacketError::AzimuthOutOfRange { block, value });
            }
        }
        ReturnMode::from_byte(self.return_mode_byte())?;
        Ok(())
    }

    /// The underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    /// The raw bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    fn block_start(block: usize) -> usize {
        assert!(
            block < BLOCKS_PER_PACKET,
            "block index {block} out of range"
        );
        block * BLOCK_LEN
    }

    /// The flag word of block `block` (< 12).
    pub fn block_flag(&self, block: usize) -> u16 {
        let at = Self::block_start(block) + field::BLOCK_FLAG.start;
        read_u16(self.buffer.as_ref(), at)
    }

    /// The azimuth of block `block` (< 12) in hundredths of a degree.
    pub fn azimuth(&self, block: usize) -> u16 {
        let at = Self::block_start(block) + field::BLOCK_AZIMUTH.start;
        read_u16(self.buffer.as_ref(), at)
    }

    /// Channel record `record` (< 32) of block `block` (< 12): (distance in 2 mm units,
    /// reflectivity). A distance of 0 means no return.
    pub fn record(&self, block: usize, record: usize) -> (u16, u8) {
        assert!(
            record < RECORDS_PER_BLOCK,
            "record index {record} out of range"
        );
        let at = Self::block_start(block) + field::BLOCK_RECORDS + record * field::RECORD_LEN;
        let bytes = self.buffer.as_ref();
        (read_u16(bytes, at), bytes[at + 2])
    }

    /// The 32 records of a block as raw bytes (3 bytes each), for tight decode loops.
    pub fn block_records(&self, block: usize) -> &[u8] {
        let at = Self::block_start(block) + field::BLOCK_RECORDS;
        &self.buffer.as_ref()[at..at + RECORDS_PER_BLOCK * field::RECORD_LEN]
    }

    /// Microseconds past the top of the hour of the first firing of the first block, by the
    /// sensor's own counter.
    pub fn timestamp_us(&self) -> u32 {
        let b = &self.buffer.as_ref()[field::TIMESTAMP];
        u32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// Byte 1204.
    pub fn return_mode_byte(&self) -> u8 {
        self.buffer.as_ref()[field::RETURN_MODE]
    }

    /// Byte 1204, decoded. Cannot fail on a checked packet.
    pub fn return_mode(&self) -> Result<ReturnMode, PacketError> {
        ReturnMode::from_byte(self.return_mode_byte())
    }

    /// Byte 1205: what the sensor claims to be. Not to be trusted alone.
    pub fn product_id(&self) -> u8 {
        self.buffer.as_ref()[field::PRODUCT_ID]
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> DataPacket<T> {
    fn bytes_mut(&mut self) -> &mut [u8] {
        self.buffer.as_mut()
    }

    /// Sets block `block`'s flag word.
    pub fn set_block_flag(&mut self, block: usize, flag: u16) {
        let at = Self::block_start(block) + field::BLOCK_FLAG.start;
        self.bytes_mut()[at..at + 2].copy_from_slice(&flag.to_le_bytes());
    }

    /// Sets block `block`'s azimuth in hundredths of a degree.
    pub fn set_azimuth(&mut self, block: usize, azimuth: u16) {
        let at = Self::block_start(block) + field::BLOCK_AZIMUTH.start;
        self.bytes_mut()[at..at + 2].copy_from_slice(&azimuth.to_le_bytes());
    }

    /// Sets a channel record: distance in 2 mm units (0 = no return) and reflectivity.
    pub fn set_record(&mut self, block: usize, record: usize, distance: u16, reflectivity: u8) {
        assert!(
            record < RECORDS_PER_BLOCK,
            "record index {record} out of range"
        );
        let at = Self::block_start(block) + field::BLOCK_RECORDS + record * field::RECORD_LEN;
        let bytes = self.bytes_mut();
        bytes[at..at + 2].copy_from_slice(&distance.to_le_bytes());
        bytes[at + 2] = reflectivity;
    }

    /// Sets the µs-past-the-hour timestamp.
    pub fn set_timestamp_us(&mut self, us: u32) {
        self.bytes_mut()[field::TIMESTAMP].copy_from_slice(&us.to_le_bytes());
    }

    /// Sets the return-mode byte.
    pub fn set_return_mode(&mut self, mode: ReturnMode) {
        self.bytes_mut()[field::RETURN_MODE] = mode.byte();
    }

    /// Sets the product-id byte.
    pub fn set_product_id(&mut self, id: u8) {
        self.bytes_mut()[field::PRODUCT_ID] = id;
    }
}

/// PPS status byte of a position packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PpsStatus {
    /// 0: no PPS signal.
    Absent,
    /// 1: synchronising to PPS.
    Synchronizing,
    /// 2: PPS locked.
    Locked,
    /// 3: error.
    Error,
    /// Any other value.
    Unknown(u8),
}

impl PpsStatus {
    /// Reads the wire byte.
    pub fn from_byte(byte: u8) -> Self {
        match byte {
            0 => Self::Absent,
            1 => Self::Synchronizing,
            2 => Self::Locked,
            3 => Self::Error,
            other => Self::Unknown(other),
        }
    }

    /// The wire byte.
    pub fn byte(self) -> u8 {
        match self {
            Self::Absent => 0,
            Self::Synchronizing => 1,
            Self::Locked => 2,
            Self::Error => 3,
            Self::Unknown(b) => b,
        }
    }
}

/// A view over a 512-byte position packet payload.
#[derive(Debug, Clone, Copy)]
pub struct PositionPacket<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> PositionPacket<T> {
    /// Wraps a buffer without checking its length.
    pub fn new_unchecked(buffer: T) -> Self {
        Self { buffer }
    }

    /// Wraps a buffer after checking its length.
    pub fn new_checked(buffer: T) -> Result<Self, PacketError> {
        check_length(buffer.as_ref().len(), POSITION_PAYLOAD_LEN)?;
        Ok(Self { buffer })
    }

    /// The raw bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// Microseconds past the top of the hour, by the sensor's counter.
    pub fn timestamp_us(&self) -> u32 {
        let b = &self.buffer.as_ref()[field::POS_TIMESTAMP];
        u32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// The PPS status.
    pub fn pps_status(&self) -> PpsStatus {
        PpsStatus::from_byte(self.buffer.as_ref()[field::POS_PPS_STATUS])
    }

    /// The NMEA sentence bytes, up to the first NUL, CR or LF.
    pub fn nmea(&self) -> &[u8] {
        let raw = &self.buffer.as_ref()[field::POS_NMEA];
        let end = raw
            .iter()
            .position(|&b| b == 0 || b == b'\r' || b == b'\n')
            .unwrap_or(raw.len());
        &raw[..end]
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> PositionPacket<T> {
    /// Sets the µs-past-the-hour timestamp.
    pub fn set_timestamp_us(&mut self, us: u32) {
        self.buffer.as_mut()[field::POS_TIMESTAMP].copy_from_slice(&us.to_le_bytes());
    }

    /// Sets the PPS status byte.
    pub fn set_pps_status(&mut self, status: PpsStatus) {
        self.buffer.as_mut()[field::POS_PPS_STATUS] = status.byte();
    }

    /// Writes an NMEA sentence (with its `\r\n`), zero-filling the rest of the field. Longer
    /// sentences are cut to the field's 128 bytes.
    pub fn set_nmea(&mut self, sentence: &[u8]) {
        let field = &mut self.buffer.as_mut()[field::POS_NMEA];
        field.fill(0);
        let n = sentence.len().min(field.len());
        field[..n].copy_from_slice(&sentence[..n]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn valid_packet() -> [u8; DATA_PAYLOAD_LEN] {
        let mut buf = [0u8; DATA_PAYLOAD_LEN];
        let mut p = DataPacket::new_unchecked(&mut buf[..]);
        for b in 0..BLOCKS_PER_PACKET {
            p.set_block_flag(b, BLOCK_FLAG);
            p.set_azimuth(b, (b as u16) * 40);
        }
        p.set_return_mode(ReturnMode::Strongest);
        p.set_product_id(0x22);
        buf
    }

    #[test]
    fn block_flag_is_ff_ee_on_the_wire() {
        let buf = valid_packet();
        assert_eq!(&buf[0..2], &[0xFF, 0xEE]);
        assert_eq!(&buf[100..102], &[0xFF, 0xEE]);
    }

    #[test]
    fn known_bytes_read_back() {
        let mut buf = valid_packet();
        // Block 3, record 5: distance 0x1234 (= 9.32 m), reflectivity 77.
        let at = 3 * 100 + 4 + 5 * 3;
        buf[at..at + 3].copy_from_slice(&[0x34, 0x12, 77]);
        buf[1200..1204].copy_from_slice(&[0x78, 0x56, 0x34, 0x12]);
        let p = DataPacket::new_checked(&buf[..]).unwrap();
        assert_eq!(p.record(3, 5), (0x1234, 77));
        assert_eq!(p.timestamp_us(), 0x1234_5678);
        assert_eq!(p.azimuth(3), 120);
        assert_eq!(p.return_mode().unwrap(), ReturnMode::Strongest);
        assert_eq!(p.product_id(), 0x22);
    }

    #[test]
    fn truncation_is_kept_apart_from_corruption() {
        let buf = valid_packet();
        assert_eq!(
            DataPacket::new_checked(&buf[..1000]).unwrap_err(),
            PacketError::Truncated {
                expected: 1206,
                actual: 1000
            }
        );
        let mut long = buf.to_vec();
        long.push(0);
        assert!(matches!(
            DataPacket::new_checked(&long[..]).unwrap_err(),
            PacketError::WrongLength { .. }
        ));
        let mut bad = buf;
        bad[500] = 0x00;
        assert_eq!(
            DataPacket::new_checked(&bad[..]).unwrap_err(),
            PacketError::BadBlockFlag {
                block: 5,
                found: 0xEE00
            }
        );
        let mut bad = buf;
        bad[702..704].copy_from_slice(&36000u16.to_le_bytes());
        assert_eq!(
            DataPacket::new_checked(&bad[..]).unwrap_err(),
            PacketError::AzimuthOutOfRange {
                block: 7,
                value: 36000
            }
        );
        let mut bad = buf;
        bad[1204] = 0x40;
        assert_eq!(
            DataPacket::new_checked(&bad[..]).unwrap_err(),
            PacketError::UnknownReturnMode(0x40)
        );
    }

    #[test]
    fn position_packet_fields() {
        let mut buf = [0u8; POSITION_PAYLOAD_LEN];
        let mut p = PositionPacket::new_checked(&mut buf[..]).unwrap();
        p.set_timestamp_us(1_234_567);
        p.set_pps_status(PpsStatus::Locked);
        p.set_nmea(b"$GPRMC,120000,A*00\r\n");
        let p = PositionPacket::new_checked(&buf[..]).unwrap();
        assert_eq!(p.timestamp_us(), 1_234_567);
        assert_eq!(p.pps_status(), PpsStatus::Locked);
        assert_eq!(p.nmea(), b"$GPRMC,120000,A*00");
        assert!(matches!(
            PositionPacket::new_checked(&buf[..511]),
            Err(PacketError::Truncated { .. })
        ));
    }
}

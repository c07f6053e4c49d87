//! [`Pose`] and [`Status`] as bytes for transports that carry a byte string instead of shared
//! memory (the fleet link over Zenoh): exactly the shared-memory layout of `ipc/README.md`,
//! every field little-endian whatever the host, so a consumer of either transport reads one
//! layout. Encoding goes field by field, not through the struct's memory, so a big-endian host
//! would still write the documented bytes.

use thiserror::Error;

use crate::payload::{Frame, Pose, Status, StatusFlags};

/// Why bytes could not be read as a payload.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum BytesError {
    /// The byte string has another length than the type's.
    #[error("{type_name} is {expected} bytes, got {found}")]
    Length {
        /// The type expected.
        type_name: &'static str,
        /// Its size.
        expected: usize,
        /// Bytes there were.
        found: usize,
    },
}

/// Appends little-endian fields to a fixed buffer.
struct Writer<const N: usize> {
    bytes: [u8; N],
    at: usize,
}

impl<const N: usize> Writer<N> {
    fn new() -> Self {
        Self {
            bytes: [0; N],
            at: 0,
        }
    }

    fn put(&mut self, field: &[u8]) {
        self.bytes[self.at..self.at + field.len()].copy_from_slice(field);
        self.at += field.len();
    }

    fn u64(&mut self, v: u64) {
        self.put(&v.to_le_bytes());
    }

    fn u32(&mut self, v: u32) {
        self.put(&v.to_le_bytes());
    }

    fn f32(&mut self, v: f32) {
        self.put(&v.to_le_bytes());
    }

    fn f64s(&mut self, v: &[f64]) {
        for x in v {
            self.put(&x.to_le_bytes());
        }
    }

    fn finish(self) -> [u8; N] {
        debug_assert_eq!(self.at, N, "every byte of the layout written");
        self.bytes
    }
}

/// Reads little-endian fields from a slice whose length was checked.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const K: usize>(&mut self) -> [u8; K] {
        let mut field = [0; K];
        field.copy_from_slice(&self.bytes[self.at..self.at + K]);
        self.at += K;
        field
    }

    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }

    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }

    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }

    fn f64s<const K: usize>(&mut self) -> [f64; K] {
        let mut v = [0.0; K];
        for x in &mut v {
            *x = f64::from_le_bytes(self.take());
        }
        v
    }
}

fn reader<'a>(
    bytes: &'a [u8],
    type_name: &'static str,
    expected: usize,
) -> Result<Reader<'a>, BytesError> {
    if bytes.len() != expected {
        return Err(BytesError::Length {
            type_name,
            expected,
            found: bytes.len(),
        });
    }
    Ok(Reader { bytes, at: 0 })
}

impl Pose {
    /// Size of the layout, bytes.
    pub const SIZE: usize = 424;

    /// The pose in the documented layout, little-endian.
    pub fn to_le_bytes(&self) -> [u8; Self::SIZE] {
        let mut w = Writer::<{ Self::SIZE }>::new();
        w.u64(self.sequence);
        w.u64(self.timestamp_ns);
        w.f64s(&self.position);
        w.f64s(&self.orientation);
        w.f64s(&self.linear_velocity);
        w.f64s(&self.angular_velocity);
        w.f64s(&self.covariance);
        w.f32(self.quality);
        w.u32(self.frame.0);
        w.u32(self.status.0);
        w.u32(0);
        w.finish()
    }

    /// Reads a pose written by [`Pose::to_le_bytes`] (or by any writer of the layout).
    pub fn from_le_bytes(bytes: &[u8]) -> Result<Self, BytesError> {
        let mut r = reader(bytes, Self::TYPE_NAME, Self::SIZE)?;
        let mut pose = Pose::new(r.u64(), r.u64(), Frame::ODOM);
        pose.position = r.f64s();
        pose.orientation = r.f64s();
        pose.linear_velocity = r.f64s();
        pose.angular_velocity = r.f64s();
        pose.covariance = r.f64s();
        pose.quality = r.f32();
        pose.frame = Frame(r.u32());
        pose.status = StatusFlags(r.u32());
        Ok(pose)
    }
}

impl Status {
    /// Size of the layout, bytes.
    pub const SIZE: usize = 80;

    /// The status in the documented layout, little-endian.
    pub fn to_le_bytes(&self) -> [u8; Self::SIZE] {
        let mut w = Writer::<{ Self::SIZE }>::new();
        for v in [
            self.sequence,
            self.timestamp_ns,
            self.sweeps_processed,
            self.sweeps_dropped,
            self.packets_received,
            self.packets_dropped,
            self.packets_malformed,
        ] {
            w.u64(v);
        }
        for v in [
            self.sweep_rate_hz,
            self.packet_rate_hz,
            self.latency_median_ms,
            self.latency_p99_ms,
        ] {
            w.f32(v);
        }
        w.u32(self.flags.0);
        w.u32(0);
        w.finish()
    }

    /// Reads a status written by [`Status::to_le_bytes`] (or by any writer of the layout).
    pub fn from_le_bytes(bytes: &[u8]) -> Result<Self, BytesError> {
        let mut r = reader(bytes, Self::TYPE_NAME, Self::SIZE)?;
        let mut status = Status::new(r.u64(), r.u64());
        status.sweeps_processed = r.u64();
        status.sweeps_dropped = r.u64();
        status.packets_received = r.u64();
        status.packets_dropped = r.u64();
        status.packets_malformed = r.u64();
        status.sweep_rate_hz = r.f32();
        status.packet_rate_hz = r.f32();
        status.latency_median_ms = r.f32();
        status.latency_p99_ms = r.f32();
        status.flags = StatusFlags(r.u32());
        Ok(status)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> Pose {
        let mut p = Pose::new(7, 1_700_000_000_123_456_789, Frame::MAP);
        p.position = [1.5, -2.25, 0.125];
        p.orientation = [0.0, 0.0, 0.38268343236508984, 0.9238795325112867];
        p.linear_velocity = [1.2, 0.0, 0.01];
        p.angular_velocity = [0.0, 0.0, -0.3];
        for (i, c) in p.covariance.iter_mut().enumerate() {
            *c = i as f64 * 1e-4;
        }
        p.quality = 0.875;
        p.status = StatusFlags(0b1_0000_0101);
        p
    }

    #[test]
    fn a_pose_survives_the_round_trip() {
        let p = pose();
        assert_eq!(Pose::from_le_bytes(&p.to_le_bytes()), Ok(p));
    }

    #[test]
    fn the_bytes_are_the_shared_memory_layout_on_this_little_endian_host() {
        // The field-by-field encoding must equal the struct's memory on the hosts Glint
        // supports (x86-64, AArch64), so both transports carry one layout.
        let p = pose();
        let bytes = p.to_le_bytes();
        assert_eq!(size_of::<Pose>(), Pose::SIZE);
        assert_eq!(&bytes[0..8], &7u64.to_le_bytes());
        assert_eq!(&bytes[16..24], &1.5f64.to_le_bytes());
        assert_eq!(&bytes[408..412], &0.875f32.to_le_bytes());
        assert_eq!(&bytes[412..416], &1u32.to_le_bytes());
        assert_eq!(&bytes[416..420], &0b1_0000_0101u32.to_le_bytes());
        assert_eq!(&bytes[420..424], &[0; 4]);
        let s = Status::new(3, 4);
        assert_eq!(size_of::<Status>(), Status::SIZE);
        assert_eq!(&s.to_le_bytes()[8..16], &4u64.to_le_bytes());
    }

    #[test]
    fn a_status_survives_the_round_trip() {
        let mut s = Status::new(11, 22);
        s.sweeps_processed = 33;
        s.sweeps_dropped = 1;
        s.packets_received = 44;
        s.packets_dropped = 2;
        s.packets_malformed = 3;
        s.sweep_rate_hz = 10.0;
        s.packet_rate_hz = 754.0;
        s.latency_median_ms = 4.5;
        s.latency_p99_ms = 9.25;
        s.flags = StatusFlags(0x101);
        assert_eq!(Status::from_le_bytes(&s.to_le_bytes()), Ok(s));
    }

    #[test]
    fn a_wrong_length_is_refused() {
        let bytes = pose().to_le_bytes();
        assert_eq!(
            Pose::from_le_bytes(&bytes[..423]),
            Err(BytesError::Length {
                type_name: Pose::TYPE_NAME,
                expected: 424,
                found: 423
            })
        );
        assert!(Status::from_le_bytes(&bytes).is_err());
    }
}

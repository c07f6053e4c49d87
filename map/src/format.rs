//! The `.glintmap` byte layout, version 1: [`encode`] a [`SiteMap`] into bytes, [`decode`] them
//! back, and [`check`] what makes a map valid. Pure: no I/O. Little-endian throughout; the
//! fixed header's fields sit at the offsets in [`field`], then come the sensor model, the
//! sections (keyframes, intensity cells, graph edges) and a trailer with the CRC-32 of all the
//! bytes before it. `docs/map-format.md` states the layout byte by byte.
//!
//! [`decode`] takes untrusted bytes: it refuses (never panics) what is not a whole, intact,
//! valid map, and allocates only for counts the bytes present could hold.

use std::ops::Range;

use glint_core::backend::keyframe::{CloudPoint, Keyframe};
use glint_core::backend::pose_graph::Edge;
use glint_core::backend::scan_context::ScanContext;
use glint_core::config::IntensityMapConfig;
use glint_core::intensity_map::IntensityMap;
use glint_core::site_map::{SiteKeyframe, SiteMap};
use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};

use crate::MapError;

/// The first eight bytes of every `.glintmap`.
pub const MAGIC: &[u8; 8] = b"GLINTMAP";

/// The format version this build writes, and the newest it reads.
pub const FORMAT_VERSION: u32 = 1;

/// Byte ranges of the fixed header's fields.
pub mod field {
    use std::ops::Range;

    /// [`super::MAGIC`].
    pub const MAGIC: Range<usize> = 0..8;
    /// Format version, u32.
    pub const VERSION: Range<usize> = 8..12;
    /// The file's length in bytes, trailer included, u64.
    pub const LENGTH: Range<usize> = 12..20;
    /// Flags, u32: [`super::FLAG_EXTENT`].
    pub const FLAGS: Range<usize> = 20..24;
    /// Creation time, ns since the Unix epoch, u64.
    pub const CREATED: Range<usize> = 24..32;
    /// `base_from_sensor`, 7 f64: x y z qx qy qz qw.
    pub const MOUNTING: Range<usize> = 32..88;
    /// Extent in the map frame, 6 f32: min x y z, max x y z (zeros without keyframes).
    pub const EXTENT: Range<usize> = 88..112;
    /// Keyframes, u64.
    pub const KEYFRAMES: Range<usize> = 112..120;
    /// Keyframe points (edges, planes and cloud together), u64.
    pub const POINTS: Range<usize> = 120..128;
    /// Intensity cells, u64.
    pub const CELLS: Range<usize> = 128..136;
    /// Graph edges, u64.
    pub const EDGES: Range<usize> = 136..144;
    /// Intensity voxel edge, m, f32.
    pub const VOXEL: Range<usize> = 144..148;
    /// Intensity `min_weight`, f32.
    pub const MIN_WEIGHT: Range<usize> = 148..152;
    /// Intensity `max_count`, u16.
    pub const MAX_COUNT: Range<usize> = 152..154;
    /// Zero.
    pub const RESERVED: Range<usize> = 154..156;
    /// Scan Context sectors, u32 (0 without keyframes).
    pub const SECTORS: Range<usize> = 156..160;
    /// Scan Context rings, u32 (0 without keyframes).
    pub const RINGS: Range<usize> = 160..164;
    /// Length of the sensor model's UTF-8 bytes that follow the fixed header, u32.
    pub const MODEL_LENGTH: Range<usize> = 164..168;
}

/// Length of the fixed header.
pub const HEADER_LENGTH: usize = 168;

/// Length of the trailer: the length of everything before it (u64), then the CRC-32 (u32).
pub const TRAILER_LENGTH: usize = 12;

/// Flag: the header's extent is set (the map has keyframes).
pub const FLAG_EXTENT: u32 = 1;

/// A pose: 7 f64.
const POSE: usize = 56;
/// A keyframe's fixed part: pose, time, odom pose, three point counts.
const KEYFRAME_FIXED: usize = POSE + 8 + POSE + 12;
/// An intensity cell: key (3 i32), mean (f32), count (u16).
const CELL: usize = 18;
/// A graph edge: from, to (u32), measurement (pose), information (21 f64), robust (u8).
const EDGE: usize = 4 + 4 + POSE + 21 * 8 + 1;

/// How far a stored rotation's norm may be from 1.
const UNIT_TOLERANCE: f64 = 1e-6;

/// The file's bytes. Infallible, but only a map [`check`] accepts decodes again: `file::save`
/// checks first.
pub fn encode(map: &SiteMap) -> Vec<u8> {
    let (sectors, rings) = descriptor_shape(map);
    let extent = map.extent();
    let points = map.point_count();
    let descriptor = sectors * rings * 4;
    let size = HEADER_LENGTH
        + map.sensor_model.len()
        + map.keyframes.len() * (KEYFRAME_FIXED + descriptor)
        + points * 16
        + map.intensity.len() * CELL
        + map.edges.len() * EDGE
        + TRAILER_LENGTH;
    let mut out = Vec::with_capacity(size);
    out.extend_from_slice(MAGIC);
    put_u32(&mut out, FORMAT_VERSION);
    put_u64(&mut out, 0); // The length, set once known.
    put_u32(&mut out, if extent.is_some() { FLAG_EXTENT } else { 0 });
    put_u64(&mut out, map.created_ns);
    put_pose(&mut out, &map.base_from_sensor);
    let (min, max) = extent.unwrap_or_default();
    for v in min.iter().chain(&max) {
        put_f32(&mut out, *v);
    }
    put_u64(&mut out, map.keyframes.len() as u64);
    put_u64(&mut out, points as u64);
    put_u64(&mut out, map.intensity.len() as u64);
    put_u64(&mut out, map.edges.len() as u64);
    let config = map.intensity.config();
    put_f32(&mut out, config.voxel);
    put_f32(&mut out, config.min_weight);
    out.extend_from_slice(&config.max_count.to_le_bytes());
    out.extend_from_slice(&[0, 0]);
    put_u32(&mut out, sectors as u32);
    put_u32(&mut out, rings as u32);
    put_u32(&mut out, map.sensor_model.len() as u32);
    debug_assert_eq!(out.len(), HEADER_LENGTH);
    out.extend_from_slice(map.sensor_model.as_bytes());

    for k in &map.keyframes {
        let kf = &k.keyframe;
        put_pose(&mut out, &k.pose);
        put_u64(&mut out, kf.time_ns);
        put_pose(&mut out, &kf.odom_pose);
        for n in [kf.edges.len(), kf.planes.len(), kf.cloud.len()] {
            put_u32(&mut out, n as u32);
        }
        for p in kf.edges.iter().chain(&kf.planes) {
            p.iter().for_each(|v| put_f32(&mut out, *v));
        }
        for c in &kf.cloud {
            c.position.iter().for_each(|v| put_f32(&mut out, *v));
            put_f32(&mut out, c.eta);
        }
        k.descriptor
            .cells()
            .iter()
            .for_each(|v| put_f32(&mut out, *v));
    }
    for (key, mean, count) in map.intensity.cells() {
        key.iter()
            .for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
        put_f32(&mut out, mean);
        out.extend_from_slice(&count.to_le_bytes());
    }
    for e in &map.edges {
        put_u32(&mut out, e.from as u32);
        put_u32(&mut out, e.to as u32);
        put_pose(&mut out, &e.measurement);
        for r in 0..6 {
            for c in r..6 {
                put_f64(&mut out, e.information[(r, c)]);
            }
        }
        out.push(u8::from(e.robust));
    }

    let length = (out.len() + TRAILER_LENGTH) as u64;
    out[field::LENGTH].copy_from_slice(&length.to_le_bytes());
    let content = out.len() as u64;
    put_u64(&mut out, content);
    let crc = crc32fast::hash(&out);
    put_u32(&mut out, crc);
    out
}

/// The map in `bytes`, or why they are not one: not a glintmap ([`MapError::Foreign`]), a
/// newer format ([`MapError::NewerVersion`]), cut short ([`MapError::Truncated`]), changed
/// since written ([`MapError::Corrupted`]), or intact but invalid ([`MapError::Malformed`]).
/// Linear in the bytes: a checksum pass, then one parsing pass.
pub fn decode(bytes: &[u8]) -> Result<SiteMap, MapError> {
    let found = bytes.len() as u64;
    let magic = bytes.len().min(MAGIC.len());
    if bytes[..magic] != MAGIC[..magic] {
        return Err(MapError::Foreign);
    }
    if let Some(version) = bytes.get(field::VERSION).map(u32_at) {
        if version == 0 {
            return Err(malformed("format version 0 does not exist"));
        }
        if version > FORMAT_VERSION {
            return Err(MapError::NewerVersion(version));
        }
    }
    if bytes.len() < HEADER_LENGTH {
        return Err(MapError::Truncated {
            expected: HEADER_LENGTH as u64,
            found,
        });
    }
    let declared = u64_at(&bytes[field::LENGTH]);
    if declared < (HEADER_LENGTH + TRAILER_LENGTH) as u64 {
        return Err(malformed(format!(
            "the header declares {declared} bytes, fewer than a header and trailer"
        )));
    }
    if found < declared {
        return Err(MapError::Truncated {
            expected: declared,
            found,
        });
    }
    if found > declared {
        return Err(malformed(format!(
            "{} bytes follow the declared end at byte {declared}",
            found - declared
        )));
    }
    let (before_crc, crc) = bytes.split_at(bytes.len() - 4);
    let (stored, computed) = (u32_at(crc), crc32fast::hash(before_crc));
    if stored != computed {
        return Err(MapError::Corrupted { stored, computed });
    }
    let content = &bytes[..bytes.len() - TRAILER_LENGTH];
    let payload = u64_at(&bytes[content.len()..content.len() + 8]);
    if payload != content.len() as u64 {
        return Err(malformed(format!(
            "the trailer says {payload} bytes precede it, the header {}",
            content.len()
        )));
    }
    let (map, extent) = parse(content)?;
    check(&map)?;
    // Bit for bit: the writer computed it from these very values.
    let bits = |e: Option<([f32; 3], [f32; 3])>| {
        let (min, max) = e.unwrap_or_default();
        min.iter()
            .chain(&max)
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    let computed = map.extent();
    if extent.is_some() != computed.is_some() || bits(extent) != bits(computed) {
        return Err(malformed("the header's extent is not the keyframes'"));
    }
    Ok(map)
}

/// Whether `map` is one [`decode`] would return: the same descriptor shape for every
/// keyframe, finite poses with unit rotations, finite points, edges between existing keyframes
/// with finite, symmetric information, and counts within the format's fields.
pub fn check(map: &SiteMap) -> Result<(), MapError> {
    if !pose_is_valid(&map.base_from_sensor) {
        return Err(malformed("the mounting is not a finite rigid transform"));
    }
    if u32::try_from(map.sensor_model.len()).is_err() {
        return Err(malformed("the sensor model is longer than 4 GiB"));
    }
    let config = map.intensity.config();
    if !(config.voxel.is_finite() && config.voxel > 0.0 && config.min_weight.is_finite()) {
        return Err(malformed(format!(
            "intensity voxel {} m, min_weight {}: not a usable map",
            config.voxel, config.min_weight
        )));
    }
    let shape = descriptor_shape(map);
    if u32::try_from(shape.0).is_err() || u32::try_from(shape.1).is_err() {
        return Err(malformed("a descriptor of over 2³² sectors or rings"));
    }
    for (i, k) in map.keyframes.iter().enumerate() {
        if !pose_is_valid(&k.pose) || !pose_is_valid(&k.keyframe.odom_pose) {
            return Err(malformed(format!(
                "keyframe {i}: a pose is not a finite rigid transform"
            )));
        }
        let kf = &k.keyframe;
        let counts = [kf.edges.len(), kf.planes.len(), kf.cloud.len()];
        if counts.iter().any(|&n| u32::try_from(n).is_err()) {
            return Err(malformed(format!(
                "keyframe {i}: over 2³² points of a kind"
            )));
        }
        let finite = kf
            .edges
            .iter()
            .chain(&kf.planes)
            .flatten()
            .chain(
                kf.cloud
                    .iter()
                    .flat_map(|c| c.position.iter().chain([&c.eta])),
            )
            .all(|v| v.is_finite());
        if !finite {
            return Err(malformed(format!("keyframe {i}: a point is not finite")));
        }
        let own = (k.descriptor.sectors(), k.descriptor.rings());
        if own != shape {
            return Err(malformed(format!(
                "keyframe {i}: descriptor of {}×{}, the first keyframe's is {}×{}",
                own.0, own.1, shape.0, shape.1
            )));
        }
    }
    let graph = map.graph();
    graph
        .validate()
        .map_err(|e| malformed(format!("graph: {e}")))?;
    if u32::try_from(map.keyframes.len()).is_err() {
        return Err(malformed("over 2³² keyframes"));
    }
    for (i, e) in map.edges.iter().enumerate() {
        if !pose_is_valid(&e.measurement) {
            return Err(malformed(format!(
                "edge {i}: the measurement's rotation is not a unit quaternion"
            )));
        }
        if e.information != e.information.transpose() {
            return Err(malformed(format!(
                "edge {i}: the information is not symmetric"
            )));
        }
    }
    Ok(())
}

/// The map's Scan Context shape: the first keyframe's, (0, 0) without keyframes.
fn descriptor_shape(map: &SiteMap) -> (usize, usize) {
    map.keyframes
        .first()
        .map_or((0, 0), |k| (k.descriptor.sectors(), k.descriptor.rings()))
}

/// Finite, with a rotation of unit norm.
fn pose_is_valid(pose: &Isometry3<f64>) -> bool {
    let q = &pose.rotation.coords;
    pose.translation
        .vector
        .iter()
        .chain(q.iter())
        .all(|v| v.is_finite())
        && (q.norm() - 1.0).abs() <= UNIT_TOLERANCE
}

fn malformed(what: impl Into<String>) -> MapError {
    MapError::Malformed(what.into())
}

/// The extent a header states.
type Extent = Option<([f32; 3], [f32; 3])>;

/// The header and sections of checksummed content (the file less its trailer), and the
/// extent the header states.
fn parse(content: &[u8]) -> Result<(SiteMap, Extent), MapError> {
    let header = |range: Range<usize>| &content[range];
    let flags = u32_at(header(field::FLAGS));
    if flags & !FLAG_EXTENT != 0 {
        return Err(malformed(format!("unknown flags {flags:#x}")));
    }
    if header(field::RESERVED) != [0, 0] {
        return Err(malformed("reserved header bytes are not zero"));
    }
    let created_ns = u64_at(header(field::CREATED));
    let base_from_sensor = pose_at(header(field::MOUNTING));
    let extent: Vec<f32> = header(field::EXTENT).chunks_exact(4).map(f32_at).collect();
    let keyframes = u64_at(header(field::KEYFRAMES));
    let points = u64_at(header(field::POINTS));
    let cells = u64_at(header(field::CELLS));
    let edges = u64_at(header(field::EDGES));
    let config = IntensityMapConfig {
        voxel: f32_at(header(field::VOXEL)),
        min_weight: f32_at(header(field::MIN_WEIGHT)),
        max_count: u16::from_le_bytes(array(header(field::MAX_COUNT))),
    };
    if config.max_count == 0 {
        return Err(malformed("intensity max_count is 0"));
    }
    let sectors = u32_at(header(field::SECTORS)) as usize;
    let rings = u32_at(header(field::RINGS)) as usize;
    let model_length = u32_at(header(field::MODEL_LENGTH)) as usize;

    let mut r = Reader {
        bytes: content,
        at: HEADER_LENGTH,
    };
    let model = r.take(model_length, "the sensor model")?;
    let sensor_model = String::from_utf8(model.to_vec())
        .map_err(|_| malformed("the sensor model is not UTF-8"))?;

    if keyframes > 0 && (sectors == 0 || rings == 0) {
        return Err(malformed(format!(
            "keyframes with a descriptor of {sectors}×{rings} cells"
        )));
    }
    let descriptor = sectors
        .checked_mul(rings)
        .and_then(|n| n.checked_mul(4))
        .ok_or_else(|| malformed(format!("a descriptor of {sectors}×{rings} cells")))?;
    // Every section's smallest size, so no count can make us allocate for bytes not there.
    let needed = (KEYFRAME_FIXED as u128 + descriptor as u128) * u128::from(keyframes)
        + CELL as u128 * u128::from(cells)
        + EDGE as u128 * u128::from(edges);
    if needed > r.remaining() as u128 {
        return Err(malformed(format!(
            "the header counts {keyframes} keyframes, {cells} intensity cells and {edges} edges: \
             at least {needed} bytes, but {} follow the header",
            r.remaining()
        )));
    }

    let mut site_keyframes = Vec::with_capacity(keyframes as usize);
    let mut held = 0u64;
    for i in 0..keyframes as usize {
        let pose = pose_at(r.take(POSE, "a keyframe")?);
        let time_ns = u64_at(r.take(8, "a keyframe")?);
        let odom_pose = pose_at(r.take(POSE, "a keyframe")?);
        let n_edges = u32_at(r.take(4, "a keyframe")?) as usize;
        let n_planes = u32_at(r.take(4, "a keyframe")?) as usize;
        let n_cloud = u32_at(r.take(4, "a keyframe")?) as usize;
        let what = format!("keyframe {i}'s points");
        let edges = r
            .take(n_edges.saturating_mul(12), &what)?
            .chunks_exact(12)
            .map(point_at);
        let edges = edges.collect();
        let planes = r
            .take(n_planes.saturating_mul(12), &what)?
            .chunks_exact(12)
            .map(point_at);
        let planes = planes.collect();
        let cloud = r.take(n_cloud.saturating_mul(16), &what)?.chunks_exact(16);
        let cloud = cloud
            .map(|c| CloudPoint {
                position: point_at(&c[..12]),
                eta: f32_at(&c[12..]),
            })
            .collect();
        held += (n_edges + n_planes + n_cloud) as u64;
        let grid = r.take(descriptor, &format!("keyframe {i}'s descriptor"))?;
        let grid = grid.chunks_exact(4).map(f32_at).collect();
        let descriptor = ScanContext::from_cells(sectors, rings, grid).ok_or_else(|| {
            malformed(format!(
                "keyframe {i}: descriptor cells must be finite and not negative"
            ))
        })?;
        site_keyframes.push(SiteKeyframe {
            pose,
            keyframe: Keyframe {
                time_ns,
                odom_pose,
                edges,
                planes,
                cloud,
            },
            descriptor,
        });
    }
    if held != points {
        return Err(malformed(format!(
            "the header counts {points} points, the keyframes hold {held}"
        )));
    }

    let mut intensity = IntensityMap::new(&config);
    for i in 0..cells {
        let cell = r.take(CELL, "the intensity cells")?;
        let key = [0, 4, 8].map(|at| i32::from_le_bytes(array(&cell[at..at + 4])));
        let mean = f32_at(&cell[12..16]);
        let count = u16::from_le_bytes(array(&cell[16..18]));
        if !mean.is_finite() || count == 0 || count > config.max_count {
            return Err(malformed(format!(
                "intensity cell {i}: mean {mean} seen {count} times (at most {})",
                config.max_count
            )));
        }
        intensity.insert_cell(key, mean, count);
    }
    if intensity.len() as u64 != cells {
        return Err(malformed(format!(
            "{} of the {cells} intensity cells repeat a key",
            cells - intensity.len() as u64
        )));
    }

    let mut graph_edges = Vec::with_capacity(edges as usize);
    for _ in 0..edges {
        let e = r.take(EDGE, "the graph edges")?;
        let mut information = Matrix6::zeros();
        let mut values = e[4 + 4 + POSE..].chunks_exact(8).map(f64_at);
        for row in 0..6 {
            for col in row..6 {
                let v = values.next().unwrap_or_default();
                information[(row, col)] = v;
                information[(col, row)] = v;
            }
        }
        graph_edges.push(Edge {
            from: u32_at(&e[0..4]) as usize,
            to: u32_at(&e[4..8]) as usize,
            measurement: pose_at(&e[8..8 + POSE]),
            information,
            robust: match e[EDGE - 1] {
                0 => false,
                1 => true,
                other => return Err(malformed(format!("robust flag {other}"))),
            },
        });
    }
    if r.remaining() > 0 {
        return Err(malformed(format!(
            "{} bytes follow the last section",
            r.remaining()
        )));
    }

    let map = SiteMap {
        created_ns,
        sensor_model,
        base_from_sensor,
        keyframes: site_keyframes,
        intensity,
        edges: graph_edges,
    };
    let stated = (flags & FLAG_EXTENT != 0).then(|| {
        (
            [extent[0], extent[1], extent[2]],
            [extent[3], extent[4], extent[5]],
        )
    });
    if stated.is_none() && extent.iter().any(|v| v.to_bits() != 0) {
        return Err(malformed("an extent without the flag that sets it"));
    }
    Ok((map, stated))
}

/// A cursor over checksummed content. Reading past its end means the counts in the file do
/// not match its bytes.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }

    /// The next `n` bytes, which hold `what`.
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], MapError> {
        if n > self.remaining() {
            return Err(malformed(format!(
                "{what} run past the end of the content ({n} bytes at byte {}, {} left)",
                self.at,
                self.remaining()
            )));
        }
        let slice = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(slice)
    }
}

fn array<const N: usize>(bytes: &[u8]) -> [u8; N] {
    let mut a = [0; N];
    a.copy_from_slice(&bytes[..N]);
    a
}

fn u32_at(bytes: &[u8]) -> u32 {
    u32::from_le_bytes(array(bytes))
}

fn u64_at(bytes: &[u8]) -> u64 {
    u64::from_le_bytes(array(bytes))
}

fn f32_at(bytes: &[u8]) -> f32 {
    f32::from_le_bytes(array(bytes))
}

fn f64_at(bytes: &[u8]) -> f64 {
    f64::from_le_bytes(array(bytes))
}

fn point_at(bytes: &[u8]) -> [f32; 3] {
    [
        f32_at(&bytes[0..4]),
        f32_at(&bytes[4..8]),
        f32_at(&bytes[8..12]),
    ]
}

/// A pose from x y z qx qy qz qw, kept bit for bit ([`check`] then refuses a rotation that is
/// not unit).
fn pose_at(bytes: &[u8]) -> Isometry3<f64> {
    let v: [f64; 7] = std::array::from_fn(|i| f64_at(&bytes[i * 8..]));
    Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::new_unchecked(Quaternion::new(v[6], v[3], v[4], v[5])),
    )
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_u64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f64(out: &mut Vec<u8>, v: f64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_pose(out: &mut Vec<u8>, pose: &Isometry3<f64>) {
    let t = &pose.translation.vector;
    let q = &pose.rotation.coords; // x y z w
    for v in t.iter().chain(q.iter()) {
        put_f64(out, *v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_map::{assert_same, site_map};
    use glint_testkit::SeededRng;

    /// Recomputes the trailer's CRC, so a test can reach the checks behind it.
    fn reseal(bytes: &mut [u8]) {
        let n = bytes.len();
        let crc = crc32fast::hash(&bytes[..n - 4]);
        bytes[n - 4..].copy_from_slice(&crc.to_le_bytes());
    }

    fn message(result: Result<SiteMap, MapError>) -> String {
        result.map(|_| ()).unwrap_err().to_string()
    }

    #[test]
    fn a_map_survives_the_round_trip_bit_for_bit() {
        let map = site_map(1, 24, 200);
        assert!(map.keyframes.iter().any(|k| k.keyframe.cloud.is_empty()));
        let bytes = encode(&map);
        let decoded = decode(&bytes).unwrap();
        assert_same(&map, &decoded);
        assert_eq!(encode(&decoded), bytes);
        assert_eq!(&bytes[..8], MAGIC);
        assert_eq!(u64_at(&bytes[field::LENGTH]), bytes.len() as u64);
    }

    #[test]
    fn an_empty_map_survives_the_round_trip() {
        let mut map = site_map(2, 0, 0);
        map.sensor_model.clear();
        let bytes = encode(&map);
        assert_eq!(bytes.len(), HEADER_LENGTH + TRAILER_LENGTH);
        let decoded = decode(&bytes).unwrap();
        assert_same(&map, &decoded);
        assert!(decoded.extent().is_none());
    }

    #[test]
    fn a_map_of_released_keyframes_survives_the_round_trip() {
        let mut map = site_map(3, 9, 40);
        for k in &mut map.keyframes {
            k.keyframe.edges.clear();
            k.keyframe.planes.clear();
            k.keyframe.cloud.clear();
        }
        map.sensor_model = "VLP-16 «puck»".into();
        let decoded = decode(&encode(&map)).unwrap();
        assert_same(&map, &decoded);
        assert_eq!(decoded.point_count(), 0);
        assert_eq!(decoded.extent(), map.extent());
    }

    #[test]
    fn a_changed_byte_is_refused_as_corrupted() {
        let mut bytes = encode(&site_map(4, 12, 100));
        let middle = bytes.len() / 2;
        bytes[middle] ^= 0x10;
        let error = decode(&bytes).map(|_| ()).unwrap_err();
        assert!(matches!(error, MapError::Corrupted { .. }), "{error}");
        assert!(error
            .to_string()
            .starts_with("corrupted: checksum mismatch"));
    }

    #[test]
    fn a_cut_file_is_refused_as_truncated() {
        let bytes = encode(&site_map(5, 12, 100));
        let cut = bytes.len() * 2 / 3;
        let error = decode(&bytes[..cut]).map(|_| ()).unwrap_err();
        let (expected, found) = (bytes.len() as u64, cut as u64);
        assert!(
            matches!(error, MapError::Truncated { expected: e, found: f } if e == expected && f == found),
            "{error}"
        );
        assert_eq!(
            error.to_string(),
            format!("truncated: {expected} bytes expected, {found} found")
        );
        // Shorter than the header: it cannot say its length, the header's is expected.
        assert!(matches!(
            decode(&bytes[..40]),
            Err(MapError::Truncated {
                expected: 168,
                found: 40
            })
        ));
        // An empty file is what a writer that is not crash-safe leaves.
        assert!(matches!(
            decode(&[]),
            Err(MapError::Truncated { found: 0, .. })
        ));
    }

    #[test]
    fn another_file_is_refused_as_foreign() {
        let mut bytes = encode(&site_map(6, 3, 10));
        bytes[0] = b'X';
        assert!(matches!(decode(&bytes), Err(MapError::Foreign)));
        assert!(matches!(decode(b"# ply\n"), Err(MapError::Foreign)));
        assert_eq!(
            message(decode(b"PK\x03\x04")),
            "not a glintmap (the file does not start with GLINTMAP)"
        );
    }

    #[test]
    fn a_newer_version_is_refused_by_name() {
        let mut bytes = encode(&site_map(7, 3, 10));
        bytes[field::VERSION].copy_from_slice(&2u32.to_le_bytes());
        assert_eq!(
            message(decode(&bytes)),
            "written by a newer glint: format version 2, this build reads up to 1"
        );
        // Whatever follows: a newer layout may be shorter than this one's header.
        assert!(matches!(
            decode(&bytes[..12]),
            Err(MapError::NewerVersion(2))
        ));
        bytes[field::VERSION].copy_from_slice(&0u32.to_le_bytes());
        assert!(matches!(decode(&bytes), Err(MapError::Malformed(_))));
    }

    #[test]
    fn bytes_after_the_end_are_refused() {
        let mut bytes = encode(&site_map(8, 3, 10));
        bytes.extend_from_slice(b"more");
        assert_eq!(
            message(decode(&bytes)),
            format!(
                "malformed: 4 bytes follow the declared end at byte {}",
                bytes.len() - 4
            )
        );
    }

    /// Malformed content behind a valid checksum: what a buggy writer or a hostile file holds.
    #[test]
    fn intact_but_invalid_content_is_refused_as_malformed() {
        let map = site_map(9, 6, 40);
        let good = encode(&map);
        let malformed_after = |edit: &dyn Fn(&mut Vec<u8>)| {
            let mut bytes = good.clone();
            edit(&mut bytes);
            reseal(&mut bytes);
            match decode(&bytes) {
                Err(MapError::Malformed(m)) => m,
                other => panic!("{:?}", other.map(|_| ())),
            }
        };
        let start = HEADER_LENGTH + map.sensor_model.len();
        // The first keyframe's pose x.
        let m = malformed_after(&|b| b[start..start + 8].copy_from_slice(&f64::NAN.to_le_bytes()));
        assert!(m.contains("keyframe 0: a pose is not a finite"), "{m}");
        // A rotation that is no rotation.
        let m =
            malformed_after(&|b| b[start + 48..start + 56].copy_from_slice(&3.0f64.to_le_bytes()));
        assert!(m.contains("keyframe 0"), "{m}");
        // The last edge's `to`, past the last keyframe.
        let last_edge = good.len() - TRAILER_LENGTH - EDGE;
        let m = malformed_after(&|b| {
            b[last_edge + 4..last_edge + 8].copy_from_slice(&99u32.to_le_bytes())
        });
        assert!(
            m.contains("joins node 99, but the graph has 6 nodes"),
            "{m}"
        );
        // The sensor model's bytes.
        let m = malformed_after(&|b| b[HEADER_LENGTH] = 0xff);
        assert_eq!(m, "the sensor model is not UTF-8");
        // Counts that do not add up.
        let m = malformed_after(&|b| b[field::POINTS].copy_from_slice(&7u64.to_le_bytes()));
        assert!(
            m.contains("the header counts 7 points, the keyframes hold"),
            "{m}"
        );
        let m = malformed_after(&|b| b[field::KEYFRAMES].copy_from_slice(&7u64.to_le_bytes()));
        assert!(m.contains("the header counts 7 keyframes"), "{m}");
        // One edge more, and one fewer, than there are (six).
        let m = malformed_after(&|b| b[field::EDGES].copy_from_slice(&7u64.to_le_bytes()));
        assert!(m.starts_with("the graph edges run past the end"), "{m}");
        let m = malformed_after(&|b| b[field::EDGES].copy_from_slice(&5u64.to_le_bytes()));
        assert_eq!(m, format!("{EDGE} bytes follow the last section"));
        // Counts no file could hold are refused before anything is allocated for them.
        for f in [field::KEYFRAMES, field::CELLS, field::EDGES] {
            let m = malformed_after(&|b| b[f.clone()].copy_from_slice(&u64::MAX.to_le_bytes()));
            assert!(m.contains("follow the header"), "{m}");
        }
        let m = malformed_after(&|b| b[field::SECTORS].copy_from_slice(&u32::MAX.to_le_bytes()));
        assert!(m.contains("follow the header"), "{m}");
        let m =
            malformed_after(&|b| b[field::MODEL_LENGTH].copy_from_slice(&u32::MAX.to_le_bytes()));
        assert!(m.contains("the sensor model run past the end"), "{m}");
        // The extent must be the keyframes'.
        let m = malformed_after(&|b| b[field::EXTENT.start] ^= 1);
        assert_eq!(m, "the header's extent is not the keyframes'");
        let m = malformed_after(&|b| b[field::FLAGS].copy_from_slice(&6u32.to_le_bytes()));
        assert_eq!(m, "unknown flags 0x6");
    }

    #[test]
    fn check_refuses_what_decode_would() {
        let good = site_map(10, 6, 40);
        assert!(check(&good).is_ok());
        let refused = |edit: &dyn Fn(&mut SiteMap)| {
            let mut map = good.clone();
            edit(&mut map);
            check(&map).unwrap_err().to_string()
        };
        let m = refused(&|m| m.keyframes[2].keyframe.odom_pose.translation.x = f64::INFINITY);
        assert!(m.contains("keyframe 2: a pose"), "{m}");
        let m = refused(&|m| m.keyframes[1].keyframe.planes.push([0.0, f32::NAN, 0.0]));
        assert!(m.contains("keyframe 1: a point is not finite"), "{m}");
        let m = refused(&|m| {
            let k = &m.keyframes[4].descriptor;
            let cells = k.cells()[..k.cells().len() / 2].to_vec();
            m.keyframes[4].descriptor =
                ScanContext::from_cells(k.sectors() / 2, k.rings(), cells).unwrap();
        });
        assert!(
            m.contains("keyframe 4: descriptor of 30×20, the first keyframe's is 60×20"),
            "{m}"
        );
        let m = refused(&|m| m.edges[0].information[(0, 1)] += 1.0);
        assert!(
            m.contains("edge 0: the information is not symmetric"),
            "{m}"
        );
        let m = refused(&|m| m.edges[0].from = 6);
        assert!(m.contains("graph: edge 0 joins node 6"), "{m}");
    }

    /// Every prefix and many altered copies of a file: refused, never a panic.
    #[test]
    fn damaged_files_are_refused_without_panicking() {
        let bytes = encode(&site_map(11, 5, 24));
        for cut in 0..bytes.len() {
            assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let mut rng = SeededRng::new(12);
        for round in 0..3000 {
            let mut damaged = bytes.clone();
            for _ in 0..1 + round % 4 {
                let at = rng.below(damaged.len());
                damaged[at] ^= 1 + rng.below(255) as u8;
            }
            assert!(decode(&damaged).is_err(), "round {round}");
            // Behind a valid checksum the parser itself meets the damage: it may accept a
            // changed value (a point moved), but must not panic.
            reseal(&mut damaged);
            let _ = decode(&damaged);
        }
        // Damage concentrated in the header, where the counts are.
        for round in 0..3000 {
            let mut damaged = bytes.clone();
            let at = rng.below(HEADER_LENGTH);
            damaged[at] = (rng.next_u64() >> 56) as u8;
            reseal(&mut damaged);
            let _ = decode(&damaged);
            let _ = round;
        }
    }
}

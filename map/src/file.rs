//! The `.glintmap` on disk: [`save`] replaces a map so that a crash at any point leaves the
//! old file or the new one, never a mix; [`load`] and [`info`] read one back whole. Every
//! error names the file.
//!
//! A save writes a temporary file beside the target (`.NAME.tmp-PID-N`, hidden, in the same
//! directory so the rename stays on one file system), syncs it, renames it over the target and
//! syncs the directory so the rename itself survives a power cut. A process killed mid-save
//! leaves its temporary behind; nothing reads those, and they can be deleted.

use std::ffi::OsString;
use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use glint_core::config::IntensityMapConfig;
use glint_core::site_map::SiteMap;
use nalgebra::Isometry3;

use crate::format::{check, decode, encode, field};
use crate::MapError;

/// How much a map holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapCounts {
    /// Keyframes (graph nodes).
    pub keyframes: usize,
    /// Keyframes that released their points: a place in the graph, no points.
    pub released: usize,
    /// Keyframe points: edges, planes and cloud together.
    pub points: usize,
    /// Observed intensity cells.
    pub intensity_cells: usize,
    /// Pose graph edges.
    pub edges: usize,
}

impl MapCounts {
    /// The counts of `map`.
    pub fn of(map: &SiteMap) -> Self {
        Self {
            keyframes: map.keyframes.len(),
            released: map
                .keyframes
                .iter()
                .filter(|k| {
                    let kf = &k.keyframe;
                    kf.edges.is_empty() && kf.planes.is_empty() && kf.cloud.is_empty()
                })
                .count(),
            points: map.point_count(),
            intensity_cells: map.intensity.len(),
            edges: map.edges.len(),
        }
    }
}

/// What [`save`] wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SaveReport {
    /// The file.
    pub path: PathBuf,
    /// Its size, bytes.
    pub bytes: u64,
    /// What it holds.
    pub counts: MapCounts,
}

/// A map file's description, for `glintd map info`.
#[derive(Debug, Clone, PartialEq)]
pub struct MapInfo {
    /// The file.
    pub path: PathBuf,
    /// Its size, bytes.
    pub file_bytes: u64,
    /// Its format version.
    pub format_version: u32,
    /// When the map was made, ns since the Unix epoch.
    pub created_ns: u64,
    /// The sensor that made it.
    pub sensor_model: String,
    /// The mapping robot's mounting, sensor → base_link.
    pub base_from_sensor: Isometry3<f64>,
    /// Bounds of the keyframes and their points in the map frame, m; `None` if empty.
    pub extent: Option<([f32; 3], [f32; 3])>,
    /// What it holds.
    pub counts: MapCounts,
    /// The intensity map's configuration.
    pub intensity: IntensityMapConfig,
    /// The keyframe descriptors' sectors and rings ((0, 0) without keyframes).
    pub descriptor_shape: (usize, usize),
}

/// Writes `map` to `path`, replacing any file there only once the new one is complete and on
/// disk (see the module docs). A map [`check`] refuses is not written. On error the previous
/// file is as it was and the temporary file is removed.
pub fn save(path: impl AsRef<Path>, map: &SiteMap) -> Result<SaveReport, MapError> {
    let path = path.as_ref();
    check(map).map_err(|e| in_file(path, e))?;
    let bytes = encode(map);
    let Some(name) = path.file_name() else {
        return Err(io("write", path, std::io::ErrorKind::InvalidInput.into()));
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // Unique within the process too, so two threads saving one path do not share a temporary.
    static SAVES: AtomicU64 = AtomicU64::new(0);
    let mut temporary = OsString::from(".");
    temporary.push(name);
    temporary.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        SAVES.fetch_add(1, Ordering::Relaxed)
    ));
    let temporary = dir.join(temporary);
    if let Err(e) = write_synced(&temporary, &bytes) {
        // Best effort: the error worth reporting is the write's.
        let _ = fs::remove_file(&temporary);
        return Err(e);
    }
    if let Err(e) = fs::rename(&temporary, path) {
        let _ = fs::remove_file(&temporary);
        return Err(io("replace", path, e));
    }
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| io("sync the directory", dir, e))?;
    Ok(SaveReport {
        path: path.to_path_buf(),
        bytes: bytes.len() as u64,
        counts: MapCounts::of(map),
    })
}

/// Creates `path` holding `bytes` and waits until they are on the disk.
fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), MapError> {
    let mut file = File::create(path).map_err(|e| io("create", path, e))?;
    file.write_all(bytes).map_err(|e| io("write", path, e))?;
    file.sync_all().map_err(|e| io("sync", path, e))
}

/// The map saved at `path`. It reads the whole file, checks its CRC and decodes it: linear in
/// the file's size. On one core of the development machine a 70 MB map (1000 keyframes of
/// 4 500 points, ~260 000 intensity cells) loads in about 0.15 s from the page cache; reading
/// from a cold disk adds the disk's time for the bytes.
pub fn load(path: impl AsRef<Path>) -> Result<SiteMap, MapError> {
    let path = path.as_ref();
    let bytes = fs::read(path).map_err(|e| io("read", path, e))?;
    decode(&bytes).map_err(|e| in_file(path, e))
}

/// The description of the map at `path`, after verifying it as [`load`] does (so at the
/// same cost).
pub fn info(path: impl AsRef<Path>) -> Result<MapInfo, MapError> {
    let path = path.as_ref();
    let bytes = fs::read(path).map_err(|e| io("read", path, e))?;
    let map = decode(&bytes).map_err(|e| in_file(path, e))?;
    Ok(MapInfo {
        path: path.to_path_buf(),
        file_bytes: bytes.len() as u64,
        format_version: u32::from_le_bytes(array(&bytes[field::VERSION])),
        created_ns: map.created_ns,
        extent: map.extent(),
        counts: MapCounts::of(&map),
        intensity: map.intensity.config(),
        descriptor_shape: map
            .keyframes
            .first()
            .map_or((0, 0), |k| (k.descriptor.sectors(), k.descriptor.rings())),
        base_from_sensor: map.base_from_sensor,
        sensor_model: map.sensor_model,
    })
}

fn array(bytes: &[u8]) -> [u8; 4] {
    let mut a = [0; 4];
    a.copy_from_slice(bytes);
    a
}

fn io(op: &'static str, path: &Path, source: std::io::Error) -> MapError {
    MapError::Io {
        op,
        path: path.to_path_buf(),
        source,
    }
}

fn in_file(path: &Path, error: MapError) -> MapError {
    MapError::File {
        path: path.to_path_buf(),
        error: Box::new(error),
    }
}

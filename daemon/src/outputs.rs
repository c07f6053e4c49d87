//! Files the daemon writes: trajectories (TUM, KITTI) and maps (PCD, PLY), formatted by core
//! where the format is the algorithm's business, written here.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use glint_core::trajectory::{format_kitti_line, format_tum_line, StampedPose};
use glint_core::world_map::MapPoint;

/// A trajectory file written pose by pose as the run goes.
pub struct TrajectoryWriter {
    path: PathBuf,
    out: BufWriter<File>,
    kitti: bool,
}

impl TrajectoryWriter {
    /// Creates a TUM (`kitti == false`) or KITTI trajectory file.
    pub fn create(path: &Path, kitti: bool) -> Result<Self> {
        let file =
            File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            out: BufWriter::new(file),
            kitti,
        })
    }

    /// Appends one pose.
    pub fn write(&mut self, pose: &StampedPose) -> Result<()> {
        let line = if self.kitti {
            format_kitti_line(&pose.pose)
        } else {
            format_tum_line(pose)
        };
        writeln!(self.out, "{line}")
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    /// Flushes to disk.
    pub fn finish(mut self) -> Result<()> {
        self.out
            .flush()
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

/// Writes a map: binary PCD (x y z intensity, readable by PCL, Open3D and CloudCompare), or
/// binary PLY when the name ends in `.ply`.
pub fn write_map(path: &Path, points: &[MapPoint]) -> Result<()> {
    let file = File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut out = BufWriter::new(file);
    let ply = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"));
    let n = points.len();
    if ply {
        write!(
            out,
            "ply\nformat binary_little_endian 1.0\ncomment glintd map: map frame, metres; intensity is calibrated reflectivity\n\
             element vertex {n}\nproperty float x\nproperty float y\nproperty float z\nproperty float intensity\nend_header\n"
        )?;
    } else {
        write!(
            out,
            "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\n\
             COUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
        )?;
    }
    for p in points {
        for v in [p.position[0], p.position[1], p.position[2], p.intensity] {
            out.write_all(&v.to_le_bytes())?;
        }
    }
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

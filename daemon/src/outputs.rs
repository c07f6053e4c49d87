//! Files the daemon writes: trajectories (TUM, KITTI) and maps (PCD, PLY), formatted by core
//! where the format is the algorithm's business, written here.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use glint_core::trajectory::{format_kitti_line, format_tum_line, StampedPose};
use glint_core::world_map::MapPoint;

/// A trajectory file written pose by pose as the run goes. With a size limit it rotates: the
/// full file becomes `<name>.1` (replacing the previous one) and a new one starts, so a run of
/// months keeps at most twice the limit on disk. It also rotates when a stamp goes back (the
/// host clock was stepped back under the daemon), so that every file's stamps increase.
pub struct TrajectoryWriter {
    path: PathBuf,
    out: BufWriter<File>,
    kitti: bool,
    max_bytes: Option<u64>,
    written: u64,
    last_ns: Option<u64>,
}

impl TrajectoryWriter {
    /// Creates a TUM (`kitti == false`) or KITTI trajectory file.
    pub fn create(path: &Path, kitti: bool, max_bytes: Option<u64>) -> Result<Self> {
        Ok(Self {
            path: path.to_path_buf(),
            out: BufWriter::new(create(path)?),
            kitti,
            max_bytes,
            written: 0,
            last_ns: None,
        })
    }

    /// Appends one pose.
    pub fn write(&mut self, pose: &StampedPose) -> Result<()> {
        let line = if self.kitti {
            format_kitti_line(&pose.pose)
        } else {
            format_tum_line(pose)
        };
        let full = self
            .max_bytes
            .is_some_and(|max| self.written + line.len() as u64 + 1 > max);
        let back = self.last_ns.is_some_and(|last| pose.time_ns < last);
        if full || back {
            self.rotate()?;
        }
        self.last_ns = Some(pose.time_ns);
        writeln!(self.out, "{line}")
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        self.written += line.len() as u64 + 1;
        Ok(())
    }

    fn rotate(&mut self) -> Result<()> {
        self.flush()?;
        let mut old = self.path.clone().into_os_string();
        old.push(".1");
        std::fs::rename(&self.path, &old)
            .with_context(|| format!("cannot rotate {}", self.path.display()))?;
        self.out = BufWriter::new(create(&self.path)?);
        self.written = 0;
        Ok(())
    }

    /// Pushes what is buffered to the file.
    pub fn flush(&mut self) -> Result<()> {
        self.out
            .flush()
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    /// Flushes to disk.
    pub fn finish(mut self) -> Result<()> {
        self.flush()?;
        self.out
            .get_ref()
            .sync_data()
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

fn create(path: &Path) -> Result<File> {
    File::create(path).with_context(|| format!("cannot create {}", path.display()))
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Isometry3;

    #[test]
    fn a_trajectory_rotates_at_its_size_limit() {
        let dir = std::env::temp_dir().join(format!("glint-rotate-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.tum");
        let mut w = TrajectoryWriter::create(&path, false, Some(4096)).unwrap();
        for i in 0..200u64 {
            w.write(&StampedPose {
                time_ns: 1_000_000_000 * i,
                pose: Isometry3::identity(),
            })
            .unwrap();
        }
        w.finish().unwrap();
        let current = std::fs::metadata(&path).unwrap().len();
        let old = std::fs::metadata(dir.join("t.tum.1")).unwrap().len();
        assert!(
            current <= 4096 && old <= 4096 && old > 3000,
            "{current} {old}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_stamp_that_goes_back_starts_a_new_file() {
        let dir = std::env::temp_dir().join(format!("glint-back-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.tum");
        let mut w = TrajectoryWriter::create(&path, false, None).unwrap();
        // An hour in, the clock is stepped back by an hour.
        let hour = 3_600_000_000_000u64;
        let stamps = (0..5u64)
            .map(|i| hour + i * 100_000_000)
            .chain((5..9).map(|i| i * 100_000_000));
        for time_ns in stamps {
            w.write(&StampedPose {
                time_ns,
                pose: Isometry3::identity(),
            })
            .unwrap();
        }
        w.finish().unwrap();
        let stamps_in = |p: &Path| -> Vec<f64> {
            std::fs::read_to_string(p)
                .unwrap()
                .lines()
                .map(|l| l.split(' ').next().unwrap().parse().unwrap())
                .collect()
        };
        let before = stamps_in(&dir.join("t.tum.1"));
        let after = stamps_in(&path);
        assert_eq!((before.len(), after.len()), (5, 4));
        for file in [&before, &after] {
            assert!(file.windows(2).all(|w| w[0] < w[1]), "{file:?}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_full_disk_is_an_error() {
        let Ok(mut w) = TrajectoryWriter::create(Path::new("/dev/full"), false, None) else {
            return; // no /dev/full here
        };
        let pose = StampedPose {
            time_ns: 1,
            pose: Isometry3::identity(),
        };
        let mut failed = false;
        for _ in 0..10_000 {
            if w.write(&pose).is_err() {
                failed = true;
                break;
            }
        }
        assert!(failed || w.flush().is_err());
    }
}

//! Laser calibration files in the ROS `velodyne_pointcloud` layout (`VLP16db.yaml`), which
//! override a model's factory laser table.
//!
//! The layout: a top-level `lasers` list of maps with `laser_id` (firing-order index),
//! `vert_correction` (elevation, rad), `rot_correction` (azimuth correction, rad),
//! `vert_offset_correction` (m), `horiz_offset_correction` (m), `dist_correction` (m), and an
//! optional `num_lasers`. Keys Glint does not use (focal distances, `dist_correction_x`, …) are
//! accepted and ignored, as the ROS driver ignores them for the VLP-16.

use std::path::Path;

use thiserror::Error;
use yaml_rust2::{Yaml, YamlLoader};

use crate::model::{Laser, LaserTable, LaserTableError};

/// Why a calibration file could not be used.
#[derive(Debug, Error)]
pub enum CalibrationError {
    /// The file could not be read.
    #[error("cannot read calibration file {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    /// The file is not YAML.
    #[error("calibration file is not valid YAML: {0}")]
    Yaml(String),
    /// A required key is missing or has the wrong type.
    #[error("calibration file: {0}")]
    Layout(String),
    /// The values do not make a laser table.
    #[error("calibration file: {0}")]
    Table(#[from] LaserTableError),
}

/// Reads a calibration file.
pub fn load_calibration(path: &Path) -> Result<LaserTable, CalibrationError> {
    let text = std::fs::read_to_string(path).map_err(|source| CalibrationError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_calibration(&text)
}

/// Parses calibration text in the ROS layout.
pub fn parse_calibration(text: &str) -> Result<LaserTable, CalibrationError> {
    let docs =
        YamlLoader::load_from_str(text).map_err(|e| CalibrationError::Yaml(e.to_string()))?;
    let doc = docs
        .first()
        .ok_or_else(|| CalibrationError::Layout("empty document".into()))?;
    let lasers = doc["lasers"]
        .as_vec()
        .ok_or_else(|| CalibrationError::Layout("no `lasers` list".into()))?;
    if let Some(n) = doc["num_lasers"].as_i64() {
        if n as usize != lasers.len() {
            return Err(CalibrationError::Layout(format!(
                "num_lasers is {n} but {} lasers are listed",
                lasers.len()
            )));
        }
    }
    let mut table: Vec<Option<Laser>> = vec![None; lasers.len()];
    for (i, entry) in lasers.iter().enumerate() {
        let id = entry["laser_id"]
            .as_i64()
            .ok_or_else(|| CalibrationError::Layout(format!("laser entry {i} has no laser_id")))?;
        let slot = usize::try_from(id)
            .ok()
            .and_then(|id| table.get_mut(id))
            .ok_or_else(|| CalibrationError::Layout(format!("laser_id {id} out of range")))?;
        if slot.is_some() {
            return Err(CalibrationError::Layout(format!(
                "laser_id {id} listed twice"
            )));
        }
        let elevation = number(entry, "vert_correction")?.ok_or_else(|| {
            CalibrationError::Layout(format!("laser {id} has no vert_correction"))
        })?;
        *slot = Some(Laser {
            elevation,
            vertical_offset: number(entry, "vert_offset_correction")?.unwrap_or(0.0),
            azimuth_correction: number(entry, "rot_correction")?.unwrap_or(0.0),
            horizontal_offset: number(entry, "horiz_offset_correction")?.unwrap_or(0.0),
            distance_correction: number(entry, "dist_correction")?.unwrap_or(0.0),
        });
    }
    let lasers: Vec<Laser> = table
        .into_iter()
        .map(|l| l.expect("every id checked"))
        .collect();
    Ok(LaserTable::new(lasers)?)
}

/// A numeric key: YAML integers and reals both count.
fn number(entry: &Yaml, key: &str) -> Result<Option<f64>, CalibrationError> {
    match &entry[key] {
        Yaml::BadValue | Yaml::Null => Ok(None),
        Yaml::Real(_) => Ok(entry[key].as_f64()),
        Yaml::Integer(i) => Ok(Some(*i as f64)),
        other => Err(CalibrationError::Layout(format!(
            "{key} is not a number: {other:?}"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Model;

    fn vlp16_yaml(rot0: f64) -> String {
        let mut s = String::from("lasers:\n");
        for (i, l) in Model::Vlp16.laser_table().lasers().iter().enumerate() {
            let rot = if i == 0 { rot0 } else { 0.0 };
            s += &format!(
                "- {{dist_correction: 0.0, dist_correction_x: 0.0, focal_distance: 0.0, \
                 horiz_offset_correction: 0.0, laser_id: {i}, rot_correction: {rot}, \
                 vert_correction: {}, vert_offset_correction: {}}}\n",
                l.elevation, l.vertical_offset
            );
        }
        s + "num_lasers: 16\ndistance_resolution: 0.002\n"
    }

    #[test]
    fn ros_layout_round_trips_the_factory_table() {
        let t = parse_calibration(&vlp16_yaml(0.0)).unwrap();
        assert_eq!(t, Model::Vlp16.laser_table());
    }

    #[test]
    fn overrides_apply() {
        let t = parse_calibration(&vlp16_yaml(0.01)).unwrap();
        assert_eq!(t.lasers()[0].azimuth_correction, 0.01);
    }

    #[test]
    fn bad_files_are_errors() {
        assert!(parse_calibration("lasers: 3").is_err());
        assert!(parse_calibration("{").is_err());
        let dup = vlp16_yaml(0.0).replace("laser_id: 1,", "laser_id: 0,");
        assert!(parse_calibration(&dup).is_err());
        let bad = vlp16_yaml(0.0).replace("num_lasers: 16", "num_lasers: 32");
        assert!(parse_calibration(&bad).is_err());
        let nan = vlp16_yaml(0.0).replace("rot_correction: 0,", "rot_correction: .nan,");
        assert!(parse_calibration(&nan).is_err());
    }
}

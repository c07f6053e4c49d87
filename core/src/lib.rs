//! Glint's method (`shared/docs/method.md`) as pure functions over plain data: no I/O, no
//! threads, no clocks. Time comes in with the data as u64 ns since the Unix epoch.
//!
//! Conventions, stated once for the algorithm: poses are `nalgebra::Isometry3<f64>` mapping
//! points of the moving frame (sensor) into the fixed frame (world/map); units SI; frames
//! REP-103; quaternions Hamilton (`nalgebra::UnitQuaternion`), written `qx qy qz qw` in files.

pub mod backend;
pub mod metrics;
pub mod odometry;
pub mod tracker;
pub mod trajectory;

pub mod calibration;
pub mod config;
pub mod extension;
pub mod features;
pub mod front_end;
pub mod intensity_map;
pub mod local_map;
pub mod localiser;
pub mod scan;
pub mod se3;
pub mod site_map;
pub mod solver;
pub mod world_map;

#[cfg(test)]
mod test_scenes;

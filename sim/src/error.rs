//! Why a run could not be carried out: an invalid configuration, a layout that failed to build,
//! an output that could not be written, a destination that could not be reached.

use std::io;
use std::path::PathBuf;

use thiserror::Error;

use crate::config::ConfigError;
use crate::scenarios::LayoutError;

/// The error of [`crate::simulate_to_dir`], [`crate::run`] and [`crate::Simulation::new`].
/// Messages name what failed; the cause is the error's `source()`, so a printed chain shows
/// each cause once.
#[derive(Debug, Error)]
pub enum SimError {
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The scenario's layout for this seed could not be built (a bug: please report the seed).
    #[error("the {scenario} layout for seed {seed} could not be built")]
    Layout {
        /// The scenario's name.
        scenario: String,
        /// The seed.
        seed: u64,
        /// What went wrong (boxed: a layout error carries the offending shape).
        source: Box<LayoutError>,
    },
    /// The kidnap cannot happen as asked: no sweep ends in the run after the requested time, or
    /// no place on the route is far enough from where the robot is then.
    #[error("cannot kidnap the robot {time_s} s after the start: {reason}")]
    Kidnap {
        /// The requested time, s after the start.
        time_s: f64,
        /// Why not.
        reason: String,
    },
    /// A run needs somewhere to go: an output directory or a UDP destination.
    #[error("nothing to do: give an output directory or a UDP destination")]
    NoOutput,
    /// An output file or directory could not be created or written.
    #[error("cannot {action} {path}")]
    Io {
        /// What was being done ("create directory", "write").
        action: &'static str,
        /// The path.
        path: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// The UDP destination could not be resolved or the socket could not be opened.
    #[error("cannot stream to {target}")]
    Udp {
        /// The destination as given.
        target: String,
        /// The cause.
        source: io::Error,
    },
}

//! The saved site map on disk: the `.glintmap` file a mapping run writes and every later boot
//! loads to localise in. This crate owns the file and nothing else — its byte layout
//! ([`format`], pure) and saving it crash-safely and loading it back ([`file`]); the map itself
//! is `glint_core::site_map::SiteMap`, plain data. `docs/map-format.md` states the layout.
//!
//! | module | owns |
//! | --- | --- |
//! | [`format`] | [`encode`], [`decode`], [`check`]: bytes ↔ [`SiteMap`], and what a valid map is |
//! | [`file`] | [`save`] (temporary file, sync, rename), [`install`] (received bytes, verified first), [`load`], [`info`] |

pub mod file;
pub mod format;

#[cfg(test)]
mod test_map;

use std::path::PathBuf;

pub use file::{info, install, load, save, MapCounts, MapInfo, SaveReport};
pub use format::{check, decode, encode, FORMAT_VERSION, MAGIC};
pub use glint_core::site_map::{SiteKeyframe, SiteMap};

/// Why a map could not be read, written or accepted. Each message is one line naming what is
/// wrong; errors of a file on disk say which file.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// The bytes do not start with [`MAGIC`]: some other file.
    #[error("not a glintmap (the file does not start with GLINTMAP)")]
    Foreign,
    /// Written in a format version this build does not know.
    #[error(
        "written by a newer glint: format version {0}, this build reads up to {FORMAT_VERSION}"
    )]
    NewerVersion(u32),
    /// Shorter than its header says: cut off, e.g. by a copy that did not finish.
    #[error("truncated: {expected} bytes expected, {found} found")]
    Truncated {
        /// Bytes the file declares (or the fixed header's length, if it is shorter than that).
        expected: u64,
        /// Bytes there are.
        found: u64,
    },
    /// The checksum does not match the content: bytes changed on disk or in transit.
    #[error("corrupted: checksum mismatch (stored {stored:08x}, computed {computed:08x})")]
    Corrupted {
        /// The CRC-32 the file ends with.
        stored: u32,
        /// The CRC-32 of the bytes before it.
        computed: u32,
    },
    /// Intact bytes that do not make a valid map (counts that do not add up, non-finite poses,
    /// edges to missing keyframes…); also what [`check`] finds wrong with a map before it
    /// is written.
    #[error("malformed: {0}")]
    Malformed(String),
    /// A file operation failed. (The system's error is in the message, so it is not also
    /// given as the source: an error chain prints it once.)
    #[error("cannot {op} {}: {error}", path.display())]
    Io {
        /// What was being done: "read", "write", "replace"…
        op: &'static str,
        /// The file (or directory) it was done to.
        path: PathBuf,
        /// The system's error.
        error: std::io::Error,
    },
    /// One of the errors above, met in a file.
    #[error("{}: {error}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        error: Box<MapError>,
    },
}

impl MapError {
    /// The error itself, behind the file it was met in: what to match on.
    pub fn content(&self) -> &MapError {
        match self {
            MapError::File { error, .. } => error.content(),
            other => other,
        }
    }
}

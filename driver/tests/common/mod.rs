//! Helpers shared by the driver's integration tests: finding `shared/data`.

use std::path::PathBuf;

/// The path of a file in `../shared/data`, or `None` (with a message) when the folder is absent.
/// Under `CI=true` its absence is a failure.
pub fn shared_data(name: &str) -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    let path = dir.join(name);
    if path.exists() {
        return Some(path);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "{} is missing: CI must run with shared/ beside the repository",
            path.display()
        );
    }
    eprintln!(
        "skipping: {} not found (shared/data is not beside the repository)",
        path.display()
    );
    None
}

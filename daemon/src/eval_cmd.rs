//! `glintd eval`: how far an estimated trajectory is from the ground truth, from two TUM files:
//! KITTI-style relative error (drift) and the ATE after alignment. Reads the files; the
//! association and the metrics are `glint_core::metrics`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use glint_core::metrics::{self, WAREHOUSE_LENGTHS};
use glint_core::trajectory::{parse_tum, Trajectory};

/// Arguments of `glintd eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// The estimated trajectory, TUM format (`t x y z qx qy qz qw`, t in seconds).
    pub estimate: PathBuf,
    /// The ground truth, TUM format, dense enough to interpolate at the estimate's times.
    pub groundtruth: PathBuf,
    /// Segment lengths in metres for the relative error [default: 5,10,20,30,40,50].
    #[arg(long, value_delimiter = ',')]
    pub lengths: Option<Vec<f64>>,
}

/// Runs the command.
pub fn run(args: EvalArgs) -> Result<()> {
    let lengths = args.lengths.unwrap_or_else(|| WAREHOUSE_LENGTHS.to_vec());
    if let Some(bad) = lengths.iter().find(|l| !(l.is_finite() && **l > 0.0)) {
        bail!("--lengths: {bad} is not a positive length in metres");
    }
    let estimate = read_tum(&args.estimate)?;
    let groundtruth = read_tum(&args.groundtruth)?;
    let pairs = metrics::associate(&estimate, &groundtruth);
    if pairs.len() < 2 {
        bail!(
            "only {} of the {} poses of {} fall inside the time span of {} ({} poses); at least 2 are needed",
            pairs.len(),
            estimate.len(),
            args.estimate.display(),
            args.groundtruth.display(),
            groundtruth.len()
        );
    }
    let path = metrics::path_length(&pairs);
    say!(
        "associated poses: {} of {} estimated ({} ground-truth poses), {path:.2} m of ground-truth path",
        pairs.len(),
        estimate.len(),
        groundtruth.len()
    );
    match metrics::relative_errors(&pairs, &lengths) {
        Some(rpe) => {
            say!("relative error: {rpe}");
            for length in &lengths {
                match rpe.per_length.iter().find(|(l, _)| l == length) {
                    Some((_, err)) => say!("  {length:>6} m: {err}"),
                    None => say!("  {length:>6} m: no segment fits"),
                }
            }
        }
        None => say!("relative error: no segment fits in {path:.2} m of path"),
    }
    if let Some(ate) = metrics::ate_rmse(&pairs) {
        say!(
            "ATE: RMSE {:.4} m, mean {:.4} m, median {:.4} m, max {:.4} m over {} poses",
            ate.rmse,
            ate.mean,
            ate.median,
            ate.max,
            ate.poses
        );
    }
    if let Some(r) = metrics::return_to_start(&pairs, metrics::RETURN_MIN_TRAVEL_M) {
        say!(
            "return to start: {:.4} m error at pose {}, where the truth comes back within {:.3} m of its start",
            r.error,
            r.index,
            r.distance_from_start
        );
    }
    if let Some(e) = metrics::end_point_error(&pairs) {
        say!("end-point error in the start's frame: {e:.4} m");
    }
    Ok(())
}

fn read_tum(path: &Path) -> Result<Trajectory> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    // The parse error starts with "line N: ", so the chain reads "FILE: line N: …".
    parse_tum(&text).with_context(|| path.display().to_string())
}

//! `glintd eval`: how far an estimated trajectory is from the ground truth, from two TUM files:
//! KITTI-style relative error (drift) and the ATE after alignment; or, with `--no-align`, the
//! errors of a run localising in a saved map, in the map's frame anchored to the ground truth
//! through the mapping run (`--anchor MAPRUN.tum MAPRUN_GT.tum`), skipping kidnap jumps listed
//! in a `kidnaps.txt` beside a ground truth. Reads the files; the association and the metrics
//! are `glint_core::metrics`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use glint_core::metrics::{self, Jump, WAREHOUSE_LENGTHS, WRONG_POSITION_M, WRONG_YAW_DEG};
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
    /// Score the estimate in a fixed frame without aligning it: position and heading errors
    /// against the ground truth at each pose's time (never across a jump in kidnaps.txt beside
    /// the ground truth). The frame is the scene's, or the map's with --anchor.
    #[arg(long)]
    pub no_align: bool,
    /// The mapping run's estimate and ground truth: the map frame is anchored to the scene
    /// through the estimate's first pose (scene←map = GT_map(t0)·EST_map(t0)⁻¹).
    #[arg(
        long,
        num_args = 2,
        value_names = ["MAPRUN_TUM", "MAPRUN_GT_TUM"],
        requires = "no_align"
    )]
    pub anchor: Option<Vec<PathBuf>>,
}

/// The file beside a ground truth that lists its kidnap jumps.
const KIDNAPS_FILE: &str = "kidnaps.txt";

/// Runs the command.
pub fn run(args: EvalArgs) -> Result<()> {
    if args.no_align {
        return run_fixed_frame(&args);
    }
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

/// `--no-align`: errors in the map's frame (or the scene's), no alignment.
fn run_fixed_frame(args: &EvalArgs) -> Result<()> {
    let estimate = read_tum(&args.estimate)?;
    let groundtruth = read_tum(&args.groundtruth)?;
    let jumps = read_jumps(&args.groundtruth)?;
    let mut fitted = None;
    let scene_from_map = match args.anchor.as_deref() {
        Some([map_estimate, map_groundtruth]) => {
            let map_est = read_tum(map_estimate)?;
            let map_gt = read_tum(map_groundtruth)?;
            let map_jumps = read_jumps(map_groundtruth)?;
            let Some(anchor) = metrics::anchor_map_frame(&map_est, &map_gt, &map_jumps) else {
                bail!(
                    "cannot anchor the map frame: {} has no first pose inside the ground truth of {} (outside its time span or inside a jump)",
                    map_estimate.display(),
                    map_groundtruth.display()
                );
            };
            let t0 = map_est[0].time_ns;
            let yaw = metrics::yaw_difference(&anchor.rotation, &Default::default());
            let t = anchor.translation.vector;
            say!(
                "map frame: anchored at {}.{:09} s, the first pose of {}; scene←map moves by ({:.4}, {:.4}, {:.4}) m and turns by {:.3}° in yaw",
                t0 / 1_000_000_000,
                t0 % 1_000_000_000,
                map_estimate.display(),
                t.x,
                t.y,
                t.z,
                yaw.to_degrees()
            );
            fitted = metrics::fit_map_frame(&map_est, &map_gt, &map_jumps);
            anchor
        }
        Some(_) => {
            bail!("--anchor takes two files: the mapping run's estimate and its ground truth")
        }
        None => {
            say!("map frame: the scene's (no --anchor)");
            Default::default()
        }
    };
    if !jumps.is_empty() {
        say!(
            "kidnap jumps: {} in {} beside {}",
            jumps.len(),
            KIDNAPS_FILE,
            args.groundtruth.display()
        );
    }
    let Some(r) = metrics::fixed_frame_errors(&estimate, &groundtruth, &scene_from_map, &jumps)
    else {
        bail!(
            "none of the {} poses of {} has ground truth in {} ({} poses) outside the jumps",
            estimate.len(),
            args.estimate.display(),
            args.groundtruth.display(),
            groundtruth.len()
        );
    };
    say!(
        "compared poses: {} of {} estimated ({} skipped inside kidnap jumps)",
        r.poses,
        estimate.len(),
        r.in_jumps
    );
    say!("position RMSE: {:.4} m", r.position_rmse);
    say!("heading RMSE: {:.3} °", r.yaw_rmse_deg);
    say!(
        "horizontal RMSE: {:.4} m, vertical RMSE: {:.4} m",
        r.horizontal_rmse,
        r.vertical_rmse
    );
    say!("max position error: {:.4} m", r.max_position);
    say!(
        "wrong poses: {} of {} (error > {WRONG_POSITION_M} m or > {WRONG_YAW_DEG}°)",
        r.wrong_poses,
        r.poses
    );
    if let Some(fit) = fitted {
        // Diagnostic only: what the errors are when one pose's own error is not carried into
        // the frame (the figures above are the ones that count).
        let (tilt, yaw) = metrics::frame_difference_deg(&scene_from_map, &fit);
        if let Some(f) = metrics::fixed_frame_errors(&estimate, &groundtruth, &fit, &jumps) {
            say!(
                "with the map frame fitted to the whole mapping run (the anchor is {tilt:.3}° of tilt and {yaw:.3}° of heading off it): position RMSE {:.4} m (horizontal {:.4}, vertical {:.4}), heading RMSE {:.3} °",
                f.position_rmse,
                f.horizontal_rmse,
                f.vertical_rmse,
                f.yaw_rmse_deg
            );
        }
    }
    Ok(())
}

/// The jumps listed in `kidnaps.txt` beside a ground-truth file (none without the file).
fn read_jumps(groundtruth: &Path) -> Result<Vec<Jump>> {
    let path = groundtruth
        .parent()
        .unwrap_or_else(|| Path::new(""))
        .join(KIDNAPS_FILE);
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    parse_jumps(&text).with_context(|| path.display().to_string())
}

/// `kidnaps.txt`: one jump per line, `before after` in seconds (up to 9 decimals); blank lines
/// and `#` comments are skipped.
fn parse_jumps(text: &str) -> Result<Vec<Jump>> {
    let mut jumps = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split_whitespace().collect();
        let parsed = match fields[..] {
            [a, b] => seconds_to_ns(a).zip(seconds_to_ns(b)),
            _ => None,
        };
        let Some((before_ns, after_ns)) = parsed.filter(|(a, b)| a < b) else {
            bail!(
                "line {}: expected `before after`, two times in seconds with before < after",
                i + 1
            );
        };
        jumps.push(Jump {
            before_ns,
            after_ns,
        });
    }
    Ok(jumps)
}

/// Seconds written as `digits[.digits]` to ns, exactly (an f64 would round at ~100 ns).
fn seconds_to_ns(text: &str) -> Option<u64> {
    let (whole, frac) = text.split_once('.').unwrap_or((text, ""));
    let digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if whole.is_empty() || frac.len() > 9 || !digits(whole) || !digits(frac) {
        return None;
    }
    let frac_ns: u64 = format!("{frac:0<9}").parse().ok()?;
    whole
        .parse::<u64>()
        .ok()?
        .checked_mul(1_000_000_000)?
        .checked_add(frac_ns)
}

fn read_tum(path: &Path) -> Result<Trajectory> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    // The parse error starts with "line N: ", so the chain reads "FILE: line N: …".
    parse_tum(&text).with_context(|| path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser, Debug)]
    struct Cli {
        #[command(flatten)]
        eval: EvalArgs,
    }

    fn parse(args: &[&str]) -> Result<EvalArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("eval").chain(args.iter().copied())).map(|c| c.eval)
    }

    #[test]
    fn anchor_takes_the_mapping_runs_two_files_and_needs_no_align() {
        let a = parse(&[
            "--no-align",
            "--anchor",
            "m.tum",
            "mgt.tum",
            "e.tum",
            "g.tum",
        ])
        .unwrap();
        assert!(a.no_align);
        assert_eq!(
            a.anchor.unwrap(),
            [PathBuf::from("m.tum"), PathBuf::from("mgt.tum")]
        );
        assert_eq!(
            (a.estimate, a.groundtruth),
            (PathBuf::from("e.tum"), PathBuf::from("g.tum"))
        );
        assert!(parse(&["--anchor", "m.tum", "mgt.tum", "e.tum", "g.tum"]).is_err());
        let plain = parse(&["e.tum", "g.tum"]).unwrap();
        assert!(!plain.no_align && plain.anchor.is_none());
    }

    #[test]
    fn kidnap_files_parse_exactly_and_refuse_nonsense() {
        let jumps =
            parse_jumps("1632206185.746189752 1632206185.846164920\n\n# note\n7 8.5\n").unwrap();
        assert_eq!(
            jumps,
            [
                Jump {
                    before_ns: 1_632_206_185_746_189_752,
                    after_ns: 1_632_206_185_846_164_920
                },
                Jump {
                    before_ns: 7_000_000_000,
                    after_ns: 8_500_000_000
                }
            ]
        );
        for bad in ["1 2 3", "2 1", "1.5", "a b", "-1 2", "1.0000000001 2"] {
            assert!(parse_jumps(bad).is_err(), "{bad}");
        }
    }
}

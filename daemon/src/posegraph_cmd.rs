//! `glintd posegraph`: optimises a g2o pose graph (`VERTEX_SE3:QUAT`, `EDGE_SE3:QUAT`, `FIX`)
//! with the back end's own optimiser and writes the result, printing the cost before and after,
//! the iterations and the time. Reading, writing and the optimiser are `glint_core::backend`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use glint_core::backend::g2o;
use glint_core::backend::pose_graph::PoseGraphConfig;

/// Arguments of `glintd posegraph`.
#[derive(Args, Debug)]
pub struct PoseGraphArgs {
    /// The graph to optimise, g2o format.
    pub input: PathBuf,
    /// Where to write the optimised graph (same vertices and edges, new vertex poses).
    #[arg(long)]
    pub out: PathBuf,
    /// Put a Cauchy kernel on edges between non-consecutive vertex ids (loop closures), as the
    /// SLAM back end does; off, the cost is g2o's plain χ².
    #[arg(long)]
    pub robust_loops: bool,
    /// Levenberg–Marquardt iterations at most.
    #[arg(long, default_value_t = PoseGraphConfig::default().max_iterations)]
    pub max_iterations: usize,
}

/// Runs the command.
pub fn run(args: PoseGraphArgs) -> Result<()> {
    let text = std::fs::read_to_string(&args.input)
        .with_context(|| format!("reading {}", args.input.display()))?;
    let mut file =
        g2o::parse(&text).with_context(|| format!("parsing {}", args.input.display()))?;
    if !args.robust_loops {
        for e in &mut file.graph.edges {
            e.robust = false;
        }
    }
    let config = PoseGraphConfig {
        max_iterations: args.max_iterations,
        ..PoseGraphConfig::default()
    };
    say!(
        "{}: {} vertices, {} edges ({} between non-consecutive ids)",
        args.input.display(),
        file.graph.poses.len(),
        file.graph.edges.len(),
        file.graph
            .edges
            .iter()
            .filter(|e| e.from.abs_diff(e.to) != 1)
            .count()
    );
    let start = Instant::now();
    let report = file
        .graph
        .optimize(&config)
        .with_context(|| format!("optimising {}", args.input.display()))?;
    let elapsed = start.elapsed();
    say!(
        "initial χ² {:.6e}, final χ² {:.6e}{}",
        report.initial_chi2,
        report.final_chi2,
        if args.robust_loops {
            format!(
                " (robust cost {:.6e} → {:.6e})",
                report.initial_cost, report.final_cost
            )
        } else {
            String::new()
        }
    );
    say!(
        "iterations: {} ({} accepted); {} blocks in the factor; {:.3} s",
        report.iterations,
        report.accepted,
        report.factor_blocks,
        elapsed.as_secs_f64()
    );
    std::fs::write(&args.out, g2o::write(&file))
        .with_context(|| format!("writing {}", args.out.display()))?;
    say!("wrote {}", args.out.display());
    Ok(())
}

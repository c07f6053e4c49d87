//! The pose graph on a public benchmark: `parking-garage.g2o` (1,661 poses, 6,275 edges, a
//! multi-storey garage; Carlone et al., ICRA 2015), read from `../shared/data/` beside the
//! workspace through `glint_testkit::shared_data` (skipped when absent, required under CI).

use glint_core::backend::g2o;
use glint_core::backend::pose_graph::PoseGraphConfig;

#[test]
fn parking_garage_converges_to_the_known_optimum() {
    let Some(path) = glint_testkit::shared_data("parking-garage pose graph", "parking-garage.g2o")
    else {
        return;
    };
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut file = g2o::parse(&text).expect("the benchmark parses");
    assert_eq!(file.graph.poses.len(), 1661);
    assert_eq!(file.graph.edges.len(), 6275);
    // The benchmark is a plain least-squares problem: no kernel, as g2o's own figures.
    for e in &mut file.graph.edges {
        e.robust = false;
    }
    let report = file
        .graph
        .optimize(&PoseGraphConfig::default())
        .expect("valid graph");
    eprintln!("parking garage: {report:?}");
    // Converged, χ² is 1.2387 (16,720 at the start; optimising the result again leaves it
    // there). 1.5 leaves room for another order of floating-point sums; a stalled solver or a
    // worse local minimum is far above it.
    assert!(report.initial_chi2 > 1e4 * report.final_chi2, "{report:?}");
    assert!(report.final_chi2 < 1.5, "{report:?}");
}

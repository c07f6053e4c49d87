//! The three scenarios — warehouse, corridor, yard — built from a seed, and their printable
//! descriptions. The seed moves things (sizes, positions, patterns, occupancy); it never changes
//! what kind of place a scenario is.

mod corridor;
mod warehouse;
mod yard;

use std::fmt::Write as _;

use rand_chacha::ChaCha8Rng;
use thiserror::Error;

use crate::config::{seeded_rng, Scenario, Stream};
use crate::scene::{Scene, SceneBuilder, SceneError};
use crate::trajectory::{Trajectory, TrajectoryError, Vibration};

/// A scenario's scene, motion and description.
#[derive(Debug, Clone)]
pub struct Built {
    /// The place.
    pub scene: Scene,
    /// The robot's motion.
    pub trajectory: Trajectory,
    /// A printable description of the layout.
    pub description: String,
}

/// A layout that could not be built: a bug in a builder for this seed, never a user error.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum LayoutError {
    /// A primitive or material was invalid.
    #[error("invalid scene element: {0}")]
    Scene(#[from] SceneError),
    /// The loop could not be driven within the motion limits.
    #[error("invalid trajectory: {0}")]
    Trajectory(#[from] TrajectoryError),
}

/// Builds a scenario for a seed.
pub fn build(scenario: Scenario, seed: u64) -> Result<Built, LayoutError> {
    let mut ctx = Ctx::new(seed);
    let (trajectory, lines) = match scenario {
        Scenario::Warehouse => warehouse::build(&mut ctx)?,
        Scenario::Corridor => corridor::build(&mut ctx)?,
        Scenario::Yard => yard::build(&mut ctx)?,
    };
    let scene = ctx.builder.build();
    let description = describe_built(scenario, seed, &scene, &trajectory, &lines);
    Ok(Built {
        scene,
        trajectory,
        description,
    })
}

/// The printable description of a scenario's layout for a seed.
pub fn describe(scenario: Scenario, seed: u64) -> Result<String, LayoutError> {
    Ok(build(scenario, seed)?.description)
}

/// What builders share: the scene under construction, the layout's random stream, and a
/// vibration stream kept apart so that layout draws do not shift it.
pub(crate) struct Ctx {
    pub builder: SceneBuilder,
    pub rng: ChaCha8Rng,
    pub vibration: Vibration,
}

impl Ctx {
    fn new(seed: u64) -> Ctx {
        let mut vib_rng = seeded_rng(seed, Stream::Vibration);
        // Pitch and roll each at most 0.3°, heave at most 3 mm.
        let vibration = Vibration::random(&mut vib_rng, 0.3f64.to_radians(), 0.003);
        Ctx {
            builder: SceneBuilder::new(),
            rng: seeded_rng(seed, Stream::Layout),
            vibration,
        }
    }
}

fn describe_built(
    scenario: Scenario,
    seed: u64,
    scene: &Scene,
    trajectory: &Trajectory,
    lines: &[String],
) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "{scenario} (seed {seed})");
    for l in lines {
        let _ = writeln!(out, "  {l}");
    }
    if let Some(f) = trajectory.figures() {
        let _ = writeln!(
            out,
            "  loop: {:.1} m per lap, {:.1} s per lap (two laps {:.1} s); speed {:.2}–{:.2} m/s, |accel| ≤ {:.2} m/s², |yaw rate| ≤ {:.2} rad/s, tightest radius {:.2} m; {} waypoints",
            f.lap_length_m,
            f.lap_seconds,
            2.0 * f.lap_seconds,
            f.min_speed,
            f.max_speed,
            f.max_accel,
            f.max_yaw_rate,
            f.min_radius,
            trajectory.waypoints().len()
        );
    }
    let m = trajectory.mount();
    let _ = writeln!(
        out,
        "  sensor: {:.2} m above the floor, {:.2} m ahead of the base centre; pitch/roll vibration ≤ {:.2}°",
        m.z,
        m.x,
        trajectory.vibration().pitch.iter().map(|s| s.amplitude).sum::<f64>().max(trajectory.vibration().roll.iter().map(|s| s.amplitude).sum::<f64>()).to_degrees()
    );
    let b = scene.bounds();
    let _ = writeln!(
        out,
        "  extent: x {:.1}…{:.1} m, y {:.1}…{:.1} m, z {:.1}…{:.1} m",
        b.min[0], b.max[0], b.min[1], b.max[1], b.min[2], b.max[2]
    );
    let mut shapes: Vec<(&str, usize)> = Vec::new();
    for p in scene.primitives() {
        match shapes.iter_mut().find(|(k, _)| *k == p.shape.kind()) {
            Some(e) => e.1 += 1,
            None => shapes.push((p.shape.kind(), 1)),
        }
    }
    let shapes: Vec<String> = shapes.iter().map(|(k, n)| format!("{n} {k}")).collect();
    let decals: usize = scene.materials().iter().map(|m| m.decals.len()).sum();
    let _ = writeln!(
        out,
        "  primitives: {} ({}); {} moving; {} materials with {} decals; BVH {} nodes",
        scene.primitives().len(),
        shapes.join(", "),
        scene.movers().len(),
        scene.materials().len(),
        decals,
        scene.bvh_nodes()
    );
    let tags: Vec<String> = scene
        .tag_counts()
        .iter()
        .map(|(t, n)| format!("{t} {n}"))
        .collect();
    let _ = writeln!(out, "  objects by kind: {}", tags.join(", "));
    out
}

/// Common reflectivities (at 905 nm), so scenarios agree on what things look like.
pub(crate) mod rho {
    pub const CONCRETE: f64 = 0.30;
    pub const WHITE_PAINT: f64 = 0.85;
    pub const YELLOW_PAINT: f64 = 0.65;
    pub const BLACK: f64 = 0.05;
    pub const GLASS: f64 = 0.03;
    pub const CARDBOARD: f64 = 0.45;
    pub const WOOD: f64 = 0.35;
    pub const STEEL: f64 = 0.40;
    pub const ASPHALT: f64 = 0.12;
}

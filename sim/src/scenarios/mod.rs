//! The three scenarios — warehouse, corridor, yard — built from a seed, and their printable
//! descriptions. The seed moves things (sizes, positions, patterns, occupancy); it never changes
//! what kind of place a scenario is.
//!
//! Each scenario also offers other closed routes through the same layout. A run of one scene
//! may take another of them (chosen by a path seed from a stream of its own, so the layout is
//! the same for every path seed), drive it backwards, start part-way round it, find some goods
//! moved, or meet more or fewer movers; the scene frame stays the same, so the ground truth of
//! all runs of a scene can be compared directly.

mod corridor;
mod warehouse;
mod yard;

use std::fmt::Write as _;

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

use crate::bvh::Aabb;
use crate::changes::{change_goods, ChangedObject};
use crate::config::{seeded_rng, Scenario, SimConfig, Stream};
use crate::geometry::bounds;
use crate::scene::{Scene, SceneBuilder, SceneError};
use crate::trajectory::{MotionLimits, Mount, Trajectory, TrajectoryError, Vibration};

/// A scenario's scene, motion and description.
#[derive(Debug, Clone)]
pub struct Built {
    /// The place.
    pub scene: Scene,
    /// The robot's motion.
    pub trajectory: Trajectory,
    /// A printable description of the layout.
    pub description: String,
    /// The movable objects removed or shifted (empty unless changes were asked for).
    pub changes: Vec<ChangedObject>,
}

/// Closest an alternative route may pass to anything in the robot's height band, m (from the
/// base's centre line; the scenarios' own routes keep more than this).
pub const ROUTE_CLEARANCE_M: f64 = 0.7;
/// Spacing of the points that stand for a lane when goods are moved, m.
const LANE_STEP_M: f64 = 0.2;

/// A closed route through a layout: its waypoints and the description's line about it.
#[derive(Debug, Clone)]
pub(crate) struct Route {
    pub waypoints: Vec<[f64; 2]>,
    pub text: String,
}

/// What a scenario builder returns besides the scene: its own route, the other routes through
/// the same layout, the robot, and the description's lines.
pub(crate) struct Plan {
    pub route: Route,
    pub alternatives: Vec<Route>,
    pub limits: MotionLimits,
    pub mount: Mount,
    pub lines: Vec<String>,
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
    /// No alternative route of the layout is drivable and clear.
    #[error("none of the {0} other routes through this layout is clear of obstacles")]
    NoRoute(usize),
}

/// Builds a scenario for a seed, with its own route and contents.
pub fn build(scenario: Scenario, seed: u64) -> Result<Built, LayoutError> {
    build_run(&SimConfig {
        scenario,
        seed,
        ..SimConfig::default()
    })
}

/// Builds the scene and motion of a run: the scenario and seed's layout, with the route,
/// direction, start, changed goods and movers the config asks for. The kidnap, which depends
/// on the sensor's timing, is the simulation's.
pub fn build_run(config: &SimConfig) -> Result<Built, LayoutError> {
    let (scenario, seed) = (config.scenario, config.seed);
    let mut ctx = Ctx::new(seed);
    let plan = match scenario {
        Scenario::Warehouse => warehouse::build(&mut ctx)?,
        Scenario::Corridor => corridor::build(&mut ctx)?,
        Scenario::Yard => yard::build(&mut ctx)?,
    };
    let Plan {
        route,
        alternatives,
        limits,
        mount,
        mut lines,
    } = plan;
    let lanes: Vec<[f64; 2]> = std::iter::once(&route)
        .chain(&alternatives)
        .flat_map(|r| densify(&r.waypoints, LANE_STEP_M))
        .collect();
    let (route, mut trajectory) = match config.path_seed {
        None => {
            let t =
                Trajectory::closed_loop(&route.waypoints, limits, mount, ctx.vibration.clone())?;
            (route, t)
        }
        Some(path_seed) => choose_route(&ctx, alternatives, limits, mount, path_seed)?,
    };
    lines.push(route.text);
    if let Some(m) = config.path_seed {
        lines.push(format!(
            "route: chosen by path seed {m} among the layout's other routes"
        ));
    }
    if config.reverse {
        trajectory = trajectory.reversed()?;
        lines.push("direction: the route is driven in reverse".to_string());
    }
    if config.start_fraction != 0.0 {
        trajectory = trajectory.starting_at(config.start_fraction);
        lines.push(format!(
            "start: {:.3} of the lap along the route",
            config.start_fraction
        ));
    }
    let mut changes = Vec::new();
    if config.change > 0.0 {
        let total = ctx.builder.movable_objects().len();
        let mut rng = seeded_rng(config.change_seed, Stream::Change);
        changes = change_goods(&mut ctx.builder, &lanes, config.change, &mut rng);
        let removed = changes.iter().filter(|c| c.shift.is_none()).count();
        lines.push(format!(
            "changed goods (change seed {}): {} of {total} movable objects, {removed} removed, {} shifted by 0.3–1.5 m",
            config.change_seed,
            changes.len(),
            changes.len() - removed
        ));
    }
    if let Some(n) = config.movers {
        let mut rng = seeded_rng(seed, Stream::Movers);
        set_movers(&mut ctx.builder, n, &mut rng);
        lines.push(format!("movers: {n} (asked for)"));
    }
    let scene = ctx.builder.build();
    let description = describe_built(scenario, seed, &scene, &trajectory, &lines);
    Ok(Built {
        scene,
        trajectory,
        description,
        changes,
    })
}

/// The printable description of a scenario's layout for a seed.
pub fn describe(scenario: Scenario, seed: u64) -> Result<String, LayoutError> {
    Ok(build(scenario, seed)?.description)
}

/// Picks a route from `alternatives` in the order a path-seeded shuffle gives: the first that
/// the motion limits allow and that keeps [`ROUTE_CLEARANCE_M`] from everything.
fn choose_route(
    ctx: &Ctx,
    mut alternatives: Vec<Route>,
    limits: MotionLimits,
    mount: Mount,
    path_seed: u64,
) -> Result<(Route, Trajectory), LayoutError> {
    let mut rng = seeded_rng(path_seed, Stream::Path);
    let n = alternatives.len();
    for i in 0..n {
        let j = rng.random_range(i..n);
        alternatives.swap(i, j);
    }
    let obstacles = body_band_boxes(&ctx.builder);
    for route in alternatives {
        let Ok(t) = Trajectory::closed_loop(&route.waypoints, limits, mount, ctx.vibration.clone())
        else {
            continue;
        };
        if clearance(&obstacles, &t.route_points()) >= ROUTE_CLEARANCE_M {
            return Ok((route, t));
        }
    }
    Err(LayoutError::NoRoute(n))
}

/// Boxes of what a robot could run into: primitives reaching into the body's height band and
/// the boxes movers sweep.
fn body_band_boxes(builder: &SceneBuilder) -> Vec<Aabb> {
    let in_band = |b: &Aabb| b.max[2] > 0.02 && b.min[2] < 2.0;
    let mut boxes: Vec<Aabb> = builder
        .primitives()
        .iter()
        .map(|p| bounds(&p.shape))
        .filter(in_band)
        .collect();
    for m in builder.movers() {
        let b = bounds(&m.shape);
        let end = Aabb {
            min: [0, 1, 2].map(|i| b.min[i] + m.travel[i]),
            max: [0, 1, 2].map(|i| b.max[i] + m.travel[i]),
        };
        boxes.push(b.union(&end));
    }
    boxes
}

/// The smallest distance in the xy plane from any of `points` (every tenth is enough at the
/// path's 2 cm grid) to any box.
fn clearance(boxes: &[Aabb], points: &[[f64; 2]]) -> f64 {
    let mut best = f64::INFINITY;
    for p in points.iter().step_by(10) {
        for b in boxes {
            let dx = (b.min[0] - p[0]).max(p[0] - b.max[0]).max(0.0);
            let dy = (b.min[1] - p[1]).max(p[1] - b.max[1]).max(0.0);
            best = best.min(dx.hypot(dy));
        }
    }
    best
}

/// Points every `step` m along a closed polyline.
fn densify(waypoints: &[[f64; 2]], step: f64) -> Vec<[f64; 2]> {
    let n = waypoints.len();
    let mut out = Vec::new();
    for i in 0..n {
        let (a, b) = (waypoints[i], waypoints[(i + 1) % n]);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let k = (len / step).ceil().max(1.0) as usize;
        out.extend((0..k).map(|j| {
            let f = j as f64 / k as f64;
            [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]
        }));
    }
    out
}

/// Keeps the first `n` movers or adds copies of them: each copy follows its original's lane at
/// a phase drawn from `rng`, so copies of one mover pass each other (through each other: the
/// simulator has no collisions between movers).
fn set_movers(builder: &mut SceneBuilder, n: usize, rng: &mut ChaCha8Rng) {
    let originals = builder.movers().to_vec();
    if n <= originals.len() || originals.is_empty() {
        builder.keep_movers(n);
        return;
    }
    for k in originals.len()..n {
        let m = originals[k % originals.len()];
        let period = 2.0 * m.travel.iter().map(|x| x * x).sum::<f64>().sqrt() / m.speed;
        let phase = m.phase + rng.random_range(0.2..0.8) * period;
        builder.copy_mover(&m, phase);
    }
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

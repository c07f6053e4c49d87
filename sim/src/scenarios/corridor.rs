//! The corridor: 400 m long, ~3.5 m wide, ~3 m high, built from six plain rectangles (two
//! walls, floor, ceiling, two end walls) and nothing else, so that geometry says nothing about
//! where along the axis the robot is. The only axial cues are painted: doors (frame, leaf, kick
//! plate, number plate) at a regular spacing on each wall, retro-reflective AGV markers every
//! 15 m, ceiling lights and exit signs, a dashed centre line — all repeating, so look-alike places
//! abound — and a few unique ones: posters, a double door, a glass door, floor hazard markings,
//! odd retro strips. The robot drives a 60–80 m stretch in the middle down and back on a
//! racetrack, so the end walls stay more than 100 m away and are never hit. The other routes are
//! racetracks of 40–80 m over other stretches within 15 m of it, where the unique cues are.

use std::f64::consts::PI;
use std::fmt::Write as _;

use rand::Rng;

use super::{rho, Ctx, LayoutError, Plan, Route};
use crate::scene::{Decal, Material, Pattern, Shape};
use crate::trajectory::{rounded_polygon, MotionLimits, Mount};

/// Half the corridor's length, m.
pub const HALF_LENGTH: f64 = 200.0;
/// Half the distance between the robot's two lanes, m (also the U-turn radius).
const LANE: f64 = 0.85;

pub(super) fn build(ctx: &mut Ctx) -> Result<Plan, LayoutError> {
    let width = ctx.rng.random_range(3.3..3.7);
    let height = ctx.rng.random_range(2.9..3.1);
    let hw = 0.5 * width;
    let len = 2.0 * HALF_LENGTH;
    let wall_rho = ctx.rng.random_range(0.5..0.65);
    let floor_rho = ctx.rng.random_range(0.2..0.3);
    let door_left = ctx.rng.random_range(5.5..7.0);
    let door_right = door_left * if ctx.rng.random_bool(0.5) { 1.5 } else { 2.0 };
    let centre = ctx.rng.random_range(-10.0..10.0);
    let stretch = ctx.rng.random_range(60.0..80.0);
    let (xa, xb) = (centre - 0.5 * stretch, centre + 0.5 * stretch);
    // Unique features go where the robot sees them.
    let near = |ctx: &mut Ctx| ctx.rng.random_range(xa - 25.0..xb + 25.0) + HALF_LENGTH;
    let mut notes: Vec<String> = Vec::new();

    // Walls: u = x + 200 along both, v = height.
    let plain = Pattern::uniform(wall_rho);
    let skirting = Decal::new([0.0, 0.0], [len, 0.1], Pattern::uniform(0.15));
    let mut left = Material::new("left wall", plain).with_decal(skirting);
    let mut right = Material::new("right wall", plain).with_decal(skirting);
    let double_door_at = near(ctx);
    let glass_door_at = near(ctx);
    let mut doors = [Vec::new(), Vec::new()];
    for (side, spacing, first) in [
        (0usize, door_left, 2.0),
        (1, door_right, 2.0 + 0.5 * door_left),
    ] {
        let m = if side == 0 { &mut left } else { &mut right };
        let mut u = first;
        while u + 2.0 < len {
            let special = if side == 1 && (u - double_door_at).abs() < 0.5 * spacing {
                "double"
            } else if side == 0 && (u - glass_door_at).abs() < 0.5 * spacing {
                "glass"
            } else {
                ""
            };
            let w = if special == "double" { 1.9 } else { 0.95 };
            m.decals.push(Decal::new(
                [u - 0.08, 0.0],
                [u + w + 0.08, 2.18],
                Pattern::uniform(0.3),
            ));
            let leaf = if special == "glass" { rho::GLASS } else { 0.18 };
            m.decals
                .push(Decal::new([u, 0.0], [u + w, 2.1], Pattern::uniform(leaf)));
            if special.is_empty() {
                m.decals
                    .push(Decal::new([u, 0.0], [u + w, 0.25], Pattern::uniform(0.7)));
            } else {
                notes.push(format!(
                    "{special} door on the {} wall at x = {:.1} m",
                    if side == 0 { "left" } else { "right" },
                    u - HALF_LENGTH
                ));
            }
            m.decals.push(Decal::new(
                [u + w + 0.15, 1.45],
                [u + w + 0.3, 1.6],
                Pattern::uniform(0.9),
            ));
            doors[side].push((u - 0.1, u + w + 0.35));
            u += spacing;
        }
    }
    // AGV reflectors every 15 m on the right wall, low down.
    let mut u = 7.0;
    let mut reflectors = 0;
    while u < len - 1.0 {
        right.decals.push(Decal::new(
            [u, 0.45],
            [u + 0.05, 0.55],
            Pattern::Retro { value: 200 },
        ));
        reflectors += 1;
        u += 15.0;
    }
    // Unique posters, avoiding doors.
    let posters = ctx.rng.random_range(6..=10);
    let mut placed = 0;
    for _ in 0..posters * 10 {
        if placed == posters {
            break;
        }
        let side = ctx.rng.random_range(0..2usize);
        let (w, h) = if ctx.rng.random_bool(0.5) {
            (0.6, 0.85)
        } else {
            (0.9, 0.6)
        };
        let u = near(ctx);
        if doors[side].iter().any(|&(a, b)| u + w > a && u < b) {
            continue;
        }
        let v = ctx.rng.random_range(1.1..1.7);
        let pattern = poster(ctx);
        let m = if side == 0 { &mut left } else { &mut right };
        m.decals.push(Decal::new([u, v], [u + w, v + h], pattern));
        doors[side].push((u, u + w));
        placed += 1;
        notes.push(format!(
            "poster on the {} wall at x = {:.1} m",
            if side == 0 { "left" } else { "right" },
            u - HALF_LENGTH
        ));
    }
    // One or two odd retro strips.
    for _ in 0..ctx.rng.random_range(1..=2) {
        let u = near(ctx);
        let side = ctx.rng.random_range(0..2usize);
        let m = if side == 0 { &mut left } else { &mut right };
        m.decals.push(Decal::new(
            [u, 1.0],
            [u + 0.3, 1.05],
            Pattern::Retro {
                value: ctx.rng.random_range(150..=250),
            },
        ));
        notes.push(format!(
            "retro strip on the {} wall at x = {:.1} m",
            if side == 0 { "left" } else { "right" },
            u - HALF_LENGTH
        ));
    }
    let left = ctx.builder.material(left)?;
    let right = ctx.builder.material(right)?;
    ctx.builder.add(
        Shape::wall([-HALF_LENGTH, hw], [HALF_LENGTH, hw], 0.0, height),
        left,
        "wall",
    )?;
    ctx.builder.add(
        Shape::wall([-HALF_LENGTH, -hw], [HALF_LENGTH, -hw], 0.0, height),
        right,
        "wall",
    )?;
    let end = ctx.builder.material(Material::diffuse("end wall", 0.5))?;
    ctx.builder.add(
        Shape::wall([-HALF_LENGTH, -hw], [-HALF_LENGTH, hw], 0.0, height),
        end,
        "end wall",
    )?;
    ctx.builder.add(
        Shape::wall([HALF_LENGTH, hw], [HALF_LENGTH, -hw], 0.0, height),
        end,
        "end wall",
    )?;

    // Floor: u = x + 200, v = y + hw. Continuous edge lines, a dashed centre line (3 m period),
    // unique hazard markings.
    let mut floor = Material::diffuse("floor", floor_rho);
    for v in [0.15, width - 0.25] {
        floor
            .decals
            .push(Decal::new([0.0, v], [len, v + 0.1], Pattern::uniform(0.6)));
    }
    floor.decals.push(Decal::new(
        [0.0, hw - 0.05],
        [len, hw + 0.05],
        Pattern::stripes_u(0.7, floor_rho, 3.0, 1.0 / 3.0),
    ));
    for _ in 0..ctx.rng.random_range(3..=4) {
        let u = near(ctx);
        let l = ctx.rng.random_range(0.8..2.0);
        let pattern = Pattern::Stripes {
            rho_a: rho::YELLOW_PAINT,
            rho_b: 0.08,
            period: 0.3,
            duty: 0.5,
            angle: ctx.rng.random_range(0.3..PI - 0.3),
        };
        floor
            .decals
            .push(Decal::new([u, 0.4], [u + l, width - 0.4], pattern));
        notes.push(format!(
            "floor hazard marking from x = {:.1} to {:.1} m",
            u - HALF_LENGTH,
            u + l - HALF_LENGTH
        ));
    }
    let floor = ctx.builder.material(floor)?;
    ctx.builder.add(
        Shape::horizontal(-HALF_LENGTH, -hw, HALF_LENGTH, hw, 0.0),
        floor,
        "floor",
    )?;

    // Ceiling: light panels every 3.6 m, exit signs every 20 m.
    let mut ceiling = Material::diffuse("ceiling", ctx.rng.random_range(0.65..0.75));
    let mut u = 1.0;
    while u < len - 1.0 {
        ceiling.decals.push(Decal::new(
            [u, hw - 0.3],
            [u + 1.2, hw + 0.3],
            Pattern::uniform(0.9),
        ));
        u += 3.6;
    }
    let mut u = 10.0;
    while u < len - 1.0 {
        ceiling.decals.push(Decal::new(
            [u, hw + 0.5],
            [u + 0.4, hw + 0.65],
            Pattern::uniform(0.95),
        ));
        u += 20.0;
    }
    let ceiling = ctx.builder.material(ceiling)?;
    ctx.builder.add(
        Shape::horizontal(-HALF_LENGTH, -hw, HALF_LENGTH, hw, height),
        ceiling,
        "ceiling",
    )?;

    let racetrack = |xa: f64, xb: f64| -> Route {
        let corners = [[xa, -LANE], [xb, -LANE], [xb, LANE], [xa, LANE]];
        Route {
            waypoints: rounded_polygon(&corners, LANE, 2.0),
            text: format!(
                "robot: a racetrack between x = {xa:.1} and {xb:.1} m, out on y = −{LANE} m and back on y = +{LANE} m, U-turns of radius {LANE} m; the end walls stay at least {:.0} m away",
                HALF_LENGTH - xa.abs().max(xb.abs()) - LANE
            ),
        }
    };
    let route = racetrack(xa, xb);
    let mut alternatives = Vec::new();
    for shift in [-15.0, -10.0, -5.0, 0.0, 5.0, 10.0, 15.0] {
        for length in [40.0, 60.0, 80.0] {
            let c = centre + shift;
            if shift != 0.0 || (length - stretch).abs() > 5.0 {
                alternatives.push(racetrack(c - 0.5 * length, c + 0.5 * length));
            }
        }
    }
    let limits = MotionLimits {
        cruise_speed: 1.5,
        min_speed: 0.5,
        max_accel: 0.5,
        max_lateral_accel: 0.5,
        max_yaw_rate: 0.8,
    };
    let mount = Mount {
        x: 0.2,
        y: 0.0,
        z: ctx.rng.random_range(0.5..0.9),
    };

    let mut unique = String::new();
    for n in &notes {
        let _ = write!(unique, "\n    - {n}");
    }
    let lines = vec![
        format!(
            "corridor x −{HALF_LENGTH:.0}…{HALF_LENGTH:.0} m, {width:.2} m wide, {height:.2} m high: two plain walls (ρ {wall_rho:.2}), floor (ρ {floor_rho:.2}), ceiling and two end walls; no other geometry"
        ),
        format!(
            "repeating cues: doors every {door_left:.2} m on the left wall and every {door_right:.2} m on the right (dark leaf, frame, kick plate, number plate), {reflectors} retro AGV reflectors every 15 m on the right wall, ceiling lights every 3.6 m, exit signs every 20 m, a dashed centre line (3 m period)"
        ),
        format!("unique cues ({}):{unique}", notes.len()),
    ];
    Ok(Plan {
        route,
        alternatives,
        limits,
        mount,
        lines,
    })
}

fn poster(ctx: &mut Ctx) -> Pattern {
    match ctx.rng.random_range(0..3) {
        0 => Pattern::Stripes {
            rho_a: ctx.rng.random_range(0.75..0.95),
            rho_b: ctx.rng.random_range(0.05..0.25),
            period: ctx.rng.random_range(0.06..0.25),
            duty: ctx.rng.random_range(0.3..0.7),
            angle: ctx.rng.random_range(0.0..PI),
        },
        1 => Pattern::Checker {
            rho_a: ctx.rng.random_range(0.75..0.95),
            rho_b: ctx.rng.random_range(0.05..0.25),
            size: ctx.rng.random_range(0.08..0.3),
        },
        _ => Pattern::uniform(ctx.rng.random_range(0.8..0.95)),
    }
}

//! The warehouse: a ~40 × 60 m hall with a dock zone along its west wall and selective pallet
//! racking in blocks of bays separated by cross aisles. Racks are built part by part (uprights
//! with location labels and some retro-reflective AGV markers, braces, beams with labels,
//! pallets and their loads), so a warehouse has thousands of primitives. Pillars stand at the
//! east ends of the double rows, the floor has slab-to-slab variation, aisle lines, a zebra
//! walkway, stop bars and a unique painted label at each aisle entrance; the walls carry dock
//! doors, signs, posters and retro markers. A pedestrian and a forklift move where the robot does
//! not drive. The robot loops around one double row of the first block; the other routes loop
//! around one or two adjacent double rows of one or two adjacent blocks.
//!
//! Longer than most modules: a warehouse is built part by part (racks, bays, floor paint, walls,
//! routes), and its layout reads best as one description.

use std::f64::consts::{FRAC_PI_4, PI};

use rand::Rng;

use super::{rho, Ctx, LayoutError, Plan, Route};
use crate::scene::{Decal, Material, MaterialId, Pattern, Shape};
use crate::trajectory::{rounded_polygon, MotionLimits, Mount};

const BAY: f64 = 2.7;
const RACK_DEPTH: f64 = 1.1;
const FLUE: f64 = 0.2;
const DOUBLE_DEPTH: f64 = 2.0 * RACK_DEPTH + FLUE;
const DOCK_DEPTH: f64 = 8.0;
const UPRIGHT: [f64; 2] = [0.09, 0.08];
const BEAM_HEIGHT: f64 = 0.12;
const PALLET_HEIGHT: f64 = 0.144;

struct Row {
    y0: f64,
    y1: f64,
    double: bool,
    /// For a single row: its aisle side faces +y.
    faces_up: bool,
}

struct Block {
    x0: f64,
    bays: usize,
}

impl Block {
    fn x1(&self) -> f64 {
        self.x0 + self.bays as f64 * BAY
    }
}

struct Palette {
    upright: MaterialId,
    upright_label: MaterialId,
    upright_retro: MaterialId,
    brace: MaterialId,
    beam: MaterialId,
    pallet: MaterialId,
    loads: Vec<MaterialId>,
}

pub(super) fn build(ctx: &mut Ctx) -> Result<Plan, LayoutError> {
    let lx = ctx.rng.random_range(56.0..62.0);
    let ly = ctx.rng.random_range(38.0..42.0);
    let height = ctx.rng.random_range(9.0..11.0);
    let aisle = ctx.rng.random_range(3.0..3.4);
    let cross = ctx.rng.random_range(3.6..4.2);
    let n_levels = ctx.rng.random_range(3..=4usize);
    let first_beam = ctx.rng.random_range(1.6..1.8);
    let spacing = ctx.rng.random_range(1.5..1.7);
    let levels: Vec<f64> = (0..n_levels)
        .map(|k| first_beam + k as f64 * spacing)
        .collect();
    let rack_height = levels[n_levels - 1] + 1.0;
    let occupancy = ctx.rng.random_range(0.6..0.85);

    // Rows across y: a single row on the south wall, double rows, maybe a single row north.
    let mut rows = vec![Row {
        y0: 0.4,
        y1: 0.4 + RACK_DEPTH,
        double: false,
        faces_up: true,
    }];
    let mut y = 0.4 + RACK_DEPTH + aisle;
    while y + DOUBLE_DEPTH + aisle + RACK_DEPTH + 0.4 <= ly {
        rows.push(Row {
            y0: y,
            y1: y + DOUBLE_DEPTH,
            double: true,
            faces_up: false,
        });
        y += DOUBLE_DEPTH + aisle;
    }
    if y + RACK_DEPTH <= ly - 0.4 {
        rows.push(Row {
            y0: y,
            y1: y + RACK_DEPTH,
            double: false,
            faces_up: false,
        });
    }
    // Blocks along x: the first (the robot's) has 4–5 bays, the others 4–6, each followed by
    // a cross aisle.
    let mut blocks = Vec::new();
    let mut x = DOCK_DEPTH + cross;
    loop {
        let max_bays = if blocks.is_empty() { 5 } else { 6 };
        let bays = ctx.rng.random_range(4..=max_bays);
        let fits = (4..=bays).rev().find(|&b| x + b as f64 * BAY + cross <= lx);
        let Some(bays) = fits else { break };
        blocks.push(Block { x0: x, bays });
        x += bays as f64 * BAY + cross;
    }

    let palette = palette(ctx)?;
    let mut uprights_with_retro = 0;
    for block in &blocks {
        for row in &rows {
            let racks: Vec<(f64, f64)> = if row.double {
                vec![(row.y0, row.y0 + RACK_DEPTH), (row.y1, row.y1 - RACK_DEPTH)]
            } else if row.faces_up {
                vec![(row.y1, row.y0)]
            } else {
                vec![(row.y0, row.y1)]
            };
            for (front, back) in racks {
                uprights_with_retro += rack(
                    ctx,
                    &palette,
                    block,
                    front,
                    back,
                    &levels,
                    rack_height,
                    occupancy,
                )?;
            }
        }
    }

    // Pillars at the east end of every double row of every block.
    let concrete = Material::diffuse("pillar", 0.4).with_decal(Decal::new(
        [0.0, 0.0],
        [0.5, 1.2],
        Pattern::Stripes {
            rho_a: rho::YELLOW_PAINT,
            rho_b: rho::BLACK,
            period: 0.2,
            duty: 0.5,
            angle: FRAC_PI_4,
        },
    ));
    let pillar = ctx.builder.material(concrete.clone())?;
    let band = Pattern::Retro { value: 220 };
    let pillar_retro =
        ctx.builder
            .material(concrete.with_decal(Decal::new([0.0, 1.4], [0.5, 1.5], band)))?;
    let (mut pillars, mut banded_pillars) = (0, 0);
    for block in &blocks {
        for row in rows.iter().filter(|r| r.double) {
            let banded = ctx.rng.random_bool(0.5);
            banded_pillars += usize::from(banded);
            let m = if banded { pillar_retro } else { pillar };
            let c = [block.x1() + 0.5, 0.5 * (row.y0 + row.y1)];
            ctx.builder.add(
                Shape::standing_box(c, 0.0, 0.0, [0.5, 0.5, height]),
                m,
                "pillar",
            )?;
            pillars += 1;
        }
    }

    let (doors, wall_markers) = shell(ctx, lx, ly, height)?;
    floor(ctx, lx, ly, &rows, &blocks)?;
    let banded_bollards = dock_zone(ctx, ly, &doors)?;

    // Movers: a pedestrian crossing the dock zone, a forklift in the east end aisle.
    let person = ctx.builder.material(Material::diffuse("clothing", 0.35))?;
    let person_phase = ctx.rng.random_range(0.0..30.0);
    ctx.builder.add_mover(
        Shape::Cylinder {
            base: [4.0, 3.0, 0.0],
            height: 1.75,
            radius: 0.25,
        },
        person,
        "pedestrian",
        [0.0, ly - 8.0, 0.0],
        1.2,
        person_phase,
    )?;
    let end_aisle = blocks.last().map_or(lx - cross, |b| b.x1());
    let forklift = ctx.builder.material(Material::diffuse("forklift", 0.5))?;
    let forklift_phase = ctx.rng.random_range(0.0..30.0);
    ctx.builder.add_mover(
        Shape::standing_box([0.5 * (end_aisle + lx), 3.0], 0.0, 0.0, [1.2, 2.4, 2.1]),
        forklift,
        "forklift",
        [0.0, ly - 6.0, 0.0],
        1.8,
        forklift_phase,
    )?;

    // The loop: around a double row of the first block, counter-clockwise.
    let doubles: Vec<&Row> = rows.iter().filter(|r| r.double).collect();
    let row = ctx.rng.random_range(0..doubles.len());
    let radius = 0.5 * aisle.min(cross) - 0.15;
    let around = |b0: usize, b1: usize, r0: usize, r1: usize| -> Route {
        let (xw, xe) = (blocks[b0].x0 - 0.5 * cross, blocks[b1].x1() + 0.5 * cross);
        let (ys, yn) = (doubles[r0].y0 - 0.5 * aisle, doubles[r1].y1 + 0.5 * aisle);
        let waypoints = rounded_polygon(&[[xw, ys], [xe, ys], [xe, yn], [xw, yn]], radius, 2.0);
        let text = if (b0, b1, r0, r1) == (0, 0, row, row) {
            format!(
                "robot: loops counter-clockwise around the double row at y {:.1}–{:.1} m in the first block (aisles at y {ys:.2} and {yn:.2} m, cross aisles at x {xw:.2} and {xe:.2} m)",
                doubles[r0].y0, doubles[r0].y1
            )
        } else {
            format!(
                "robot: loops counter-clockwise around {} at y {:.1}–{:.1} m in {} (aisles at y {ys:.2} and {yn:.2} m, cross aisles at x {xw:.2} and {xe:.2} m)",
                if r0 == r1 { "the double row" } else { "two double rows" },
                doubles[r0].y0,
                doubles[r1].y1,
                if b0 == b1 { format!("block {}", b0 + 1) } else { format!("blocks {}–{}", b0 + 1, b1 + 1) }
            )
        };
        Route { waypoints, text }
    };
    let route = around(0, 0, row, row);
    let mut alternatives = Vec::new();
    for b0 in 0..blocks.len() {
        for b1 in b0..blocks.len().min(b0 + 2) {
            for r0 in 0..doubles.len() {
                for r1 in r0..doubles.len().min(r0 + 2) {
                    if (b0, b1, r0, r1) != (0, 0, row, row) {
                        alternatives.push(around(b0, b1, r0, r1));
                    }
                }
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
        z: ctx.rng.random_range(0.6..0.9),
    };

    let bays: Vec<String> = blocks.iter().map(|b| b.bays.to_string()).collect();
    let singles = rows.iter().filter(|r| !r.double).count();
    let levels_txt: Vec<String> = levels.iter().map(|z| format!("{z:.2}")).collect();
    let lines = vec![
        format!("hall {lx:.1} × {ly:.1} m, ceiling {height:.1} m; dock zone x < {DOCK_DEPTH:.0} m with {} dock doors on the west wall, a loading ramp and floor-stacked pallets", doors.len()),
        format!(
            "racks: {} blocks of {} bays ({BAY} m) × {} rows ({} double back-to-back, {} single); aisles {aisle:.2} m, cross aisles {cross:.2} m; beam levels at {} m, uprights {rack_height:.2} m; {:.0} % of pallet positions loaded",
            blocks.len(),
            bays.join("/"),
            rows.len(),
            doubles.len(),
            singles,
            levels_txt.join(", "),
            occupancy * 100.0
        ),
        format!("pillars: {pillars} (0.5 m square, yellow/black striped base, some with a retro band) at the east ends of the double rows"),
        format!(
            "retro-reflective markers (reported above 100): {uprights_with_retro} on rack uprights, {wall_markers} on the walls; retro bands on {banded_pillars} pillars and {banded_bollards} bollards"
        ),
        "floor: concrete slabs (ρ 0.28/0.32), yellow aisle lines, zebra walkway, stop bars at aisle exits, a unique painted label at each aisle entrance, oil stains".to_string(),
        "movers: a pedestrian walking across the dock zone, a forklift driving the east end aisle".to_string(),
    ];
    Ok(Plan {
        route,
        alternatives,
        limits,
        mount,
        lines,
    })
}

fn palette(ctx: &mut Ctx) -> Result<Palette, LayoutError> {
    let blue = 0.35;
    let label = |v0: f64| {
        Decal::new(
            [0.0, v0],
            [UPRIGHT[0], v0 + 0.12],
            Pattern::uniform(rho::WHITE_PAINT),
        )
    };
    let upright = ctx.builder.material(Material::diffuse("upright", blue))?;
    let upright_label = ctx
        .builder
        .material(Material::diffuse("upright with label", blue).with_decal(label(1.25)))?;
    let marker = Pattern::Retro { value: 200 };
    let upright_retro = ctx.builder.material(
        Material::diffuse("upright with label and retro marker", blue)
            .with_decal(label(1.25))
            .with_decal(Decal::new([0.0, 0.55], [UPRIGHT[0], 0.70], marker)),
    )?;
    let brace = ctx.builder.material(Material::diffuse("brace", blue))?;
    let beam_label = |u0: f64| {
        Decal::new(
            [u0, 0.0],
            [u0 + 0.2, BEAM_HEIGHT],
            Pattern::uniform(rho::WHITE_PAINT),
        )
    };
    let beam = ctx.builder.material(
        Material::diffuse("beam", 0.5)
            .with_decal(beam_label(0.35))
            .with_decal(beam_label(1.65)),
    )?;
    let pallet = ctx
        .builder
        .material(Material::diffuse("pallet", rho::WOOD))?;
    let shipping_label = Decal::on_face(2, [0.3, 0.2], [0.45, 0.3], Pattern::uniform(0.9));
    let loads = vec![
        ctx.builder
            .material(Material::diffuse("cartons", rho::CARDBOARD))?,
        ctx.builder
            .material(Material::diffuse("stretch-wrapped", 0.25))?,
        ctx.builder
            .material(Material::diffuse("white sacks", 0.75))?,
        ctx.builder
            .material(Material::diffuse("dark crates", 0.08))?,
        ctx.builder.material(
            Material::diffuse("labelled cartons", 0.5)
                .with_decal(shipping_label)
                .with_decal(Decal {
                    face: Some(3),
                    ..shipping_label
                }),
        )?,
    ];
    Ok(Palette {
        upright,
        upright_label,
        upright_retro,
        brace,
        beam,
        pallet,
        loads,
    })
}

/// One rack (one side of a row) over a block: `front` is the y of its aisle face, `back` of its
/// flue or wall side. Returns how many uprights carry a retro marker.
#[allow(clippy::too_many_arguments)]
fn rack(
    ctx: &mut Ctx,
    p: &Palette,
    block: &Block,
    front: f64,
    back: f64,
    levels: &[f64],
    height: f64,
    occupancy: f64,
) -> Result<usize, LayoutError> {
    let into = (back - front).signum();
    let centre_y = 0.5 * (front + back);
    let mut retro = 0;
    for k in 0..=block.bays {
        let xf = block.x0 + k as f64 * BAY;
        let (label_m, is_retro) = match ctx.rng.random_range(0..10) {
            0 | 1 => (p.upright_retro, true),
            2..=6 => (p.upright_label, false),
            _ => (p.upright, false),
        };
        retro += usize::from(is_retro);
        let front_y = front + into * 0.5 * UPRIGHT[1];
        let back_y = back - into * 0.5 * UPRIGHT[1];
        let size = [UPRIGHT[0], UPRIGHT[1], height];
        ctx.builder.add(
            Shape::standing_box([xf, front_y], 0.0, 0.0, size),
            label_m,
            "rack upright",
        )?;
        ctx.builder.add(
            Shape::standing_box([xf, back_y], 0.0, 0.0, size),
            p.upright,
            "rack upright",
        )?;
        for z in [0.3, 0.5 * height, height - 0.3] {
            let brace = [0.04, RACK_DEPTH - 2.0 * UPRIGHT[1], 0.04];
            ctx.builder.add(
                Shape::standing_box([xf, centre_y], z - 0.02, 0.0, brace),
                p.brace,
                "rack brace",
            )?;
        }
    }
    for k in 0..block.bays {
        let xf = block.x0 + k as f64 * BAY;
        let beam_len = BAY - UPRIGHT[0];
        for &z in levels {
            for y in [front + into * 0.025, back - into * 0.025] {
                let shape = Shape::standing_box(
                    [xf + 0.5 * BAY, y],
                    z - 0.5 * BEAM_HEIGHT,
                    0.0,
                    [beam_len, 0.05, BEAM_HEIGHT],
                );
                ctx.builder.add(shape, p.beam, "rack beam")?;
            }
        }
        // Pallet positions: on the floor and on each level, two per bay.
        let bases: Vec<(f64, f64)> = std::iter::once(0.0)
            .chain(levels.iter().map(|z| z + 0.5 * BEAM_HEIGHT))
            .zip(
                levels
                    .iter()
                    .map(|z| z - 0.5 * BEAM_HEIGHT)
                    .chain(std::iter::once(height + 0.5)),
            )
            .collect();
        for (base, ceiling) in bases {
            for slot in [0.25, 0.75] {
                if !ctx.rng.random_bool(occupancy) {
                    continue;
                }
                let cx = xf + slot * BAY;
                let pallet = [1.0, RACK_DEPTH - 0.1, PALLET_HEIGHT];
                let first = ctx.builder.primitive_count() as u32;
                ctx.builder.add(
                    Shape::standing_box([cx, centre_y], base, 0.0, pallet),
                    p.pallet,
                    "pallet",
                )?;
                let room = (ceiling - base - PALLET_HEIGHT - 0.1).min(1.4);
                if room < 0.3 {
                    ctx.builder.mark_movable(first);
                    continue;
                }
                let size = [
                    ctx.rng.random_range(0.85..0.98),
                    ctx.rng.random_range(0.85..0.98),
                    ctx.rng.random_range(0.3..=room),
                ];
                // A quarter of the loads sit slightly askew on their pallets.
                let yaw = if ctx.rng.random_bool(0.25) {
                    ctx.rng.random_range(-0.03..0.03)
                } else {
                    0.0
                };
                let material = p.loads[ctx.rng.random_range(0..p.loads.len())];
                ctx.builder.add(
                    Shape::standing_box([cx, centre_y], base + PALLET_HEIGHT, yaw, size),
                    material,
                    "load",
                )?;
                ctx.builder.mark_movable(first);
            }
        }
    }
    Ok(retro)
}

/// Walls (with pilasters, signs, posters, dock doors and retro markers) and the ceiling.
/// Returns the dock doors' centres (y) and the number of retro markers on the walls.
fn shell(ctx: &mut Ctx, lx: f64, ly: f64, height: f64) -> Result<(Vec<f64>, usize), LayoutError> {
    let mut markers = 0;
    let doors: Vec<f64> = (0..)
        .map(|k| 4.0 + k as f64 * 4.5)
        .take_while(|y| y + 2.0 < ly - 5.0)
        .collect();
    // Walls run counter-clockwise (face 1 looks inside); u runs along the wall from `a`.
    let walls = [
        ("south wall", [0.0, 0.0], [lx, 0.0]),
        ("east wall", [lx, 0.0], [lx, ly]),
        ("north wall", [lx, ly], [0.0, ly]),
        ("west wall", [0.0, ly], [0.0, 0.0]),
    ];
    for (name, a, b) in walls {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let mut m = Material::new(name, Pattern::stripes_u(0.45, 0.55, 0.25, 0.2)).with_decal(
            Decal::new([0.0, 0.0], [len, 1.0], Pattern::uniform(rho::CONCRETE)),
        );
        let mut taken: Vec<(f64, f64)> = Vec::new();
        if name == "west wall" {
            for &y in &doors {
                let u = ly - y;
                m.decals.push(Decal::new(
                    [u - 1.5, 0.0],
                    [u + 1.5, 3.5],
                    Pattern::stripes_v(0.6, 0.45, 0.12, 0.5),
                ));
                taken.push((u - 2.0, u + 2.0));
            }
        } else {
            // An emergency exit with its sign.
            let u = ctx.rng.random_range(5.0..len - 5.0);
            m.decals.push(Decal::new(
                [u - 0.5, 0.0],
                [u + 0.5, 2.1],
                Pattern::uniform(0.25),
            ));
            m.decals.push(Decal::new(
                [u - 0.2, 2.3],
                [u + 0.2, 2.5],
                Pattern::uniform(0.75),
            ));
            taken.push((u - 1.0, u + 1.0));
        }
        // Fire-point signs every 15 m (a repeating cue), then unique posters and markers.
        let mut u = 7.5;
        while u < len - 1.0 {
            if !taken.iter().any(|&(a, b)| u > a - 0.5 && u < b + 0.5) {
                m.decals.push(Decal::new(
                    [u - 0.15, 1.8],
                    [u + 0.15, 2.1],
                    Pattern::uniform(0.4),
                ));
                m.decals.push(Decal::new(
                    [u - 0.08, 1.85],
                    [u + 0.08, 2.0],
                    Pattern::uniform(rho::WHITE_PAINT),
                ));
            }
            u += 15.0;
        }
        for _ in 0..ctx.rng.random_range(2..=4) {
            let (w, h) = (
                ctx.rng.random_range(0.6..1.5),
                ctx.rng.random_range(0.5..1.2),
            );
            let u = ctx.rng.random_range(1.0..len - 2.5);
            if taken.iter().any(|&(a, b)| u + w > a && u < b) {
                continue;
            }
            let v = ctx.rng.random_range(1.3..2.6);
            m.decals
                .push(Decal::new([u, v], [u + w, v + h], random_pattern(ctx)));
            taken.push((u, u + w));
        }
        for _ in 0..ctx.rng.random_range(3..=5) {
            let u = ctx.rng.random_range(1.0..len - 1.0);
            if taken.iter().any(|&(a, b)| u + 0.1 > a && u < b) {
                continue;
            }
            let value = ctx.rng.random_range(190..=230);
            m.decals.push(Decal::new(
                [u, 0.8],
                [u + 0.1, 1.1],
                Pattern::Retro { value },
            ));
            taken.push((u, u + 0.1));
            markers += 1;
        }
        let id = ctx.builder.material(m)?;
        ctx.builder
            .add(Shape::wall(a, b, 0.0, height), id, "wall")?;
    }
    // Pilasters every ~12 m on the south, east and north walls.
    let pilaster = ctx.builder.material(Material::diffuse("pilaster", 0.4))?;
    let offset = ctx.rng.random_range(3.0..9.0);
    let mut x = offset;
    while x < lx - 1.0 {
        for (y0, y1) in [(0.0, 0.3), (ly - 0.3, ly)] {
            ctx.builder.add(
                Shape::aabox([x - 0.2, y0, 0.0], [x + 0.2, y1, height]),
                pilaster,
                "pilaster",
            )?;
        }
        x += 12.0;
    }
    let mut y = offset;
    while y < ly - 1.0 {
        ctx.builder.add(
            Shape::aabox([lx - 0.3, y - 0.2, 0.0], [lx, y + 0.2, height]),
            pilaster,
            "pilaster",
        )?;
        y += 12.0;
    }
    // The ceiling with rows of lights along x.
    let mut ceiling = Material::diffuse("ceiling", 0.45);
    let mut yl = 3.0;
    while yl < ly - 2.0 {
        ceiling.decals.push(Decal::new(
            [2.0, yl],
            [lx - 2.0, yl + 0.3],
            Pattern::uniform(0.85),
        ));
        yl += 6.0;
    }
    let ceiling = ctx.builder.material(ceiling)?;
    ctx.builder.add(
        Shape::horizontal(0.0, 0.0, lx, ly, height),
        ceiling,
        "ceiling",
    )?;
    Ok((doors, markers))
}

/// A poster- or sign-like pattern.
fn random_pattern(ctx: &mut Ctx) -> Pattern {
    match ctx.rng.random_range(0..3) {
        0 => Pattern::Stripes {
            rho_a: ctx.rng.random_range(0.7..0.95),
            rho_b: ctx.rng.random_range(0.05..0.3),
            period: ctx.rng.random_range(0.08..0.3),
            duty: ctx.rng.random_range(0.3..0.7),
            angle: ctx.rng.random_range(0.0..PI),
        },
        1 => Pattern::Checker {
            rho_a: ctx.rng.random_range(0.7..0.95),
            rho_b: ctx.rng.random_range(0.05..0.3),
            size: ctx.rng.random_range(0.1..0.35),
        },
        _ => Pattern::uniform(ctx.rng.random_range(0.75..0.95)),
    }
}

/// The floor and its markings.
fn floor(
    ctx: &mut Ctx,
    lx: f64,
    ly: f64,
    rows: &[Row],
    blocks: &[Block],
) -> Result<(), LayoutError> {
    let mut m = Material::new(
        "floor",
        Pattern::Checker {
            rho_a: 0.28,
            rho_b: 0.32,
            size: 6.0,
        },
    );
    let yellow = Pattern::uniform(rho::YELLOW_PAINT);
    let white = Pattern::uniform(rho::WHITE_PAINT);
    for b in blocks {
        for r in rows {
            // Aisle lines in front of each rack face that looks onto an aisle.
            let faces: &[f64] = if r.double {
                &[r.y0 - 0.25, r.y1 + 0.15]
            } else if r.faces_up {
                &[r.y1 + 0.15]
            } else {
                &[r.y0 - 0.25]
            };
            for &v in faces {
                m.decals
                    .push(Decal::new([b.x0, v], [b.x1(), v + 0.1], yellow));
            }
        }
        // Per aisle (the gap between consecutive rows): an entrance label and a stop bar.
        for pair in rows.windows(2) {
            let (a0, a1) = (pair[0].y1, pair[1].y0);
            let mid = 0.5 * (a0 + a1);
            m.decals.push(Decal::new(
                [b.x0 - 1.3, mid - 0.5],
                [b.x0 - 0.3, mid + 0.5],
                random_pattern(ctx),
            ));
            m.decals.push(Decal::new(
                [b.x1() + 0.1, a0 + 0.3],
                [b.x1() + 0.4, a1 - 0.3],
                white,
            ));
        }
    }
    // A zebra walkway in the cross aisle beside the dock zone.
    m.decals.push(Decal::new(
        [DOCK_DEPTH + 0.2, 2.0],
        [DOCK_DEPTH + 1.4, ly - 2.0],
        Pattern::Stripes {
            rho_a: rho::WHITE_PAINT,
            rho_b: 0.3,
            period: 0.8,
            duty: 0.5,
            angle: PI / 2.0,
        },
    ));
    // Staging lanes outlined in yellow.
    for (x0, x1) in [(1.6, 3.0), (5.2, 7.2)] {
        let (y0, y1) = (2.5, ly - 4.5);
        m.decals.push(Decal::new([x0 - 0.1, y0], [x0, y1], yellow));
        m.decals.push(Decal::new([x1, y0], [x1 + 0.1, y1], yellow));
        m.decals
            .push(Decal::new([x0 - 0.1, y0 - 0.1], [x1 + 0.1, y0], yellow));
    }
    for _ in 0..ctx.rng.random_range(8..14) {
        let (x, y) = (
            ctx.rng.random_range(1.0..lx - 1.0),
            ctx.rng.random_range(1.0..ly - 1.0),
        );
        let s = ctx.rng.random_range(0.3..0.8);
        m.decals.push(Decal::new(
            [x, y],
            [x + s, y + 0.7 * s],
            Pattern::uniform(0.1),
        ));
    }
    let id = ctx.builder.material(m)?;
    ctx.builder
        .add(Shape::horizontal(0.0, 0.0, lx, ly, 0.0), id, "floor")?;
    Ok(())
}

/// Dock bumpers, bollards, a loading ramp and floor-stacked pallets in the dock zone. Returns
/// how many bollards carry a retro band.
fn dock_zone(ctx: &mut Ctx, ly: f64, doors: &[f64]) -> Result<usize, LayoutError> {
    let rubber = ctx
        .builder
        .material(Material::diffuse("dock bumper", rho::BLACK))?;
    let yellow = ctx
        .builder
        .material(Material::diffuse("bollard", rho::YELLOW_PAINT))?;
    let band = Pattern::Retro { value: 210 };
    let mut banded = 0;
    let circumference = 2.0 * PI * 0.08;
    let yellow_retro =
        ctx.builder.material(
            Material::diffuse("bollard with retro band", rho::YELLOW_PAINT)
                .with_decal(Decal::on_face(0, [0.0, 0.85], [circumference, 0.95], band)),
        )?;
    for &y in doors {
        for side in [-1.0, 1.0] {
            let yb = y + side * 1.7;
            ctx.builder.add(
                Shape::aabox([0.0, yb - 0.125, 1.0], [0.12, yb + 0.125, 1.5]),
                rubber,
                "dock bumper",
            )?;
            let retro = ctx.rng.random_bool(0.5);
            banded += usize::from(retro);
            let m = if retro { yellow_retro } else { yellow };
            ctx.builder.add(
                Shape::Pole {
                    base: [1.0, y + side * 1.9, 0.0],
                    height: 1.1,
                    radius: 0.08,
                },
                m,
                "bollard",
            )?;
        }
    }
    let ramp = ctx
        .builder
        .material(Material::diffuse("ramp", 0.35).with_decal(Decal::on_face(
            0,
            [0.0, 0.0],
            [6.0, 0.15],
            Pattern::uniform(rho::YELLOW_PAINT),
        )))?;
    ctx.builder.add(
        Shape::Ramp {
            base: [6.8, ly - 2.6, 0.0],
            yaw: PI,
            length: 5.0,
            width: 2.4,
            height: 1.0,
        },
        ramp,
        "loading ramp",
    )?;
    let pallet = ctx
        .builder
        .material(Material::diffuse("pallet", rho::WOOD))?;
    let goods = [
        ctx.builder
            .material(Material::diffuse("cartons", rho::CARDBOARD))?,
        ctx.builder
            .material(Material::diffuse("stretch-wrapped", 0.25))?,
        ctx.builder.material(Material::diffuse("drums", 0.55))?,
    ];
    for x in [2.3, 6.2] {
        let mut y = 3.2;
        while y < ly - 5.5 {
            if ctx.rng.random_bool(0.55) {
                let stack = ctx.rng.random_range(1..=2);
                let first = ctx.builder.primitive_count() as u32;
                let mut z = 0.0;
                for _ in 0..stack {
                    ctx.builder.add(
                        Shape::standing_box([x, y], z, 0.0, [1.2, 1.0, PALLET_HEIGHT]),
                        pallet,
                        "pallet",
                    )?;
                    z += PALLET_HEIGHT;
                    let h = ctx.rng.random_range(0.5..1.1);
                    let g = goods[ctx.rng.random_range(0..goods.len())];
                    ctx.builder.add(
                        Shape::standing_box([x, y], z, 0.0, [1.15, 0.95, h]),
                        g,
                        "load",
                    )?;
                    z += h;
                }
                ctx.builder.mark_movable(first);
            }
            y += 1.4;
        }
    }
    Ok(banded)
}

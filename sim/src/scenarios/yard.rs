//! The yard: an outdoor area about 100 × 80 m. A warehouse facade along the north side (roll-up
//! doors, dark windows, a sign, panel joints) with loading ramps and bollards; an office block on
//! the west; a chain-link fence with posts on the east (it intercepts a third of the beam, so
//! dual return sees both the fence and what is behind it) with a far building beyond; containers
//! and a low wall on the south. Inside the robot's loop: parking rows with painted bays, cars,
//! vans, a trailer, skips and a tree island (foliage is partial too). Lamp posts line the loop and
//! sign posts with retro-reflective plates stand at its corners. A car drives along the south and
//! a pedestrian walks along the north. The robot drives a rounded rectangle of 200–300 m; the
//! other routes are the loop's south or north half, closed along the lane between the parking
//! rows and the trees.

use std::f64::consts::{FRAC_PI_2, PI};

use rand::Rng;

use super::{rho, Ctx, LayoutError, Plan, Route};
use crate::scene::{Decal, Material, MaterialId, Pattern, Shape};
use crate::trajectory::{rounded_polygon, MotionLimits, Mount};

pub(super) fn build(ctx: &mut Ctx) -> Result<Plan, LayoutError> {
    // The loop's half extents.
    let hx: f64 = ctx.rng.random_range(34.0..42.0);
    let hy: f64 = ctx.rng.random_range(22.0..28.0);
    let corner = 6.0;

    // Ground, well beyond everything.
    let mut ground = Material::diffuse("asphalt", rho::ASPHALT);
    let (gx, gy) = (hx + 60.0, hy + 60.0);
    // Painted parking bays inside the loop (two rows facing each other across a lane).
    let bay_w: f64 = 2.6;
    let rows_y = [-6.0, 6.0];
    let bay_x0 = -hx + 10.0;
    let bays = ((2.0 * hx - 20.0) / bay_w).floor() as usize;
    for &ry in &rows_y {
        for k in 0..=bays {
            let x = bay_x0 + k as f64 * bay_w;
            let (v0, v1) = if ry < 0.0 {
                (ry - 5.0, ry)
            } else {
                (ry, ry + 5.0)
            };
            ground.decals.push(Decal::new(
                [x - 0.06 + gx, v0 + gy],
                [x + 0.06 + gx, v1 + gy],
                Pattern::uniform(0.7),
            ));
        }
    }
    // A zebra crossing across the north side of the loop and a few manholes and stains.
    let zx = ctx.rng.random_range(-hx + 10.0..hx - 10.0);
    ground.decals.push(Decal::new(
        [zx - 2.0 + gx, hy - 3.0 + gy],
        [zx + 2.0 + gx, hy + 3.0 + gy],
        Pattern::Stripes {
            rho_a: 0.75,
            rho_b: rho::ASPHALT,
            period: 0.8,
            duty: 0.5,
            angle: 0.0,
        },
    ));
    for _ in 0..ctx.rng.random_range(10..20) {
        let (x, y) = (ctx.rng.random_range(-hx..hx), ctx.rng.random_range(-hy..hy));
        let s = ctx.rng.random_range(0.5..1.5);
        let r = if ctx.rng.random_bool(0.3) { 0.25 } else { 0.05 };
        ground.decals.push(Decal::new(
            [x + gx, y + gy],
            [x + s + gx, y + 0.8 * s + gy],
            Pattern::uniform(r),
        ));
    }
    let ground = ctx.builder.material(ground)?;
    ctx.builder
        .add(Shape::horizontal(-gx, -gy, gx, gy, 0.0), ground, "ground")?;

    // North: a warehouse facade 12 m beyond the loop.
    let north_y = hy + 12.0;
    let north_h = ctx.rng.random_range(9.0..12.0);
    let north_len = 2.0 * hx + 30.0;
    let mut facade = Material::new("north facade", Pattern::stripes_u(0.38, 0.2, 3.0, 0.98));
    // On the −y face (face 3) of a box from x = −north_len/2: u = x + north_len/2, v = z.
    let n_doors = ctx.rng.random_range(4..=7);
    let door_gap = north_len / (n_doors as f64 + 1.0);
    let mut door_x = Vec::new();
    for k in 1..=n_doors {
        let u = k as f64 * door_gap - 2.0;
        facade.decals.push(Decal::on_face(
            3,
            [u, 0.0],
            [u + 4.0, 4.5],
            Pattern::stripes_v(0.5, 0.38, 0.15, 0.5),
        ));
        door_x.push(u + 2.0 - 0.5 * north_len);
    }
    let mut u = 3.0;
    while u < north_len - 4.0 {
        if !door_x
            .iter()
            .any(|&x| (u + 0.5 * north_len - x - 0.75).abs() < 3.5)
        {
            facade.decals.push(Decal::on_face(
                3,
                [u, 5.0],
                [u + 1.5, 6.4],
                Pattern::uniform(rho::GLASS),
            ));
        }
        u += 3.0;
    }
    let sign_u = ctx.rng.random_range(5.0..north_len - 15.0);
    facade.decals.push(Decal::on_face(
        3,
        [sign_u, 7.0],
        [sign_u + 8.0, 8.4],
        Pattern::stripes_u(0.9, 0.2, 0.6, 0.7),
    ));
    let facade = ctx.builder.material(facade)?;
    ctx.builder.add(
        Shape::aabox(
            [-0.5 * north_len, north_y, 0.0],
            [0.5 * north_len, north_y + 20.0, north_h],
        ),
        facade,
        "building",
    )?;
    // Loading ramps in front of some doors, bollards beside every door.
    let ramp = ctx.builder.material(Material::diffuse("ramp", 0.3))?;
    let bollard =
        ctx.builder
            .material(Material::diffuse("bollard", rho::YELLOW_PAINT).with_decal(
                Decal::on_face(
                    0,
                    [0.0, 0.8],
                    [2.0 * PI * 0.1, 0.9],
                    Pattern::Retro { value: 210 },
                ),
            ))?;
    let mut ramps = 0;
    for &x in &door_x {
        if ctx.rng.random_bool(0.5) {
            ctx.builder.add(
                Shape::Ramp {
                    base: [x, north_y - 6.0, 0.0],
                    yaw: FRAC_PI_2,
                    length: 6.0,
                    width: 3.6,
                    height: 1.2,
                },
                ramp,
                "loading ramp",
            )?;
            ramps += 1;
        }
        for side in [-1.0, 1.0] {
            ctx.builder.add(
                Shape::Pole {
                    base: [x + side * 2.6, north_y - 0.6, 0.0],
                    height: 1.0,
                    radius: 0.1,
                },
                bollard,
                "bollard",
            )?;
        }
    }

    // West: an office block.
    let west_x = -hx - 12.0;
    let mut office = Material::diffuse("office facade", 0.45);
    let office_len = 2.0 * hy + 16.0;
    for floor in 0..3 {
        let mut u = 2.0;
        while u < office_len - 2.0 {
            office.decals.push(Decal::on_face(
                0,
                [u, 1.0 + 3.2 * floor as f64],
                [u + 1.8, 2.5 + 3.2 * floor as f64],
                Pattern::uniform(rho::GLASS),
            ));
            u += 3.0;
        }
    }
    let entrance = ctx.rng.random_range(5.0..office_len - 8.0);
    office.decals.push(Decal::on_face(
        0,
        [entrance, 0.0],
        [entrance + 3.0, 2.6],
        Pattern::uniform(0.15),
    ));
    let office = ctx.builder.material(office)?;
    ctx.builder.add(
        Shape::aabox([west_x - 18.0, -hy - 8.0, 0.0], [west_x, hy + 8.0, 10.0]),
        office,
        "building",
    )?;

    // East: a chain-link fence with posts, and a far building beyond.
    let fence_x = hx + 10.0;
    let fence = ctx
        .builder
        .material(Material::diffuse("chain-link fence", 0.4).with_coverage(0.35))?;
    ctx.builder.add(
        Shape::wall([fence_x, -hy - 10.0], [fence_x, hy + 10.0], 0.0, 2.2),
        fence,
        "fence",
    )?;
    let post = ctx
        .builder
        .material(Material::diffuse("fence post", rho::STEEL))?;
    let mut y = -hy - 10.0;
    let mut posts = 0;
    while y <= hy + 10.0 {
        ctx.builder.add(
            Shape::Pole {
                base: [fence_x, y, 0.0],
                height: 2.3,
                radius: 0.04,
            },
            post,
            "fence post",
        )?;
        posts += 1;
        y += 3.0;
    }
    let far = ctx.builder.material(Material::new(
        "far facade",
        Pattern::stripes_v(0.5, 0.3, 3.0, 0.8),
    ))?;
    ctx.builder.add(
        Shape::aabox(
            [fence_x + 20.0, -hy - 20.0, 0.0],
            [fence_x + 35.0, hy + 20.0, 14.0],
        ),
        far,
        "building",
    )?;

    // South: containers in a row (some stacked) and a low wall behind them.
    let container_mats: Vec<MaterialId> = [0.25, 0.35, 0.5, 0.6]
        .iter()
        .map(|&r| {
            ctx.builder.material(Material::new(
                "container",
                Pattern::stripes_u(r, r * 0.8, 0.28, 0.5),
            ))
        })
        .collect::<Result<_, _>>()?;
    let mut x = -hx - 2.0;
    let mut containers = 0;
    while x < hx - 2.0 {
        if ctx.rng.random_bool(0.8) {
            let m = container_mats[ctx.rng.random_range(0..container_mats.len())];
            let stack = if ctx.rng.random_bool(0.3) { 2 } else { 1 };
            let first = ctx.builder.primitive_count() as u32;
            for level in 0..stack {
                ctx.builder.add(
                    Shape::standing_box(
                        [x + 3.03, -hy - 9.5],
                        level as f64 * 2.59,
                        0.0,
                        [6.06, 2.44, 2.59],
                    ),
                    m,
                    "container",
                )?;
                containers += 1;
            }
            ctx.builder.mark_movable(first);
        }
        x += ctx.rng.random_range(6.3..7.5);
    }
    let low_wall = ctx.builder.material(Material::diffuse("low wall", 0.3))?;
    ctx.builder.add(
        Shape::aabox([-hx - 10.0, -hy - 14.3, 0.0], [hx + 10.0, -hy - 14.0, 1.2]),
        low_wall,
        "low wall",
    )?;

    // Inside the loop: vehicles in the bays, a trailer, skips, a tree island.
    let body_mats: Vec<MaterialId> = [0.08, 0.25, 0.5, 0.8]
        .iter()
        .map(|&r| ctx.builder.material(Material::diffuse("car body", r)))
        .collect::<Result<_, _>>()?;
    let glass = ctx
        .builder
        .material(Material::diffuse("car glass", rho::GLASS))?;
    let mut cars = 0;
    for &ry in &rows_y {
        for k in 0..bays {
            if !ctx.rng.random_bool(0.6) {
                continue;
            }
            let cx = bay_x0 + (k as f64 + 0.5) * bay_w;
            let cy = if ry < 0.0 { ry - 2.5 } else { ry + 2.5 };
            let body = body_mats[ctx.rng.random_range(0..body_mats.len())];
            let yaw = FRAC_PI_2 + ctx.rng.random_range(-0.05..0.05);
            let first = ctx.builder.primitive_count() as u32;
            if ctx.rng.random_bool(0.2) {
                ctx.builder.add(
                    Shape::standing_box([cx, cy], 0.25, yaw, [4.9, 2.0, 2.2]),
                    body,
                    "van",
                )?;
            } else {
                ctx.builder.add(
                    Shape::standing_box([cx, cy], 0.2, yaw, [4.4, 1.8, 0.75]),
                    body,
                    "car",
                )?;
                ctx.builder.add(
                    Shape::standing_box([cx, cy], 0.95, yaw, [2.4, 1.6, 0.55]),
                    glass,
                    "car",
                )?;
            }
            ctx.builder.mark_movable(first);
            cars += 1;
        }
    }
    let trailer = ctx.builder.material(Material::diffuse("trailer", 0.7))?;
    let tx = ctx.rng.random_range(-hx + 15.0..hx - 15.0);
    let first = ctx.builder.primitive_count() as u32;
    ctx.builder.add(
        Shape::standing_box([tx, -hy + 5.0], 1.1, 0.0, [13.6, 2.5, 2.9]),
        trailer,
        "trailer",
    )?;
    ctx.builder.mark_movable(first);
    let skip = ctx.builder.material(Material::diffuse("skip", 0.2))?;
    for _ in 0..ctx.rng.random_range(2..=4) {
        let sx = ctx.rng.random_range(-hx + 8.0..hx - 8.0);
        let first = ctx.builder.primitive_count() as u32;
        ctx.builder.add(
            Shape::standing_box(
                [sx, hy - 5.0],
                0.0,
                ctx.rng.random_range(0.0..PI),
                [3.6, 1.8, 1.5],
            ),
            skip,
            "skip",
        )?;
        ctx.builder.mark_movable(first);
    }
    let bark = ctx.builder.material(Material::diffuse("tree trunk", 0.3))?;
    let leaves = ctx
        .builder
        .material(Material::diffuse("foliage", 0.45).with_coverage(0.5))?;
    let trees = ctx.rng.random_range(3..=6);
    for k in 0..trees {
        let x = -hx + 12.0 + k as f64 * (2.0 * hx - 24.0) / (trees as f64 - 1.0).max(1.0);
        ctx.builder.add(
            Shape::Cylinder {
                base: [x, 0.0, 0.0],
                height: 3.0,
                radius: 0.2,
            },
            bark,
            "tree",
        )?;
        ctx.builder.add(
            Shape::Cylinder {
                base: [x, 0.0, 3.0],
                height: 3.5,
                radius: 1.8,
            },
            leaves,
            "tree",
        )?;
    }

    // Lamp posts 3 m outside the loop every ~20 m, sign posts with retro plates at the corners.
    let lamp = ctx
        .builder
        .material(Material::diffuse("lamp post", rho::STEEL))?;
    let head = ctx.builder.material(Material::diffuse("lamp head", 0.6))?;
    let mut lamps = 0;
    let mut x = -hx + corner;
    while x <= hx - corner {
        for (y, dir) in [(-hy - 3.0, 1.0), (hy + 3.0, -1.0)] {
            ctx.builder.add(
                Shape::Pole {
                    base: [x, y, 0.0],
                    height: 8.0,
                    radius: 0.1,
                },
                lamp,
                "lamp post",
            )?;
            ctx.builder.add(
                Shape::standing_box([x, y + dir * 0.4], 7.9, 0.0, [0.3, 0.7, 0.15]),
                head,
                "lamp post",
            )?;
            lamps += 1;
        }
        x += ctx.rng.random_range(18.0..22.0);
    }
    let sign_pole = ctx
        .builder
        .material(Material::diffuse("sign post", rho::STEEL))?;
    let plate =
        ctx.builder.material(
            Material::diffuse("sign back", 0.3).with_decal(Decal::on_face(
                2,
                [0.0, 0.0],
                [0.6, 0.6],
                Pattern::Retro { value: 220 },
            )),
        )?;
    for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)] {
        // Inside the loop, 3.5 m from its straight sides, the plate facing the corner's approach.
        let (x, y) = (sx * (hx - 3.5), sy * (hy - 3.5));
        ctx.builder.add(
            Shape::Pole {
                base: [x, y, 0.0],
                height: 2.2,
                radius: 0.04,
            },
            sign_pole,
            "sign post",
        )?;
        let yaw = (sy).atan2(sx) + ctx.rng.random_range(-0.3..0.3);
        ctx.builder.add(
            Shape::Cuboid {
                center: [x, y, 2.5],
                yaw: yaw - FRAC_PI_2,
                pitch: 0.0,
                roll: 0.0,
                half: [0.3, 0.015, 0.3],
            },
            plate,
            "traffic sign",
        )?;
    }

    // Movers: a car along the south between the loop and the containers, a pedestrian north.
    let car = body_mats[1];
    let car_phase = ctx.rng.random_range(0.0..60.0);
    ctx.builder.add_mover(
        Shape::standing_box([-hx, -hy - 4.5], 0.2, 0.0, [4.5, 1.8, 1.4]),
        car,
        "moving car",
        [2.0 * hx, 0.0, 0.0],
        3.0,
        car_phase,
    )?;
    let person = ctx.builder.material(Material::diffuse("clothing", 0.35))?;
    let walk_phase = ctx.rng.random_range(0.0..60.0);
    ctx.builder.add_mover(
        Shape::Cylinder {
            base: [-20.0, hy + 4.5, 0.0],
            height: 1.75,
            radius: 0.25,
        },
        person,
        "pedestrian",
        [40.0, 0.0, 0.0],
        1.3,
        walk_phase,
    )?;

    let corners = [[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]];
    let route = Route {
        waypoints: rounded_polygon(&corners, corner, 3.0),
        text: format!("robot: a rounded rectangle x ±{hx:.1} m, y ±{hy:.1} m, corner radius {corner} m, counter-clockwise"),
    };
    // Halves of the loop, closed along the lane between the parking rows, 3 m from the trees.
    let half = |y0: f64, y1: f64, name: &str| {
        Route {
        waypoints: rounded_polygon(&[[-hx, y0], [hx, y0], [hx, y1], [-hx, y1]], corner, 3.0),
        text: format!("robot: the {name} half of the loop, a rounded rectangle x ±{hx:.1} m, y {y0:.1}…{y1:.1} m, corner radius {corner} m, counter-clockwise"),
    }
    };
    let alternatives = vec![half(-hy, -3.0, "south"), half(3.0, hy, "north")];
    let limits = MotionLimits {
        cruise_speed: 1.8,
        min_speed: 0.5,
        max_accel: 0.5,
        max_lateral_accel: 0.6,
        max_yaw_rate: 0.6,
    };
    let mount = Mount {
        x: 0.25,
        y: 0.0,
        z: ctx.rng.random_range(0.7..1.0),
    };

    let lines = vec![
        format!("yard ~{:.0} × {:.0} m of asphalt (ρ {}), painted parking bays, a zebra crossing, stains and manholes", 2.0 * hx + 24.0, 2.0 * hy + 26.0, rho::ASPHALT),
        format!("north: warehouse facade {north_len:.0} m long, {north_h:.1} m high, at y = {north_y:.1} m with {n_doors} roll-up doors, dark windows, a sign; {ramps} loading ramps, {} bollards with retro bands", 2 * door_x.len()),
        format!("west: office block at x = {west_x:.1} m with three rows of windows; east: chain-link fence (coverage 0.35) at x = {fence_x:.1} m with {posts} posts, a far building behind it"),
        format!("south: {containers} containers (some stacked) and a low wall"),
        format!("inside the loop: {cars} parked cars and vans, a trailer, skips, {trees} trees (foliage coverage 0.5)"),
        format!("poles: {lamps} lamp posts 3 m outside the loop, 4 sign posts with retro-reflective plates at the corners"),
        "movers: a car driving along the south side, a pedestrian walking along the north side".to_string(),
    ];
    Ok(Plan {
        route,
        alternatives,
        limits,
        mount,
        lines,
    })
}

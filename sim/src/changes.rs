//! Changed goods: the same place on another day. A fraction of the movable objects (pallets
//! and their loads, floor stacks, parked vehicles; never walls, racks or pillars) is removed or
//! shifted by 0.3–1.5 m onto free floor, decided by a random stream of its own, so that a run
//! can localise in a map made before the goods moved.
//!
//! "Free" means: the moved object's box overlaps no other object's box and keeps
//! [`LANE_CLEARANCE_M`] from every lane a robot may drive (all the scenario's routes, not only
//! this run's), so every route stays drivable and runs with different routes see the same
//! changes. Goods above the floor (on rack beams) slide only along x, the racks' direction;
//! goods on the floor may move in any horizontal direction. A shift that finds no free place
//! in a few tries becomes a removal.

use rand::Rng;
use serde::Serialize;

use crate::bvh::Aabb;
use crate::geometry::bounds;
use crate::scene::SceneBuilder;

/// Smallest distance from a moved object to the centre line of any lane, m.
pub const LANE_CLEARANCE_M: f64 = 0.8;
/// Shift distances, m.
const SHIFT_M: (f64, f64) = (0.3, 1.5);
/// Objects whose base is higher than this stand on something other than the floor, m.
const ON_FLOOR_M: f64 = 0.05;
/// Height band of the robot's body: only boxes reaching into it can block a lane, m.
const BODY_BAND_M: (f64, f64) = (0.02, 2.0);
/// Tries to find a free place before removing the object instead.
const SHIFT_TRIES: usize = 20;
/// Shrinks the moved box before the overlap test, so that goods resting on a beam or on
/// each other do not count as overlapping it, m.
const TOUCH_M: f64 = 0.01;

/// What happened to one movable object.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChangedObject {
    /// The tag of its first primitive ("pallet", "car", …).
    pub tag: String,
    /// The centre of its box in the unchanged scene, m.
    pub center: [f64; 3],
    /// The horizontal shift applied, m; `None` when it was removed.
    pub shift: Option<[f64; 2]>,
}

/// Removes or shifts `round(fraction × n)` of the builder's `n` movable objects, chosen by
/// `rng`; `lanes` are points along every drivable lane (a few dm apart). Returns what changed,
/// in the order of the objects.
pub fn change_goods(
    builder: &mut SceneBuilder,
    lanes: &[[f64; 2]],
    fraction: f64,
    rng: &mut impl Rng,
) -> Vec<ChangedObject> {
    let objects = builder.movable_objects().to_vec();
    let n = objects.len();
    let count = ((fraction.clamp(0.0, 1.0) * n as f64).round() as usize).min(n);
    let mut order: Vec<usize> = (0..n).collect();
    for i in 0..count {
        let j = rng.random_range(i..n);
        order.swap(i, j);
    }
    let mut chosen = order[..count].to_vec();
    chosen.sort_unstable();

    let mut obstacles = obstacle_boxes(builder);
    let object_box = |obstacles: &[Aabb], [first, end]: [u32; 2]| {
        obstacles[first as usize..end as usize]
            .iter()
            .fold(Aabb::EMPTY, |a, b| a.union(b))
    };
    let mut changed = Vec::with_capacity(count);
    let mut removed = Vec::new();
    for index in chosen {
        let range = objects[index];
        let own = object_box(&obstacles, range);
        let center = [0, 1, 2].map(|i| 0.5 * (own.min[i] + own.max[i]));
        let tag = builder.tags()[usize::from(builder.primitives()[range[0] as usize].tag)].clone();
        let shift = if rng.random_bool(0.5) {
            find_free_shift(&obstacles, range, &own, lanes, rng)
        } else {
            None
        };
        match shift {
            Some(d) => {
                builder.shift_movable(index, [d[0], d[1], 0.0]);
                for b in &mut obstacles[range[0] as usize..range[1] as usize] {
                    *b = moved(b, d);
                }
            }
            None => {
                removed.push(index);
                obstacles[range[0] as usize..range[1] as usize].fill(Aabb::EMPTY);
            }
        }
        changed.push(ChangedObject { tag, center, shift });
    }
    builder.remove_movables(&removed);
    changed
}

/// Boxes of every primitive (by id; floors and ceilings, which cover the whole scene, as
/// empty boxes) followed by the boxes the movers sweep.
fn obstacle_boxes(builder: &SceneBuilder) -> Vec<Aabb> {
    let mut boxes: Vec<Aabb> = builder
        .primitives()
        .iter()
        .map(|p| {
            let b = bounds(&p.shape);
            // Horizontal slabs (floor, ceiling, ground) are never in the way.
            if b.max[2] - b.min[2] < 1e-6 {
                Aabb::EMPTY
            } else {
                b
            }
        })
        .collect();
    boxes.extend(builder.movers().iter().map(|m| {
        let b = bounds(&m.shape);
        b.union(&moved(&b, [m.travel[0], m.travel[1]]))
    }));
    boxes
}

fn moved(b: &Aabb, d: [f64; 2]) -> Aabb {
    if b.min[0] > b.max[0] {
        return *b;
    }
    Aabb {
        min: [b.min[0] + d[0], b.min[1] + d[1], b.min[2]],
        max: [b.max[0] + d[0], b.max[1] + d[1], b.max[2]],
    }
}

fn overlaps(a: &Aabb, b: &Aabb) -> bool {
    (0..3).all(|i| a.min[i] < b.max[i] && b.min[i] < a.max[i])
}

/// Distance in the xy plane from a point to a box's footprint.
fn xy_distance(b: &Aabb, p: [f64; 2]) -> f64 {
    let dx = (b.min[0] - p[0]).max(p[0] - b.max[0]).max(0.0);
    let dy = (b.min[1] - p[1]).max(p[1] - b.max[1]).max(0.0);
    dx.hypot(dy)
}

/// A shift that puts the object on free floor, or `None` after [`SHIFT_TRIES`] tries.
fn find_free_shift(
    obstacles: &[Aabb],
    [first, end]: [u32; 2],
    own: &Aabb,
    lanes: &[[f64; 2]],
    rng: &mut impl Rng,
) -> Option<[f64; 2]> {
    let on_floor = own.min[2] <= ON_FLOOR_M;
    let in_body_band = own.min[2] < BODY_BAND_M.1 && own.max[2] > BODY_BAND_M.0;
    // The floor the object may stand on: the extent of everything else.
    let extent = obstacles.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
    for _ in 0..SHIFT_TRIES {
        let distance = rng.random_range(SHIFT_M.0..=SHIFT_M.1);
        let d = if on_floor {
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            [distance * angle.cos(), distance * angle.sin()]
        } else if rng.random_bool(0.5) {
            [distance, 0.0]
        } else {
            [-distance, 0.0]
        };
        let target = moved(own, d);
        let inside = target.min[0] >= extent.min[0]
            && target.max[0] <= extent.max[0]
            && target.min[1] >= extent.min[1]
            && target.max[1] <= extent.max[1];
        if !inside {
            continue;
        }
        let probe = Aabb {
            min: target.min.map(|x| x + TOUCH_M),
            max: target.max.map(|x| x - TOUCH_M),
        };
        let blocked = obstacles
            .iter()
            .enumerate()
            .any(|(id, b)| !(first as usize..end as usize).contains(&id) && overlaps(&probe, b));
        if blocked {
            continue;
        }
        if in_body_band
            && lanes
                .iter()
                .any(|&p| xy_distance(&target, p) < LANE_CLEARANCE_M)
        {
            continue;
        }
        return Some(d);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Material, Shape};
    use rand::SeedableRng;

    /// Ten 1 m boxes in a row on a floor, a wall beside them and a lane 3 m away.
    fn yard() -> SceneBuilder {
        let mut b = SceneBuilder::new();
        let m = b.material(Material::diffuse("m", 0.5)).unwrap();
        b.add(Shape::horizontal(-20.0, -20.0, 20.0, 20.0, 0.0), m, "floor")
            .unwrap();
        b.add(
            Shape::wall([-10.0, -2.0], [10.0, -2.0], 0.0, 3.0),
            m,
            "wall",
        )
        .unwrap();
        for k in 0..10 {
            let first = b.primitive_count() as u32;
            b.add(
                Shape::standing_box([k as f64 * 2.0 - 9.0, 0.0], 0.0, 0.0, [1.0; 3]),
                m,
                "box",
            )
            .unwrap();
            b.mark_movable(first);
        }
        b
    }

    #[test]
    fn the_fraction_asked_for_changes_and_nothing_else() {
        let lanes: Vec<[f64; 2]> = (-100..=100).map(|k| [k as f64 * 0.1, 3.0]).collect();
        for seed in 0..20 {
            let mut b = yard();
            let before = b.primitives().to_vec();
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let changed = change_goods(&mut b, &lanes, 0.3, &mut rng);
            assert_eq!(changed.len(), 3);
            let removed = changed.iter().filter(|c| c.shift.is_none()).count();
            assert_eq!(b.primitives().len(), before.len() - removed);
            assert_eq!(b.movable_objects().len(), 10 - removed);
            // The floor and the wall are untouched; 7 boxes are where they were.
            assert_eq!(&b.primitives()[..2], &before[..2]);
            let unmoved = b
                .primitives()
                .iter()
                .filter(|p| before[2..].contains(p))
                .count();
            assert_eq!(unmoved, 7, "seed {seed}");
            for c in changed.iter().filter_map(|c| c.shift) {
                let d = c[0].hypot(c[1]);
                assert!((0.3..=1.5).contains(&d), "{d}");
            }
            // No box overlaps another, the wall, or comes near the lane.
            let boxes: Vec<Aabb> = b.primitives()[2..]
                .iter()
                .map(|p| bounds(&p.shape))
                .collect();
            for (i, a) in boxes.iter().enumerate() {
                assert!(a.min[1] > -2.0 + 1e-9 && a.max[1] < 3.0 - LANE_CLEARANCE_M + 1e-9);
                for c in &boxes[i + 1..] {
                    assert!(!overlaps(a, c), "seed {seed}: {a:?} {c:?}");
                }
            }
        }
    }

    #[test]
    fn nothing_changes_at_fraction_zero_and_everything_at_one() {
        let mut b = yard();
        let before = b.primitives().to_vec();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        assert!(change_goods(&mut b, &[], 0.0, &mut rng).is_empty());
        assert_eq!(b.primitives(), &before[..]);
        let changed = change_goods(&mut b, &[], 1.0, &mut rng);
        assert_eq!(changed.len(), 10);
        let unmoved = b.primitives()[2..]
            .iter()
            .filter(|p| before.contains(p))
            .count();
        assert_eq!(unmoved, 0);
    }
}

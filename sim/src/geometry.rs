//! Geometry of primitives: the shapes (rectangles, oriented boxes, vertical cylinders, thin
//! poles, ramps), their bounds, ray intersection in f64, and the surface frame at a hit.
//!
//! Longer than most modules: each primitive's intersection, bounds and surface frame are kept
//! together here so that the ray tracer's hot path is one file.
//!
//! Every surface has coordinates (u, v) in metres so that materials can paint it:
//! - rectangle: face 0 is the side the normal `u × v` points to, face 1 the other; (u, v) from
//!   the corner at `−half` along both axes;
//! - cuboid: faces 0..6 are +x, −x, +y, −y, +z, −z of its own frame; (u, v) are (y, z) on the x
//!   faces, (x, z) on the y faces and (x, y) on the z faces, each from the box's lower corner;
//! - cylinder and pole: face 0 the side with u the arc length counter-clockwise from the +x
//!   direction and v the height above the base; faces 1 and 2 the top and bottom caps with (u, v)
//!   the (x, y) offset from the cap's lower corner;
//! - ramp: face 0 the slope (u up the slope from the low edge, v across from the right side),
//!   1 the back (x = length), 2 and 3 the left and right sides, 4 the bottom.
//!
//! Intersection tests return only the distance; the face and (u, v) are worked out once, for the
//! nearest hit.

use nalgebra::{Rotation3, Vector3};
use serde::Serialize;

use crate::bvh::Aabb;
use crate::scene::SceneError;

type V3 = Vector3<f64>;

/// Geometry of a primitive, in the scene frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Shape {
    /// A two-sided rectangle: its centre, two orthonormal in-plane axes and half-sizes along
    /// them. The normal of face 0 is `u × v`.
    Rect {
        /// Centre.
        center: [f64; 3],
        /// First in-plane axis (unit).
        u: [f64; 3],
        /// Second in-plane axis (unit, orthogonal to `u`).
        v: [f64; 3],
        /// Half-sizes along `u` and `v`.
        half: [f64; 2],
    },
    /// A box turned by yaw, then pitch, then roll (rotation Rz(yaw)·Ry(pitch)·Rx(roll)).
    Cuboid {
        /// Centre.
        center: [f64; 3],
        /// Rotation about z, rad.
        yaw: f64,
        /// Rotation about the turned y, rad.
        pitch: f64,
        /// Rotation about the turned x, rad.
        roll: f64,
        /// Half-sizes along the box's own axes.
        half: [f64; 3],
    },
    /// A vertical cylinder with caps.
    Cylinder {
        /// Centre of the bottom cap.
        base: [f64; 3],
        /// Height.
        height: f64,
        /// Radius.
        radius: f64,
    },
    /// A thin vertical cylinder (lamp post, bollard, fence post): it may be narrower than the
    /// beam, which then returns only part of its energy and continues behind it.
    Pole {
        /// Centre of the bottom.
        base: [f64; 3],
        /// Height.
        height: f64,
        /// Radius.
        radius: f64,
    },
    /// A wedge rising from a low edge: a loading ramp.
    Ramp {
        /// Centre of the low edge.
        base: [f64; 3],
        /// Direction of ascent, rad about z from +x.
        yaw: f64,
        /// Horizontal run.
        length: f64,
        /// Width across.
        width: f64,
        /// Rise.
        height: f64,
    },
}

impl Shape {
    /// A horizontal rectangle at height `z` over [x0, x1] × [y0, y1], face 0 up, (u, v) = (x −
    /// x0, y − y0).
    pub fn horizontal(x0: f64, y0: f64, x1: f64, y1: f64, z: f64) -> Shape {
        Shape::Rect {
            center: [0.5 * (x0 + x1), 0.5 * (y0 + y1), z],
            u: [1.0, 0.0, 0.0],
            v: [0.0, 1.0, 0.0],
            half: [0.5 * (x1 - x0).abs(), 0.5 * (y1 - y0).abs()],
        }
    }

    /// A vertical rectangle from `a` to `b` (in xy) between heights `z0` and `z1`: u runs from
    /// `a` to `b`, v up, and face 0 (normal u × v) looks to the right of a→b seen from above.
    pub fn wall(a: [f64; 2], b: [f64; 2], z0: f64, z1: f64) -> Shape {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len = (dx * dx + dy * dy).sqrt().max(f64::MIN_POSITIVE);
        Shape::Rect {
            center: [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (z0 + z1)],
            u: [dx / len, dy / len, 0.0],
            v: [0.0, 0.0, 1.0],
            half: [0.5 * len, 0.5 * (z1 - z0).abs()],
        }
    }

    /// An axis-aligned box between two corners.
    pub fn aabox(min: [f64; 3], max: [f64; 3]) -> Shape {
        Shape::Cuboid {
            center: [
                0.5 * (min[0] + max[0]),
                0.5 * (min[1] + max[1]),
                0.5 * (min[2] + max[2]),
            ],
            yaw: 0.0,
            pitch: 0.0,
            roll: 0.0,
            half: [
                0.5 * (max[0] - min[0]),
                0.5 * (max[1] - min[1]),
                0.5 * (max[2] - min[2]),
            ],
        }
    }

    /// A box standing on height `z0`, turned by `yaw`, with full sizes `size`.
    pub fn standing_box(center_xy: [f64; 2], z0: f64, yaw: f64, size: [f64; 3]) -> Shape {
        Shape::Cuboid {
            center: [center_xy[0], center_xy[1], z0 + 0.5 * size[2]],
            yaw,
            pitch: 0.0,
            roll: 0.0,
            half: [0.5 * size[0], 0.5 * size[1], 0.5 * size[2]],
        }
    }

    /// The same shape moved by `d`.
    pub fn translated(&self, d: [f64; 3]) -> Shape {
        let add = |p: [f64; 3]| [p[0] + d[0], p[1] + d[1], p[2] + d[2]];
        match *self {
            Shape::Rect { center, u, v, half } => Shape::Rect {
                center: add(center),
                u,
                v,
                half,
            },
            Shape::Cuboid {
                center,
                yaw,
                pitch,
                roll,
                half,
            } => Shape::Cuboid {
                center: add(center),
                yaw,
                pitch,
                roll,
                half,
            },
            Shape::Cylinder {
                base,
                height,
                radius,
            } => Shape::Cylinder {
                base: add(base),
                height,
                radius,
            },
            Shape::Pole {
                base,
                height,
                radius,
            } => Shape::Pole {
                base: add(base),
                height,
                radius,
            },
            Shape::Ramp {
                base,
                yaw,
                length,
                width,
                height,
            } => Shape::Ramp {
                base: add(base),
                yaw,
                length,
                width,
                height,
            },
        }
    }

    /// A short name for reports.
    pub fn kind(&self) -> &'static str {
        match self {
            Shape::Rect { .. } => "rectangle",
            Shape::Cuboid { .. } => "box",
            Shape::Cylinder { .. } => "cylinder",
            Shape::Pole { .. } => "pole",
            Shape::Ramp { .. } => "ramp",
        }
    }

    pub(crate) fn validate(&self) -> Result<(), SceneError> {
        let finite = |xs: &[f64]| xs.iter().all(|x| x.is_finite());
        let positive = |xs: &[f64]| xs.iter().all(|&x| x > 0.0);
        let ok = match *self {
            Shape::Rect { center, u, v, half } => {
                let (u, v) = (V3::from(u), V3::from(v));
                finite(&center)
                    && finite(&half)
                    && positive(&half)
                    && (u.norm() - 1.0).abs() < 1e-9
                    && (v.norm() - 1.0).abs() < 1e-9
                    && u.dot(&v).abs() < 1e-9
            }
            Shape::Cuboid {
                center,
                yaw,
                pitch,
                roll,
                half,
            } => finite(&center) && finite(&[yaw, pitch, roll]) && finite(&half) && positive(&half),
            Shape::Cylinder {
                base,
                height,
                radius,
            }
            | Shape::Pole {
                base,
                height,
                radius,
            } => finite(&base) && finite(&[height, radius]) && positive(&[height, radius]),
            Shape::Ramp {
                base,
                yaw,
                length,
                width,
                height,
            } => {
                finite(&base)
                    && finite(&[yaw, length, width, height])
                    && positive(&[length, width, height])
            }
        };
        if ok {
            Ok(())
        } else {
            Err(SceneError::BadShape(*self))
        }
    }
}

/// The axis-aligned bounds of a shape.
pub fn bounds(shape: &Shape) -> Aabb {
    match *shape {
        Shape::Rect { center, u, v, half } => {
            let (c, u, v) = (
                V3::from(center),
                V3::from(u) * half[0],
                V3::from(v) * half[1],
            );
            corners_box([c + u + v, c + u - v, c - u + v, c - u - v].iter())
        }
        Shape::Cuboid {
            center,
            yaw,
            pitch,
            roll,
            half,
        } => {
            let r = Rotation3::from_euler_angles(roll, pitch, yaw);
            let c = V3::from(center);
            let mut pts = Vec::with_capacity(8);
            for sx in [-1.0, 1.0] {
                for sy in [-1.0, 1.0] {
                    for sz in [-1.0, 1.0] {
                        pts.push(c + r * V3::new(sx * half[0], sy * half[1], sz * half[2]));
                    }
                }
            }
            corners_box(pts.iter())
        }
        Shape::Cylinder {
            base,
            height,
            radius,
        }
        | Shape::Pole {
            base,
            height,
            radius,
        } => Aabb {
            min: [base[0] - radius, base[1] - radius, base[2]],
            max: [base[0] + radius, base[1] + radius, base[2] + height],
        },
        Shape::Ramp {
            base,
            yaw,
            length,
            width,
            height,
        } => {
            let r = Rotation3::from_euler_angles(0.0, 0.0, yaw);
            let c = V3::from(base);
            let w = 0.5 * width;
            let pts = [
                V3::new(0.0, -w, 0.0),
                V3::new(0.0, w, 0.0),
                V3::new(length, -w, 0.0),
                V3::new(length, w, 0.0),
                V3::new(length, -w, height),
                V3::new(length, w, height),
            ];
            corners_box(pts.iter().map(|p| c + r * p).collect::<Vec<_>>().iter())
        }
    }
}

fn corners_box<'a>(pts: impl Iterator<Item = &'a V3>) -> Aabb {
    pts.fold(Aabb::EMPTY, |b, p| b.with_point([p.x, p.y, p.z]))
}

/// Intersection data precomputed from a shape.
#[derive(Debug, Clone)]
pub(crate) enum Isect {
    Rect {
        c: V3,
        n: V3,
        u: V3,
        v: V3,
        hu: f64,
        hv: f64,
    },
    /// An unrotated box (most boxes in a scene): slab test without a change of frame.
    AaBox { min: [f64; 3], max: [f64; 3] },
    /// `rows` turn scene vectors into the box's frame (they are its axes in the scene frame).
    Cuboid {
        c: V3,
        rows: [V3; 3],
        half: [f64; 3],
    },
    Cylinder {
        cx: f64,
        cy: f64,
        z0: f64,
        z1: f64,
        r: f64,
    },
    /// A convex solid given by its face planes in the local frame (`n·p ≤ d`).
    Ramp {
        c: V3,
        rows: [V3; 3],
        planes: [(V3, f64); 5],
        length: f64,
        width: f64,
        height: f64,
    },
}

impl Isect {
    pub(crate) fn new(shape: &Shape) -> Isect {
        match *shape {
            Shape::Rect { center, u, v, half } => {
                let (u, v) = (V3::from(u), V3::from(v));
                Isect::Rect {
                    c: V3::from(center),
                    n: u.cross(&v),
                    u,
                    v,
                    hu: half[0],
                    hv: half[1],
                }
            }
            Shape::Cuboid {
                center,
                yaw: 0.0,
                pitch: 0.0,
                roll: 0.0,
                half,
            } => {
                let (c, h) = (V3::from(center), V3::from(half));
                Isect::AaBox {
                    min: (c - h).into(),
                    max: (c + h).into(),
                }
            }
            Shape::Cuboid {
                center,
                yaw,
                pitch,
                roll,
                half,
            } => {
                let m = Rotation3::from_euler_angles(roll, pitch, yaw).into_inner();
                let rows = [m.column(0).into(), m.column(1).into(), m.column(2).into()];
                Isect::Cuboid {
                    c: V3::from(center),
                    rows,
                    half,
                }
            }
            Shape::Cylinder {
                base,
                height,
                radius,
            }
            | Shape::Pole {
                base,
                height,
                radius,
            } => Isect::Cylinder {
                cx: base[0],
                cy: base[1],
                z0: base[2],
                z1: base[2] + height,
                r: radius,
            },
            Shape::Ramp {
                base,
                yaw,
                length,
                width,
                height,
            } => {
                let m = Rotation3::from_euler_angles(0.0, 0.0, yaw).into_inner();
                let rows = [m.column(0).into(), m.column(1).into(), m.column(2).into()];
                let slope = V3::new(-height, 0.0, length).normalize();
                let w = 0.5 * width;
                let planes = [
                    (slope, 0.0),
                    (V3::x(), length),
                    (V3::y(), w),
                    (-V3::y(), w),
                    (-V3::z(), 0.0),
                ];
                Isect::Ramp {
                    c: V3::from(base),
                    rows,
                    planes,
                    length,
                    width,
                    height,
                }
            }
        }
    }

    /// The nearest distance in `(t_min, t_max)` at which the ray meets the solid or surface.
    #[inline]
    pub(crate) fn intersect(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<f64> {
        let (o, d) = (&ray.o, &ray.d);
        match self {
            Isect::Rect { c, n, u, v, hu, hv } => {
                let denom = n.dot(d);
                if denom.abs() < 1e-12 {
                    return None;
                }
                let t = n.dot(&(c - o)) / denom;
                if !(t > t_min && t < t_max) {
                    return None;
                }
                let p = o + d * t - c;
                if p.dot(u).abs() > *hu || p.dot(v).abs() > *hv {
                    return None;
                }
                Some(t)
            }
            Isect::AaBox { min, max } => {
                let mut lo = f64::NEG_INFINITY;
                let mut hi = f64::INFINITY;
                for (((lo_i, hi_i), o_i), inv_i) in min.iter().zip(max).zip(&ray.oa).zip(&ray.inva)
                {
                    let a = (lo_i - o_i) * inv_i;
                    let b = (hi_i - o_i) * inv_i;
                    let (near, far) = if a < b { (a, b) } else { (b, a) };
                    lo = if near > lo { near } else { lo };
                    hi = if far < hi { far } else { hi };
                }
                pick(lo, hi, t_min, t_max)
            }
            Isect::Cuboid { c, rows, half } => {
                let rel = o - c;
                let mut lo = f64::NEG_INFINITY;
                let mut hi = f64::INFINITY;
                for i in 0..3 {
                    let ol = rows[i].dot(&rel);
                    let inv = 1.0 / nonzero(rows[i].dot(d));
                    let a = (-half[i] - ol) * inv;
                    let b = (half[i] - ol) * inv;
                    let (near, far) = if a < b { (a, b) } else { (b, a) };
                    lo = if near > lo { near } else { lo };
                    hi = if far < hi { far } else { hi };
                }
                pick(lo, hi, t_min, t_max)
            }
            Isect::Cylinder { cx, cy, z0, z1, r } => {
                let (ox, oy) = (o.x - cx, o.y - cy);
                let mut best: Option<f64> = None;
                let mut limit = t_max;
                let a = d.x * d.x + d.y * d.y;
                if a > 1e-15 {
                    let b = ox * d.x + oy * d.y;
                    let cc = ox * ox + oy * oy - r * r;
                    let disc = b * b - a * cc;
                    if disc >= 0.0 {
                        let s = disc.sqrt();
                        for t in [(-b - s) / a, (-b + s) / a] {
                            if t > t_min && t < limit {
                                let z = o.z + d.z * t;
                                if z >= *z0 && z <= *z1 {
                                    best = Some(t);
                                    limit = t;
                                    break;
                                }
                            }
                        }
                    }
                }
                if d.z.abs() > 1e-15 {
                    for z in [*z1, *z0] {
                        let t = (z - o.z) / d.z;
                        if t > t_min && t < limit {
                            let (x, y) = (ox + d.x * t, oy + d.y * t);
                            if x * x + y * y <= r * r {
                                best = Some(t);
                                limit = t;
                            }
                        }
                    }
                }
                best
            }
            Isect::Ramp {
                c, rows, planes, ..
            } => {
                let rel = o - c;
                let ol = V3::new(rows[0].dot(&rel), rows[1].dot(&rel), rows[2].dot(&rel));
                let dl = V3::new(rows[0].dot(d), rows[1].dot(d), rows[2].dot(d));
                let mut lo = f64::NEG_INFINITY;
                let mut hi = f64::INFINITY;
                for (n, dist) in planes {
                    let denom = n.dot(&dl);
                    let gap = dist - n.dot(&ol);
                    if denom.abs() < 1e-15 {
                        if gap < 0.0 {
                            return None;
                        }
                        continue;
                    }
                    let t = gap / denom;
                    if denom < 0.0 {
                        lo = lo.max(t);
                    } else {
                        hi = hi.min(t);
                    }
                }
                pick(lo, hi, t_min, t_max)
            }
        }
    }

    /// The face a surface point `p` lies on (the one it is nearest to), for a ray along `d`.
    pub(crate) fn face_at(&self, p: &V3, d: &V3) -> u8 {
        let nearest = |dists: &[f64]| -> u8 {
            let mut best = 0;
            for (i, x) in dists.iter().enumerate() {
                if *x < dists[best] {
                    best = i;
                }
            }
            best as u8
        };
        match self {
            Isect::Rect { n, .. } => u8::from(n.dot(d) > 0.0),
            Isect::AaBox { min, max } => nearest(&[
                (p.x - max[0]).abs(),
                (p.x - min[0]).abs(),
                (p.y - max[1]).abs(),
                (p.y - min[1]).abs(),
                (p.z - max[2]).abs(),
                (p.z - min[2]).abs(),
            ]),
            Isect::Cuboid { c, rows, half } => {
                let rel = p - c;
                let l = [rows[0].dot(&rel), rows[1].dot(&rel), rows[2].dot(&rel)];
                nearest(&[
                    (l[0] - half[0]).abs(),
                    (l[0] + half[0]).abs(),
                    (l[1] - half[1]).abs(),
                    (l[1] + half[1]).abs(),
                    (l[2] - half[2]).abs(),
                    (l[2] + half[2]).abs(),
                ])
            }
            Isect::Cylinder { cx, cy, z0, z1, r } => {
                let radial = ((p.x - cx).powi(2) + (p.y - cy).powi(2)).sqrt();
                nearest(&[(radial - r).abs(), (p.z - z1).abs(), (p.z - z0).abs()])
            }
            Isect::Ramp {
                c, rows, planes, ..
            } => {
                let rel = p - c;
                let l = V3::new(rows[0].dot(&rel), rows[1].dot(&rel), rows[2].dot(&rel));
                let mut dists = [0.0; 5];
                for (k, (n, dist)) in planes.iter().enumerate() {
                    dists[k] = (dist - n.dot(&l)).abs();
                }
                nearest(&dists)
            }
        }
    }
}

/// A ray with its reciprocal direction, computed once per cast (also as plain arrays, which
/// index without checks in the box test).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ray {
    pub(crate) o: V3,
    pub(crate) d: V3,
    oa: [f64; 3],
    inva: [f64; 3],
}

impl Ray {
    pub(crate) fn new(o: V3, d: V3) -> Ray {
        Ray {
            o,
            d,
            oa: o.into(),
            inva: [d.x, d.y, d.z].map(|x| 1.0 / nonzero(x)),
        }
    }

    pub(crate) fn moved(&self, shift: [f64; 3]) -> Ray {
        let o = self.o - V3::from(shift);
        Ray {
            o,
            oa: o.into(),
            ..*self
        }
    }
}

/// A direction component made safe to invert: a zero would give 0 × ∞ = NaN on a slab
/// boundary; 1e-300 keeps every product finite or signed-infinite.
#[inline]
fn nonzero(x: f64) -> f64 {
    if x.abs() < 1e-300 {
        1e-300f64.copysign(x)
    } else {
        x
    }
}

/// For a convex solid entered at `lo` and left at `hi`: the entry if it is in range, else the
/// exit (the ray starts inside).
#[inline]
fn pick(lo: f64, hi: f64, t_min: f64, t_max: f64) -> Option<f64> {
    if lo > hi {
        None
    } else if lo > t_min && lo < t_max {
        Some(lo)
    } else if lo <= t_min && hi > t_min && hi < t_max {
        Some(hi)
    } else {
        None
    }
}

impl Isect {
    /// The outward normal and (u, v) of `face` at `p` (scene frame, the shape at its own place).
    #[inline]
    pub(crate) fn surface(&self, p: &V3, face: u8) -> (V3, f64, f64) {
        let axes = |axis: usize| match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
        match self {
            Isect::Rect { c, n, u, v, hu, hv } => {
                let rel = p - c;
                (
                    if face == 0 { *n } else { -n },
                    rel.dot(u) + hu,
                    rel.dot(v) + hv,
                )
            }
            Isect::AaBox { min, .. } => {
                let min = V3::from(*min);
                let axis = usize::from(face / 2);
                let mut n = V3::zeros();
                n[axis] = sign;
                let (a, b) = axes(axis);
                (n, p[a] - min[a], p[b] - min[b])
            }
            Isect::Cuboid { c, rows, half } => {
                let rel = p - c;
                let axis = usize::from(face / 2);
                let (a, b) = axes(axis);
                (
                    rows[axis] * sign,
                    rows[a].dot(&rel) + half[a],
                    rows[b].dot(&rel) + half[b],
                )
            }
            Isect::Cylinder { cx, cy, z0, r, .. } => {
                let (x, y) = (p.x - cx, p.y - cy);
                match face {
                    0 => {
                        let theta = y.atan2(x).rem_euclid(std::f64::consts::TAU);
                        (V3::new(x, y, 0.0) / *r, r * theta, p.z - z0)
                    }
                    1 => (V3::z(), x + r, y + r),
                    _ => (-V3::z(), x + r, y + r),
                }
            }
            Isect::Ramp {
                c,
                rows,
                planes,
                length,
                width,
                height,
            } => {
                let rel = p - c;
                let l = V3::new(rows[0].dot(&rel), rows[1].dot(&rel), rows[2].dot(&rel));
                let w = 0.5 * width;
                let n_local = planes[usize::from(face).min(4)].0;
                let n = rows[0] * n_local.x + rows[1] * n_local.y + rows[2] * n_local.z;
                let (u, v) = match face {
                    0 => (
                        l.x * (length * length + height * height).sqrt() / length,
                        l.y + w,
                    ),
                    1 => (l.y + w, l.z),
                    2 | 3 => (l.x, l.z),
                    _ => (l.x, l.y + w),
                };
                (n, u, v)
            }
        }
    }
}

//! Scenes: primitives with materials, a few moving occluders, and ray casting through a BVH.
//! Shapes and their intersection live in [`crate::geometry`], reflectivity in
//! [`crate::material`]; both are re-exported here. Units are metres; the scene frame is
//! right-handed with z up and z = 0 the floor.
//!
//! The floor and ceiling, whose boxes would cover every other box, are tested before the BVH
//! walk: they shorten the walk for most rays instead of lengthening it. Movers sit in the BVH
//! with the box they sweep along their whole path.

use nalgebra::Vector3;
use serde::Serialize;
use thiserror::Error;

use crate::bvh::{Aabb, Bvh};
pub use crate::geometry::{bounds, Shape};
use crate::geometry::{Isect, Ray};
pub use crate::material::{Decal, Material, Pattern, Reflect};
use crate::num::fract;

type V3 = Vector3<f64>;

/// What a scene cannot be built from.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SceneError {
    /// Sizes not positive, coordinates not finite, or rectangle axes not orthonormal.
    #[error("invalid shape {0:?}")]
    BadShape(Shape),
    /// A reflectivity outside [0, 1], a retro value not above 100, a non-positive period.
    #[error("invalid pattern {0:?}")]
    BadPattern(Pattern),
    /// A decal whose corners are not ordered or finite.
    #[error("material {material:?} has a decal with unordered or non-finite corners")]
    BadDecal {
        /// The material's name.
        material: String,
    },
    /// A coverage outside (0, 1].
    #[error("coverage must be in (0, 1], got {0}")]
    BadCoverage(f64),
    /// A primitive refers to a material that was not added.
    #[error("material {0} does not exist")]
    UnknownMaterial(u32),
    /// A mover's path is not finite or its speed not positive.
    #[error("a mover needs a finite path and a positive speed")]
    BadMover,
}

/// A material's index in its scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
pub struct MaterialId(pub u32);

/// A static primitive.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Primitive {
    /// Its geometry.
    pub shape: Shape,
    /// Its material.
    pub material: MaterialId,
    /// Index of its tag (what it is: "rack upright", "wall", …) in the scene's tag list.
    pub tag: u16,
}

/// A moving occluder: a shape that slides back and forth between its start and
/// `start + travel` at constant speed, without turning (a pedestrian, a forklift on its lane).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Mover {
    /// The shape at the start of its path.
    pub shape: Shape,
    /// Its material.
    pub material: MaterialId,
    /// Tag index.
    pub tag: u16,
    /// Displacement from the start to the far end of its path, m.
    pub travel: [f64; 3],
    /// Speed along the path, m/s.
    pub speed: f64,
    /// Time offset into its back-and-forth cycle at simulation time 0, s.
    pub phase: f64,
}

impl Mover {
    /// Its displacement from the start at time `t` (s since the simulation's start).
    #[inline]
    pub fn offset(&self, t: f64) -> [f64; 3] {
        let length = norm(self.travel);
        if length == 0.0 {
            return [0.0; 3];
        }
        let cycles = (t + self.phase) * self.speed / (2.0 * length);
        let x = 2.0 * fract(cycles);
        let f = if x <= 1.0 { x } else { 2.0 - x };
        self.travel.map(|c| c * f)
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Collects materials, primitives and movers, then builds the acceleration structure.
#[derive(Debug, Clone, Default)]
pub struct SceneBuilder {
    materials: Vec<Material>,
    primitives: Vec<Primitive>,
    movers: Vec<Mover>,
    tags: Vec<String>,
    movable: Vec<[u32; 2]>,
}

impl SceneBuilder {
    /// An empty builder.
    pub fn new() -> SceneBuilder {
        SceneBuilder::default()
    }

    /// Adds a material.
    pub fn material(&mut self, material: Material) -> Result<MaterialId, SceneError> {
        material.validate()?;
        self.materials.push(material);
        Ok(MaterialId(self.materials.len() as u32 - 1))
    }

    fn tag(&mut self, tag: &str) -> u16 {
        match self.tags.iter().position(|t| t == tag) {
            Some(i) => i as u16,
            None => {
                self.tags.push(tag.to_string());
                self.tags.len() as u16 - 1
            }
        }
    }

    /// Adds a static primitive tagged with what it is; returns its id.
    pub fn add(
        &mut self,
        shape: Shape,
        material: MaterialId,
        tag: &str,
    ) -> Result<u32, SceneError> {
        shape.validate()?;
        if material.0 as usize >= self.materials.len() {
            return Err(SceneError::UnknownMaterial(material.0));
        }
        let tag = self.tag(tag);
        self.primitives.push(Primitive {
            shape,
            material,
            tag,
        });
        Ok(self.primitives.len() as u32 - 1)
    }

    /// Adds a moving occluder.
    pub fn add_mover(
        &mut self,
        shape: Shape,
        material: MaterialId,
        tag: &str,
        travel: [f64; 3],
        speed: f64,
        phase: f64,
    ) -> Result<(), SceneError> {
        shape.validate()?;
        if material.0 as usize >= self.materials.len() {
            return Err(SceneError::UnknownMaterial(material.0));
        }
        if !(travel.iter().all(|x| x.is_finite())
            && speed > 0.0
            && speed.is_finite()
            && phase.is_finite())
        {
            return Err(SceneError::BadMover);
        }
        let tag = self.tag(tag);
        self.movers.push(Mover {
            shape,
            material,
            tag,
            travel,
            speed,
            phase,
        });
        Ok(())
    }

    /// Primitives added so far.
    pub fn primitive_count(&self) -> usize {
        self.primitives.len()
    }

    /// The primitives added so far, by id.
    pub fn primitives(&self) -> &[Primitive] {
        &self.primitives
    }

    /// The movers added so far.
    pub fn movers(&self) -> &[Mover] {
        &self.movers
    }

    /// Tag names so far.
    pub fn tags(&self) -> &[String] {
        &self.tags
    }

    /// Declares the primitives added since id `first` one movable object (a pallet with its
    /// load, a stack, a parked car): goods that may be somewhere else on another day, unlike
    /// walls, racks and pillars. Nothing is recorded when no primitive was added.
    pub fn mark_movable(&mut self, first: u32) {
        let end = self.primitives.len() as u32;
        if first < end {
            self.movable.push([first, end]);
        }
    }

    /// The movable objects, each as the id range `[first, end)` of its primitives.
    pub fn movable_objects(&self) -> &[[u32; 2]] {
        &self.movable
    }

    /// Moves movable object `index` by `d`.
    pub fn shift_movable(&mut self, index: usize, d: [f64; 3]) {
        let [first, end] = self.movable[index];
        for p in &mut self.primitives[first as usize..end as usize] {
            p.shape = p.shape.translated(d);
        }
    }

    /// Removes the movable objects whose indices are listed; the ids of later primitives
    /// shift down accordingly.
    pub fn remove_movables(&mut self, indices: &[usize]) {
        let mut gone = vec![false; self.primitives.len()];
        for &i in indices {
            let [first, end] = self.movable[i];
            gone[first as usize..end as usize].fill(true);
        }
        // New id of every kept primitive: the kept ones before it.
        let mut new_id = Vec::with_capacity(gone.len() + 1);
        let mut kept = 0u32;
        for &g in &gone {
            new_id.push(kept);
            kept += u32::from(!g);
        }
        new_id.push(kept);
        let mut k = 0;
        self.primitives.retain(|_| {
            k += 1;
            !gone[k - 1]
        });
        let mut index = 0;
        self.movable.retain(|_| {
            index += 1;
            !indices.contains(&(index - 1))
        });
        for range in &mut self.movable {
            *range = range.map(|id| new_id[id as usize]);
        }
    }

    /// Keeps the first `n` movers only.
    pub fn keep_movers(&mut self, n: usize) {
        self.movers.truncate(n);
    }

    /// Adds a mover like `mover` at another phase of its back-and-forth.
    pub fn copy_mover(&mut self, mover: &Mover, phase: f64) {
        self.movers.push(Mover { phase, ..*mover });
    }

    /// Builds the scene: decal grids, the floor/ceiling list and the BVH over the rest.
    pub fn build(mut self) -> Scene {
        for m in &mut self.materials {
            m.index_decals();
        }
        let boxes: Vec<Aabb> = self.primitives.iter().map(|p| bounds(&p.shape)).collect();
        let scene_box = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        let footprint = |b: &Aabb| (b.max[0] - b.min[0]).max(0.0) * (b.max[1] - b.min[1]).max(0.0);
        let scene_footprint = footprint(&scene_box);
        let (mut big, mut rest) = (Vec::new(), Vec::new());
        for (i, b) in boxes.iter().enumerate() {
            // Floors and ceilings: boxes covering a quarter of the scene's footprint.
            if footprint(b) > 0.25 * scene_footprint {
                big.push(i as u32);
            } else {
                rest.push(i as u32);
            }
        }
        // Movers join the tree with the box they sweep along their whole path, so that only rays
        // passing near one test it.
        let n = self.primitives.len() as u32;
        let mut rest_boxes: Vec<Aabb> = rest.iter().map(|&i| boxes[i as usize]).collect();
        for (k, m) in self.movers.iter().enumerate() {
            let b = bounds(&m.shape);
            let end = Aabb {
                min: [0, 1, 2].map(|i| b.min[i] + m.travel[i]),
                max: [0, 1, 2].map(|i| b.max[i] + m.travel[i]),
            };
            rest.push(n + k as u32);
            rest_boxes.push(b.union(&end));
        }
        let bvh = Bvh::build(&rest_boxes);
        let mut isects: Vec<Isect> = self
            .primitives
            .iter()
            .map(|p| Isect::new(&p.shape))
            .collect();
        isects.extend(self.movers.iter().map(|m| Isect::new(&m.shape)));
        let leaf_ids: Vec<u32> = bvh.items().iter().map(|&k| rest[k as usize]).collect();
        let leaf_isects = leaf_ids
            .iter()
            .map(|&i| isects[i as usize].clone())
            .collect();
        let big = big
            .into_iter()
            .map(|i| (isects[i as usize].clone(), i))
            .collect();
        Scene {
            materials: self.materials,
            primitives: self.primitives,
            movers: self.movers,
            tags: self.tags,
            movable: self.movable,
            bounds: scene_box,
            bvh,
            leaf_ids,
            leaf_isects,
            big,
            isects,
        }
    }
}

/// A ray's nearest intersection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) direction from the origin, m.
    pub t: f64,
    /// The object hit: a primitive id, or `primitive_count() + k` for mover `k`.
    pub id: u32,
    /// The face hit (see the module docs).
    pub face: u8,
}

/// What a ray finds at its hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    /// The hit point, scene frame.
    pub point: [f64; 3],
    /// The surface normal, facing the ray's origin.
    pub normal: [f64; 3],
    /// cos of the angle between the ray and the normal, in [0, 1].
    pub cos_incidence: f64,
    /// The reflectivity there.
    pub reflect: Reflect,
    /// The material's coverage.
    pub coverage: f64,
    /// The radius, when the object is a thin pole (the beam may be wider than it).
    pub pole_radius: Option<f64>,
}

/// A built scene: immutable, cheap to cast rays into, shareable between threads.
#[derive(Debug, Clone)]
pub struct Scene {
    materials: Vec<Material>,
    primitives: Vec<Primitive>,
    movers: Vec<Mover>,
    tags: Vec<String>,
    movable: Vec<[u32; 2]>,
    bounds: Aabb,
    bvh: Bvh,
    leaf_ids: Vec<u32>,
    leaf_isects: Vec<Isect>,
    big: Vec<(Isect, u32)>,
    /// By object id (primitives, then movers), for sampling.
    isects: Vec<Isect>,
}

impl Scene {
    /// Materials by id.
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Static primitives by id.
    pub fn primitives(&self) -> &[Primitive] {
        &self.primitives
    }

    /// Moving occluders.
    pub fn movers(&self) -> &[Mover] {
        &self.movers
    }

    /// Tag names.
    pub fn tags(&self) -> &[String] {
        &self.tags
    }

    /// The movable objects, each as the id range `[first, end)` of its primitives (see
    /// [`SceneBuilder::mark_movable`]).
    pub fn movable_objects(&self) -> &[[u32; 2]] {
        &self.movable
    }

    /// The box around every static primitive.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Nodes of the BVH (for reports).
    pub fn bvh_nodes(&self) -> usize {
        self.bvh.node_count()
    }

    /// The tag of an object id (a primitive or a mover).
    pub fn tag_of(&self, id: u32) -> &str {
        let tag = match self.primitives.get(id as usize) {
            Some(p) => p.tag,
            None => self.movers[id as usize - self.primitives.len()].tag,
        };
        &self.tags[usize::from(tag)]
    }

    /// Object counts per tag, in tag order.
    pub fn tag_counts(&self) -> Vec<(String, usize)> {
        let mut counts = vec![0usize; self.tags.len()];
        for p in &self.primitives {
            counts[usize::from(p.tag)] += 1;
        }
        for m in &self.movers {
            counts[usize::from(m.tag)] += 1;
        }
        self.tags.iter().cloned().zip(counts).collect()
    }

    /// The nearest hit of the ray `origin + t·dir` (`dir` a unit vector) with `t` in
    /// `(t_min, t_max)` at time `time_s` (s since the start, for the movers), skipping the
    /// objects in `exclude`.
    #[inline]
    pub fn cast(
        &self,
        origin: [f64; 3],
        dir: [f64; 3],
        t_min: f64,
        t_max: f64,
        time_s: f64,
        exclude: &[u32],
    ) -> Option<Hit> {
        let ray = Ray::new(V3::from(origin), V3::from(dir));
        let mut best: Option<(f64, u32)> = None;
        let mut t_best = t_max;
        for (isect, id) in &self.big {
            if exclude.contains(id) {
                continue;
            }
            if let Some(t) = isect.intersect(&ray, t_min, t_best) {
                t_best = t;
                best = Some((t, *id));
            }
        }
        let n = self.primitives.len() as u32;
        let mut mover_ray = None;
        self.bvh.traverse(origin, dir, t_min, t_best, |k, t_max| {
            let id = self.leaf_ids[k];
            if exclude.contains(&id) {
                return None;
            }
            if id < n {
                let t = self.leaf_isects[k].intersect(&ray, t_min, t_max)?;
                best = Some((t, id));
                return Some(t);
            }
            // A mover: its shape where it is at this instant.
            let local = ray.moved(self.movers[(id - n) as usize].offset(time_s));
            let t = self.leaf_isects[k].intersect(&local, t_min, t_max)?;
            best = Some((t, id));
            mover_ray = Some(local);
            Some(t)
        });
        let (t, id) = best?;
        let local = match mover_ray {
            Some(r) if id >= n => r,
            _ => ray,
        };
        let face = self.isects[id as usize].face_at(&(local.o + local.d * t), &local.d);
        Some(Hit { t, id, face })
    }

    /// The surface at a hit returned by [`Scene::cast`] for the same ray and time.
    #[inline]
    pub fn sample(&self, hit: &Hit, origin: [f64; 3], dir: [f64; 3], time_s: f64) -> SurfaceSample {
        let d = V3::from(dir);
        let n = self.primitives.len();
        let (shape, material, shift) = match self.primitives.get(hit.id as usize) {
            Some(p) => (&p.shape, p.material, V3::zeros()),
            None => {
                let m = &self.movers[hit.id as usize - n];
                (&m.shape, m.material, V3::from(m.offset(time_s)))
            }
        };
        let point = V3::from(origin) + d * hit.t;
        let (normal, u, v) = self.isects[hit.id as usize].surface(&(point - shift), hit.face);
        let cos = normal.dot(&d);
        let normal = if cos > 0.0 { -normal } else { normal };
        let material = &self.materials[material.0 as usize];
        SurfaceSample {
            point: point.into(),
            normal: normal.into(),
            cos_incidence: cos.abs().min(1.0),
            reflect: material.reflect(hit.face, u, v),
            coverage: material.coverage,
            pole_radius: match shape {
                Shape::Pole { radius, .. } => Some(*radius),
                _ => None,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn single(shape: Shape, material: Material) -> Scene {
        let mut b = SceneBuilder::new();
        let m = b.material(material).unwrap();
        b.add(shape, m, "thing").unwrap();
        b.build()
    }

    fn cast(scene: &Scene, o: [f64; 3], d: [f64; 3]) -> Option<(Hit, SurfaceSample)> {
        let n = norm(d);
        let d = d.map(|x| x / n);
        let h = scene.cast(o, d, 0.0, 100.0, 0.0, &[])?;
        Some((h, scene.sample(&h, o, d, 0.0)))
    }

    #[test]
    fn rectangle_hit_normal_and_decal() {
        let wall = Shape::wall([0.0, 5.0], [10.0, 5.0], 0.0, 3.0);
        let mat = Material::diffuse("wall", 0.5).with_decal(Decal::new(
            [2.0, 1.0],
            [3.0, 2.0],
            Pattern::uniform(0.9),
        ));
        let s = single(wall, mat);
        // Face 0 of a→b = +x looks right, to −y, where the ray comes from.
        let (h, smp) = cast(&s, [2.5, 0.0, 1.5], [0.0, 1.0, 0.0]).unwrap();
        assert!((h.t - 5.0).abs() < 1e-12);
        assert_eq!(h.face, 0);
        assert_eq!(smp.normal, [0.0, -1.0, 0.0]);
        assert_eq!(smp.reflect, Reflect::Diffuse(0.9));
        let (_, smp) = cast(&s, [5.0, 0.0, 1.5], [0.0, 1.0, 0.0]).unwrap();
        assert_eq!(smp.reflect, Reflect::Diffuse(0.5));
        assert!(
            cast(&s, [11.0, 0.0, 1.5], [0.0, 1.0, 0.0]).is_none(),
            "beyond the wall's end"
        );
    }

    #[test]
    fn rotated_box_faces_and_uv() {
        let shape = Shape::Cuboid {
            center: [10.0, 0.0, 1.0],
            yaw: 0.3,
            pitch: 0.0,
            roll: 0.0,
            half: [1.0, 2.0, 1.0],
        };
        let mat = Material::diffuse("box", 0.2).with_decal(Decal::on_face(
            1,
            [0.0, 0.0],
            [4.0, 2.0],
            Pattern::Retro { value: 200 },
        ));
        let s = single(shape, mat);
        let (h, smp) = cast(&s, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]).unwrap();
        // The −x face (face 1) of the box faces the origin.
        assert_eq!(h.face, 1);
        assert_eq!(smp.reflect, Reflect::Retro(200));
        // Its plane: x_local = −1 → distance along +x is 10 − 1/cos(0.3) at y = 0.
        assert!((h.t - (10.0 - 1.0 / 0.3f64.cos())).abs() < 1e-9, "{}", h.t);
        assert!((smp.cos_incidence - 0.3f64.cos()).abs() < 1e-9);
        // From above: the +z face, which has no decal.
        let (h, smp) = cast(&s, [10.0, 0.0, 5.0], [0.0, 0.0, -1.0]).unwrap();
        assert_eq!((h.face, smp.reflect), (4, Reflect::Diffuse(0.2)));
        assert!((h.t - 3.0).abs() < 1e-12);
        // From inside (a sensor must never be inside, but the exit is still found).
        let (h, _) = cast(&s, [10.0, 0.0, 1.0], [0.0, 0.0, 1.0]).unwrap();
        assert_eq!((h.face, h.t), (4, 1.0));
    }

    #[test]
    fn cylinder_side_caps_and_arc_length() {
        let shape = Shape::Cylinder {
            base: [5.0, 0.0, 0.0],
            height: 2.0,
            radius: 0.5,
        };
        let s = single(
            shape,
            Material::new("stripes", Pattern::stripes_u(0.9, 0.1, 0.5, 0.5)),
        );
        let (h, smp) = cast(&s, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]).unwrap();
        assert!((h.t - 4.5).abs() < 1e-12);
        assert_eq!(h.face, 0);
        // The hit is at angle π: arc length 0.5π = 1.571, phase 3.14 periods → 0.14 < 0.5 → rho_a.
        assert_eq!(smp.reflect, Reflect::Diffuse(0.9));
        assert!((smp.normal[0] + 1.0).abs() < 1e-12);
        let (h, _) = cast(&s, [5.2, 0.1, 10.0], [0.0, 0.0, -1.0]).unwrap();
        assert_eq!((h.face, h.t), (1, 8.0));
        assert!(
            cast(&s, [0.0, 0.0, 2.5], [1.0, 0.0, 0.0]).is_none(),
            "above the top"
        );
    }

    #[test]
    fn ramp_slope_and_back() {
        let shape = Shape::Ramp {
            base: [0.0, 0.0, 0.0],
            yaw: 0.0,
            length: 4.0,
            width: 2.0,
            height: 1.0,
        };
        let s = single(shape, Material::diffuse("ramp", 0.4));
        // Straight down onto the middle of the slope: z = 0.5 at x = 2.
        let (h, smp) = cast(&s, [2.0, 0.0, 5.0], [0.0, 0.0, -1.0]).unwrap();
        assert_eq!(h.face, 0);
        assert!((h.t - 4.5).abs() < 1e-12);
        let expect = 4.0 / 17f64.sqrt();
        assert!((smp.cos_incidence - expect).abs() < 1e-12);
        // Horizontally from behind at z = 0.5: the vertical back at x = 4.
        let (h, _) = cast(&s, [10.0, 0.0, 0.5], [-1.0, 0.0, 0.0]).unwrap();
        assert_eq!((h.face, h.t), (1, 6.0));
        // Over the ramp: miss.
        assert!(cast(&s, [-5.0, 0.0, 1.1], [1.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn movers_move_and_exclusion_skips() {
        let mut b = SceneBuilder::new();
        let m = b.material(Material::diffuse("m", 0.5)).unwrap();
        let wall = b
            .add(Shape::wall([10.0, -5.0], [10.0, 5.0], 0.0, 3.0), m, "wall")
            .unwrap();
        b.add_mover(
            Shape::Cylinder {
                base: [5.0, -2.0, 0.0],
                height: 2.0,
                radius: 0.3,
            },
            m,
            "person",
            [0.0, 4.0, 0.0],
            1.0,
            0.0,
        )
        .unwrap();
        let s = b.build();
        let (o, d) = ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
        // At t = 0 the person is at y = −2: the ray reaches the wall.
        assert_eq!(s.cast(o, d, 0.0, 100.0, 0.0, &[]).unwrap().id, wall);
        // At t = 2 s it is at y = 0, in the way.
        let h = s.cast(o, d, 0.0, 100.0, 2.0, &[]).unwrap();
        assert_eq!(s.tag_of(h.id), "person");
        assert!((h.t - 4.7).abs() < 1e-9);
        let n = s.sample(&h, o, d, 2.0).normal;
        assert!(
            (n[0] + 1.0).abs() < 1e-12 && n[1].abs() < 1e-12 && n[2] == 0.0,
            "{n:?}"
        );
        // At t = 6 s it is back at y = −2 (4 m out, 4 m back at 1 m/s: period 8 s, 6 s → 2 m).
        assert!((s.movers()[0].offset(6.0)[1] - 2.0).abs() < 1e-12);
        // Excluding the person finds the wall behind.
        assert_eq!(s.cast(o, d, 0.0, 100.0, 2.0, &[h.id]).unwrap().id, wall);
    }

    #[test]
    fn invalid_inputs_are_refused() {
        let mut b = SceneBuilder::new();
        assert!(b.material(Material::diffuse("x", 1.5)).is_err());
        assert!(b
            .material(Material::new("r", Pattern::Retro { value: 90 }))
            .is_err());
        assert!(b
            .material(Material::diffuse("x", 0.5).with_coverage(0.0))
            .is_err());
        let m = b.material(Material::diffuse("x", 0.5)).unwrap();
        assert!(b
            .add(Shape::aabox([0.0; 3], [0.0, 1.0, 1.0]), m, "flat")
            .is_err());
        let skew = Shape::Rect {
            center: [0.0; 3],
            u: [1.0, 0.0, 0.0],
            v: [0.6, 0.8, 0.0],
            half: [1.0, 1.0],
        };
        assert!(b.add(skew, m, "skew").is_err());
        assert!(b
            .add(Shape::aabox([0.0; 3], [1.0; 3]), MaterialId(9), "x")
            .is_err());
    }
}

//! How surfaces reflect: reflectivity patterns over a surface's (u, v) coordinates (uniform,
//! stripes, checkers, retro-reflective sheeting), decals painted over a base pattern (labels,
//! posters, floor markings, doors), and a material's coverage of the beam. Materials with many
//! decals index them by a uniform grid so that a lookup costs a few comparisons.

use serde::Serialize;

use crate::num::{floor, fract};
use crate::scene::SceneError;

/// What a surface point does with the laser.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reflect {
    /// A Lambertian surface of reflectivity ρ in [0, 1].
    Diffuse(f64),
    /// Retro-reflective sheeting reporting this value (101–255) at normal incidence.
    Retro(u8),
}

/// A reflectivity function over a surface's (u, v) coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Pattern {
    /// One diffuse reflectivity.
    Uniform {
        /// ρ in [0, 1].
        rho: f64,
    },
    /// Parallel stripes: `rho_a` over the first `duty` fraction of every `period`, measured
    /// along the direction at `angle` (rad) from the u axis towards v; `rho_b` elsewhere.
    Stripes {
        /// ρ of the first part of each period.
        rho_a: f64,
        /// ρ of the rest.
        rho_b: f64,
        /// Period, m.
        period: f64,
        /// Fraction of the period in `rho_a`, in [0, 1].
        duty: f64,
        /// Direction across the stripes, rad from u towards v.
        angle: f64,
    },
    /// A checkerboard of `size`-metre squares, `rho_a` on the square at the origin.
    Checker {
        /// ρ of the squares at even (i + j).
        rho_a: f64,
        /// ρ of the others.
        rho_b: f64,
        /// Square side, m.
        size: f64,
    },
    /// Retro-reflective sheeting.
    Retro {
        /// Reported value at normal incidence, 101–255.
        value: u8,
    },
}

impl Pattern {
    /// A uniform diffuse pattern.
    pub const fn uniform(rho: f64) -> Pattern {
        Pattern::Uniform { rho }
    }

    /// Stripes across u (the stripes run along v).
    pub const fn stripes_u(rho_a: f64, rho_b: f64, period: f64, duty: f64) -> Pattern {
        Pattern::Stripes {
            rho_a,
            rho_b,
            period,
            duty,
            angle: 0.0,
        }
    }

    /// Stripes across v (the stripes run along u).
    pub const fn stripes_v(rho_a: f64, rho_b: f64, period: f64, duty: f64) -> Pattern {
        Pattern::Stripes {
            rho_a,
            rho_b,
            period,
            duty,
            angle: std::f64::consts::FRAC_PI_2,
        }
    }

    /// The reflectivity at (u, v).
    #[inline]
    pub fn eval(&self, u: f64, v: f64) -> Reflect {
        match *self {
            Pattern::Uniform { rho } => Reflect::Diffuse(rho),
            Pattern::Stripes {
                rho_a,
                rho_b,
                period,
                duty,
                angle,
            } => {
                let c = if angle == 0.0 {
                    u
                } else {
                    u * angle.cos() + v * angle.sin()
                };
                let phase = fract(c / period);
                Reflect::Diffuse(if phase < duty { rho_a } else { rho_b })
            }
            Pattern::Checker { rho_a, rho_b, size } => {
                let parity = (floor(u / size) as i64 + floor(v / size) as i64) & 1;
                Reflect::Diffuse(if parity == 0 { rho_a } else { rho_b })
            }
            Pattern::Retro { value } => Reflect::Retro(value),
        }
    }

    pub(crate) fn validate(&self) -> Result<(), SceneError> {
        let rho_ok = |r: f64| (0.0..=1.0).contains(&r);
        let ok = match *self {
            Pattern::Uniform { rho } => rho_ok(rho),
            Pattern::Stripes {
                rho_a,
                rho_b,
                period,
                duty,
                angle,
            } => {
                rho_ok(rho_a)
                    && rho_ok(rho_b)
                    && period > 0.0
                    && (0.0..=1.0).contains(&duty)
                    && angle.is_finite()
            }
            Pattern::Checker { rho_a, rho_b, size } => rho_ok(rho_a) && rho_ok(rho_b) && size > 0.0,
            Pattern::Retro { value } => value > 100,
        };
        if ok {
            Ok(())
        } else {
            Err(SceneError::BadPattern(*self))
        }
    }
}

/// A painted or stuck-on rectangle in a surface's (u, v) coordinates: a floor marking, a label,
/// a poster, a door leaf, a retro-reflective marker. Its pattern is evaluated relative to its
/// own lower corner. Later decals cover earlier ones.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Decal {
    /// The face it is on, or every face.
    pub face: Option<u8>,
    /// Lower (u, v) corner, m.
    pub min: [f64; 2],
    /// Upper (u, v) corner, m.
    pub max: [f64; 2],
    /// What it looks like.
    pub pattern: Pattern,
}

impl Decal {
    /// A decal on every face of its primitive.
    pub fn new(min: [f64; 2], max: [f64; 2], pattern: Pattern) -> Decal {
        Decal {
            face: None,
            min,
            max,
            pattern,
        }
    }

    /// A decal on one face.
    pub fn on_face(face: u8, min: [f64; 2], max: [f64; 2], pattern: Pattern) -> Decal {
        Decal {
            face: Some(face),
            min,
            max,
            pattern,
        }
    }

    #[inline]
    fn contains(&self, face: u8, u: f64, v: f64) -> bool {
        self.face.is_none_or(|f| f == face)
            && u >= self.min[0]
            && u < self.max[0]
            && v >= self.min[1]
            && v < self.max[1]
    }
}

/// How a surface reflects: a base pattern, decals over it, and how much of the beam it
/// intercepts (1 = opaque; less for chain-link fences and foliage, which let part of the beam
/// through to what is behind and so make second echoes).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Material {
    /// A name for reports.
    pub name: String,
    /// The pattern where no decal is.
    pub base: Pattern,
    /// Decals, later ones on top.
    pub decals: Vec<Decal>,
    /// Fraction of the beam intercepted, in (0, 1].
    pub coverage: f64,
    #[serde(skip)]
    grid: Option<DecalGrid>,
}

impl Material {
    /// An opaque material with a base pattern.
    pub fn new(name: impl Into<String>, base: Pattern) -> Material {
        Material {
            name: name.into(),
            base,
            decals: Vec::new(),
            coverage: 1.0,
            grid: None,
        }
    }

    /// An opaque uniform diffuse material.
    pub fn diffuse(name: impl Into<String>, rho: f64) -> Material {
        Material::new(name, Pattern::uniform(rho))
    }

    /// Adds a decal (builder style).
    pub fn with_decal(mut self, decal: Decal) -> Material {
        self.decals.push(decal);
        self
    }

    /// Sets the coverage (builder style).
    pub fn with_coverage(mut self, coverage: f64) -> Material {
        self.coverage = coverage;
        self
    }

    /// The reflectivity at (u, v) of `face`.
    #[inline]
    pub fn reflect(&self, face: u8, u: f64, v: f64) -> Reflect {
        let decal = match &self.grid {
            Some(grid) => grid.find(&self.decals, face, u, v),
            None => self.decals.iter().rev().find(|d| d.contains(face, u, v)),
        };
        match decal {
            Some(d) => d.pattern.eval(u - d.min[0], v - d.min[1]),
            None => self.base.eval(u, v),
        }
    }

    /// Builds the decal grid when there are enough decals to need one.
    pub(crate) fn index_decals(&mut self) {
        self.grid = (self.decals.len() > GRID_THRESHOLD).then(|| DecalGrid::build(&self.decals));
    }

    pub(crate) fn validate(&self) -> Result<(), SceneError> {
        self.base.validate()?;
        for d in &self.decals {
            d.pattern.validate()?;
            if !(d.min[0] <= d.max[0] && d.min[1] <= d.max[1])
                || d.min.iter().chain(&d.max).any(|x| !x.is_finite())
            {
                return Err(SceneError::BadDecal {
                    material: self.name.clone(),
                });
            }
        }
        if !(self.coverage > 0.0 && self.coverage <= 1.0) {
            return Err(SceneError::BadCoverage(self.coverage));
        }
        Ok(())
    }
}

/// Decals with more than this many are indexed by a grid.
const GRID_THRESHOLD: usize = 8;
/// Grid cells at most per material.
const GRID_MAX_CELLS: f64 = 250_000.0;

/// A uniform grid over a material's decals in (u, v): each cell lists the decals overlapping it
/// in painter's order, as ranges into one array (no allocation per cell).
#[derive(Debug, Clone, PartialEq)]
struct DecalGrid {
    origin: [f64; 2],
    inv_cell: f64,
    dims: [usize; 2],
    starts: Vec<u32>,
    entries: Vec<u32>,
}

impl DecalGrid {
    fn build(decals: &[Decal]) -> DecalGrid {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for d in decals {
            for k in 0..2 {
                lo[k] = lo[k].min(d.min[k]);
                hi[k] = hi[k].max(d.max[k]);
            }
        }
        let extent = [(hi[0] - lo[0]).max(1e-3), (hi[1] - lo[1]).max(1e-3)];
        let mut cell = 1.0f64;
        while (extent[0] / cell).ceil() * (extent[1] / cell).ceil() > GRID_MAX_CELLS {
            cell *= 2.0;
        }
        let dims = [
            (extent[0] / cell).ceil() as usize + 1,
            (extent[1] / cell).ceil() as usize + 1,
        ];
        let cell_range = |d: &Decal, k: usize| {
            let a = ((d.min[k] - lo[k]) / cell).floor().max(0.0) as usize;
            let b = ((d.max[k] - lo[k]) / cell).floor().max(0.0) as usize;
            a.min(dims[k] - 1)..=b.min(dims[k] - 1)
        };
        let mut counts = vec![0u32; dims[0] * dims[1] + 1];
        for d in decals {
            for i in cell_range(d, 0) {
                for j in cell_range(d, 1) {
                    counts[i * dims[1] + j + 1] += 1;
                }
            }
        }
        for c in 1..counts.len() {
            counts[c] += counts[c - 1];
        }
        let starts = counts.clone();
        let mut fill = counts;
        let mut entries = vec![0u32; *starts.last().unwrap_or(&0) as usize];
        for (n, d) in decals.iter().enumerate() {
            for i in cell_range(d, 0) {
                for j in cell_range(d, 1) {
                    let c = i * dims[1] + j;
                    entries[fill[c] as usize] = n as u32;
                    fill[c] += 1;
                }
            }
        }
        DecalGrid {
            origin: lo,
            inv_cell: 1.0 / cell,
            dims,
            starts,
            entries,
        }
    }

    #[inline]
    fn find<'a>(&self, decals: &'a [Decal], face: u8, u: f64, v: f64) -> Option<&'a Decal> {
        let i = floor((u - self.origin[0]) * self.inv_cell);
        let j = floor((v - self.origin[1]) * self.inv_cell);
        if i < 0.0 || j < 0.0 || i >= self.dims[0] as f64 || j >= self.dims[1] as f64 {
            return None;
        }
        let c = i as usize * self.dims[1] + j as usize;
        let range = self.starts[c] as usize..self.starts[c + 1] as usize;
        self.entries[range]
            .iter()
            .rev()
            .map(|&n| &decals[n as usize])
            .find(|d| d.contains(face, u, v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decal_grid_agrees_with_linear_search() {
        let mut mat = Material::diffuse("floor", 0.3);
        for i in 0..200 {
            let x = i as f64 * 0.7;
            let v = (i % 7) as f64;
            mat.decals.push(Decal::new(
                [x, v],
                [x + 1.5, v + 0.4],
                Pattern::uniform(0.01 * (i % 90) as f64),
            ));
        }
        let linear = mat.clone();
        mat.index_decals();
        assert!(mat.grid.is_some() && linear.grid.is_none());
        for k in 0..20_000 {
            let (u, v) = ((k as f64 * 0.0137) % 150.0, (k as f64 * 0.391) % 8.0);
            assert_eq!(mat.reflect(0, u, v), linear.reflect(0, u, v), "at {u}, {v}");
        }
    }

    #[test]
    fn patterns_and_face_specific_decals() {
        let stripes = Pattern::stripes_u(0.9, 0.1, 0.5, 0.2);
        assert_eq!(stripes.eval(0.05, 3.0), Reflect::Diffuse(0.9));
        assert_eq!(stripes.eval(0.3, 3.0), Reflect::Diffuse(0.1));
        assert_eq!(
            stripes.eval(-0.45, 0.0),
            Reflect::Diffuse(0.9),
            "periodic below zero too"
        );
        let checker = Pattern::Checker {
            rho_a: 0.8,
            rho_b: 0.2,
            size: 1.0,
        };
        assert_eq!(checker.eval(0.5, 0.5), Reflect::Diffuse(0.8));
        assert_eq!(checker.eval(1.5, 0.5), Reflect::Diffuse(0.2));
        assert_eq!(checker.eval(-0.5, 0.5), Reflect::Diffuse(0.2));
        let m = Material::diffuse("box", 0.4).with_decal(Decal::on_face(
            2,
            [0.0, 0.0],
            [1.0, 1.0],
            Pattern::Retro { value: 180 },
        ));
        assert_eq!(m.reflect(2, 0.5, 0.5), Reflect::Retro(180));
        assert_eq!(
            m.reflect(3, 0.5, 0.5),
            Reflect::Diffuse(0.4),
            "other faces are bare"
        );
        assert_eq!(m.reflect(2, 1.5, 0.5), Reflect::Diffuse(0.4));
    }
}

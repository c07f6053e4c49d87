//! Path geometry: the periodic cubic spline a loop is drawn with, and waypoints along a
//! polygon with rounded corners (straight runs and arcs) that scenarios lay their loops out with.

use nalgebra::{DMatrix, DVector};

/// A C² closed cubic spline through points with chord-length knots, one per coordinate.
pub(crate) struct PeriodicSpline {
    p: Vec<[f64; 2]>,
    m: Vec<[f64; 2]>,
    h: Vec<f64>,
}

impl PeriodicSpline {
    pub(crate) fn new(points: &[[f64; 2]], h: &[f64]) -> PeriodicSpline {
        let n = points.len();
        // The cyclic tridiagonal system for the second derivatives M:
        // h[i-1] M[i-1] + 2 (h[i-1] + h[i]) M[i] + h[i] M[i+1] = 6 (slope[i] − slope[i-1]).
        let mut a = DMatrix::<f64>::zeros(n, n);
        for i in 0..n {
            let prev = (i + n - 1) % n;
            a[(i, prev)] += h[prev];
            a[(i, i)] += 2.0 * (h[prev] + h[i]);
            a[(i, (i + 1) % n)] += h[i];
        }
        let lu = a.lu();
        let mut m = vec![[0.0; 2]; n];
        for c in 0..2 {
            let rhs = DVector::from_fn(n, |i, _| {
                let prev = (i + n - 1) % n;
                let next = (i + 1) % n;
                let s1 = (points[next][c] - points[i][c]) / h[i];
                let s0 = (points[i][c] - points[prev][c]) / h[prev];
                6.0 * (s1 - s0)
            });
            // The matrix is strictly diagonally dominant, hence invertible.
            let sol = lu.solve(&rhs).unwrap_or_else(|| DVector::zeros(n));
            for i in 0..n {
                m[i][c] = sol[i];
            }
        }
        PeriodicSpline {
            p: points.to_vec(),
            m,
            h: h.to_vec(),
        }
    }

    /// Position, first and second derivative on segment `i` at `x` ∈ [0, h[i]].
    pub(crate) fn eval(&self, i: usize, x: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
        let n = self.p.len();
        let j = (i + 1) % n;
        let h = self.h[i];
        let w = h - x;
        let mut p = [0.0; 2];
        let mut d1 = [0.0; 2];
        let mut d2 = [0.0; 2];
        for c in 0..2 {
            let (mi, mj) = (self.m[i][c], self.m[j][c]);
            let a = self.p[i][c] / h - mi * h / 6.0;
            let b = self.p[j][c] / h - mj * h / 6.0;
            p[c] = mi * w.powi(3) / (6.0 * h) + mj * x.powi(3) / (6.0 * h) + a * w + b * x;
            d1[c] = -mi * w * w / (2.0 * h) + mj * x * x / (2.0 * h) - a + b;
            d2[c] = mi * w / h + mj * x / h;
        }
        (p, d1, d2)
    }
}

/// Waypoints along a rounded rectangle-like polygon: straight runs sampled every `step` m and
/// each corner replaced by a circular arc of radius `radius` sampled every `radius · 0.2` rad.
/// `corners` are visited in order; consecutive corners must be farther apart than two radii.
pub fn rounded_polygon(corners: &[[f64; 2]], radius: f64, step: f64) -> Vec<[f64; 2]> {
    let n = corners.len();
    let mut out = Vec::new();
    let unit = |a: [f64; 2], b: [f64; 2]| {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let l = (dx * dx + dy * dy).sqrt();
        [dx / l, dy / l]
    };
    for i in 0..n {
        let (prev, cur, next) = (corners[(i + n - 1) % n], corners[i], corners[(i + 1) % n]);
        let (d_in, d_out) = (unit(prev, cur), unit(cur, next));
        let turn = (d_in[0] * d_out[1] - d_in[1] * d_out[0])
            .atan2(d_in[0] * d_out[0] + d_in[1] * d_out[1]);
        let cut = radius * (turn.abs() / 2.0).tan();
        let start = [cur[0] - d_in[0] * cut, cur[1] - d_in[1] * cut];
        // Arc centre: to the left of the incoming direction for a left turn.
        let side = turn.signum();
        let centre = [
            start[0] - d_in[1] * radius * side,
            start[1] + d_in[0] * radius * side,
        ];
        let a0 = (start[1] - centre[1]).atan2(start[0] - centre[0]);
        let steps = ((turn.abs() / 0.2).ceil() as usize).max(2);
        for k in 0..=steps {
            let a = a0 + turn * k as f64 / steps as f64;
            out.push([centre[0] + radius * a.cos(), centre[1] + radius * a.sin()]);
        }
        // The straight run to the next corner's arc.
        let end = [cur[0] + d_out[0] * cut, cur[1] + d_out[1] * cut];
        let next_turn = {
            let nn = corners[(i + 2) % n];
            let d2 = unit(next, nn);
            (d_out[0] * d2[1] - d_out[1] * d2[0]).atan2(d_out[0] * d2[0] + d_out[1] * d2[1])
        };
        let next_cut = radius * (next_turn.abs() / 2.0).tan();
        let run_end = [next[0] - d_out[0] * next_cut, next[1] - d_out[1] * next_cut];
        let run = ((run_end[0] - end[0]).powi(2) + (run_end[1] - end[1]).powi(2)).sqrt();
        let pieces = (run / step).round() as usize;
        for k in 1..pieces {
            let f = k as f64 / pieces as f64;
            out.push([
                end[0] + f * (run_end[0] - end[0]),
                end[1] + f * (run_end[1] - end[1]),
            ]);
        }
    }
    // The start: the middle of the first straight run, so a lap starts at cruise speed.
    dedup_close(rotate_to_longest_run(out))
}

fn rotate_to_longest_run(mut pts: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    let n = pts.len();
    if n < 3 {
        return pts;
    }
    // Find the longest stretch of collinear points and start in its middle.
    let straight = |i: usize| {
        let (a, b, c) = (pts[(i + n - 1) % n], pts[i], pts[(i + 1) % n]);
        ((b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])).abs() < 1e-9
    };
    let mut best = (0usize, 0usize);
    let mut i = 0;
    while i < n {
        if straight(i) {
            let start = i;
            while i < n && straight(i) {
                i += 1;
            }
            if i - start > best.1 {
                best = (start, i - start);
            }
        } else {
            i += 1;
        }
    }
    pts.rotate_left((best.0 + best.1 / 2) % n);
    pts
}

fn dedup_close(pts: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    let mut out: Vec<[f64; 2]> = Vec::with_capacity(pts.len());
    for p in pts {
        if out
            .last()
            .is_none_or(|q| (p[0] - q[0]).hypot(p[1] - q[1]) > 1e-3)
        {
            out.push(p);
        }
    }
    while out.len() > 1 && {
        let (a, b) = (out[0], out[out.len() - 1]);
        (a[0] - b[0]).hypot(a[1] - b[1]) <= 1e-3
    } {
        out.pop();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spline_interpolates_its_points_with_continuous_derivatives() {
        let pts: [[f64; 2]; 5] = [[0.0, 0.0], [4.0, 0.5], [6.0, 3.0], [3.0, 6.0], [-1.0, 3.0]];
        let n = pts.len();
        let h: Vec<f64> = (0..n)
            .map(|i| {
                let (a, b) = (pts[i], pts[(i + 1) % n]);
                (b[0] - a[0]).hypot(b[1] - a[1])
            })
            .collect();
        let s = PeriodicSpline::new(&pts, &h);
        for (i, pt) in pts.iter().enumerate() {
            let (p, d1, d2) = s.eval(i, 0.0);
            assert!((p[0] - pt[0]).abs() < 1e-12 && (p[1] - pt[1]).abs() < 1e-12);
            // The end of the previous segment meets this start in value, slope and curvature.
            let prev = (i + n - 1) % n;
            let (q, e1, e2) = s.eval(prev, h[prev]);
            for c in 0..2 {
                assert!(
                    (q[c] - p[c]).abs() < 1e-9
                        && (e1[c] - d1[c]).abs() < 1e-9
                        && (e2[c] - d2[c]).abs() < 1e-9
                );
            }
        }
    }

    #[test]
    fn rounded_polygons_start_mid_straight_and_keep_their_radius() {
        let corners = [[0.0, 0.0], [20.0, 0.0], [20.0, 10.0], [0.0, 10.0]];
        let pts = rounded_polygon(&corners, 2.0, 1.0);
        // The first point is in the middle of the longest straight run (a 16 m side).
        assert!(
            (pts[0][1]).abs() < 1e-9 && (pts[0][0] - 10.0).abs() < 1.0,
            "{:?}",
            pts[0]
        );
        // Every point is on the rounded rectangle: within the box, and the corner points on
        // their arcs.
        for p in &pts {
            assert!(p[0] > -1e-9 && p[0] < 20.0 + 1e-9 && p[1] > -1e-9 && p[1] < 10.0 + 1e-9);
            if p[0] < 2.0 && p[1] < 2.0 {
                assert!(((p[0] - 2.0).hypot(p[1] - 2.0) - 2.0).abs() < 1e-9);
            }
        }
    }
}

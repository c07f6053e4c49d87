//! The linear algebra under the pose graph: a block-sparse Cholesky factorisation of a
//! symmetric positive-definite matrix made of 6×6 blocks (one block row per free pose).
//! Elimination order by greedy minimum degree on the block graph (ties by index, so the order
//! and the result are deterministic), symbolic fill from the same elimination, then a
//! right-looking numeric factorisation and the two triangular solves.
//!
//! Why our own and not `faer`'s sparse Cholesky: a pose graph's blocks are dense 6×6 and few
//! per row, so block-level minimum degree with nalgebra's fixed-size blocks is both short
//! (~200 lines) and fast (the parking garage factorises in milliseconds), and it keeps `core`'s
//! dependencies to nalgebra — `faer` alone would add most of a minute of compilation on CI's
//! two cores.

use std::collections::BTreeSet;

use nalgebra::{Matrix6, Vector6};

/// The structure of the factor, computed once per graph shape.
#[derive(Debug, Clone)]
pub(crate) struct Symbolic {
    /// `position[v]`: when block `v` is eliminated.
    position: Vec<usize>,
    /// For each elimination step `k`, the (sorted) later steps whose rows are non-zero in
    /// column `k` of the factor.
    columns: Vec<Vec<usize>>,
}

impl Symbolic {
    /// Orders `n` blocks connected by `pairs` (off-diagonal non-zeros, either orientation) and
    /// computes the factor's structure.
    pub(crate) fn analyse(n: usize, pairs: impl IntoIterator<Item = (usize, usize)>) -> Self {
        let mut adjacency: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); n];
        for (a, b) in pairs {
            if a != b && a < n && b < n {
                adjacency[a].insert(b);
                adjacency[b].insert(a);
            }
        }
        let mut queue: BTreeSet<(usize, usize)> = (0..n).map(|v| (adjacency[v].len(), v)).collect();
        let mut position = vec![usize::MAX; n];
        let mut eliminated_neighbours: Vec<Vec<usize>> = Vec::with_capacity(n);
        while let Some((_, v)) = queue.pop_first() {
            position[v] = eliminated_neighbours.len();
            let neighbours: Vec<usize> = std::mem::take(&mut adjacency[v]).into_iter().collect();
            // Eliminating v makes its neighbours a clique (the fill).
            for &a in &neighbours {
                queue.remove(&(adjacency[a].len(), a));
                adjacency[a].remove(&v);
                for &b in &neighbours {
                    if a != b {
                        adjacency[a].insert(b);
                    }
                }
                queue.insert((adjacency[a].len(), a));
            }
            eliminated_neighbours.push(neighbours);
        }
        let columns = eliminated_neighbours
            .into_iter()
            .map(|neighbours| {
                let mut c: Vec<usize> = neighbours.into_iter().map(|v| position[v]).collect();
                c.sort_unstable();
                c
            })
            .collect();
        Self { position, columns }
    }

    /// Blocks in the factor (diagonal and below), a measure of fill.
    pub(crate) fn factor_blocks(&self) -> usize {
        self.columns.iter().map(|c| c.len() + 1).sum()
    }

    /// An empty matrix with this structure.
    pub(crate) fn matrix(&self) -> BlockMatrix {
        BlockMatrix {
            diagonal: vec![Matrix6::zeros(); self.columns.len()],
            lower: self
                .columns
                .iter()
                .map(|c| vec![Matrix6::zeros(); c.len()])
                .collect(),
        }
    }

    /// Adds `block` at (row block `r`, column block `c`) of the symmetric matrix, in the
    /// original numbering; (r, c) and (c, r) are the same entry, stored once.
    pub(crate) fn add(&self, m: &mut BlockMatrix, r: usize, c: usize, block: &Matrix6<f64>) {
        let (pr, pc) = (self.position[r], self.position[c]);
        if pr == pc {
            m.diagonal[pr] += block;
            return;
        }
        // Stored below the diagonal in elimination order: (later, earlier).
        let (row, col, b) = if pr > pc {
            (pr, pc, *block)
        } else {
            (pc, pr, block.transpose())
        };
        let slot = self.columns[col]
            .binary_search(&row)
            .expect("the block was declared to analyse");
        m.lower[col][slot] += b;
    }

    /// Solves `M·x = rhs` (blocks in the original numbering) by factorising `m` in place.
    /// `None` if `m` is not positive definite.
    pub(crate) fn solve(
        &self,
        m: &mut BlockMatrix,
        rhs: &[Vector6<f64>],
    ) -> Option<Vec<Vector6<f64>>> {
        let n = self.columns.len();
        // Factorise: M = L·Lᵀ, L's diagonal blocks lower-triangular.
        let mut inverse_diagonal = Vec::with_capacity(n);
        for k in 0..n {
            let l_kk = m.diagonal[k].cholesky()?.unpack();
            let inv = l_kk.try_inverse()?;
            let inv_t = inv.transpose();
            for block in &mut m.lower[k] {
                *block *= inv_t;
            }
            let column = &self.columns[k];
            for a in 0..column.len() {
                let i = column[a];
                let l_ik = m.lower[k][a];
                m.diagonal[i] -= l_ik * l_ik.transpose();
                for (b, &j) in column.iter().enumerate().take(a) {
                    let l_jk = m.lower[k][b];
                    let slot = self.columns[j]
                        .binary_search(&i)
                        .expect("the fill is symbolic");
                    m.lower[j][slot] -= l_ik * l_jk.transpose();
                }
            }
            m.diagonal[k] = l_kk;
            inverse_diagonal.push(inv);
        }
        // Forward: L·y = b.
        let mut y = vec![Vector6::zeros(); n];
        for (v, &p) in self.position.iter().enumerate() {
            y[p] = rhs[v];
        }
        for k in 0..n {
            y[k] = inverse_diagonal[k] * y[k];
            let yk = y[k];
            for (slot, &i) in self.columns[k].iter().enumerate() {
                y[i] -= m.lower[k][slot] * yk;
            }
        }
        // Backward: Lᵀ·x = y.
        for k in (0..n).rev() {
            let mut acc = y[k];
            for (slot, &i) in self.columns[k].iter().enumerate() {
                acc -= m.lower[k][slot].transpose() * y[i];
            }
            y[k] = inverse_diagonal[k].transpose() * acc;
        }
        Some(self.position.iter().map(|&p| y[p]).collect())
    }
}

/// A symmetric block matrix stored as its lower triangle in elimination order.
#[derive(Debug, Clone)]
pub(crate) struct BlockMatrix {
    diagonal: Vec<Matrix6<f64>>,
    lower: Vec<Vec<Matrix6<f64>>>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use std::ops::AddAssign;

    #[test]
    fn solves_like_a_dense_cholesky() {
        // A ring of 7 blocks with two chords: fill appears, the answer must not change.
        let n = 7;
        let mut pairs: Vec<(usize, usize)> = (0..n).map(|i| (i, (i + 1) % n)).collect();
        pairs.extend([(0, 3), (2, 5)]);
        let mut rng = glint_testkit::SeededRng::new(11);
        let mut next = || rng.centred();
        let mut dense = DMatrix::<f64>::zeros(6 * n, 6 * n);
        let symbolic = Symbolic::analyse(n, pairs.iter().copied());
        let mut m = symbolic.matrix();
        for &(a, b) in &pairs {
            let block = Matrix6::from_fn(|_, _| next());
            symbolic.add(&mut m, a, b, &block);
            dense.view_mut((6 * a, 6 * b), (6, 6)).add_assign(&block);
            dense
                .view_mut((6 * b, 6 * a), (6, 6))
                .add_assign(&block.transpose());
        }
        for v in 0..n {
            let block = Matrix6::identity() * 10.0;
            symbolic.add(&mut m, v, v, &block);
            dense.view_mut((6 * v, 6 * v), (6, 6)).add_assign(&block);
        }
        let rhs: Vec<Vector6<f64>> = (0..n).map(|_| Vector6::from_fn(|_, _| next())).collect();
        let x = symbolic.solve(&mut m, &rhs).expect("positive definite");
        let flat =
            nalgebra::DVector::from_iterator(6 * n, rhs.iter().flat_map(|v| v.iter().copied()));
        let expected = dense.cholesky().expect("positive definite").solve(&flat);
        for (v, xv) in x.iter().enumerate() {
            let e = expected.rows(6 * v, 6);
            assert!((xv - e).norm() < 1e-9, "block {v}: {xv} vs {e}");
        }
        assert!(symbolic.factor_blocks() >= n + pairs.len());
    }

    #[test]
    fn an_indefinite_matrix_is_reported() {
        let symbolic = Symbolic::analyse(1, []);
        let mut m = symbolic.matrix();
        symbolic.add(&mut m, 0, 0, &(-Matrix6::identity()));
        assert!(symbolic.solve(&mut m, &[Vector6::zeros()]).is_none());
    }
}

//! Minimum-norm solutions of the polish's small symmetric positive semi-definite Delassus
//! systems `D δ = r` (`conic/step.rs`, `StepQp::correct_normal_impulses`): `D = W_Jᵀ M⁻¹ W_J`
//! of the loaded vertices of a body, singular whenever four of them are coplanar.
//!
//! A pivoted Cholesky factorisation `D ≈ F Fᵀ` with a rank test (`F` of full column rank `r`)
//! and a Householder QR `F = Q R` give the range of `D` (the first `r` columns of `Q`), its null
//! space (the others) and `D⁺ = Q₁ R⁻ᵀ R⁻¹ Q₁ᵀ`, the minimum-norm solution. This replaces a
//! symmetric eigendecomposition (`faer`, half the polish's instructions on the desk) for bodies
//! without anchored contacts; the storage is on the stack up to 8 loaded vertices
//! ([`STACK_LEN`]), on the heap above. (The anchored correction stays on the eigendecomposition:
//! `docs/latency.md#the-dense-qps-kkt-solve-by-its-schur-complement-the-polish-without-faer-branch-wip-conickernel-issues-18-and-15`.)

use std::ops::{Deref, DerefMut};

/// Largest order whose permutation and reflector factors are kept on the stack (a body with
/// four loaded contacts of four vertices); larger ones use the heap.
pub(crate) const STACK_ORDER: usize = 16;

/// Pivots of the Cholesky factorisation at most this fraction of the largest diagonal entry
/// count as zero: the rank test (the eigendecomposition dropped eigenvalues below the same
/// fraction of the largest).
const RANK_TOLERANCE: f64 = 1e-12;

/// Largest length kept on the stack by [`Scratch`]: an 8 × 8 system (two four-vertex
/// contacts of a body). Each scratch is zeroed and moved whole, so it is kept small: at
/// `STACK_ORDER²` (2 KB) the zeroing and moving of the polish's four scratches per correction
/// cost about 28 k instructions of the desk step's 867 k
/// (`docs/latency.md#the-conic-desk-step-against-newtons-time-and-instructions-branch-wip-conicratio-issue-18`).
const STACK_LEN: usize = 64;

/// `len` numbers, zeroed: on the stack up to [`STACK_LEN`], otherwise on the heap.
// The large variant is the point: no allocation for the usual sizes.
#[allow(clippy::large_enum_variant)]
pub(crate) enum Scratch {
    Stack([f64; STACK_LEN], usize),
    Heap(Vec<f64>),
}

impl Scratch {
    pub(crate) fn new(len: usize) -> Self {
        if len <= STACK_LEN {
            Scratch::Stack([0.0; STACK_LEN], len)
        } else {
            Scratch::Heap(vec![0.0; len])
        }
    }
}

impl Deref for Scratch {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        match self {
            Scratch::Stack(a, len) => &a[..*len],
            Scratch::Heap(v) => v,
        }
    }
}

impl DerefMut for Scratch {
    fn deref_mut(&mut self) -> &mut [f64] {
        match self {
            Scratch::Stack(a, len) => &mut a[..*len],
            Scratch::Heap(v) => v,
        }
    }
}

/// The range and null space of a symmetric positive semi-definite `k × k` matrix `D`, from the
/// Householder QR of its pivoted Cholesky factor.
pub(crate) struct PsdRange {
    k: usize,
    rank: usize,
    /// `F = Q R`, column-major `k × rank`: `R` on and above the diagonal, the Householder
    /// vectors (first entry 1, not stored) below it.
    qr: Scratch,
    /// The reflectors' factors: `H_j = I − τ_j v_j v_jᵀ`.
    tau: [f64; STACK_ORDER],
    /// Heap copy of `tau` when `rank > STACK_ORDER`.
    tau_heap: Vec<f64>,
}

impl PsdRange {
    /// Factors `d` (`k × k`, row-major, symmetric positive semi-definite); `None` when it has a
    /// non-finite entry or no positive diagonal entry.
    pub(crate) fn new(d: &[f64], k: usize) -> Option<Self> {
        with_order(k, |k| Self::factor(d, k))
    }

    /// [`PsdRange::new`], inlined into each of [`with_order`]'s arms.
    #[inline(always)]
    fn factor(d: &[f64], k: usize) -> Option<Self> {
        if d.len() != k * k || d.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let max_diag = (0..k).map(|i| d[i * k + i]).fold(0.0f64, f64::max);
        if max_diag <= 0.0 {
            return None;
        }
        let tolerance = RANK_TOLERANCE * max_diag;
        // Pivoted Cholesky in the outer-product form on a full symmetric copy: step j takes the
        // largest remaining diagonal entry of the Schur complement as its pivot, and stops
        // when that is at most `tolerance` (all remaining eigenvalues are then below
        // `(k − j) · tolerance`, as the Schur complement is positive semi-definite).
        let mut a_scratch = Scratch::new(k * k);
        // Dereferenced once: each access through `Scratch` would match on its variant.
        let a: &mut [f64] = &mut a_scratch;
        a.copy_from_slice(d);
        let mut perm_stack = [0usize; STACK_ORDER];
        let mut perm_heap = Vec::new();
        let perm: &mut [usize] = if k <= STACK_ORDER {
            &mut perm_stack[..k]
        } else {
            perm_heap.resize(k, 0);
            &mut perm_heap
        };
        for (i, p) in perm.iter_mut().enumerate() {
            *p = i;
        }
        let mut rank = 0;
        while rank < k {
            let j = rank;
            let (p, pivot) = (j..k)
                .map(|i| (i, a[i * k + i]))
                .fold((j, f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b });
            if pivot <= tolerance {
                break;
            }
            if p != j {
                for c in 0..k {
                    a.swap(j * k + c, p * k + c);
                }
                for r in 0..k {
                    a.swap(r * k + j, r * k + p);
                }
                perm.swap(j, p);
            }
            let l = pivot.sqrt();
            a[j * k + j] = l;
            for i in j + 1..k {
                a[i * k + j] /= l;
            }
            for i in j + 1..k {
                let li = a[i * k + j];
                for c in j + 1..k {
                    a[i * k + c] -= li * a[c * k + j];
                }
            }
            rank += 1;
        }
        // F = Πᵀ L (k × rank, column-major): row perm[i] of F is row i of L.
        let mut qr = Scratch::new(k * rank);
        let f: &mut [f64] = &mut qr;
        for j in 0..rank {
            for i in j..k {
                f[j * k + perm[i]] = a[i * k + j];
            }
        }
        let mut range = PsdRange {
            k,
            rank,
            qr,
            tau: [0.0; STACK_ORDER],
            tau_heap: if rank > STACK_ORDER {
                vec![0.0; rank]
            } else {
                Vec::new()
            },
        };
        range.householder()?;
        Some(range)
    }

    /// Rank of `D`.
    #[cfg(test)]
    pub(crate) fn rank(&self) -> usize {
        self.rank
    }

    fn taus(&self) -> &[f64] {
        if self.rank > STACK_ORDER {
            &self.tau_heap
        } else {
            &self.tau[..self.rank]
        }
    }

    /// QR of `F` in place (LAPACK's `dgeqr2`); `None` when a column is zero (`F` has full
    /// column rank by construction, so only for non-finite data).
    #[inline(always)]
    fn householder(&mut self) -> Option<()> {
        let (k, rank) = (self.k, self.rank);
        let mut taus = [0.0; STACK_ORDER];
        let mut taus_heap = Vec::new();
        let taus: &mut [f64] = if rank > STACK_ORDER {
            taus_heap.resize(rank, 0.0);
            &mut taus_heap
        } else {
            &mut taus[..rank]
        };
        let qr: &mut [f64] = &mut self.qr;
        for j in 0..rank {
            let (done, rest) = qr.split_at_mut((j + 1) * k);
            let col = &mut done[j * k..];
            let x0 = col[j];
            let tail: f64 = col[j + 1..].iter().map(|v| v * v).sum();
            let norm = (x0 * x0 + tail).sqrt();
            if !(norm > 0.0 && norm.is_finite()) {
                return None;
            }
            let beta = if x0 >= 0.0 { -norm } else { norm };
            let tau = (beta - x0) / beta;
            let scale = 1.0 / (x0 - beta);
            for v in &mut col[j + 1..] {
                *v *= scale;
            }
            col[j] = beta;
            let v = &col[j + 1..];
            for other in rest.chunks_exact_mut(k) {
                let s = tau * (other[j] + dot(v, &other[j + 1..]));
                other[j] -= s;
                for (o, vi) in other[j + 1..].iter_mut().zip(v) {
                    *o -= s * vi;
                }
            }
            taus[j] = tau;
        }
        if rank > STACK_ORDER {
            self.tau_heap = taus_heap;
        } else {
            self.tau[..rank].copy_from_slice(taus);
        }
        Some(())
    }

    /// `b := Q b` (`b` of length `k`).
    #[cfg(test)]
    pub(crate) fn apply_q(&self, b: &mut [f64]) {
        let qr: &[f64] = &self.qr;
        for (j, &tau) in self.taus().iter().enumerate().rev() {
            reflect(qr, self.k, j, tau, b);
        }
    }

    /// `x = D⁺ b = Q₁ R⁻ᵀ R⁻¹ Q₁ᵀ b`, the minimum-norm least-squares solution of `D x = b`
    /// (`b`, `x` of length `k`); `false` when it is not finite.
    pub(crate) fn min_norm(&self, b: &[f64], x: &mut [f64]) -> bool {
        with_order(self.k, |k| self.min_norm_sized(k, b, x))
    }

    /// [`PsdRange::min_norm`] with `k` its order, inlined into each of [`with_order`]'s arms.
    #[inline(always)]
    fn min_norm_sized(&self, k: usize, b: &[f64], x: &mut [f64]) -> bool {
        let r = self.rank;
        let qr: &[f64] = &self.qr;
        x.copy_from_slice(b);
        for (j, &tau) in self.taus().iter().enumerate() {
            reflect(qr, k, j, tau, x);
        }
        // y = R⁻¹ (Qᵀb)₁, then z = R⁻ᵀ y, both in x[..r].
        for i in (0..r).rev() {
            let mut acc = x[i];
            for c in i + 1..r {
                acc -= qr[c * k + i] * x[c];
            }
            x[i] = acc / qr[i * k + i];
        }
        for i in 0..r {
            let col = &qr[i * k..i * k + i];
            x[i] = (x[i] - dot(col, &x[..i])) / qr[i * k + i];
        }
        x[r..].fill(0.0);
        for (j, &tau) in self.taus().iter().enumerate().rev() {
            reflect(qr, k, j, tau, x);
        }
        x.iter().all(|v| v.is_finite())
    }
}

/// `f(k)` with `k` a constant for the desk's four loaded vertices (and for three): the
/// factorisation's and solve's loops over `k` are unrolled, which removes the mispredicted exits
/// of their short loops (`PsdRange::new` had the most mispredicted branches of any function of
/// the conic desk step, `docs/latency.md`). The same operations in the same order.
#[inline(always)]
fn with_order<R>(k: usize, f: impl FnOnce(usize) -> R) -> R {
    match k {
        3 => f(3),
        4 => f(4),
        _ => f(k),
    }
}

/// `b := H_j b`, `H_j = I − τ v_j v_jᵀ` the `j`-th reflector stored in `qr` (column-major, `k`
/// rows).
#[inline(always)]
fn reflect(qr: &[f64], k: usize, j: usize, tau: f64, b: &mut [f64]) {
    let v = &qr[j * k + j + 1..(j + 1) * k];
    let s = tau * (b[j] + dot(v, &b[j + 1..k]));
    b[j] -= s;
    for (bi, vi) in b[j + 1..k].iter_mut().zip(v) {
        *bi -= s * vi;
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecp_model::linalg;

    /// The reference: `D⁺ b` from the eigendecomposition, eigenvalues at most `1e-12` of the
    /// largest dropped (the polish's method before this module).
    fn eigen_min_norm(d: &[f64], k: usize, b: &[f64]) -> Vec<f64> {
        let (eig, u) = linalg::symmetric_eigen(d, k).expect("finite");
        let max = eig.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        let mut x = vec![0.0; k];
        for (c, &e) in eig.iter().enumerate() {
            if e > 1e-12 * max {
                let v = &u[c * k..(c + 1) * k];
                let p = dot(v, b) / e;
                for i in 0..k {
                    x[i] += p * v[i];
                }
            }
        }
        x
    }

    /// `Wᵀ M⁻¹ W` of unit-mass normal wrenches `[n; r × n]` at the points `(x, y, z)`, `n = e_z`.
    fn delassus(points: &[[f64; 3]], inertia: [f64; 3]) -> Vec<f64> {
        let k = points.len();
        let w: Vec<[f64; 6]> = points
            .iter()
            .map(|p| [0.0, 0.0, 1.0, p[1], -p[0], 0.0])
            .collect();
        let minv = [
            1.0,
            1.0,
            1.0,
            1.0 / inertia[0],
            1.0 / inertia[1],
            1.0 / inertia[2],
        ];
        let mut d = vec![0.0; k * k];
        for i in 0..k {
            for j in 0..k {
                d[i * k + j] = (0..6).map(|a| w[i][a] * minv[a] * w[j][a]).sum();
            }
        }
        d
    }

    fn check(d: &[f64], k: usize, b: &[f64], rank: usize) {
        let range = PsdRange::new(d, k).expect("factored");
        assert_eq!(range.rank(), rank);
        let mut x = vec![0.0; k];
        assert!(range.min_norm(b, &mut x));
        let reference = eigen_min_norm(d, k, b);
        let scale = reference.iter().fold(1.0f64, |m, v| m.max(v.abs()));
        for (a, e) in x.iter().zip(&reference) {
            assert!(
                (a - e).abs() <= 1e-12 * scale,
                "rank {rank}: {x:?} vs {reference:?}"
            );
        }
    }

    #[test]
    fn full_rank_systems_are_solved() {
        let d = [4.0, 1.0, 0.0, 1.0, 3.0, 0.5, 0.0, 0.5, 2.0];
        let b = [1.0, -2.0, 0.5];
        check(&d, 3, &b, 3);
        let range = PsdRange::new(&d, 3).expect("factored");
        let mut x = [0.0; 3];
        assert!(range.min_norm(&b, &mut x));
        for i in 0..3 {
            let dx: f64 = (0..3).map(|j| d[i * 3 + j] * x[j]).sum();
            assert!((dx - b[i]).abs() < 1e-14, "{dx} vs {}", b[i]);
        }
    }

    /// Four coplanar vertices of a box (rank 3, the desk), six (rank 3), two coincident
    /// vertices (rank 1 of 2) and a line of three (rank 2): the same minimum-norm answers as
    /// the eigendecomposition to 1e-12, also for a right-hand side outside the range.
    #[test]
    fn rank_deficient_systems_give_the_eigendecomposition_answer() {
        let box4 = [
            [0.5, 0.4, -0.2],
            [-0.5, 0.4, -0.2],
            [-0.5, -0.4, -0.2],
            [0.5, -0.4, -0.2],
        ];
        let d = delassus(&box4, [0.3, 0.4, 0.5]);
        check(&d, 4, &[0.1, -0.3, 0.2, 0.05], 3);
        let six = [
            [0.5, 0.4, -0.2],
            [0.0, 0.4, -0.2],
            [-0.5, 0.4, -0.2],
            [-0.5, -0.4, -0.2],
            [0.0, -0.4, -0.2],
            [0.5, -0.4, -0.2],
        ];
        let d = delassus(&six, [0.02, 0.05, 0.06]);
        check(&d, 6, &[0.1, -0.3, 0.2, 0.05, 1.0, -2.0], 3);
        let same = [[0.3, 0.1, 0.0], [0.3, 0.1, 0.0]];
        check(&delassus(&same, [1.0, 2.0, 3.0]), 2, &[1.0, 1.0], 1);
        let line = [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]];
        check(&delassus(&line, [1.0, 2.0, 3.0]), 3, &[1.0, 0.3, -0.2], 2);
        // D = u uᵀ, u = (1, 1): the minimum-norm answer of D x = (2, 2) is (1, 1).
        let range = PsdRange::new(&[1.0, 1.0, 1.0, 1.0], 2).expect("factored");
        let mut x = [0.0; 2];
        assert!(range.min_norm(&[2.0, 2.0], &mut x));
        assert!(
            (x[0] - 1.0).abs() < 1e-15 && (x[1] - 1.0).abs() < 1e-15,
            "{x:?}"
        );
    }

    /// Beyond the stack (20 vertices on a circle, rank 3), and the null space: `Q`'s last
    /// `k − r` columns are annihilated by `D`.
    #[test]
    fn large_systems_and_the_null_space() {
        let points: Vec<[f64; 3]> = (0..20)
            .map(|i| {
                let t = i as f64 * 0.3;
                [t.cos(), 0.7 * t.sin(), -0.1]
            })
            .collect();
        let d = delassus(&points, [0.2, 0.3, 0.4]);
        let b: Vec<f64> = (0..20).map(|i| (i as f64 * 0.7).sin()).collect();
        check(&d, 20, &b, 3);
        let range = PsdRange::new(&d, 20).expect("factored");
        for c in 3..20 {
            let mut e = vec![0.0; 20];
            e[c] = 1.0;
            range.apply_q(&mut e);
            for i in 0..20 {
                let de: f64 = (0..20).map(|j| d[i * 20 + j] * e[j]).sum();
                assert!(de.abs() < 1e-13, "column {c}: {de}");
            }
        }
    }

    #[test]
    fn refuses_zero_and_non_finite_matrices() {
        assert!(PsdRange::new(&[0.0; 4], 2).is_none());
        assert!(PsdRange::new(&[1.0, f64::NAN, f64::NAN, 1.0], 2).is_none());
    }
}

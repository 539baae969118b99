//! Dense Cholesky factorisation `A = L Lᵀ` of the Levenberg–Marquardt matrix `HᵀH + λI`
//! (`docs/newton.md#wall-time`): symmetric positive definite for `λ > 0`, so it needs half the
//! arithmetic of the general LU and no pivoting. Written here (like the minimum-norm QR) because
//! it is twenty lines and allocates nothing after the first call.

/// The factor of one matrix; workspace kept between calls.
#[derive(Debug, Default)]
pub(crate) struct Cholesky {
    n: usize,
    /// Column-major `n × n`: `L` on and below the diagonal (above it: unused).
    l: Vec<f64>,
    factored: bool,
}

/// A pivot `d_j` at or below this fraction of the largest diagonal entry of `A` counts as a
/// failure (the matrix is not numerically positive definite); the LU's singularity test uses
/// the same ratio (`ecp_model::linalg::SINGULAR_PIVOT_RATIO`).
const PIVOT_RATIO: f64 = 1e-13;

impl Cholesky {
    /// Factorises the column-major `n × n` symmetric matrix `a` (its lower triangle is read).
    /// `false` when it is not numerically positive definite or holds a non-finite entry.
    pub(crate) fn factor(&mut self, n: usize, a: &[f64]) -> bool {
        self.factored = false;
        if a.len() != n * n {
            return false;
        }
        self.n = n;
        self.l.clear();
        self.l.extend_from_slice(a);
        let l = &mut self.l;
        let largest = (0..n).map(|j| l[j * n + j]).fold(0.0f64, f64::max);
        let floor = PIVOT_RATIO * largest;
        // Right-looking: finish column j, then subtract its outer product from the trailing
        // lower triangle, column by column (contiguous inner loops).
        for j in 0..n {
            let d = l[j * n + j];
            // NaN fails `d > floor` as well: refused like a small pivot.
            if d.partial_cmp(&floor) != Some(std::cmp::Ordering::Greater) || !d.is_finite() {
                return false;
            }
            let ljj = d.sqrt();
            l[j * n + j] = ljj;
            let inv = 1.0 / ljj;
            for v in &mut l[j * n + j + 1..(j + 1) * n] {
                *v *= inv;
            }
            let (done, rest) = l.split_at_mut((j + 1) * n);
            let col = &done[j * n..];
            for c in j + 1..n {
                let f = col[c];
                if f == 0.0 {
                    continue;
                }
                let target = &mut rest[(c - j - 1) * n + c..(c - j) * n];
                for (t, &v) in target.iter_mut().zip(&col[c..n]) {
                    *t -= f * v;
                }
            }
        }
        self.factored = true;
        true
    }

    /// Solves `A x = b` in place with the last factorisation; `false` when there is none or the
    /// result is not finite.
    pub(crate) fn solve_in_place(&self, b: &mut [f64]) -> bool {
        let n = self.n;
        if !self.factored || b.len() != n {
            return false;
        }
        let l = &self.l;
        // L y = b.
        for j in 0..n {
            let y = b[j] / l[j * n + j];
            b[j] = y;
            for (bi, &v) in b[j + 1..].iter_mut().zip(&l[j * n + j + 1..(j + 1) * n]) {
                *bi -= v * y;
            }
        }
        // Lᵀ x = y.
        for j in (0..n).rev() {
            let s: f64 = b[j + 1..]
                .iter()
                .zip(&l[j * n + j + 1..(j + 1) * n])
                .map(|(x, v)| x * v)
                .sum();
            b[j] = (b[j] - s) / l[j * n + j];
        }
        b.iter().all(|v| v.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `A = MᵀM + I` for a fixed non-symmetric `M`: the solve matches `A x = b` to 1e-12
    /// (relative), and an indefinite matrix is refused.
    #[test]
    fn solves_a_positive_definite_system_and_refuses_an_indefinite_one() {
        let n = 17;
        let m: Vec<f64> = (0..n * n)
            .map(|p| ((p * 37 % 23) as f64 - 11.0) / 7.0)
            .collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                let s: f64 = (0..n).map(|k| m[i * n + k] * m[j * n + k]).sum();
                a[j * n + i] = s + if i == j { 1.0 } else { 0.0 };
            }
        }
        let x: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        let mut b: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| a[j * n + i] * x[j]).sum())
            .collect();
        let mut c = Cholesky::default();
        assert!(c.factor(n, &a));
        assert!(c.solve_in_place(&mut b));
        for (u, v) in b.iter().zip(&x) {
            assert!((u - v).abs() <= 1e-12 * (1.0 + v.abs()), "{u} vs {v}");
        }
        a[3 * n + 3] = -1.0;
        assert!(!c.factor(n, &a));
        assert!(!c.solve_in_place(&mut b));
    }
}

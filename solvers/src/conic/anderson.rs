//! Anderson acceleration (type II, Walker & Ni, SIAM J. Numer. Anal. 49, 2011) of the outer
//! fixed point `x ← G(x)` of the conic backend.
//!
//! The plain De Saxcé / Acary–Cadoux iteration converges linearly; its slow modes are the shift
//! `μ ‖E u_T‖` for large μ and the ECP, which sets the friction's lever arm and is moved by the
//! friction's moment (`docs/decisions.md#conic-backend-anderson-acceleration`). Anderson mixing
//! of the last few iterates removes them; the solver falls back to the plain update when the
//! mixing does not help.

/// Memory and history of the accelerator. Its history's vectors are kept when it is reset
/// (the solver keeps one accelerator across solves, `conic/mod.rs`).
#[derive(Default)]
pub(crate) struct Anderson {
    memory: usize,
    xs: Vec<Vec<f64>>,
    gs: Vec<Vec<f64>>,
    /// Vectors of a forgotten history, reused for the next pairs.
    spare: Vec<Vec<f64>>,
}

impl Anderson {
    /// An accelerator remembering `memory` previous iterates (0 disables it).
    #[cfg(test)]
    pub fn new(memory: usize) -> Self {
        Anderson {
            memory,
            ..Anderson::default()
        }
    }

    /// Forgets the history and remembers `memory` previous iterates from now on.
    pub fn restart(&mut self, memory: usize) {
        self.memory = memory;
        self.reset();
    }

    /// Forgets the history (after a failed step or a change of active set).
    pub fn reset(&mut self) {
        self.spare.append(&mut self.xs);
        self.spare.append(&mut self.gs);
    }

    /// `v` as a kept vector (a spare one refilled, or a new one).
    fn kept_copy(&mut self, v: &[f64]) -> Vec<f64> {
        let mut out = self.spare.pop().unwrap_or_default();
        out.clear();
        out.extend_from_slice(v);
        out
    }

    /// Records the pair `(x, G(x))` and returns the next input: the mixed point, or `g` itself
    /// when there is no usable history.
    #[cfg(test)]
    pub fn next(&mut self, x: &[f64], g: &[f64]) -> Vec<f64> {
        let mut out = Vec::new();
        self.next_into(x, g, &mut out);
        out
    }

    /// Records the pair `(x, G(x))` and writes the next input into `out`: the mixed point, or
    /// `g` itself when there is no usable history.
    pub fn next_into(&mut self, x: &[f64], g: &[f64], out: &mut Vec<f64>) {
        out.clear();
        out.extend_from_slice(g);
        if self.memory == 0 {
            return;
        }
        let xk = self.kept_copy(x);
        let gk = self.kept_copy(g);
        self.xs.push(xk);
        self.gs.push(gk);
        if self.xs.len() > self.memory + 1 {
            let (x0, g0) = (self.xs.remove(0), self.gs.remove(0));
            self.spare.push(x0);
            self.spare.push(g0);
        }
        let k = self.xs.len();
        if k < 2 {
            return;
        }
        let n = x.len();
        let f: Vec<Vec<f64>> = (0..k)
            .map(|i| (0..n).map(|j| self.gs[i][j] - self.xs[i][j]).collect())
            .collect();
        let m = k - 1;
        // ΔF_i = f_{i+1} − f_i, ΔG_i = g_{i+1} − g_i; γ = argmin ‖f_k − ΔF γ‖.
        let df: Vec<Vec<f64>> = (0..m)
            .map(|i| (0..n).map(|j| f[i + 1][j] - f[i][j]).collect())
            .collect();
        let mut a = vec![vec![0.0; m]; m];
        let mut rhs = vec![0.0; m];
        for i in 0..m {
            for j in 0..m {
                a[i][j] = dot(&df[i], &df[j]);
            }
            rhs[i] = dot(&df[i], &f[k - 1]);
        }
        let trace: f64 = (0..m).map(|i| a[i][i]).sum();
        if trace.is_nan() || trace <= 0.0 || !trace.is_finite() {
            return;
        }
        for i in 0..m {
            a[i][i] += 1e-12 * trace;
        }
        let Some(gamma) = gauss(a, rhs) else {
            return;
        };
        for i in 0..m {
            for j in 0..n {
                out[j] -= gamma[i] * (self.gs[i + 1][j] - self.gs[i][j]);
            }
        }
        if !out.iter().all(|v| v.is_finite()) {
            out.clear();
            out.extend_from_slice(g);
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Gaussian elimination with partial pivoting; `None` when singular.
fn gauss(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].is_nan() || a[p][c] == 0.0 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..n {
            let factor = a[r][c] / a[c][c];
            for k in c..n {
                a[r][k] -= factor * a[c][k];
            }
            b[r] -= factor * b[c];
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|k| a[r][k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    if x.iter().all(|v| v.is_finite()) {
        Some(x)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accelerates_a_slow_linear_fixed_point() {
        // x ← 0.95 x + 0.05 c converges with factor 0.95; Anderson solves it in a few steps.
        let c = [1.0, -2.0];
        let g = |x: &[f64]| vec![0.95 * x[0] + 0.05 * c[0], 0.9 * x[1] + 0.1 * c[1]];
        let mut acc = Anderson::new(3);
        let mut x = vec![0.0, 0.0];
        for _ in 0..6 {
            let gx = g(&x);
            x = acc.next(&x, &gx);
        }
        assert!(
            (x[0] - c[0]).abs() < 1e-10 && (x[1] - c[1]).abs() < 1e-10,
            "{x:?}"
        );
    }
}

//! The Cholesky factor of a body's 6 × 6 mass matrix, computed once per polish and applied to
//! every wrench: the polish (`conic/step.rs`, `StepQp::extract`) solves `M x = w` for each
//! vertex and friction wrench in each Gauss–Seidel sweep, 28 solves per polish on the desk, and
//! refactoring `M` each time was a seventh of the desk step's instructions
//! (`docs/latency.md#the-conic-desk-step-against-newtons-time-and-instructions-branch-wip-conicratio-issue-18`).
//! Factor and solve are the operations of the former `solve6` in the same order, so the answers
//! are the same to the bit.

/// `M = L Lᵀ` of a symmetric positive definite 6 × 6 mass matrix; a matrix with a non-positive
/// pivot (not a mass matrix) solves every system to zero, never NaN.
#[derive(Clone, Copy, Debug)]
pub(crate) struct MassFactor {
    /// The lower factor `L`; unused when `!positive`.
    l: [[f64; 6]; 6],
    positive: bool,
}

impl MassFactor {
    pub(crate) fn new(m: &[[f64; 6]; 6]) -> Self {
        let mut l = [[0.0f64; 6]; 6];
        for i in 0..6 {
            for j in 0..=i {
                let mut s = m[i][j];
                for k in 0..j {
                    s -= l[i][k] * l[j][k];
                }
                if i == j {
                    if s.is_nan() || s <= 0.0 {
                        return MassFactor { l, positive: false };
                    }
                    l[i][i] = s.sqrt();
                } else {
                    l[i][j] = s / l[j][j];
                }
            }
        }
        MassFactor { l, positive: true }
    }

    /// `x` with `M x = r`.
    pub(crate) fn solve(&self, r: &[f64; 6]) -> [f64; 6] {
        if !self.positive {
            return [0.0; 6];
        }
        let l = &self.l;
        let mut y = [0.0; 6];
        for i in 0..6 {
            let mut s = r[i];
            for k in 0..i {
                s -= l[i][k] * y[k];
            }
            y[i] = s / l[i][i];
        }
        let mut x = [0.0; 6];
        for i in (0..6).rev() {
            let mut s = y[i];
            for k in i + 1..6 {
                s -= l[k][i] * x[k];
            }
            x[i] = s / l[i][i];
        }
        x
    }
}

/// Solves the 6×6 symmetric positive definite system `M x = r` (Cholesky) once; a
/// non-positive pivot (not a mass matrix) gives zero, never NaN.
pub(crate) fn solve6(m: &[[f64; 6]; 6], r: &[f64; 6]) -> [f64; 6] {
    MassFactor::new(m).solve(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solve6_inverts_a_mass_matrix() {
        let mut m = [[0.0; 6]; 6];
        for i in 0..3 {
            m[i][i] = 10.0;
        }
        m[3][3] = 2.0;
        m[4][4] = 3.0;
        m[5][5] = 1.0;
        m[3][4] = 0.5;
        m[4][3] = 0.5;
        let r = [1.0, -2.0, 3.0, 0.5, 0.25, -1.0];
        let x = solve6(&m, &r);
        for i in 0..6 {
            let mx: f64 = (0..6).map(|j| m[i][j] * x[j]).sum();
            assert!((mx - r[i]).abs() < 1e-14);
        }
        // The kept factor gives the same answer to the bit, for every right-hand side.
        let f = MassFactor::new(&m);
        assert_eq!(f.solve(&r), x);
        m[5][5] = -1.0;
        assert_eq!(solve6(&m, &r), [0.0; 6]);
        assert_eq!(MassFactor::new(&m).solve(&r), [0.0; 6]);
    }
}

//! A body's 6 × 6 mass matrix inverted once per polish and applied to every wrench: the polish
//! (`conic/step.rs`, `StepQp::extract`) solves `M x = w` for each vertex and friction wrench in
//! each Gauss–Seidel sweep (about 60 solves per desk step), and refactoring `M` each time was a
//! seventh of the desk step's instructions
//! (`docs/latency.md#the-conic-desk-step-against-newtons-time-and-instructions-branch-wip-conicratio-issue-18`).
//! The inverse is formed from the Cholesky factor (the former `solve6`'s factor and
//! substitutions, one column per unit vector), so a solve is one product `M⁻¹ r` whose 36
//! products are independent, where the substitutions were a chain of 12 divisions each waiting
//! for the last (`docs/latency.md`, branch wip-conic3x).

/// `M⁻¹` of a symmetric positive definite 6 × 6 mass matrix, by columns; a matrix with a
/// non-positive pivot (not a mass matrix) solves every system to zero, never NaN.
#[derive(Clone, Copy, Debug)]
pub(crate) struct MassFactor {
    /// The columns of `M⁻¹` (zero when `M` is not positive definite). `M⁻¹` is symmetric up to
    /// the round-off of its columns' substitutions; the product uses it by columns.
    inverse_columns: [[f64; 6]; 6],
}

/// The lower Cholesky factor `L` of `M = L Lᵀ`, or `None` at a non-positive pivot.
fn cholesky6(m: &[[f64; 6]; 6]) -> Option<[[f64; 6]; 6]> {
    let mut l = [[0.0f64; 6]; 6];
    for i in 0..6 {
        for j in 0..=i {
            let mut s = m[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                if s.is_nan() || s <= 0.0 {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    Some(l)
}

/// `x` with `L Lᵀ x = r`, by forward and backward substitution.
fn substitute6(l: &[[f64; 6]; 6], r: &[f64; 6]) -> [f64; 6] {
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

impl MassFactor {
    pub(crate) fn new(m: &[[f64; 6]; 6]) -> Self {
        let inverse_columns = cholesky6(m).map_or([[0.0; 6]; 6], |l| {
            std::array::from_fn(|j| {
                let mut e = [0.0; 6];
                e[j] = 1.0;
                substitute6(&l, &e)
            })
        });
        MassFactor { inverse_columns }
    }

    /// `x` with `M x = r`: `Σⱼ rⱼ (M⁻¹)ⱼ`, the columns' products independent of each other.
    #[inline]
    pub(crate) fn solve(&self, r: &[f64; 6]) -> [f64; 6] {
        let mut x = [0.0; 6];
        for (col, &rj) in self.inverse_columns.iter().zip(r) {
            for (xi, &c) in x.iter_mut().zip(col) {
                *xi += c * rj;
            }
        }
        x
    }
}

/// Solves the 6×6 symmetric positive definite system `M x = r` (Cholesky) once; a
/// non-positive pivot (not a mass matrix) gives zero, never NaN.
pub(crate) fn solve6(m: &[[f64; 6]; 6], r: &[f64; 6]) -> [f64; 6] {
    cholesky6(m).map_or([0.0; 6], |l| substitute6(&l, r))
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
        // The kept inverse gives the substitutions' answer to round-off.
        let f = MassFactor::new(&m);
        for (a, b) in f.solve(&r).iter().zip(&x) {
            assert!((a - b).abs() <= 1e-14 * b.abs().max(1.0), "{a} {b}");
        }
        m[5][5] = -1.0;
        assert_eq!(solve6(&m, &r), [0.0; 6]);
        assert_eq!(MassFactor::new(&m).solve(&r), [0.0; 6]);
    }
}

//! Scene scales of an MCP (`docs/decisions.md#scene-scaled-convergence`): per-variable and
//! per-row units in which a backend judges the natural residual and its merit functions, so
//! that a tolerance means the same in a scene given in millimetres, stepped at `h = 1e-5` or
//! with `μ = 1e6` as in the original.
//!
//! A problem offers its scales through [`crate::Mcp::scales`]; a backend that honours them
//! solves [`ScaledMcp`], the same MCP in the dimensionless unknowns `z̃ = z / d_x` with the rows
//! `F̃(z̃) = F(d_x z̃) / d_f`. Positive diagonal scalings map solutions to solutions (each pair
//! `l ≤ z ⊥ F` keeps its signs), so only the judging changes, not the answer.

use std::sync::Arc;

use crate::family::McpFamily;
use crate::mcp::{Mcp, diagnose_values, fb_residual};
use crate::pattern::CscPattern;
use crate::solver::{Solution, SolveError};

/// Per-variable and per-row scales (positive, finite) of an MCP of dimension `n`.
#[derive(Clone, Debug, PartialEq)]
pub struct McpScales {
    /// `d_x`: the unit of each unknown (`z_i = d_x,i z̃_i`).
    pub variables: Vec<f64>,
    /// `d_f`: the unit of each row (`F_i = d_f,i F̃_i`).
    pub rows: Vec<f64>,
}

impl McpScales {
    /// Scales of dimension `n`, all 1.
    pub fn identity(n: usize) -> Self {
        McpScales {
            variables: vec![1.0; n],
            rows: vec![1.0; n],
        }
    }

    /// Rounds every scale to the nearest power of two (in the logarithm), so that scaling and
    /// unscaling are exact in floating point; a scale that is not positive and finite becomes 1.
    pub fn rounded_to_powers_of_two(mut self) -> Self {
        self.round_to_powers_of_two();
        self
    }

    /// [`McpScales::rounded_to_powers_of_two`] in place.
    pub fn round_to_powers_of_two(&mut self) {
        // The two vectors one after the other (a chained iterator costs a test per entry).
        for s in self.variables.iter_mut() {
            *s = power_of_two(*s);
        }
        for s in self.rows.iter_mut() {
            *s = power_of_two(*s);
        }
    }

    /// Whether both vectors have length `n` and every scale is positive and finite.
    pub fn is_valid(&self, n: usize) -> bool {
        // `0 < s < ∞` (false for a NaN) over every entry without an exit per entry: a loop the
        // compiler can vectorise (a valid vector is read to its end either way).
        let valid = |v: &[f64]| {
            v.iter()
                .fold(true, |ok, &s| ok & (s > 0.0) & (s < f64::INFINITY))
        };
        self.variables.len() == n
            && self.rows.len() == n
            && valid(&self.variables)
            && valid(&self.rows)
    }

    /// Whether every scale is exactly 1 (nothing to do).
    pub fn is_identity(&self) -> bool {
        self.variables.iter().all(|s| *s == 1.0) && self.rows.iter().all(|s| *s == 1.0)
    }

    /// How [`solve_in_scales`] uses these scales for a problem of dimension `n`: not at all
    /// when they are all 1 ([`McpScales::is_identity`]) or not valid ([`McpScales::is_valid`]),
    /// else in the order [`far_from_si`] says. The same verdict as those three tests, from one
    /// pass over the scales when every scale lies in `[2⁻¹⁹, 2¹⁹]` (valid and inside the band,
    /// as a scene in SI units gives); the three tests decide the rest.
    pub fn usage(&self, n: usize) -> ScalesUsage {
        if self.variables.len() != n || self.rows.len() != n {
            return ScalesUsage::Unscaled;
        }
        // Without an exit per entry (a loop the compiler can vectorise); a NaN is neither 1 nor
        // inside.
        let (mut identity, mut inside) = (true, true);
        for v in [&self.variables, &self.rows] {
            for &s in v.iter() {
                identity &= s == 1.0;
                inside &= (s >= SI_INNER.0) & (s <= SI_INNER.1);
            }
        }
        if identity {
            ScalesUsage::Unscaled
        } else if inside {
            ScalesUsage::WithinSi
        } else if !self.is_valid(n) {
            ScalesUsage::Unscaled
        } else if far_from_si(self) {
            ScalesUsage::FarFromSi
        } else {
            ScalesUsage::WithinSi
        }
    }
}

/// What [`solve_in_scales`] does with a problem's scales ([`McpScales::usage`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalesUsage {
    /// No scales to use (all 1, or not valid): the problem is solved as given only.
    Unscaled,
    /// Valid scales within [`SI_BAND_LOG2`]'s band: solved as given first, in scales second.
    WithinSi,
    /// Valid scales that leave the band somewhere: solved in scales first.
    FarFromSi,
}

/// `√2 − 1` in units of the last place of a mantissa in `[1, 2)`: `s = (1 + f 2⁻⁵²) 2^e` lies
/// below `√2 · 2^e` when `f` is below it.
const SQRT_2_FRACTION: u64 = ((std::f64::consts::SQRT_2 - 1.0) * (1u64 << 52) as f64) as u64;

/// Mantissas within this many units of the last place of `√2` are left to the logarithm (a
/// relative distance of `2⁻²²`; `log2`'s error, an ulp of a number of at most 1000 in magnitude, is below `2⁻⁴²`).
const SQRT_2_MARGIN: u64 = 1 << 30;

/// The power of two nearest to `s` in the logarithm (1 for a scale that is not positive and
/// finite, or whose power is outside the normal range): what
/// [`McpScales::round_to_powers_of_two`] makes of each scale.
///
/// From the bits of `s` (`s = m 2^e`, `1 ≤ m < 2`: `2^e` when `m < √2`, else `2^(e+1)`), the
/// same number as `power_of_two_by_log2` gives: where the two could differ — `m` near `√2`,
/// where `log2`'s round-off may decide the rounding, subnormals, `|e|` near the clamp — the
/// logarithm decides. A desk step rounds 62 scales; `log2`, `round` and `powi` were 7 k of
/// its instructions.
pub fn power_of_two(s: f64) -> f64 {
    let bits = s.to_bits();
    // The biased exponent; at least 2048 for a negative `s` (the sign bit).
    let biased = bits >> 52;
    let fraction = bits & ((1u64 << 52) - 1);
    // `e = biased − 1023 ∈ [−999, 998]`: `e` and `e + 1` within the clamp of ±1000.
    if (24..=2021).contains(&biased) {
        if fraction < SQRT_2_FRACTION - SQRT_2_MARGIN {
            return f64::from_bits(biased << 52);
        }
        if fraction > SQRT_2_FRACTION + SQRT_2_MARGIN {
            return f64::from_bits((biased + 1) << 52);
        }
    }
    power_of_two_by_log2(s)
}

/// [`power_of_two`] by the logarithm: `2^round(log2 s)`.
fn power_of_two_by_log2(s: f64) -> f64 {
    if !(s.is_finite() && s > 0.0) {
        return 1.0;
    }
    let e = s.log2().round().clamp(-1000.0, 1000.0) as i32;
    2f64.powi(e)
}

/// The MCP `inner` in the scaled unknowns `z̃ = z / d_x`, rows `F̃ = F / d_f` and Jacobian
/// `J̃_ij = J_ij d_x,j / d_f,i` (same sparsity pattern), bounds `l / d_x`, `u / d_x`.
pub struct ScaledMcp<'a> {
    inner: &'a dyn Mcp,
    scales: &'a McpScales,
    lower: Vec<f64>,
    upper: Vec<f64>,
    /// Per stored Jacobian entry, `d_x,col / d_f,row`.
    factors: Vec<f64>,
    z: std::cell::RefCell<Vec<f64>>,
}

impl<'a> ScaledMcp<'a> {
    /// The scaled view of `inner`; `None` when `scales` do not fit it (wrong length, a scale not
    /// positive and finite), so the caller solves the unscaled problem.
    pub fn new(inner: &'a dyn Mcp, scales: &'a McpScales) -> Option<Self> {
        let n = inner.dim();
        if !scales.is_valid(n) {
            return None;
        }
        let dx = &scales.variables;
        let lower = inner.lower().iter().zip(dx).map(|(l, d)| l / d).collect();
        let upper = inner.upper().iter().zip(dx).map(|(u, d)| u / d).collect();
        let pattern = inner.jacobian_pattern();
        let mut factors = Vec::with_capacity(pattern.nnz());
        let (ptr, rows) = (pattern.col_ptr(), pattern.row_idx());
        for col in 0..n {
            for &row in &rows[ptr[col]..ptr[col + 1]] {
                factors.push(dx[col] / scales.rows[row]);
            }
        }
        Some(ScaledMcp {
            inner,
            scales,
            lower,
            upper,
            factors,
            z: std::cell::RefCell::new(vec![0.0; n]),
        })
    }

    /// `z̃ = z / d_x`.
    pub fn to_scaled(&self, z: &[f64]) -> Vec<f64> {
        z.iter()
            .zip(&self.scales.variables)
            .map(|(z, d)| z / d)
            .collect()
    }

    /// `z = d_x z̃`.
    pub fn to_unscaled(&self, z: &[f64]) -> Vec<f64> {
        z.iter()
            .zip(&self.scales.variables)
            .map(|(z, d)| z * d)
            .collect()
    }

    fn unscale_into(&self, zs: &[f64]) -> std::cell::RefMut<'_, Vec<f64>> {
        let mut z = self.z.borrow_mut();
        for ((zi, s), d) in z.iter_mut().zip(zs).zip(&self.scales.variables) {
            *zi = s * d;
        }
        z
    }

    fn scale_rows(&self, f: &mut [f64]) {
        for (fi, d) in f.iter_mut().zip(&self.scales.rows) {
            *fi /= d;
        }
    }

    fn scale_jacobian(&self, values: &mut [f64]) {
        for (v, k) in values.iter_mut().zip(&self.factors) {
            *v *= k;
        }
    }
}

impl Mcp for ScaledMcp<'_> {
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn lower(&self) -> &[f64] {
        &self.lower
    }
    fn upper(&self) -> &[f64] {
        &self.upper
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        let zu = self.unscale_into(z);
        self.inner.evaluate(&zu, f);
        self.scale_rows(f);
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        self.inner.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        let zu = self.unscale_into(z);
        self.inner.jacobian(&zu, values);
        self.scale_jacobian(values);
    }
    fn evaluate_with_jacobian(&self, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        let zu = self.unscale_into(z);
        self.inner.evaluate_with_jacobian(&zu, f, values);
        self.scale_rows(f);
        self.scale_jacobian(values);
    }
    fn component_name(&self, i: usize) -> String {
        self.inner.component_name(i)
    }
    fn write_component_name(&self, i: usize, out: &mut String) {
        self.inner.write_component_name(i, out)
    }
    // No structural view: its data are in the unscaled units.
    fn elimination_groups(&self) -> &[Vec<usize>] {
        // A diagonal scaling keeps every block of the Jacobian where it was.
        self.inner.elimination_groups()
    }
    fn friction_family(&self) -> Option<&dyn McpFamily> {
        // The family in the same scales (the inner one's, evaluated through this view).
        self.inner.friction_family().map(|_| self as &dyn McpFamily)
    }
}

/// The inner problem's friction family ([`Mcp::friction_family`]) in the scaled unknowns and rows.
impl McpFamily for ScaledMcp<'_> {
    fn evaluate_at(&self, s: f64, z: &[f64], f: &mut [f64]) {
        if let Some(family) = self.inner.friction_family() {
            let zu = self.unscale_into(z);
            family.evaluate_at(s, &zu, f);
            self.scale_rows(f);
        }
    }
    fn evaluate_with_jacobian_at(&self, s: f64, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        if let Some(family) = self.inner.friction_family() {
            let zu = self.unscale_into(z);
            family.evaluate_with_jacobian_at(s, &zu, f, values);
            self.scale_rows(f);
            self.scale_jacobian(values);
        }
    }
}

/// A backend's solve, as [`solve_in_scales`] calls it.
type SolveFn<'f> = dyn FnMut(&dyn Mcp, &[f64]) -> Result<Solution, SolveError> + 'f;

/// Scales within this many factors of two of 1 (`2^±20`, about 1e∓6) count as SI's own: a
/// problem whose every scale is within it is solved as given first, so that the scenes the
/// backends were tuned on (the reference scenes, ordinary SI scenes) take exactly the same
/// iterations as without scales (`docs/decisions.md#scene-scaled-convergence`).
pub const SI_BAND_LOG2: f64 = 20.0;

/// Scales in `[2⁻¹⁹, 2¹⁹]` (`SI_BAND_LOG2` − 1 in the logarithm) are inside the band whatever
/// `log2`'s round-off.
const SI_INNER: (f64, f64) = (1.0 / 524_288.0, 524_288.0);

/// Whether `scales` leave [`SI_BAND_LOG2`]'s band anywhere.
pub fn far_from_si(scales: &McpScales) -> bool {
    scales.variables.iter().any(|&s| outside_si_band(s))
        || scales.rows.iter().any(|&s| outside_si_band(s))
}

/// `|log2 s| > SI_BAND_LOG2` (false for a NaN or a negative `s`, true for 0 and `+∞`), decided
/// by comparisons where `log2` cannot be near the band's edge: `s ∈ [2⁻¹⁹, 2¹⁹]` is inside,
/// `s ≥ 2²¹` and `0 ≤ s ≤ 2⁻²¹` outside; the logarithm decides the rest.
fn outside_si_band(s: f64) -> bool {
    // 2^±21 (`SI_BAND_LOG2` + 1).
    const OUTER: (f64, f64) = (1.0 / 2_097_152.0, 2_097_152.0);
    if (SI_INNER.0..=SI_INNER.1).contains(&s) {
        false
    } else if s >= OUTER.1 || (0.0..=OUTER.0).contains(&s) {
        true
    } else {
        s.log2().abs() > SI_BAND_LOG2
    }
}

/// Solves `mcp` by `solve`, in its scene scales where it has valid ones ([`Mcp::scales`]).
///
/// A problem whose scales leave the SI band ([`far_from_si`]: a scene in millimetres, at
/// `h = 1e-5`, with `μ = 1e6`, …) is solved in its scales first: `solve` is given the
/// [`ScaledMcp`] and `z0 / d_x`, its point (converged or best) is mapped back, and the summary's
/// residuals are recomputed for it on `mcp` (the termination is the scaled tolerance's verdict). A problem within the band is
/// solved as given first. Either way, when the first attempt fails, the other one is tried from
/// the same start; the first that converges is returned (iterations of both counted), else the
/// first attempt's failure. Without (valid) scales `solve` gets `mcp` and `z0` unchanged.
pub fn solve_in_scales(
    mcp: &dyn Mcp,
    z0: &[f64],
    mut solve: impl FnMut(&dyn Mcp, &[f64]) -> Result<Solution, SolveError>,
) -> Result<Solution, SolveError> {
    // `ScaledMcp::new` accepts exactly the valid scales; it is only built when the scaled
    // attempt runs (a problem within the SI band that converges as given never needs it).
    let Some((scales, usage)) = mcp
        .scales_usage()
        .filter(|(_, usage)| *usage != ScalesUsage::Unscaled)
        .filter(|_| z0.len() == mcp.dim())
    else {
        return solve(mcp, z0);
    };
    let in_scales = |solve: &mut SolveFn<'_>| {
        let Some(scaled) = ScaledMcp::new(mcp, scales) else {
            return solve(mcp, z0);
        };
        // The point in the problem's unknowns, its residuals recomputed there: a summary's
        // residual is always that of the returned point on the problem given; only the
        // termination says what the scaled tolerance judged.
        let unscale = |mut sol: Box<Solution>| {
            sol.z = scaled.to_unscaled(&sol.z);
            let mut f = vec![0.0; sol.z.len()];
            mcp.evaluate(&sol.z, &mut f);
            let (residual, worst) = diagnose_values(mcp, &sol.z, &f);
            sol.summary.residual = residual;
            sol.summary.worst = worst;
            sol.summary.fb_residual = fb_residual(&sol.z, &f, mcp.lower(), mcp.upper());
            sol.summary.f_evals += 1;
            sol
        };
        match solve(&scaled, &scaled.to_scaled(z0)) {
            Ok(sol) => Ok(*unscale(Box::new(sol))),
            Err(SolveError::NotConverged { best }) => Err(SolveError::NotConverged {
                best: unscale(best),
            }),
            Err(e) => Err(e),
        }
    };
    let scaled_first = usage == ScalesUsage::FarFromSi;
    let first = if scaled_first {
        in_scales(&mut solve)
    } else {
        solve(mcp, z0)
    };
    let Err(SolveError::NotConverged { mut best }) = first else {
        return first;
    };
    let second = if scaled_first {
        solve(mcp, z0)
    } else {
        in_scales(&mut solve)
    };
    match second {
        Ok(mut sol) => {
            sol.summary.iterations += best.summary.iterations;
            Ok(sol)
        }
        Err(SolveError::NotConverged { best: other }) => {
            best.summary.iterations += other.summary.iterations;
            Err(SolveError::NotConverged { best })
        }
        Err(_) => Err(SolveError::NotConverged { best }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mcp::{FnMcp, natural_residual};

    /// The LCP 0 ≤ z ⊥ M z + q ≥ 0 with a badly scaled second row, scaled: the Jacobian is
    /// `D_f⁻¹ J D_x` entry by entry and a solution maps to a solution.
    #[test]
    fn the_scaled_problem_has_the_scaled_rows_jacobian_and_solutions() {
        let mcp = FnMcp::dense(
            vec![0.0, f64::NEG_INFINITY],
            vec![f64::INFINITY, f64::INFINITY],
            |z, f| {
                f[0] = 2.0 * z[0] + z[1] - 1.0;
                f[1] = 1e6 * (z[0] - 3.0 * z[1]);
            },
            |_z, j| {
                j[0] = 2.0;
                j[1] = 1e6;
                j[2] = 1.0;
                j[3] = -3e6;
            },
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let scales = McpScales {
            variables: vec![4.0, 0.5],
            rows: vec![1.0, 1e6],
        }
        .rounded_to_powers_of_two();
        assert_eq!(scales.rows[1], 2f64.powi(20));
        let scaled = ScaledMcp::new(&mcp, &scales).unwrap_or_else(|| panic!("valid scales"));
        let zs = [0.25, 2.0];
        let mut f = [0.0; 2];
        let mut j = [0.0; 4];
        scaled.evaluate_with_jacobian(&zs, &mut f, &mut j);
        // z = (1, 1): F = (2, −2e6).
        assert_eq!(f, [2.0, -2e6 / 2f64.powi(20)]);
        assert_eq!(j, [8.0, 4e6 / 2f64.powi(20), 0.5, -1.5e6 / 2f64.powi(20)]);
        // The solution z = (3/7, 1/7) (F = 0) stays a solution (to round-off).
        let z = [3.0 / 7.0, 1.0 / 7.0];
        let zt = scaled.to_scaled(&z);
        scaled.evaluate(&zt, &mut f);
        assert!(natural_residual(&zt, &f, scaled.lower(), scaled.upper()) < 1e-15);
        assert_eq!(scaled.to_unscaled(&zt), z.to_vec());
    }

    #[test]
    fn scales_that_do_not_fit_are_refused() {
        let mcp = FnMcp::dense(vec![0.0], vec![1.0], |z, f| f[0] = z[0], |_z, j| j[0] = 1.0)
            .unwrap_or_else(|e| panic!("{e}"));
        let bad = McpScales {
            variables: vec![0.0],
            rows: vec![1.0],
        };
        assert!(ScaledMcp::new(&mcp, &bad).is_none());
        assert!(ScaledMcp::new(&mcp, &McpScales::identity(2)).is_none());
        for bad in [f64::NAN, f64::INFINITY, -1.0, -0.0, 0.0] {
            let scales = |v: Vec<f64>, r: Vec<f64>| McpScales {
                variables: v,
                rows: r,
            };
            assert!(!scales(vec![1.0, bad], vec![1.0, 1.0]).is_valid(2), "{bad}");
            assert!(!scales(vec![1.0, 1.0], vec![bad, 1.0]).is_valid(2), "{bad}");
        }
        assert!(McpScales::identity(3).is_valid(3) && !McpScales::identity(3).is_valid(2));
        assert_eq!(power_of_two(3.0), 4.0);
        assert_eq!(power_of_two(f64::NAN), 1.0);
    }

    /// `usage` is the verdict of `is_identity`, `is_valid` and `far_from_si` on every pair of
    /// scales from a list that holds each case (1, inside the inner band, between the inner
    /// band and the band's edge, outside, not positive, not finite), at either place.
    #[test]
    fn usage_is_the_verdict_of_the_three_tests() {
        let values = [
            1.0,
            0.5,
            2f64.powi(19),
            2f64.powi(-19),
            1.5 * 2f64.powi(19),
            2f64.powi(20),
            1.5 * 2f64.powi(20),
            2f64.powi(-21),
            2f64.powi(30),
            0.0,
            -0.0,
            -1.0,
            f64::NAN,
            f64::INFINITY,
        ];
        let mut seen = [0usize; 3];
        for a in values {
            for b in values {
                for scales in [
                    McpScales {
                        variables: vec![1.0, a, 1.0],
                        rows: vec![b, 1.0, 1.0],
                    },
                    McpScales {
                        variables: vec![b, 1.0, a],
                        rows: vec![1.0, 1.0, 1.0],
                    },
                    McpScales {
                        variables: vec![1.0, 1.0, 1.0],
                        rows: vec![1.0, a, b],
                    },
                ] {
                    let expected = if scales.is_identity() || !scales.is_valid(3) {
                        ScalesUsage::Unscaled
                    } else if far_from_si(&scales) {
                        ScalesUsage::FarFromSi
                    } else {
                        ScalesUsage::WithinSi
                    };
                    assert_eq!(scales.usage(3), expected, "{scales:?}");
                    assert_eq!(scales.usage(2), ScalesUsage::Unscaled);
                    seen[expected as usize] += 1;
                }
            }
        }
        // Each verdict occurs.
        assert!(seen.iter().all(|&n| n > 0), "{seen:?}");
    }

    /// The scales from their bits are those of the logarithm bit for bit: on a sweep of
    /// mantissas and exponents (the ulps either side of `√2` included), at the clamp, for
    /// subnormals and for what is not a positive finite number.
    #[test]
    fn powers_of_two_from_bits_are_those_of_the_logarithm() {
        let sqrt2 = std::f64::consts::SQRT_2;
        let mut values = vec![
            0.0,
            -0.0,
            -1.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE,
            f64::MIN_POSITIVE / 3.0,
            f64::MAX,
            2f64.powi(-1000),
            2f64.powi(1000),
            1.5 * 2f64.powi(-1001),
            1.5 * 2f64.powi(1000),
        ];
        for e in (-1030..=1030).step_by(7).chain(-3..=3) {
            let p = 2f64.powi(e);
            let mut m = sqrt2;
            let mut below = sqrt2;
            for _ in 0..4 {
                m = f64::from_bits(m.to_bits() + 1);
                below = f64::from_bits(below.to_bits() - 1);
                values.extend([m * p, below * p]);
            }
            for k in 0..64 {
                values.push((1.0 + k as f64 / 64.0) * p);
            }
        }
        for s in values {
            assert_eq!(
                power_of_two(s).to_bits(),
                power_of_two_by_log2(s).to_bits(),
                "s = {s:e}"
            );
            assert_eq!(
                outside_si_band(s),
                s.log2().abs() > SI_BAND_LOG2,
                "s = {s:e}"
            );
        }
        assert_eq!(power_of_two(1.4 * 8.0), 8.0);
        assert_eq!(power_of_two(1.42 * 8.0), 16.0);
        assert!(!outside_si_band(2f64.powi(20)) && outside_si_band(2f64.powi(20) * 1.5));
        assert!(outside_si_band(0.0) && !outside_si_band(-1.0) && !outside_si_band(f64::NAN));
    }
}

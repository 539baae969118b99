//! The scene scales of an ECP step problem (`docs/decisions.md#scene-scaled-convergence`): the
//! unit of every unknown and every row, from the span's own mass, length and time scales, so
//! that the backends judge the natural residual in dimensionless units
//! ([`ecp_model::McpScales`]).
//!
//! Per body `b`: mass `M = m_b`, length `L = ` the diagonal of the bounding box of Conv(F),
//! step `h`, acceleration `A = |g|` (`L / h²` without gravity), velocity `V = A h` (the velocity
//! gravity adds in one step), impulse `P = M V`. Each unit is the quantity's dimension in these
//! (`docs/model.md#unknowns`, `#contact`):
//!
//! | unknown | unit | its row | unit |
//! |---|---|---|---|
//! | `v`, `ω` | `V`, `V / L` | Newton–Euler (16), force, torque | `P`, `P L` |
//! | `x`, `Q` | `L`, 1 | kinematic map (17), position, quaternion | `L`, 1 |
//! | `a1`, `a2`, `l_g` | `L` | C1 (8) (× 1/h) | `L / h` |
//! | `l_i` | 1 | C2 (9), C3 (10) (× 1/h) | 1, `L / h` |
//! | `p_n` | `P` | C4 (11), C5 (12) (× 1/h) | `L / h` |
//! | `p_t`, `p_o`, `p_r` | `μ̄ P`, `μ̄ P`, `μ̄ P L` | maximum dissipation (14) | `μ̄ P V`, `μ̄ P V`, `μ̄ P V L` |
//! | `σ` | `V` | friction cone (15) | `μ̄ P` |
//!
//! with `μ̄ = max(μ, 1)` (the friction impulse is bounded by `μ p_n`; a large μ would otherwise
//! make the friction rows dominate every other). Contacts take their body's units; l_g and the
//! C2 rows of the union formulation are those of its piece's body. Every unit is rounded to a
//! power of two, so that scaling and unscaling are exact.

use ecp_model::{BlockMcp, Mcp, McpScales, power_of_two};

use super::layout::Layout;

/// One body's units, each rounded to a power of two ([`power_of_two`], as
/// [`McpScales::round_to_powers_of_two`] rounds every scale): the eleven distinct scales its
/// unknowns and rows take (module documentation), with `L` the body's length, `V` its velocity,
/// `P = M V` its impulse and `P̄ = μ̄ P` its friction impulse.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct BodyUnits {
    l: f64,
    v: f64,
    v_per_l: f64,
    p: f64,
    p_l: f64,
    /// `L / h`, the contact rows of a length (× 1/h).
    l_per_h: f64,
    pf: f64,
    pf_l: f64,
    pf_v: f64,
    pf_v_l: f64,
}

impl BodyUnits {
    /// The units of length `l`, velocity `v` and impulse `p` (unrounded) in a span of length `h`
    /// with `μ̄ = mu_bar`, rounded: the products formed as the scales' entries were before
    /// rounding, so each is that entry's rounding.
    fn rounded(l: f64, v: f64, p: f64, h: f64, mu_bar: f64) -> Self {
        let pf = mu_bar * p;
        BodyUnits {
            l: power_of_two(l),
            v: power_of_two(v),
            v_per_l: power_of_two(v / l),
            p: power_of_two(p),
            p_l: power_of_two(p * l),
            l_per_h: power_of_two(l / h),
            pf: power_of_two(pf),
            pf_l: power_of_two(pf * l),
            pf_v: power_of_two(pf * v),
            pf_v_l: power_of_two(pf * v * l),
        }
    }
}

impl Layout {
    /// The scales of the span just recorded ([`Layout::record_span`]), in `mcp`'s layout,
    /// written into `s` (and each body's rounded units into `units`), whose storage is reused.
    /// When `s` holds the scales of a span of the same problem whose rounded units are those of
    /// this span (`units` on entry; the common case: a speed or a step length that changed
    /// within a factor of `√2` of the same power of two), it is left as it is, the same
    /// numbers as filling it again. Returns whether it filled `s` (`false`: left as it was).
    pub(crate) fn scene_scales_into(
        &self,
        mcp: &BlockMcp,
        s: &mut McpScales,
        units: &mut Vec<BodyUnits>,
    ) -> bool {
        let n = mcp.dim();
        let h = self.span.h;
        let mu_bar = self.span.friction[0].max(1.0);
        let filled =
            s.variables.len() == n && s.rows.len() == n && units.len() == self.bodies.len();
        units.resize(self.bodies.len(), BodyUnits::default());
        let mut same = filled;
        for ((body, data), kept) in self
            .bodies
            .iter()
            .zip(&self.span.bodies)
            .zip(units.iter_mut())
        {
            let l = body.length;
            let g = data.gravity.norm();
            let a = if g > 0.0 { g } else { l / (h * h) };
            // The body's own speed at the span's start, when above what gravity adds.
            let speed = data.nu_start.fixed_rows::<3>(0).norm()
                + data.nu_start.fixed_rows::<3>(3).norm() * 0.5 * l;
            let v = (a * h).max(speed);
            let u = BodyUnits::rounded(l, v, data.mass * v, h, mu_bar);
            same &= *kept == u;
            *kept = u;
        }
        if same {
            return false;
        }
        for v in [&mut s.variables, &mut s.rows] {
            v.clear();
            v.resize(n, 1.0);
        }
        let mut set = |v: ecp_model::VarId, var: &[f64], row: &[f64]| {
            let r = self.range(v);
            for (k, i) in r.enumerate() {
                s.variables[i] = var[k.min(var.len() - 1)];
                s.rows[i] = row[k.min(row.len() - 1)];
            }
        };
        for (body, u) in self.bodies.iter().zip(units.iter()) {
            let (v, vl, p, pl) = (u.v, u.v_per_l, u.p, u.p_l);
            set(body.nu, &[v, v, v, vl, vl, vl], &[p, p, p, pl, pl, pl]);
            set(body.q, &[u.l, u.l, u.l, 1.0], &[u.l, u.l, u.l, 1.0]);
        }
        for c in &self.contacts {
            let Some(u) = units.get(c.body) else {
                continue;
            };
            let geometry_row = u.l_per_h;
            set(c.a1, &[u.l], &[geometry_row]);
            set(c.a2, &[u.l], &[1.0]);
            set(c.l, &[1.0], &[geometry_row]);
            set(c.lg, &[u.l], &[geometry_row]);
            set(c.pn, &[u.p], &[geometry_row]);
            set(c.pf, &[u.pf, u.pf, u.pf_l], &[u.pf_v, u.pf_v, u.pf_v_l]);
            set(c.sigma, &[u.v], &[u.pf]);
        }
        true
    }
}

/// The diagonal of the axis-aligned bounding box of `points` (1 for an empty or degenerate set).
pub(super) fn bounding_diagonal(points: &[nalgebra::Vector3<f64>]) -> f64 {
    let Some(first) = points.first() else {
        return 1.0;
    };
    let (mut lo, mut hi) = (*first, *first);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let d = (hi - lo).norm();
    if d.is_finite() && d > 0.0 { d } else { 1.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ecp::EcpContacts;
    use crate::scenarios;
    use crate::step::Simulation;

    /// The scales as they were computed before the rounded units were kept: every entry set
    /// from the unrounded units, then every entry rounded.
    fn scales_by_entries(layout: &Layout, mcp: &BlockMcp) -> McpScales {
        let n = mcp.dim();
        let mut s = McpScales::identity(n);
        let h = layout.span.h;
        let mu_bar = layout.span.friction[0].max(1.0);
        let units: Vec<(f64, f64, f64)> = (layout.bodies.iter().zip(&layout.span.bodies))
            .map(|(body, data)| {
                let l = bounding_diagonal(body.hull.vertices());
                let g = data.gravity.norm();
                let a = if g > 0.0 { g } else { l / (h * h) };
                let speed = data.nu_start.fixed_rows::<3>(0).norm()
                    + data.nu_start.fixed_rows::<3>(3).norm() * 0.5 * l;
                let v = (a * h).max(speed);
                (l, v, data.mass * v)
            })
            .collect();
        let mut set = |v: ecp_model::VarId, var: &[f64], row: &[f64]| {
            for (k, i) in layout.range(v).enumerate() {
                s.variables[i] = var[k.min(var.len() - 1)];
                s.rows[i] = row[k.min(row.len() - 1)];
            }
        };
        for (body, &(l, v, p)) in layout.bodies.iter().zip(&units) {
            set(
                body.nu,
                &[v, v, v, v / l, v / l, v / l],
                &[p, p, p, p * l, p * l, p * l],
            );
            set(body.q, &[l, l, l, 1.0], &[l, l, l, 1.0]);
        }
        for c in &layout.contacts {
            let (l, v, p) = units[c.body];
            let geometry_row = l / h;
            set(c.a1, &[l], &[geometry_row]);
            set(c.a2, &[l], &[1.0]);
            set(c.l, &[1.0], &[geometry_row]);
            set(c.lg, &[l], &[geometry_row]);
            set(c.pn, &[p], &[geometry_row]);
            let pf = mu_bar * p;
            set(c.pf, &[pf, pf, pf * l], &[pf * v, pf * v, pf * v * l]);
            set(c.sigma, &[v], &[pf]);
        }
        s.rounded_to_powers_of_two()
    }

    /// Over A1's slide to rest (its speed unit falling through several powers of two) and the
    /// desk's first steps, the kept scales of every step are those computed entry by entry, bit
    /// for bit, both when the rounded units changed (a refill) and when they did not (kept).
    #[test]
    fn kept_scales_are_those_computed_entry_by_entry() {
        let mut solver = ecp_solvers::newton::NewtonSolver::new(Default::default());
        let (mut kept, mut refilled) = (0, 0);
        let mut usages = std::collections::BTreeSet::new();
        for (scene, steps) in [(scenarios::a1_sliding(), 50), (scenarios::desk(), 40)] {
            let mut sim = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
            let mut last: Option<Vec<BodyUnits>> = None;
            for step in 0..steps {
                let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
                assert!(rec.converged, "step {step}");
                let ecp = sim
                    .formulation_as::<EcpContacts>()
                    .unwrap_or_else(|| panic!("an ECP formulation"));
                let layout = &ecp.layout;
                let scales = layout.scales.as_ref().unwrap_or_else(|| panic!("scales"));
                let expected = scales_by_entries(layout, sim.mcp());
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&scales.variables),
                    bits(&expected.variables),
                    "step {step}"
                );
                assert_eq!(bits(&scales.rows), bits(&expected.rows), "step {step}");
                // The verdict kept with the scales is that of a pass over them, and the one
                // the step problem hands the backends.
                let n = sim.mcp().dim();
                assert_eq!(
                    layout.scales_usage,
                    Some((n, scales.usage(n))),
                    "step {step}"
                );
                let handed = sim.step_problem().scales_usage().map(|(_, u)| u);
                assert_eq!(handed, Some(scales.usage(n)), "step {step}");
                usages.insert(format!("{:?}", scales.usage(n)));
                if last.as_ref() == Some(&layout.span.units) {
                    kept += 1;
                } else {
                    refilled += 1;
                }
                last = Some(layout.span.units.clone());
            }
        }
        assert!(
            kept > 10 && refilled > 3,
            "kept {kept}, refilled {refilled}"
        );
        // Both scenes in SI units: within the band, solved as given first.
        assert_eq!(usages.into_iter().collect::<Vec<_>>(), ["WithinSi"]);
    }
}

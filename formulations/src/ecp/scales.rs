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

use ecp_model::{BlockMcp, Mcp, McpScales};

use super::layout::Layout;

impl Layout {
    /// The scales of the span just recorded ([`Layout::record_span`]), in `mcp`'s layout,
    /// written into `s` (and each body's units into `units`), whose storage is reused.
    pub(crate) fn scene_scales_into(
        &self,
        mcp: &BlockMcp,
        s: &mut McpScales,
        units: &mut Vec<(f64, f64, f64)>,
    ) {
        let n = mcp.dim();
        for v in [&mut s.variables, &mut s.rows] {
            v.clear();
            v.resize(n, 1.0);
        }
        let h = self.span.h;
        let mu_bar = self.span.friction[0].max(1.0);
        units.clear();
        units.extend(
            (self.bodies.iter().zip(&self.span.bodies)).map(|(body, data)| {
                let l = bounding_diagonal(body.hull.vertices());
                let g = data.gravity.norm();
                let a = if g > 0.0 { g } else { l / (h * h) };
                // The body's own speed at the span's start, when above what gravity adds.
                let speed = data.nu_start.fixed_rows::<3>(0).norm()
                    + data.nu_start.fixed_rows::<3>(3).norm() * 0.5 * l;
                let v = (a * h).max(speed);
                (l, v, data.mass * v)
            }),
        );
        let mut set = |v: ecp_model::VarId, var: &[f64], row: &[f64]| {
            let r = self.range(v);
            for (k, i) in r.enumerate() {
                s.variables[i] = var[k.min(var.len() - 1)];
                s.rows[i] = row[k.min(row.len() - 1)];
            }
        };
        for (body, &(l, v, p)) in self.bodies.iter().zip(units.iter()) {
            set(
                body.nu,
                &[v, v, v, v / l, v / l, v / l],
                &[p, p, p, p * l, p * l, p * l],
            );
            set(body.q, &[l, l, l, 1.0], &[l, l, l, 1.0]);
        }
        for c in &self.contacts {
            let Some(&(l, v, p)) = units.get(c.body) else {
                continue;
            };
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
        s.round_to_powers_of_two();
    }
}

/// The diagonal of the axis-aligned bounding box of `points` (1 for an empty or degenerate set).
fn bounding_diagonal(points: &[nalgebra::Vector3<f64>]) -> f64 {
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

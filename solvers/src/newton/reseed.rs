//! The last stage of a failed solve: the warm start's contacts re-derived from the geometry
//! ([`NewtonSettings::structure_reseed`], `docs/stress.md`, branch wip-tip070).
//!
//! A warm start carries the last step's contact point (`a1`, `a2`, the hull weights). When a
//! body turns far within the step (`s20270320_070_union_tip`: 430 rad/s, 2.1 rad a step) the
//! landing vertex lies far from it, and every attempt from that point stalls at a local
//! minimiser of the merit where the old vertex's weights keep a small residual. The structure
//! knows the geometry: mapping the warm start's velocities back
//! ([`ecp_model::StepStructure::assemble`]) with each contact's normal impulse on the lowest
//! vertex of its patch at the warm start's configuration places the point where the body
//! touches there. Only the start changes; the solve from it is the whole solve.

use ecp_model::{ConicPoint, ContactImpulses, Counter, Mcp, Solution, SolveError};

use super::NewtonSolver;

/// The reseeded start of `mcp` from `z0`, or `None` without a structure or contacts.
pub(super) fn reseeded_start(mcp: &dyn Mcp, z0: &[f64]) -> Option<Vec<f64>> {
    let st = mcp.structure()?;
    let contacts = st.num_contacts();
    if contacts == 0 {
        return None;
    }
    let mut point = ConicPoint {
        velocities: st.velocities(z0),
        contacts: Vec::with_capacity(contacts),
    };
    for c in 0..contacts {
        let g = st.contact(c, z0, 0.0);
        // The warm start's normal impulse (zero when the structure does not say or it is not
        // finite): with none the map back puts the point nearest to G, not on the vertex.
        let pn = st
            .normal_impulse(c, z0)
            .filter(|p| p.is_finite())
            .unwrap_or(0.0)
            .max(0.0);
        let mut imp = ContactImpulses::default();
        if let Some(v) = g.patch.iter().min_by(|a, b| a.gap.total_cmp(&b.gap)) {
            imp.vertex_impulses.push((v.index, pn));
        }
        point.contacts.push(imp);
    }
    let mut z = z0.to_vec();
    st.assemble(&point, &mut z);
    // A start the solve can use: finite and within the bounds.
    let (lower, upper) = (mcp.lower(), mcp.upper());
    for (i, zi) in z.iter_mut().enumerate() {
        if !zi.is_finite() {
            return None;
        }
        *zi = zi.clamp(lower[i], upper[i]);
    }
    Some(z)
}

impl NewtonSolver {
    /// After the whole solve from `z0` failed (`failed`, returned as it is unless it is a
    /// `NotConverged` with its best point `best`): the whole solve again from the
    /// reseeded start ([`reseeded_start`]); its result when it converges (its iterations
    /// counting the failed solve's, one `Counter::Custom("structure_reseed")`), else the
    /// better end point of the two.
    #[cold]
    #[inline(never)]
    pub(super) fn reseed_attempt(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        failed: Result<Solution, SolveError>,
    ) -> Result<Solution, SolveError> {
        let best = match failed {
            Err(SolveError::NotConverged { best }) => best,
            other => return other,
        };
        let spent = best.summary.iterations;
        let Some(start) = reseeded_start(mcp, z0) else {
            return Err(SolveError::NotConverged { best });
        };
        match self.solve_from(mcp, &start) {
            Ok(mut sol) => {
                sol.summary.iterations += spent;
                sol.summary
                    .counters
                    .add(Counter::Custom("structure_reseed"), 1);
                Ok(sol)
            }
            Err(SolveError::NotConverged { best: other }) => {
                let total = spent + other.summary.iterations;
                let mut kept = if other.summary.residual < best.summary.residual {
                    other
                } else {
                    best
                };
                kept.summary.iterations = total;
                Err(SolveError::NotConverged { best: kept })
            }
            Err(_) => Err(SolveError::NotConverged { best }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without a structure there is nothing to reseed: the failed solve's result stands, so
    /// problems without contacts geometry (the MCP library) are solved as before.
    #[test]
    fn no_structure_no_reseed() {
        let p = ecp_model::mcp_library::kojima_josephy();
        let (_, z0) = &p.starts[0];
        assert!(p.mcp.structure().is_none());
        assert!(reseeded_start(&p.mcp, z0).is_none());
    }
}

//! Which convex pieces of a body get a contact in the union formulation (`docs/model.md#union`).

use crate::geometry::{HalfSpace, min_gap, world_vertices};
use crate::rotation::rotation_matrix;
use crate::scene::{BodySpec, BodyState};

/// Fraction of a body's extent along a plane's normal within which a piece's lowest point must
/// lie, above the body's lowest point, for the piece to get a contact in the union formulation.
/// See `docs/decisions.md#union_reach`.
pub const UNION_REACH: f64 = 0.25;

/// The pieces of `spec` that get a contact in the union formulation (`docs/model.md#union`: one
/// contact per convex piece that can touch a half-space): for some plane, the piece's lowest
/// vertex at `state` is within [`UNION_REACH`] of the body's extent along the normal above the
/// body's lowest vertex. For the desk that is the four legs, for the T-bar both bars
/// (`docs/decisions.md#union_reach`).
pub fn union_pieces(spec: &BodySpec, state: &BodyState, planes: &[HalfSpace]) -> Vec<usize> {
    let r = rotation_matrix(&state.q);
    let pieces = spec.shape.pieces();
    let mut chosen = vec![false; pieces.len()];
    for plane in planes {
        let heights: Vec<f64> = pieces
            .iter()
            .map(|p| min_gap(&p.vertices(), &state.x, &r, plane))
            .collect();
        let all: Vec<f64> = world_vertices(spec.shape.vertices(), &state.x, &r)
            .iter()
            .map(|v| plane.value(v))
            .collect();
        let lo = all.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = all.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let reach = UNION_REACH * (hi - lo);
        for (k, h) in heights.iter().enumerate() {
            if *h <= lo + reach {
                chosen[k] = true;
            }
        }
    }
    (0..pieces.len()).filter(|&k| chosen[k]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenarios;

    #[test]
    fn the_desk_gets_its_legs_and_the_t_bar_both_bars() {
        let desk = scenarios::desk();
        let b = &desk.bodies[0];
        let legs = union_pieces(b, &b.initial, &desk.planes);
        // The top slab is far above the ground: only the four legs.
        assert_eq!(legs, vec![1, 2, 3, 4]);
        let tbar = scenarios::t_bar();
        let t = &tbar.bodies[0];
        assert_eq!(union_pieces(t, &t.initial, &tbar.planes), vec![0, 1]);
    }
}

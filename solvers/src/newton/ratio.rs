//! The ratio test of the Newton search (`docs/newton.md#the-ratio-test`): along the Newton
//! direction `d`, the first step length at which the linearisation `z + t d`, `F + t J d` of a
//! complementarity pair leaves its cone — a component reaches its bound from inside, or the
//! residual of a component at its bound changes sign. The Fischer–Burmeister element of an
//! inactive pair linearises to "stay at the bound" and ignores `F`, so a long Newton step
//! drives `F` of an inactive face far below zero and the merit up by orders of magnitude; a
//! pivotal method (PATH) stops at the first such event and changes the basis there. Stopping
//! at it and linearising again at that point (where the pair now sits on its other branch) is
//! that pivot.

use ecp_model::bounds::{BoundKind, classify};

/// The first event along `z + t d` with `t` in `(0, 1)`: `(t, i, on_bound)`, where `on_bound`
/// says that component `i` reaches a bound (rather than its residual crossing zero). `jd` is
/// `J d`. `None` when no pair leaves its cone before the full step.
pub(super) fn first_event(
    z: &[f64],
    f: &[f64],
    d: &[f64],
    jd: &[f64],
    l: &[f64],
    u: &[f64],
) -> Option<(f64, usize, bool)> {
    let mut first: Option<(f64, usize, bool)> = None;
    let mut consider = |t: f64, i: usize, on_bound: bool| {
        if t > 0.0 && t < 1.0 && first.is_none_or(|(best, _, _)| t < best) {
            first = Some((t, i, on_bound));
        }
    };
    // A side `s ≥ 0` of a pair that falls at rate `ds < 0` reaches zero at `s / −ds`.
    let crossing = |s: f64, ds: f64| if s > 0.0 && ds < 0.0 { s / -ds } else { 0.0 };
    for i in 0..z.len() {
        match classify(l[i], u[i]) {
            BoundKind::Free => {}
            BoundKind::Lower => {
                consider(crossing(z[i] - l[i], d[i]), i, true);
                consider(crossing(f[i], jd[i]), i, false);
            }
            BoundKind::Upper => {
                consider(crossing(u[i] - z[i], -d[i]), i, true);
                consider(crossing(-f[i], -jd[i]), i, false);
            }
            BoundKind::Box => {
                consider(crossing(z[i] - l[i], d[i]), i, true);
                consider(crossing(u[i] - z[i], -d[i]), i, true);
                consider(crossing(f[i], jd[i]), i, false);
                consider(crossing(-f[i], -jd[i]), i, false);
            }
        }
    }
    first
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_pair_to_leave_its_cone_is_found() {
        let inf = f64::INFINITY;
        // 0: free; 1: z ≥ 0 inside, falling to its bound at t = 0.5; 2: z ≥ 0 at its bound with
        // F = 2 falling at 8 (crosses at 0.25); 3: z ≤ 1 rising to it at t = 0.75.
        let z = [5.0, 1.0, 0.0, 0.25];
        let f = [1.0, 0.0, 2.0, 0.0];
        let d = [-100.0, -2.0, 0.0, 1.0];
        let jd = [-100.0, 0.0, -8.0, 0.0];
        let l = [-inf, 0.0, 0.0, -inf];
        let u = [inf, inf, inf, 1.0];
        assert_eq!(first_event(&z, &f, &d, &jd, &l, &u), Some((0.25, 2, false)));
        let jd = [0.0; 4];
        assert_eq!(first_event(&z, &f, &d, &jd, &l, &u), Some((0.5, 1, true)));
        // Nothing before the full step.
        let d = [1.0, 1.0, 0.0, -1.0];
        assert_eq!(first_event(&z, &f, &d, &jd, &l, &u), None);
    }
}

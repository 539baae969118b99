//! The closest-point problem between two convex sets with clarabel (`docs/backends.md#conic`,
//! `docs/model.md#contact`): `min ‖p − q‖` over `p ∈ A`, `q ∈ B`.
//!
//! Two objectives with the same minimisers: the QP `½‖p − q‖²` ([`closest_points_qp`]) and the
//! distance's epigraph `t` with `(t, p − q) ∈ SOC(4)`. Each is inaccurate where the other is not:
//! the QP resolves a touching or overlapping pair only to about the square root of the tolerance,
//! the epigraph form's points only to about `√(d · tolerance)`. [`closest_points`] solves the QP
//! and re-solves in epigraph form when the distance is below `1e-4` or clarabel did not fully solve
//! the QP (`docs/decisions.md#closest-points-qp-then-epigraph-form-near-contact`); agreement with
//! parry's GJK is 1e-8 in the distance (`tests/conic_closest_point.rs`).
//!
//! ```
//! use ecp_solvers::conic::closest_point::{ConvexSet, closest_points};
//! use ecp_solvers::conic::default_clarabel_settings;
//!
//! // A unit cube 0.5 above the ground z ≤ 0.
//! let cube: Vec<[f64; 3]> = (0..8)
//!     .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, 0.5 + ((i >> 2) & 1) as f64])
//!     .collect();
//! let ground = [([0.0, 0.0, 1.0], 0.0)];
//! let r = closest_points(
//!     &ConvexSet::Vertices(&cube),
//!     &ConvexSet::HalfSpaces(&ground),
//!     &default_clarabel_settings(),
//! )
//! .unwrap();
//! assert!((r.distance - 0.5).abs() < 1e-9);
//! assert!(r.on_second[2].abs() < 1e-9);
//! ```

use clarabel::solver::{DefaultSettings, SolverStatus};

use super::qp::{Cone, ConicQp, usable};

/// A convex set in R³.
#[derive(Clone, Copy, Debug)]
pub enum ConvexSet<'a> {
    /// The convex hull of a (non-empty) point set.
    Vertices(&'a [[f64; 3]]),
    /// The intersection `{p : a_iᵀ p ≤ b_i}` of half-spaces `(a_i, b_i)` (non-empty, and bounded
    /// unless the other set makes the problem bounded, e.g. a half-space against a polytope).
    HalfSpaces(&'a [([f64; 3], f64)]),
}

/// The closest points of two convex sets.
#[derive(Clone, Debug, PartialEq)]
pub struct ClosestPoints {
    /// Euclidean distance `‖p − q‖` (0 when the sets intersect).
    pub distance: f64,
    /// The point `p` of the first set.
    pub on_first: [f64; 3],
    /// The point `q` of the second set.
    pub on_second: [f64; 3],
    /// Interior-point iterations.
    pub iterations: u32,
    /// Whether clarabel reached full accuracy (`Solved`; otherwise `AlmostSolved`).
    pub fully_solved: bool,
}

/// Why the closest points could not be computed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ClosestPointError {
    /// A set is empty or has non-finite data.
    #[error("invalid convex set: {0}")]
    InvalidSet(String),
    /// clarabel did not solve the QP; its status passes through.
    #[error("clarabel did not solve the closest-point QP: {status:?}")]
    NotSolved {
        /// clarabel's status.
        status: SolverStatus,
    },
    /// clarabel rejected the problem or failed.
    #[error("clarabel failed: {0}")]
    Failed(String),
}

/// Adds the constraints `point ∈ set` for the point in columns `col..col + 3`; extra variables
/// (convex weights) are taken from `*next`.
fn add_set(qp: &mut ConicQp, set: &ConvexSet<'_>, col: usize, next: &mut usize) {
    match set {
        ConvexSet::Vertices(v) => {
            let first = *next;
            *next += v.len();
            // p − Σ α_k v_k = 0 and Σ α_k = 1 (zero cone), then α ≥ 0.
            for i in 0..3 {
                let mut coeffs = vec![(col + i, 1.0)];
                coeffs.extend(v.iter().enumerate().map(|(k, p)| (first + k, -p[i])));
                qp.push_row(&coeffs, 0.0);
            }
            let ones: Vec<(usize, f64)> = (0..v.len()).map(|k| (first + k, 1.0)).collect();
            qp.push_row(&ones, 1.0);
            qp.cones.push(Cone::Zero(4));
            for k in 0..v.len() {
                qp.push_row(&[(first + k, -1.0)], 0.0);
            }
            qp.cones.push(Cone::Nonnegative(v.len()));
        }
        ConvexSet::HalfSpaces(h) => {
            for (a, b) in h.iter() {
                qp.push_row(&[(col, a[0]), (col + 1, a[1]), (col + 2, a[2])], *b);
            }
            qp.cones.push(Cone::Nonnegative(h.len()));
        }
    }
}

fn check(set: &ConvexSet<'_>) -> Result<usize, ClosestPointError> {
    match set {
        ConvexSet::Vertices(v) => {
            if v.is_empty() {
                return Err(ClosestPointError::InvalidSet("no vertices".into()));
            }
            if v.iter().flatten().any(|x| !x.is_finite()) {
                return Err(ClosestPointError::InvalidSet("non-finite vertex".into()));
            }
            Ok(v.len())
        }
        ConvexSet::HalfSpaces(h) => {
            if h.is_empty() {
                return Err(ClosestPointError::InvalidSet("no half-spaces".into()));
            }
            if h.iter()
                .any(|(a, b)| !b.is_finite() || a.iter().any(|x| !x.is_finite()))
            {
                return Err(ClosestPointError::InvalidSet(
                    "non-finite half-space".into(),
                ));
            }
            Ok(0)
        }
    }
}

/// The closest points of `a` and `b`: the QP, and the epigraph form when the sets (nearly)
/// touch (module docs), solved by clarabel with `settings`
/// ([`super::default_clarabel_settings`] give 1e-8 agreement with GJK).
pub fn closest_points(
    a: &ConvexSet<'_>,
    b: &ConvexSet<'_>,
    settings: &DefaultSettings<f64>,
) -> Result<ClosestPoints, ClosestPointError> {
    let quadratic = solve(a, b, settings, true);
    if let Ok(r) = &quadratic
        && r.distance >= 1e-4
        && r.fully_solved
    {
        return quadratic;
    }
    let mut conic = solve(a, b, settings, false)?;
    conic.iterations += quadratic.map_or(0, |r| r.iterations);
    Ok(conic)
}

/// The closest points of `a` and `b` from the QP `min ½‖p − q‖²` (accurate for separated
/// sets; see the module docs for touching ones).
pub fn closest_points_qp(
    a: &ConvexSet<'_>,
    b: &ConvexSet<'_>,
    settings: &DefaultSettings<f64>,
) -> Result<ClosestPoints, ClosestPointError> {
    solve(a, b, settings, true)
}

fn solve(
    a: &ConvexSet<'_>,
    b: &ConvexSet<'_>,
    settings: &DefaultSettings<f64>,
    quadratic: bool,
) -> Result<ClosestPoints, ClosestPointError> {
    let extra = check(a)? + check(b)?;
    // Variables: p (0..3), q (3..6), t (6), then the convex weights.
    let mut qp = ConicQp::new(7 + extra);
    if quadratic {
        for i in 0..3 {
            qp.add_p(i, i, 1.0);
            qp.add_p(3 + i, 3 + i, 1.0);
            qp.add_p(i, 3 + i, -1.0);
        }
        // t is unused: pin it to 0.
        qp.push_row(&[(6, 1.0)], 0.0);
        qp.cones.push(Cone::Zero(1));
    } else {
        qp.q[6] = 1.0;
        qp.push_row(&[(6, -1.0)], 0.0);
        for i in 0..3 {
            qp.push_row(&[(i, -1.0), (3 + i, 1.0)], 0.0);
        }
        qp.cones.push(Cone::SecondOrder(4));
    }
    let mut next = 7;
    add_set(&mut qp, a, 0, &mut next);
    add_set(&mut qp, b, 3, &mut next);
    let r = qp.solve(settings).map_err(ClosestPointError::Failed)?;
    if !usable(r.status) {
        return Err(ClosestPointError::NotSolved { status: r.status });
    }
    let p = [r.x[0], r.x[1], r.x[2]];
    let q = [r.x[3], r.x[4], r.x[5]];
    let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
    if !d.is_finite() {
        return Err(ClosestPointError::Failed("non-finite solution".into()));
    }
    Ok(ClosestPoints {
        distance: d,
        on_first: p,
        on_second: q,
        iterations: r.iterations,
        fully_solved: r.status == SolverStatus::Solved,
    })
}

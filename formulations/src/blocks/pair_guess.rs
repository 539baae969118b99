//! Starting guesses of a contact between two bodies (`docs/model.md#contact-between-two-bodies`,
//! "Starting guesses"): the closest-point unknowns from the closest features
//! ([`crate::geometry::pair_features`]), the impulses from the weight and the approach, `σ` and
//! the friction impulse from the slip at the start of the step.

use nalgebra::Vector3;

use super::friction::FrictionParams;
use super::pair_assembly::PairContactValues;
use super::pair_frame::PairFrame;
use crate::geometry::PairFeatures;

/// What the impulse guess needs of one body of the pair: its state at the start of the step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairMotion {
    /// Mass of a dynamic body; `None` for a fixed or kinematic one (infinitely heavy for the
    /// contact).
    pub mass: Option<f64>,
    /// CM position.
    pub x: Vector3<f64>,
    /// CM velocity.
    pub v: Vector3<f64>,
    /// Angular velocity (world frame).
    pub w: Vector3<f64>,
}

/// A guess of every unknown of one pair contact from its closest `features`, the bodies'
/// motion at the start of the step, the reference `axis` of the step's frame, the pair's
/// friction, gravity and the step `h`.
///
/// The closest-point unknowns are the features'. When the hulls touch or overlap
/// (`features.d == 0`) or `active` is set (the deterministic retry), the impulses start active,
/// as for a half-space (`docs/model.md#stepper`): `p_n` carries F's weight pressing along `−n`
/// (and G's, if G is dynamic and presses along `n`) over the step and stops the approach
/// velocity at the ECP with the pair's reduced mass; the friction impulse lies on the ellipsoid
/// against the slip at the start of the step, with `σ` the slip rate. Otherwise the impulses are
/// 0 and `σ` is the slip rate, at least `|g| h` (with `p_n = 0` and `σ = 0` the linearised
/// friction rows vanish and leave the friction impulse free, `docs/newton.md`).
#[allow(clippy::too_many_arguments)]
pub fn pair_guess(
    features: &PairFeatures,
    f: &PairMotion,
    g: &PairMotion,
    axis: &Vector3<f64>,
    friction: &FrictionParams,
    gravity: &Vector3<f64>,
    h: f64,
    active: bool,
) -> PairContactValues {
    let frame = PairFrame::new(&features.normal, axis);
    let n = frame.n;
    let v_rel = f.v + f.w.cross(&(features.a1 - f.x)) - g.v - g.w.cross(&(features.a2 - g.x));
    let w_rel = f.w - g.w;
    let (vt, vo, wn) = (frame.t.dot(&v_rel), frame.o.dot(&v_rel), n.dot(&w_rel));
    let fr = friction;
    let slip = ((fr.e_t * vt).powi(2) + (fr.e_o * vo).powi(2) + (fr.e_r * wn).powi(2)).sqrt();
    let floor = gravity.norm() * h;
    let floor = if floor > 0.0 { floor } else { 1.0 };
    let mut values = PairContactValues {
        a1: features.a1,
        a2: features.a2,
        l: features.l.clone(),
        mu: features.mu.clone(),
        d: features.d,
        pn: 0.0,
        pf: [0.0; 3],
        sigma: if slip.is_finite() && slip > floor {
            slip
        } else {
            floor
        },
    };
    if !(active || features.d == 0.0) {
        return values;
    }
    let m_f = f.mass.unwrap_or(0.0);
    let weight = h * (-m_f * gravity.dot(&n)).max(0.0)
        + g.mass
            .map_or(0.0, |m_g| h * (m_g * gravity.dot(&n)).max(0.0));
    let reduced = match g.mass {
        Some(m_g) if m_f + m_g > 0.0 => m_f * m_g / (m_f + m_g),
        _ => m_f,
    };
    values.pn = weight + reduced * (-v_rel.dot(&n)).max(0.0);
    if slip > 1e-12 && slip.is_finite() {
        let k = -fr.mu * values.pn / slip;
        values.pf = [
            k * fr.e_t * fr.e_t * vt,
            k * fr.e_o * fr.e_o * vo,
            k * fr.e_r * fr.e_r * wn,
        ];
        values.sigma = slip;
    }
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    fn features(d: f64) -> PairFeatures {
        PairFeatures {
            a1: Vector3::new(0.1, 0.0, 0.2 + d),
            a2: Vector3::new(0.1, 0.0, 0.2),
            d,
            l: vec![0.0, 1.0],
            mu: vec![1.0, 0.0],
            normal: Vector3::z(),
            distance: d,
            face_to_face: true,
        }
    }

    const FRICTION: FrictionParams = FrictionParams {
        mu: 0.3,
        e_t: 1.0,
        e_o: 1.0,
        e_r: 0.1,
    };

    #[test]
    fn resting_stack_carries_the_upper_weight() {
        let g_vec = Vector3::new(0.0, 0.0, -9.8);
        let top = PairMotion {
            mass: Some(1.0),
            x: Vector3::new(0.1, 0.0, 0.3),
            v: Vector3::zeros(),
            w: Vector3::zeros(),
        };
        let bottom = PairMotion {
            mass: Some(2.0),
            x: Vector3::new(0.0, 0.0, 0.1),
            ..top
        };
        let v = pair_guess(
            &features(0.0),
            &top,
            &bottom,
            &Vector3::x(),
            &FRICTION,
            &g_vec,
            0.01,
            false,
        );
        assert!((v.pn - 0.098).abs() < 1e-15, "{v:?}");
        assert_eq!(v.pf, [0.0; 3]);
        assert!((v.sigma - 0.098).abs() < 1e-15);
        // Sliding at 1 m/s over a fixed support: on the ellipsoid against the slip.
        let sliding = PairMotion {
            v: Vector3::new(1.0, 0.0, 0.0),
            ..top
        };
        let fixed = PairMotion {
            mass: None,
            ..bottom
        };
        let v = pair_guess(
            &features(0.0),
            &sliding,
            &fixed,
            &Vector3::x(),
            &FRICTION,
            &g_vec,
            0.01,
            false,
        );
        assert!((v.pn - 0.098).abs() < 1e-15);
        assert!((v.pf[0] + 0.3 * 0.098).abs() < 1e-15 && v.pf[1] == 0.0 && v.sigma == 1.0);
        // Separated: no impulse, σ the slip rate.
        let v = pair_guess(
            &features(0.01),
            &sliding,
            &fixed,
            &Vector3::x(),
            &FRICTION,
            &g_vec,
            0.01,
            false,
        );
        assert_eq!((v.pn, v.pf, v.sigma), (0.0, [0.0; 3], 1.0));
        // Unless forced active; approaching at 0.5 m/s with reduced mass 2/3.
        let falling = PairMotion {
            v: Vector3::new(0.0, 0.0, -0.5),
            ..top
        };
        let v = pair_guess(
            &features(0.01),
            &falling,
            &bottom,
            &Vector3::x(),
            &FRICTION,
            &g_vec,
            0.01,
            true,
        );
        assert!((v.pn - (0.098 + 0.5 * 2.0 / 3.0)).abs() < 1e-15, "{v:?}");
    }
}

//! Settings that validate themselves: every backend's settings struct has a `validate()` that
//! says which field is out of which range, and the registry ([`crate::registry`]) validates
//! whatever it builds, so a solver with a negative tolerance or no iterations cannot be built
//! by name.
//!
//! ```
//! use ecp_solvers::{NewtonSettings, PathSettings};
//!
//! let bad = NewtonSettings { tolerance: -1e-8, ..NewtonSettings::default() };
//! let e = bad.validate().unwrap_err();
//! assert_eq!((e.backend, e.setting), ("newton", "tolerance"));
//! assert!(e.to_string().contains("must be a finite number > 0"));
//!
//! let mut path = PathSettings::default();
//! path.lemke.refactorization_period = 0;
//! assert_eq!(path.validate().unwrap_err().setting, "lemke.refactorization_period");
//! ```

use std::fmt::Display;

use crate::conic::ConicSettings;
use crate::newton::NewtonSettings;
use crate::path::PathSettings;
use crate::pivot::LemkeSettings;
use crate::smoothing::SmoothingSettings;

/// A setting out of its range: which backend, which field, its value and the allowed range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{backend} setting `{setting}` = {value} is invalid: {hint}")]
pub struct SettingsError {
    /// The backend.
    pub backend: &'static str,
    /// The setting's field name (`lemke.pivot_tolerance` for a nested field).
    pub setting: &'static str,
    /// Its value, as written.
    pub value: String,
    /// The valid range.
    pub hint: &'static str,
}

impl SettingsError {
    /// The error for `setting` of `backend` at `value`, with `hint` the allowed range (for a
    /// user's backend's own settings).
    pub fn new(
        backend: &'static str,
        setting: &'static str,
        value: impl Display,
        hint: &'static str,
    ) -> Self {
        SettingsError {
            backend,
            setting,
            value: value.to_string(),
            hint,
        }
    }
}

const TOLERANCE_HINT: &str = "the tolerance must be a finite number > 0 (default 1e-10)";
const ITERATIONS_HINT: &str = "the iteration limit must be at least 1";
const AT_LEAST_ONE_HINT: &str = "must be at least 1";
const FRACTION_HINT: &str = "must lie strictly between 0 and 1";
const POSITIVE_HINT: &str = "must be a finite number > 0";
const NON_NEGATIVE_HINT: &str = "must be a finite number ≥ 0";

/// The range checks of one backend's settings.
struct Check(&'static str);

impl Check {
    fn that(
        &self,
        setting: &'static str,
        value: impl Display,
        ok: bool,
        hint: &'static str,
    ) -> Result<(), SettingsError> {
        if ok {
            Ok(())
        } else {
            Err(SettingsError::new(self.0, setting, value, hint))
        }
    }
    fn tolerance(&self, setting: &'static str, v: f64) -> Result<(), SettingsError> {
        self.that(setting, v, v.is_finite() && v > 0.0, TOLERANCE_HINT)
    }
    fn iterations(&self, setting: &'static str, v: usize) -> Result<(), SettingsError> {
        self.that(setting, v, v >= 1, ITERATIONS_HINT)
    }
    fn at_least_one(&self, setting: &'static str, v: usize) -> Result<(), SettingsError> {
        self.that(setting, v, v >= 1, AT_LEAST_ONE_HINT)
    }
    fn positive(&self, setting: &'static str, v: f64) -> Result<(), SettingsError> {
        self.that(setting, v, v.is_finite() && v > 0.0, POSITIVE_HINT)
    }
    fn non_negative(&self, setting: &'static str, v: f64) -> Result<(), SettingsError> {
        self.that(setting, v, v.is_finite() && v >= 0.0, NON_NEGATIVE_HINT)
    }
    /// Strictly between 0 and 1.
    fn fraction(&self, setting: &'static str, v: f64) -> Result<(), SettingsError> {
        self.that(setting, v, v > 0.0 && v < 1.0, FRACTION_HINT)
    }
}

impl NewtonSettings {
    /// Checks every setting's range; the error names the first field out of range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let c = Check("newton");
        c.tolerance("tolerance", self.tolerance)?;
        c.iterations("max_iterations", self.max_iterations)?;
        c.fraction("armijo", self.armijo)?;
        c.fraction("backtrack", self.backtrack)?;
        c.fraction("min_step", self.min_step)?;
        c.positive("descent_rho", self.descent_rho)?;
        c.that(
            "descent_p",
            self.descent_p,
            self.descent_p.is_finite() && self.descent_p > 2.0,
            "must be a finite number > 2 (the De Luca–Facchinei–Kanzow descent test)",
        )?;
        c.positive("lm_initial_damping", self.lm_initial_damping)?;
        c.fraction("rank_tolerance", self.rank_tolerance)?;
        c.positive("min_norm_radius", self.min_norm_radius)?;
        c.that(
            "newton_shortest_step",
            self.newton_shortest_step,
            self.newton_shortest_step > 0.0 && self.newton_shortest_step <= 1.0,
            "must lie in (0, 1]",
        )?;
        c.non_negative("polish_below", self.polish_below)?;
        if let Some(damping) = self.damped_restart {
            c.positive("damped_restart", damping)?;
        }
        if let Some(near) = self.complementary_restart {
            c.positive("complementary_restart", near)?;
        }
        if let Some(near) = self.early_complementary_restart {
            c.positive("early_complementary_restart", near)?;
        }
        if let Some(near) = self.complementary_restart_from_best {
            c.positive("complementary_restart_from_best", near)?;
        }
        if let Some(steps) = self.friction_continuation {
            c.iterations("friction_continuation", steps)?;
        }
        c.fraction("stall_reduction", self.stall_reduction)?;
        if let Some(contraction) = self.chord_contraction {
            c.fraction("chord_contraction", contraction)?;
        }
        if let Some(contraction) = self.chord_across_solves {
            c.fraction("chord_across_solves", contraction)?;
        }
        if let Some(ulps) = self.chord_round_off_floor {
            c.positive("chord_round_off_floor", ulps)?;
        }
        if let Some(factor) = self.budget_grace {
            c.fraction("budget_grace", factor)?;
        }
        if let Some(fraction) = self.fast_full_step {
            c.fraction("fast_full_step", fraction)?;
        }
        if let Some(band) = self.kink_band {
            c.non_negative("kink_band", band)?;
        }
        smoothing(&c, &self.smoothing)
    }
}

/// The checks of the smoothing continuation's settings (when it is on), the field names
/// prefixed by `smoothing.`.
fn smoothing(c: &Check, s: &Option<SmoothingSettings>) -> Result<(), SettingsError> {
    let Some(s) = s else {
        return Ok(());
    };
    c.positive("smoothing.start", s.start)?;
    c.fraction("smoothing.reduction", s.reduction)?;
    c.positive("smoothing.stage_tolerance", s.stage_tolerance)?;
    c.iterations("smoothing.stage_iterations", s.stage_iterations)
}

impl LemkeSettings {
    /// Checks every setting's range; the error names the first field out of range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        lemke(&Check("lemke"), self, false)
    }
}

/// The checks of [`LemkeSettings`], with the field names prefixed by `lemke.` when `nested` (the
/// PATH-like solver's inner pivoting settings).
fn lemke(c: &Check, s: &LemkeSettings, nested: bool) -> Result<(), SettingsError> {
    let name = |plain: &'static str, prefixed: &'static str| if nested { prefixed } else { plain };
    c.that(
        name("pivot_tolerance", "lemke.pivot_tolerance"),
        s.pivot_tolerance,
        s.pivot_tolerance >= 0.0 && s.pivot_tolerance < 1.0,
        "must lie in [0, 1): a rate blocks when it is at least this fraction of the largest",
    )?;
    c.non_negative(
        name("degeneracy_tolerance", "lemke.degeneracy_tolerance"),
        s.degeneracy_tolerance,
    )?;
    c.at_least_one(
        name("refactorization_period", "lemke.refactorization_period"),
        s.refactorization_period,
    )?;
    c.tolerance(name("tolerance", "lemke.tolerance"), s.tolerance)
}

impl PathSettings {
    /// Checks every setting's range (the inner [`LemkeSettings`] included); the error names the
    /// first field out of range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let c = Check("path");
        c.tolerance("tolerance", self.tolerance)?;
        c.iterations("max_iterations", self.max_iterations)?;
        c.fraction("sufficient_decrease", self.sufficient_decrease)?;
        c.fraction("backtrack", self.backtrack)?;
        c.positive("proximal_initial", self.proximal_initial)?;
        c.that(
            "proximal_growth",
            self.proximal_growth,
            self.proximal_growth.is_finite() && self.proximal_growth > 1.0,
            "must be a finite number > 1",
        )?;
        c.fraction("proximal_reduction", self.proximal_reduction)?;
        c.that(
            "proximal_max",
            self.proximal_max,
            self.proximal_max.is_finite() && self.proximal_max >= self.proximal_initial,
            "must be finite and at least proximal_initial",
        )?;
        c.positive("restart_proximal", self.restart_proximal)?;
        c.fraction("stall_ratio", self.stall_ratio)?;
        c.that(
            "watchdog_growth",
            self.watchdog_growth,
            self.watchdog_growth >= 1.0,
            "must be at least 1 (inf for no bound)",
        )?;
        c.that(
            "time_limit",
            self.time_limit,
            self.time_limit > 0.0 && !self.time_limit.is_nan(),
            "the time limit must be > 0 seconds (inf for none)",
        )?;
        lemke(&c, &self.lemke, true)?;
        smoothing(&c, &self.smoothing)
    }
}

impl ConicSettings {
    /// Checks every setting's range (and the clarabel settings this backend relies on); the
    /// error names the first field out of range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let c = Check("conic");
        c.tolerance("tolerance", self.tolerance)?;
        c.iterations("max_iterations", self.max_iterations)?;
        c.at_least_one("stagnation_window", self.stagnation_window)?;
        c.positive("patch_band", self.patch_band)?;
        c.non_negative("anchor_moment", self.anchor_moment)?;
        c.non_negative("anchor_load", self.anchor_load)?;
        c.non_negative("qp_tolerance_factor", self.qp_tolerance_factor)?;
        let k = &self.clarabel;
        c.iterations("clarabel.max_iter", k.max_iter as usize)?;
        c.positive("clarabel.tol_gap_abs", k.tol_gap_abs)?;
        c.positive("clarabel.tol_gap_rel", k.tol_gap_rel)?;
        c.positive("clarabel.tol_feas", k.tol_feas)?;
        c.positive("clarabel.tol_ktratio", k.tol_ktratio)?;
        c.that(
            "clarabel.max_step_fraction",
            k.max_step_fraction,
            k.max_step_fraction > 0.0 && k.max_step_fraction <= 1.0,
            "must lie in (0, 1]",
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Asserts that `settings` with one field changed is refused, naming that field.
    fn refused<S>(what: &str, settings: S, validate: fn(&S) -> Result<(), SettingsError>) {
        let e = validate(&settings).expect_err(what);
        assert_eq!(e.setting, what.split('=').next().unwrap().trim(), "{e}");
        let text = e.to_string();
        assert!(
            text.contains(e.setting) && text.contains("invalid"),
            "{text}"
        );
    }

    #[test]
    fn defaults_are_valid() {
        NewtonSettings::default().validate().unwrap();
        PathSettings::default().validate().unwrap();
        ConicSettings::default().validate().unwrap();
        LemkeSettings::default().validate().unwrap();
        PathSettings {
            time_limit: f64::INFINITY,
            ..Default::default()
        }
        .validate()
        .unwrap();
    }

    #[test]
    fn newton_refuses_each_field_out_of_range() {
        let d = NewtonSettings::default;
        let v = NewtonSettings::validate;
        for t in [-1e-3, 0.0, f64::NAN, f64::INFINITY] {
            refused(
                "tolerance",
                NewtonSettings {
                    tolerance: t,
                    ..d()
                },
                v,
            );
        }
        refused(
            "max_iterations",
            NewtonSettings {
                max_iterations: 0,
                ..d()
            },
            v,
        );
        for near in [0.0, -1.0, f64::NAN] {
            refused(
                "complementary_restart",
                NewtonSettings {
                    complementary_restart: Some(near),
                    ..d()
                },
                v,
            );
            refused(
                "early_complementary_restart",
                NewtonSettings {
                    early_complementary_restart: Some(near),
                    ..d()
                },
                v,
            );
            refused(
                "complementary_restart_from_best",
                NewtonSettings {
                    complementary_restart_from_best: Some(near),
                    ..d()
                },
                v,
            );
        }
        refused(
            "friction_continuation",
            NewtonSettings {
                friction_continuation: Some(0),
                ..d()
            },
            v,
        );
        refused("armijo", NewtonSettings { armijo: 1.0, ..d() }, v);
        refused(
            "backtrack",
            NewtonSettings {
                backtrack: 1.5,
                ..d()
            },
            v,
        );
        refused(
            "min_step",
            NewtonSettings {
                min_step: 0.0,
                ..d()
            },
            v,
        );
        refused(
            "descent_rho",
            NewtonSettings {
                descent_rho: -1.0,
                ..d()
            },
            v,
        );
        refused(
            "descent_p",
            NewtonSettings {
                descent_p: 2.0,
                ..d()
            },
            v,
        );
        refused(
            "lm_initial_damping",
            NewtonSettings {
                lm_initial_damping: f64::NAN,
                ..d()
            },
            v,
        );
        refused(
            "rank_tolerance",
            NewtonSettings {
                rank_tolerance: 1.0,
                ..d()
            },
            v,
        );
        refused(
            "min_norm_radius",
            NewtonSettings {
                min_norm_radius: 0.0,
                ..d()
            },
            v,
        );
        refused(
            "newton_shortest_step",
            NewtonSettings {
                newton_shortest_step: 1.5,
                ..d()
            },
            v,
        );
        refused(
            "polish_below",
            NewtonSettings {
                polish_below: -0.1,
                ..d()
            },
            v,
        );
        refused(
            "chord_contraction",
            NewtonSettings {
                chord_contraction: Some(1.0),
                ..d()
            },
            v,
        );
        refused(
            "chord_across_solves",
            NewtonSettings {
                chord_across_solves: Some(0.0),
                ..d()
            },
            v,
        );
        refused(
            "chord_round_off_floor",
            NewtonSettings {
                chord_round_off_floor: Some(-1.0),
                ..d()
            },
            v,
        );
        refused(
            "fast_full_step",
            NewtonSettings {
                fast_full_step: Some(1.0),
                ..d()
            },
            v,
        );
        refused(
            "kink_band",
            NewtonSettings {
                kink_band: Some(-1.0),
                ..d()
            },
            v,
        );
    }

    #[test]
    fn lemke_refuses_each_field_out_of_range() {
        let d = LemkeSettings::default;
        let v = LemkeSettings::validate;
        refused(
            "pivot_tolerance",
            LemkeSettings {
                pivot_tolerance: -1e-9,
                ..d()
            },
            v,
        );
        refused(
            "pivot_tolerance",
            LemkeSettings {
                pivot_tolerance: 1.0,
                ..d()
            },
            v,
        );
        refused(
            "degeneracy_tolerance",
            LemkeSettings {
                degeneracy_tolerance: f64::NAN,
                ..d()
            },
            v,
        );
        refused(
            "refactorization_period",
            LemkeSettings {
                refactorization_period: 0,
                ..d()
            },
            v,
        );
        refused(
            "tolerance",
            LemkeSettings {
                tolerance: 0.0,
                ..d()
            },
            v,
        );
    }

    #[test]
    fn smoothing_settings_are_checked_when_on() {
        let smoothing = |reduction: f64, stage_iterations: usize| {
            Some(SmoothingSettings {
                reduction,
                stage_iterations,
                ..Default::default()
            })
        };
        for reduction in [0.0, 1.0, f64::NAN] {
            let bad = NewtonSettings {
                smoothing: smoothing(reduction, 30),
                ..Default::default()
            };
            refused("smoothing.reduction", bad, NewtonSettings::validate);
        }
        let bad = PathSettings {
            smoothing: smoothing(0.5, 0),
            ..Default::default()
        };
        refused("smoothing.stage_iterations", bad, PathSettings::validate);
        let bad = NewtonSettings {
            smoothing: Some(SmoothingSettings {
                start: -1.0,
                ..Default::default()
            }),
            ..Default::default()
        };
        refused("smoothing.start", bad, NewtonSettings::validate);
        PathSettings {
            smoothing: None,
            ..Default::default()
        }
        .validate()
        .unwrap();
    }

    #[test]
    fn path_refuses_each_field_out_of_range() {
        let d = PathSettings::default;
        let v = PathSettings::validate;
        refused(
            "tolerance",
            PathSettings {
                tolerance: -1.0,
                ..d()
            },
            v,
        );
        refused(
            "max_iterations",
            PathSettings {
                max_iterations: 0,
                ..d()
            },
            v,
        );
        refused(
            "sufficient_decrease",
            PathSettings {
                sufficient_decrease: 0.0,
                ..d()
            },
            v,
        );
        for bad in [0.5, f64::NAN] {
            refused(
                "watchdog_growth",
                PathSettings {
                    watchdog_growth: bad,
                    ..d()
                },
                v,
            );
        }
        refused(
            "backtrack",
            PathSettings {
                backtrack: 1.0,
                ..d()
            },
            v,
        );
        for bad in [0.0, 1.0, f64::NAN] {
            refused(
                "stall_ratio",
                PathSettings {
                    stall_ratio: bad,
                    ..d()
                },
                v,
            );
        }
        refused(
            "proximal_initial",
            PathSettings {
                proximal_initial: 0.0,
                ..d()
            },
            v,
        );
        refused(
            "proximal_growth",
            PathSettings {
                proximal_growth: 1.0,
                ..d()
            },
            v,
        );
        refused(
            "proximal_reduction",
            PathSettings {
                proximal_reduction: 1.0,
                ..d()
            },
            v,
        );
        refused(
            "proximal_max",
            PathSettings {
                proximal_max: 1e-6,
                ..d()
            },
            v,
        );
        refused(
            "restart_proximal",
            PathSettings {
                restart_proximal: f64::NAN,
                ..d()
            },
            v,
        );
        for time_limit in [0.0, -1.0, f64::NAN, f64::NEG_INFINITY] {
            refused("time_limit", PathSettings { time_limit, ..d() }, v);
        }
        let lemke = |f: fn(&mut LemkeSettings)| {
            let mut s = d();
            f(&mut s.lemke);
            s
        };
        refused(
            "lemke.pivot_tolerance",
            lemke(|l| l.pivot_tolerance = 2.0),
            v,
        );
        refused(
            "lemke.degeneracy_tolerance",
            lemke(|l| l.degeneracy_tolerance = -1.0),
            v,
        );
        refused(
            "lemke.refactorization_period",
            lemke(|l| l.refactorization_period = 0),
            v,
        );
        refused("lemke.tolerance", lemke(|l| l.tolerance = f64::NAN), v);
    }

    #[test]
    fn conic_refuses_each_field_out_of_range() {
        let d = ConicSettings::default;
        let v = ConicSettings::validate;
        refused(
            "tolerance",
            ConicSettings {
                tolerance: f64::NAN,
                ..d()
            },
            v,
        );
        refused(
            "max_iterations",
            ConicSettings {
                max_iterations: 0,
                ..d()
            },
            v,
        );
        refused(
            "stagnation_window",
            ConicSettings {
                stagnation_window: 0,
                ..d()
            },
            v,
        );
        refused(
            "patch_band",
            ConicSettings {
                patch_band: 0.0,
                ..d()
            },
            v,
        );
        refused(
            "anchor_moment",
            ConicSettings {
                anchor_moment: -1.0,
                ..d()
            },
            v,
        );
        refused(
            "qp_tolerance_factor",
            ConicSettings {
                qp_tolerance_factor: -1e-3,
                ..d()
            },
            v,
        );
        refused(
            "anchor_load",
            ConicSettings {
                anchor_load: f64::INFINITY,
                ..d()
            },
            v,
        );
        let clarabel = |f: fn(&mut ConicSettings)| {
            let mut s = d();
            f(&mut s);
            s
        };
        refused(
            "clarabel.max_iter",
            clarabel(|s| s.clarabel.max_iter = 0),
            v,
        );
        refused(
            "clarabel.tol_gap_abs",
            clarabel(|s| s.clarabel.tol_gap_abs = 0.0),
            v,
        );
        refused(
            "clarabel.tol_gap_rel",
            clarabel(|s| s.clarabel.tol_gap_rel = -1.0),
            v,
        );
        refused(
            "clarabel.tol_feas",
            clarabel(|s| s.clarabel.tol_feas = f64::NAN),
            v,
        );
        refused(
            "clarabel.tol_ktratio",
            clarabel(|s| s.clarabel.tol_ktratio = 0.0),
            v,
        );
        refused(
            "clarabel.max_step_fraction",
            clarabel(|s| s.clarabel.max_step_fraction = 1.5),
            v,
        );
    }
}

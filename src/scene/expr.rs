//! Applied loads as expressions of time, parsed once with exmex.
//!
//! exmex knows `PI`, `π`, `E` and `TAU`; a lower-case `pi` would silently become a second
//! variable, so we add it as a constant and reject every variable other than `t`.

use exmex::{Express, FlatEx, FloatOpsFactory, MakeOperators, Operator};

/// exmex's float operators plus the constant `pi`.
#[derive(Clone, Debug)]
pub struct Operators;

impl MakeOperators<f64> for Operators {
    fn make<'a>() -> Vec<Operator<'a, f64>> {
        let mut ops = FloatOpsFactory::<f64>::make();
        ops.push(Operator::make_constant("pi", std::f64::consts::PI));
        ops
    }
}

/// A scalar function of time `t` given by the user, e.g. `"22.5*sin(2*pi*t) + 22.5"`.
#[derive(Clone, Debug)]
pub struct TimeExpression {
    source: String,
    kind: ExpressionKind,
}

#[derive(Clone, Debug)]
enum ExpressionKind {
    Constant(f64),
    /// The parsed expression and whether it reads `t` (exmex wants one value per variable).
    Parsed(Box<FlatEx<f64, Operators>>, bool),
}

impl TimeExpression {
    /// A constant.
    pub fn constant(value: f64) -> Self {
        TimeExpression {
            source: format!("{value}"),
            kind: ExpressionKind::Constant(value),
        }
    }

    /// Parses `source`; the only variable allowed is `t` (seconds). The error says what is
    /// wrong in words a user can act on.
    pub fn parse(source: &str) -> Result<Self, String> {
        let parsed = FlatEx::<f64, Operators>::parse(source).map_err(|e| {
            format!(
                "the expression \"{source}\" does not parse ({}); write it in t with +, -, *, /, ^, \
                 parentheses, functions such as sin, cos, exp, ln, sqrt, abs and the constant pi, \
                 e.g. \"22.5*sin(2*pi*t) + 22.5\"",
                e.msg()
            )
        })?;
        let vars = parsed.var_names().to_vec();
        if let Some(bad) = vars.iter().find(|v| v.as_str() != "t") {
            return Err(format!(
                "the expression \"{source}\" uses the unknown name `{bad}`; the only variable \
                 is t (time in seconds) and the constants are pi and E"
            ));
        }
        let uses_t = !vars.is_empty();
        Ok(TimeExpression {
            source: source.to_string(),
            kind: ExpressionKind::Parsed(Box::new(parsed), uses_t),
        })
    }

    /// The text the user wrote.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// Whether the value depends on `t`.
    pub fn is_constant(&self) -> bool {
        match &self.kind {
            ExpressionKind::Constant(_) => true,
            ExpressionKind::Parsed(_, uses_t) => !uses_t,
        }
    }

    /// The value at time `t`; NaN if the evaluation fails (checked beforehand by the loader at
    /// every step time, so this does not happen in a loaded scene).
    pub fn eval(&self, t: f64) -> f64 {
        match &self.kind {
            ExpressionKind::Constant(v) => *v,
            ExpressionKind::Parsed(ex, true) => ex.eval(&[t]).unwrap_or(f64::NAN),
            ExpressionKind::Parsed(ex, false) => ex.eval(&[]).unwrap_or(f64::NAN),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn desk_load_parses_with_lower_case_pi() {
        let e = TimeExpression::parse("22.5*sin(2*pi*t) + 22.5").expect("parses");
        assert!(!e.is_constant());
        let t: f64 = 0.3;
        let want = 22.5 * (2.0 * std::f64::consts::PI * t).sin() + 22.5;
        assert!((e.eval(t) - want).abs() < 1e-12);
    }

    #[test]
    fn constants_and_errors() {
        let c = TimeExpression::parse("2*pi").expect("parses");
        assert!(c.is_constant());
        assert!((c.eval(5.0) - 2.0 * std::f64::consts::PI).abs() < 1e-15);
        let e = TimeExpression::parse("2*pi*tt").expect_err("tt is not t");
        assert!(e.contains("`tt`"), "{e}");
        let e = TimeExpression::parse("sin(2*t").expect_err("unbalanced");
        assert!(e.contains("does not parse"), "{e}");
    }
}

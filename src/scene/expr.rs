//! Applied loads as expressions of time, parsed once with exmex.
//!
//! exmex knows `PI`, `π`, `E`, `e` (both Euler's number) and `TAU`; a lower-case `pi` would
//! silently become a second variable, so we add it as a constant and reject every variable other
//! than `t`.
//!
//! exmex's own number literals have no exponent, so `1e1` would read as `1`, Euler's number and
//! `1`, which does not parse. [`Literals`] reads scientific notation (`1e1`, `2.5E-3`, `1e+2`,
//! `.5e3`) as one number; an `e` or `E` that is not followed by digits (with an optional sign)
//! is not an exponent, so `2*e`, `exp(t)` and `E^t` keep meaning Euler's number.

use exmex::{Express, FlatEx, FloatOpsFactory, MakeOperators, MatchLiteral, Operator};

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

/// Number literals: digits with at most one decimal point (`2`, `2.`, `2.5`, `.5`), then an
/// optional exponent `e`/`E`, an optional sign and at least one digit.
#[derive(Clone, Debug)]
pub struct Literals;

impl MatchLiteral for Literals {
    fn is_literal(text: &str) -> Option<&str> {
        let bytes = text.as_bytes();
        let digits_from = |start: usize| {
            bytes[start.min(bytes.len())..]
                .iter()
                .take_while(|b| b.is_ascii_digit())
                .count()
        };
        let int = digits_from(0);
        let mut end = int;
        let mut frac = 0;
        if bytes.get(end) == Some(&b'.') {
            frac = digits_from(end + 1);
            end += 1 + frac;
        }
        // A mantissa needs a digit: `.` alone is not a number.
        if int + frac == 0 {
            return None;
        }
        if matches!(bytes.get(end), Some(b'e' | b'E')) {
            let sign = usize::from(matches!(bytes.get(end + 1), Some(b'+' | b'-')));
            let exp = digits_from(end + 1 + sign);
            if exp > 0 {
                end += 1 + sign + exp;
            }
        }
        // Every byte matched is ASCII, so `end` is a character boundary.
        text.get(..end)
    }
}

type ParsedExpression = FlatEx<f64, Operators, Literals>;

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
    Parsed(Box<ParsedExpression>, bool),
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
        let parsed = ParsedExpression::parse(source).map_err(|e| {
            format!(
                "the expression \"{source}\" does not parse ({}); write it in t with +, -, *, /, ^, \
                 parentheses, functions such as sin, cos, exp, ln, sqrt, abs, the constant pi and \
                 numbers such as 2.5 or 1e-3, e.g. \"22.5*sin(2*pi*t) + 22.5\"",
                e.msg()
            )
        })?;
        let vars = parsed.var_names().to_vec();
        if let Some(bad) = vars.iter().find(|v| v.as_str() != "t") {
            return Err(format!(
                "the expression \"{source}\" uses the unknown name `{bad}`; the only variable \
                 is t (time in seconds) and the constants are pi and E (or e)"
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

    fn value(source: &str, t: f64) -> f64 {
        TimeExpression::parse(source)
            .unwrap_or_else(|e| panic!("{source}: {e}"))
            .eval(t)
    }

    #[test]
    fn scientific_notation_in_every_form() {
        let t: f64 = 0.3;
        let cases = [
            ("1e1", 10.0),
            ("1E1", 10.0),
            ("2.5E-3", 2.5e-3),
            ("2.5e+3", 2.5e3),
            ("-3.0e-1", -0.3),
            (".5e1", 5.0),
            ("5.e-1", 0.5),
            ("1e+2*t", 100.0 * t),
            ("t*1e-2", 0.01 * t),
            ("2.5e1*sin(5*t)", 25.0 * (5.0 * t).sin()),
            ("1e1-1e0", 9.0),
            ("2*1e1^2", 200.0),
            ("(1e1)", 10.0),
        ];
        for (source, want) in cases {
            let got = value(source, t);
            assert!(
                (got - want).abs() <= 1e-15 * want.abs().max(1.0),
                "{source}: {got} != {want}"
            );
        }
    }

    #[test]
    fn e_alone_is_eulers_number_and_names_with_e_keep_working() {
        let t: f64 = 0.3;
        let euler = std::f64::consts::E;
        let cases = [
            ("e", euler),
            ("E", euler),
            ("2*e", 2.0 * euler),
            ("2*E", 2.0 * euler),
            ("e^t", euler.powf(t)),
            ("exp(t)", t.exp()),
            ("2*exp(1e-1*t)", 2.0 * (0.1 * t).exp()),
            ("sqrt(e)", euler.sqrt()),
            ("2*pi*t", 2.0 * std::f64::consts::PI * t),
            ("sin(t)*e", t.sin() * euler),
        ];
        for (source, want) in cases {
            let got = value(source, t);
            assert!((got - want).abs() <= 1e-15, "{source}: {got} != {want}");
        }
        // An exponent needs digits: `2e` is a number next to a constant, as before.
        assert!(TimeExpression::parse("2e").is_err());
        assert!(TimeExpression::parse("2e+").is_err());
        assert!(TimeExpression::parse("1e1e1").is_err());
        assert!(TimeExpression::parse(".").is_err());
    }

    #[test]
    fn literal_matcher_takes_the_longest_number() {
        for (text, want) in [
            ("1e1*t", Some("1e1")),
            ("2.5E-3)", Some("2.5E-3")),
            ("2e", Some("2")),
            ("2e-t", Some("2")),
            ("2.e+", Some("2.")),
            (".5", Some(".5")),
            ("..5", None),
            ("e1", None),
            ("-1", None),
            ("", None),
        ] {
            assert_eq!(Literals::is_literal(text), want, "{text:?}");
        }
    }
}

//! `ecp lcp FILE.json`: an LCP `0 ≤ z ⊥ M z + q ≥ 0` given as `{"M": [[..], ..], "q": [..]}`,
//! solved with the pivotal solver (Lemke's method, `docs/backends.md#path-like`), so that it can be
//! compared with other LCP solvers on the same instances.

use std::path::Path;
use std::time::Instant;

use ecp_solvers::pivot::{Lemke, LemkeSettings, PivotError};
use serde::{Deserialize, Serialize};

use crate::error::{InputError, InputErrorKind};

/// An LCP instance as read from JSON.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLcp {
    #[serde(rename = "M")]
    m: Vec<Vec<f64>>,
    q: Vec<f64>,
}

/// A validated LCP: `M` by rows and `q`.
#[derive(Clone, Debug, PartialEq)]
pub struct Lcp {
    /// `n × n`, row-major.
    pub m: Vec<f64>,
    /// Length `n`.
    pub q: Vec<f64>,
}

/// What `ecp lcp` prints: the solution, or the reason there is none.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct LcpReport {
    /// `solved`, or why not: `ray_termination`, `max_pivots`, `singular_basis`.
    pub status: String,
    /// The solution (empty when not solved).
    pub z: Vec<f64>,
    /// `w = M z + q` (empty when not solved).
    pub w: Vec<f64>,
    /// Pivots taken.
    pub pivots: usize,
    /// Wall time of the solve (µs), parsing excluded.
    pub solve_us: f64,
    /// Natural-map residual `‖min(z, w)‖∞` (infinite when not solved).
    #[serde(serialize_with = "finite_or_null")]
    pub residual: f64,
    /// The solver's message when not solved.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

fn finite_or_null<S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_finite() {
        s.serialize_f64(*v)
    } else {
        s.serialize_none()
    }
}

impl LcpReport {
    /// Whether the LCP was solved.
    pub fn solved(&self) -> bool {
        self.status == "solved"
    }
}

/// Reads and checks an LCP file: JSON syntax, the keys `M` and `q`, a square `M` matching `q`,
/// finite numbers.
pub fn load_lcp(path: &Path) -> Result<Lcp, InputError> {
    let err = |kind, key: Option<&str>, line, message: String| InputError {
        file: Some(path.to_path_buf()),
        key: key.map(str::to_string),
        line,
        kind,
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| {
        err(
            InputErrorKind::FileMissing,
            None,
            None,
            format!("cannot read the LCP file ({e}); check the path"),
        )
    })?;
    let raw: RawLcp = serde_json::from_str(&text).map_err(|e| {
        let kind = match e.classify() {
            serde_json::error::Category::Syntax | serde_json::error::Category::Eof => {
                InputErrorKind::Syntax
            }
            _ if e.to_string().starts_with("unknown field") => InputErrorKind::UnknownKey,
            _ if e.to_string().starts_with("missing field") => InputErrorKind::MissingKey,
            _ => InputErrorKind::WrongType,
        };
        err(
            kind,
            None,
            Some(e.line()),
            format!(
                "{e}; the file must be {{\"M\": [[row 1], [row 2], ...], \"q\": [...]}} with numbers"
            ),
        )
    })?;
    let n = raw.q.len();
    if n == 0 {
        return Err(err(
            InputErrorKind::InvalidValue,
            Some("q"),
            None,
            "q is empty; give at least one component".into(),
        ));
    }
    if raw.m.len() != n {
        return Err(err(
            InputErrorKind::InvalidValue,
            Some("M"),
            None,
            format!(
                "M has {} rows but q has {n} components; M must be {n} × {n}",
                raw.m.len()
            ),
        ));
    }
    let mut m = Vec::with_capacity(n * n);
    for (i, row) in raw.m.iter().enumerate() {
        if row.len() != n {
            return Err(err(
                InputErrorKind::InvalidValue,
                Some(&format!("M[{i}]")),
                None,
                format!(
                    "row {i} of M has {} entries; M must be {n} × {n}",
                    row.len()
                ),
            ));
        }
        m.extend_from_slice(row);
    }
    if m.iter().chain(&raw.q).any(|v| !v.is_finite()) {
        return Err(err(
            InputErrorKind::InvalidValue,
            None,
            None,
            "M or q has a non-finite entry".into(),
        ));
    }
    Ok(Lcp { m, q: raw.q })
}

/// Solves `lcp` with Lemke's method (default settings) and reports the result.
pub fn solve_lcp(lcp: &Lcp) -> LcpReport {
    let mut lemke = Lemke::new(LemkeSettings::default());
    let start = Instant::now();
    let result = lemke.solve_lcp(&lcp.m, &lcp.q);
    let solve_us = start.elapsed().as_secs_f64() * 1e6;
    match result {
        Ok(sol) => LcpReport {
            status: "solved".into(),
            z: sol.z,
            w: sol.w,
            pivots: sol.pivots,
            solve_us,
            residual: sol.residual,
            error: None,
        },
        Err(e) => {
            let (status, pivots) = match &e {
                PivotError::RayTermination { pivots, .. } => ("ray_termination", *pivots),
                PivotError::MaxPivots { pivots } => ("max_pivots", *pivots),
                PivotError::SingularBasis { pivots, .. } => ("singular_basis", *pivots),
                PivotError::InvalidInput(_) => ("invalid_input", 0),
            };
            LcpReport {
                status: status.into(),
                z: Vec::new(),
                w: Vec::new(),
                pivots,
                solve_us,
                residual: f64::INFINITY,
                error: Some(e.to_string()),
            }
        }
    }
}

//! `ecp lcp FILE.json`: an LCP `0 ≤ z ⊥ M z + q ≥ 0` given as `{"M": [[..], ..], "q": [..]}`,
//! solved with the pivotal solver (Lemke's method, `docs/backends.md#path-like`), so that it can be
//! compared with other LCP solvers on the same instances. `--repeat N` solves it N more times
//! with the same solver (its buffers warm) and reports the best and the median time, the number
//! other solvers' warm timings are compared with (`docs/backends.md#lemke-speed`).
//! [`random_lcp`] makes the benchmark instances (`examples/lcp_instances.rs`,
//! `benches/lemke.rs`).

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
    /// Wall time of the first solve (µs), with a new solver (its buffers allocated), parsing
    /// excluded.
    pub solve_us: f64,
    /// Warm solves timed after the first (`--repeat N`); absent when 0.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub repeat: Option<usize>,
    /// Fastest of the warm solves (µs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub best_us: Option<f64>,
    /// Median of the warm solves (µs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub median_us: Option<f64>,
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
    solve_lcp_repeated(lcp, 0)
}

/// As [`solve_lcp`], then `repeat` more solves of the same LCP with the same solver (warm: no
/// buffer is allocated again, `z` and `w` written into the caller's arrays by
/// `Lemke::solve_lcp_into`), whose best and median times are reported.
pub fn solve_lcp_repeated(lcp: &Lcp, repeat: usize) -> LcpReport {
    let mut lemke = Lemke::new(LemkeSettings::default());
    let start = Instant::now();
    let result = lemke.solve_lcp(&lcp.m, &lcp.q);
    let solve_us = start.elapsed().as_secs_f64() * 1e6;
    let (repeat, best_us, median_us) = if repeat > 0 {
        // The warm solves write z and w into these (as a C solver into its caller's arrays):
        // the timed calls allocate nothing.
        let (mut z, mut w) = (vec![0.0; lcp.q.len()], vec![0.0; lcp.q.len()]);
        let mut times: Vec<f64> = (0..repeat)
            .map(|_| {
                let start = Instant::now();
                let r = lemke.solve_lcp_into(&lcp.m, &lcp.q, &mut z, &mut w);
                let us = start.elapsed().as_secs_f64() * 1e6;
                std::hint::black_box((r.ok(), &z, &w));
                us
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let median = if repeat % 2 == 1 {
            times[repeat / 2]
        } else {
            0.5 * (times[repeat / 2 - 1] + times[repeat / 2])
        };
        (Some(repeat), Some(times[0]), Some(median))
    } else {
        (None, None, None)
    };
    match result {
        Ok(sol) => LcpReport {
            status: "solved".into(),
            z: sol.z,
            w: sol.w,
            pivots: sol.pivots,
            solve_us,
            repeat,
            best_us,
            median_us,
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
                repeat,
                best_us,
                median_us,
                residual: f64::INFINITY,
                error: Some(e.to_string()),
            }
        }
    }
}

/// A random LCP with a symmetric positive definite (hence P-) matrix, the family of the
/// pivoting benchmarks: `M = AᵀA / n + I` with `A_ij` uniform in `[−1, 1]`, `q_i` uniform in
/// `[−1, 1]`, from a fixed generator (SplitMix64) seeded with `seed`, so every machine builds
/// the same instance. A P-matrix LCP has exactly one solution and Lemke's method finds it.
pub fn random_lcp(n: usize, seed: u64) -> Lcp {
    let mut state = seed;
    let mut uniform = move || {
        // SplitMix64 (Steele, Lea & Flood 2014), mapped to [−1, 1).
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut x = state;
        x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        x ^= x >> 31;
        (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let a: Vec<f64> = (0..n * n).map(|_| uniform()).collect();
    let q: Vec<f64> = (0..n).map(|_| uniform()).collect();
    let mut m = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s: f64 = (0..n).map(|k| a[k * n + i] * a[k * n + j]).sum::<f64>() / n as f64;
            m[i * n + j] = s;
            m[j * n + i] = s;
        }
        m[i * n + i] += 1.0;
    }
    Lcp { m, q }
}

impl Lcp {
    /// The instance as the JSON `ecp lcp` reads: `{"M": [[..], ..], "q": [..]}`.
    pub fn to_json(&self) -> String {
        let n = self.q.len();
        let rows: Vec<&[f64]> = (0..n).map(|i| &self.m[i * n..(i + 1) * n]).collect();
        serde_json::json!({ "M": rows, "q": self.q }).to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_lcps_are_reproducible_p_matrix_instances_lemke_solves() {
        let a = random_lcp(30, 7);
        assert_eq!(a, random_lcp(30, 7));
        assert_ne!(a, random_lcp(30, 8));
        // Symmetric with a dominant unit diagonal shift: M − I = AᵀA/n is positive semidefinite.
        for i in 0..30 {
            assert!(a.m[i * 30 + i] >= 1.0);
            for j in 0..30 {
                assert_eq!(a.m[i * 30 + j], a.m[j * 30 + i]);
            }
        }
        let report = solve_lcp_repeated(&a, 3);
        assert!(report.solved(), "{:?}", report.error);
        assert!(report.residual <= 1e-12, "{}", report.residual);
        assert_eq!(report.repeat, Some(3));
        let (best, median) = (report.best_us.unwrap(), report.median_us.unwrap());
        assert!(best > 0.0 && best <= median, "{best} {median}");
        // The JSON round trip gives the same instance.
        let dir = std::env::temp_dir().join(format!("ecp-lcp-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.json");
        std::fs::write(&path, a.to_json()).unwrap();
        assert_eq!(load_lcp(&path).unwrap(), a);
        let _ = std::fs::remove_dir_all(dir);
    }
}

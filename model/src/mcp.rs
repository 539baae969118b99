//! The mixed complementarity problem every backend solves (`docs/model.md#mcp`), and the
//! residuals that judge a candidate solution.

use std::sync::Arc;

use crate::bounds::{BoundKind, Bounds, classify};
use crate::error::ModelError;
use crate::family::McpFamily;
use crate::pattern::CscPattern;
use crate::scaling::{McpScales, ScalesUsage};
use crate::structure::StepStructure;

/// A mixed complementarity problem `(n, l, u, F, J)` in the PATH/GAMS convention:
/// find `l ≤ z ≤ u` with `F_i(z) = 0` where `l_i < z_i < u_i`, `F_i ≥ 0` at `l_i`, `F_i ≤ 0` at `u_i`.
///
/// The Jacobian is given in a fixed sparsity pattern (diagonal included), so backends can
/// analyse it once and reuse the analysis across iterations and time steps.
pub trait Mcp {
    /// Number of unknowns `n`.
    fn dim(&self) -> usize;
    /// Lower bounds (length `n`, `-∞` allowed).
    fn lower(&self) -> &[f64];
    /// Upper bounds (length `n`, `+∞` allowed).
    fn upper(&self) -> &[f64];
    /// Evaluates `F(z)` into `f`.
    fn evaluate(&self, z: &[f64], f: &mut [f64]);
    /// The Jacobian's sparsity pattern (constant for the problem's lifetime).
    fn jacobian_pattern(&self) -> &Arc<CscPattern>;
    /// Evaluates `J(z)` into `values`, stored in the order of [`Mcp::jacobian_pattern`].
    fn jacobian(&self, z: &[f64], values: &mut [f64]);
    /// Evaluates `F` and `J` together (override when they share work).
    fn evaluate_with_jacobian(&self, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        self.evaluate(z, f);
        self.jacobian(z, values);
    }
    /// `F(z)` when the problem already holds it for this very `z` (the same bits), as
    /// [`Mcp::evaluate`] would write it, so that a backend may take it instead of evaluating:
    /// a time step's warm start evaluates `F` at the start it chooses (the extrapolated warm
    /// start's guard), and the backend's first evaluation is at that start
    /// (`docs/latency.md#the-a1-step-under-2-µs-the-guards-f-handed-over-branch-wip-a1two-issue-18`).
    /// `None` (the default): evaluate. A wrapper that changes `F` (scaled rows) must not
    /// forward it.
    fn known_value(&self, z: &[f64]) -> Option<&[f64]> {
        let _ = z;
        None
    }
    /// `Φ(z)`, the Fischer–Burmeister reformulation ([`fb_vector`]), when the problem holds it
    /// for this very `z` beside [`Mcp::known_value`]'s `F` (the bits `fb_vector` gives from
    /// that `F`): the warm start's guard computes it to compare its starts, and the semismooth
    /// Newton backend's merit at the start is its sum of squares. `None` (the default):
    /// compute it. A wrapper that changes `F` or the bounds must not forward it.
    fn known_fb_vector(&self, z: &[f64]) -> Option<&[f64]> {
        let _ = z;
        None
    }
    /// Human-readable name of component `i`, for diagnostics.
    fn component_name(&self, i: usize) -> String {
        format!("z[{i}]")
    }
    /// Appends [`Mcp::component_name`] of `i` to `out`. Override it (and forward it in wrappers)
    /// to write the name without a `String` of its own: a backend's result then names its worst
    /// component in storage kept across solves ([`McpSolver::solve_into`](crate::McpSolver)).
    fn write_component_name(&self, i: usize, out: &mut String) {
        out.push_str(&self.component_name(i));
    }
    /// The structural view of a contact step (`docs/backends.md#conic`), when this MCP is one: what
    /// the conic backend needs besides `F`. `None` for a generic MCP.
    fn structure(&self) -> Option<&dyn StepStructure> {
        None
    }
    /// The problem's scene scales (`docs/decisions.md#scene-scaled-convergence`), when it has
    /// them: a backend that honours them solves [`crate::ScaledMcp`] and judges its tolerance
    /// in those units. `None` (the default): judged as given.
    fn scales(&self) -> Option<&McpScales> {
        None
    }
    /// [`Mcp::scales`] with [`McpScales::usage`]'s verdict for this problem's dimension, which
    /// [`crate::solve_in_scales`] acts on. The default computes it (a pass over the scales); a
    /// problem whose scales stay the same from one solve to the next may keep it.
    fn scales_usage(&self) -> Option<(&McpScales, ScalesUsage)> {
        self.scales().map(|s| (s, s.usage(self.dim())))
    }
    /// Groups of unknowns that a linear solver may eliminate first, each with its own rows
    /// (`docs/latency.md#structured-linear-solve`): in a contact step, one body's Newton–Euler
    /// and kinematic-map unknowns `(ν, q)`, whose rows involve no other body's. Disjoint index
    /// lists; empty (the default) for a problem without that structure.
    fn elimination_groups(&self) -> &[Vec<usize>] {
        &[]
    }
    /// The family `F(z; s)` with every friction coefficient scaled by `s` (`s = 1`: this
    /// problem), when the problem has friction and can vary it: a backend may follow its
    /// solutions from a step it solves to this one (`docs/newton.md#a-continuation-in-the-friction-coefficient`).
    /// `None` (the default) for a problem without it.
    fn friction_family(&self) -> Option<&dyn McpFamily> {
        None
    }
}

type FFn = dyn Fn(&[f64], &mut [f64]) + Send + Sync;
type JFn = dyn Fn(&[f64], &mut [f64]) + Send + Sync;

/// An MCP given directly by a function `F`, its Jacobian and bounds, for problems that are
/// not built from blocks.
///
/// ```
/// use ecp_model::{FnMcp, Mcp, natural_residual};
/// // The LCP 0 ≤ z ⊥ z − 1 ≥ 0 (solution z = 1).
/// let mcp = FnMcp::dense(
///     vec![0.0], vec![f64::INFINITY],
///     |z, f| f[0] = z[0] - 1.0,
///     |_z, j| j[0] = 1.0,
/// ).unwrap();
/// let mut f = [0.0];
/// mcp.evaluate(&[1.0], &mut f);
/// assert_eq!(natural_residual(&[1.0], &f, mcp.lower(), mcp.upper()), 0.0);
/// ```
pub struct FnMcp {
    lower: Vec<f64>,
    upper: Vec<f64>,
    pattern: Arc<CscPattern>,
    f: Box<FFn>,
    j: Box<JFn>,
    names: Option<Vec<String>>,
}

impl FnMcp {
    /// A problem with a dense Jacobian: `jac(z, out)` fills the column-major `n × n` array `out`
    /// (which starts zeroed).
    pub fn dense(
        lower: Vec<f64>,
        upper: Vec<f64>,
        f: impl Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
        jac: impl Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
    ) -> Result<Self, ModelError> {
        let n = lower.len();
        let pattern = Arc::new(CscPattern::dense(n));
        // The dense pattern stores every entry in column-major order, so the value array is
        // exactly the dense column-major matrix.
        Self::sparse(lower, upper, pattern, f, move |z, v| {
            v.fill(0.0);
            jac(z, v)
        })
    }

    /// A problem with a sparse Jacobian: `jac(z, values)` fills the values in `pattern`'s order.
    pub fn sparse(
        lower: Vec<f64>,
        upper: Vec<f64>,
        pattern: Arc<CscPattern>,
        f: impl Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
        jac: impl Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
    ) -> Result<Self, ModelError> {
        let n = lower.len();
        if upper.len() != n || pattern.dim() != n {
            return Err(ModelError::Dimension(format!(
                "lower has {n} entries, upper {}, Jacobian pattern is {}×{}",
                upper.len(),
                pattern.dim(),
                pattern.dim()
            )));
        }
        for i in 0..n {
            Bounds::boxed(lower[i], upper[i])
                .validate()
                .map_err(|reason| ModelError::InvalidBlock {
                    block: format!("z[{i}]"),
                    reason,
                })?;
        }
        Ok(FnMcp {
            lower,
            upper,
            pattern,
            f: Box::new(f),
            j: Box::new(jac),
            names: None,
        })
    }

    /// Names the components for diagnostics.
    pub fn with_names(mut self, names: Vec<String>) -> Self {
        if names.len() == self.lower.len() {
            self.names = Some(names);
        }
        self
    }
}

impl Mcp for FnMcp {
    fn dim(&self) -> usize {
        self.lower.len()
    }
    fn lower(&self) -> &[f64] {
        &self.lower
    }
    fn upper(&self) -> &[f64] {
        &self.upper
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        (self.f)(z, f)
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        &self.pattern
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        (self.j)(z, values)
    }
    fn component_name(&self, i: usize) -> String {
        match &self.names {
            Some(n) => n[i].clone(),
            None => format!("z[{i}]"),
        }
    }
    fn write_component_name(&self, i: usize, out: &mut String) {
        use std::fmt::Write;
        match &self.names {
            Some(n) => out.push_str(&n[i]),
            // Writing into a String cannot fail.
            None => _ = write!(out, "z[{i}]"),
        }
    }
}

/// `mid(l, u, x)`: the projection of `x` onto `[l, u]`.
#[inline]
pub fn mid(l: f64, u: f64, x: f64) -> f64 {
    x.max(l).min(u)
}

/// Component `i` of the natural map `z − mid(l, u, z − F(z))`.
#[inline]
pub fn natural_map_component(z: f64, f: f64, l: f64, u: f64) -> f64 {
    z - mid(l, u, z - f)
}

/// The natural-map residual `‖z − mid(l, u, z − F(z))‖_∞` (`docs/model.md#mcp`): the one number
/// every backend is judged by. Non-finite input gives `+∞`, never a misleading small value.
pub fn natural_residual(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> f64 {
    let n = z.len();
    let (f, lower, upper) = (&f[..n], &lower[..n], &upper[..n]);
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the processor runs AVX (checked just above).
            unsafe { natural_residual_avx(z, f, lower, upper) }
        } else {
            natural_residual_sse2(z, f, lower, upper)
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        natural_residual_scalar(z, f, lower, upper, 0.0, false)
    }
}

/// The natural residual's loop from `r` and `non_finite` on, one component at a time.
#[inline]
fn natural_residual_scalar(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    mut r: f64,
    mut non_finite: bool,
) -> f64 {
    // `mid` (max/min) would silently drop a NaN in F: a NaN in `z` or `F`, or a component that
    // is not finite, is an infinite error. Tested once after the loop (no exit per component):
    // without one, `r` is the largest of finite numbers, whatever the order.
    for i in 0..z.len() {
        let c = natural_map_component(z[i], f[i], lower[i], upper[i]).abs();
        non_finite |= f[i].is_nan() | z[i].is_nan() | !c.is_finite();
        // `max` without its NaN case: a NaN `c` is counted in `non_finite` already.
        if c > r {
            r = c;
        }
    }
    if non_finite { f64::INFINITY } else { r }
}

/// [`natural_residual`] two components per instruction (SSE2, every `x86_64` has it). The
/// same bits as the scalar loop: the largest of finite numbers does not depend on the order,
/// and a component whose `z − F` is NaN (a NaN `z` or `F`) or whose `|z − mid|` is not finite
/// makes it `+∞` as there. Where `z − F` is not NaN, `max`/`min` with the bound as the first
/// operand are `f64::max`/`f64::min` (a NaN bound gives `z − F` back, as they do). The chord
/// steps evaluate it at every trial point (`docs/latency.md`).
#[cfg(target_arch = "x86_64")]
fn natural_residual_sse2(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> f64 {
    use std::arch::x86_64::*;
    let n = z.len();
    let pairs = n / 2;
    // SAFETY: SSE2 is part of the `x86_64` baseline; the loads are at `2p, 2p + 1 < n` of
    // slices of length `n` (the caller cut them to `z`'s length).
    unsafe {
        let sign = _mm_set1_pd(-0.0);
        let inf = _mm_set1_pd(f64::INFINITY);
        let (mut r, mut bad) = (_mm_setzero_pd(), _mm_setzero_pd());
        for p in 0..pairs {
            let i = 2 * p;
            let zv = _mm_loadu_pd(z.as_ptr().add(i));
            let x = _mm_sub_pd(zv, _mm_loadu_pd(f.as_ptr().add(i)));
            let m = _mm_min_pd(
                _mm_loadu_pd(upper.as_ptr().add(i)),
                _mm_max_pd(_mm_loadu_pd(lower.as_ptr().add(i)), x),
            );
            let c = _mm_andnot_pd(sign, _mm_sub_pd(zv, m));
            // `c` not below ∞ is ∞ or NaN.
            bad = _mm_or_pd(bad, _mm_or_pd(_mm_cmpunord_pd(x, x), _mm_cmpnlt_pd(c, inf)));
            r = _mm_max_pd(c, r);
        }
        let mut lanes = [0.0f64; 2];
        _mm_storeu_pd(lanes.as_mut_ptr(), r);
        let r = if lanes[1] > lanes[0] {
            lanes[1]
        } else {
            lanes[0]
        };
        let non_finite = _mm_movemask_pd(bad) != 0;
        let i = 2 * pairs;
        natural_residual_scalar(&z[i..], &f[i..], &lower[i..], &upper[i..], r, non_finite)
    }
}

/// [`natural_residual`] four components per instruction (AVX), then a pair (the VEX forms of
/// [`natural_residual_sse2`]'s), then the scalar loop: the same bits, as there (`vmaxpd`,
/// `vminpd` take their second operand for a NaN as `maxpd`, `minpd` do; the unordered and
/// not-less-than compares are `cmpunordpd`'s and `cmpnltpd`'s). Newton evaluates it ≈ 4 times a
/// desk step, 31 components each (`docs/latency.md`, branch wip-newtonown). Only called where
/// the processor runs AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn natural_residual_avx(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> f64 {
    use std::arch::x86_64::*;
    let n = z.len();
    let (f, lower, upper) = (&f[..n], &lower[..n], &upper[..n]);
    let quads = n / 4;
    let mut i = 4 * quads;
    // SAFETY: the loads are at `4q .. 4q + 3 < n`, then at `i, i + 1 < n`, of slices of length
    // `n`; unaligned loads need no alignment.
    let (lanes, non_finite) = unsafe {
        let sign = _mm256_set1_pd(-0.0);
        let inf = _mm256_set1_pd(f64::INFINITY);
        let (mut r, mut bad) = (_mm256_setzero_pd(), _mm256_setzero_pd());
        for q in 0..quads {
            let k = 4 * q;
            let zv = _mm256_loadu_pd(z.as_ptr().add(k));
            let x = _mm256_sub_pd(zv, _mm256_loadu_pd(f.as_ptr().add(k)));
            let m = _mm256_min_pd(
                _mm256_loadu_pd(upper.as_ptr().add(k)),
                _mm256_max_pd(_mm256_loadu_pd(lower.as_ptr().add(k)), x),
            );
            let c = _mm256_andnot_pd(sign, _mm256_sub_pd(zv, m));
            // `c` not below ∞ is ∞ or NaN.
            let nan_or_inf = _mm256_or_pd(
                _mm256_cmp_pd::<_CMP_UNORD_Q>(x, x),
                _mm256_cmp_pd::<_CMP_NLT_UQ>(c, inf),
            );
            bad = _mm256_or_pd(bad, nan_or_inf);
            r = _mm256_max_pd(c, r);
        }
        let mut lanes = [0.0f64; 4];
        _mm256_storeu_pd(lanes.as_mut_ptr(), r);
        let mut non_finite = _mm256_movemask_pd(bad) != 0;
        if i + 2 <= n {
            let (sign, inf) = (_mm256_castpd256_pd128(sign), _mm256_castpd256_pd128(inf));
            let zv = _mm_loadu_pd(z.as_ptr().add(i));
            let x = _mm_sub_pd(zv, _mm_loadu_pd(f.as_ptr().add(i)));
            let m = _mm_min_pd(
                _mm_loadu_pd(upper.as_ptr().add(i)),
                _mm_max_pd(_mm_loadu_pd(lower.as_ptr().add(i)), x),
            );
            let c = _mm_andnot_pd(sign, _mm_sub_pd(zv, m));
            let nan_or_inf = _mm_or_pd(_mm_cmpunord_pd(x, x), _mm_cmpnlt_pd(c, inf));
            non_finite |= _mm_movemask_pd(nan_or_inf) != 0;
            let mut pair = [0.0f64; 2];
            _mm_storeu_pd(pair.as_mut_ptr(), c);
            // Into the lanes as `max` would (a NaN `c` is counted in `non_finite`).
            for (l, c) in lanes.iter_mut().zip(pair) {
                if c > *l {
                    *l = c;
                }
            }
            i += 2;
        }
        (lanes, non_finite)
    };
    let top = |a: f64, b: f64| if b > a { b } else { a };
    let r = top(top(lanes[0], lanes[1]), top(lanes[2], lanes[3]));
    natural_residual_scalar(&z[i..], &f[i..], &lower[i..], &upper[i..], r, non_finite)
}

/// The first entry of `v` that is not finite (NaN or ±∞), `None` when all are: the test of a
/// starting point and of new data. One pass without an exit per entry (two entries per
/// instruction on `x86_64`), then the scalar search only when some entry is not finite.
pub fn first_non_finite(v: &[f64]) -> Option<usize> {
    if all_finite(v) {
        None
    } else {
        v.iter().position(|x| !x.is_finite())
    }
}

/// Whether every entry of `v` is finite: `x · 0` is NaN exactly when `x` is NaN or ±∞.
fn all_finite(v: &[f64]) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        let pairs = v.len() / 2;
        // SAFETY: SSE2 is part of the `x86_64` baseline; the loads are at `2p, 2p + 1 < len`.
        let bad = unsafe {
            let zero = _mm_setzero_pd();
            let mut bad = _mm_setzero_pd();
            for p in 0..pairs {
                let y = _mm_mul_pd(_mm_loadu_pd(v.as_ptr().add(2 * p)), zero);
                bad = _mm_or_pd(bad, _mm_cmpunord_pd(y, y));
            }
            _mm_movemask_pd(bad) != 0
        };
        !bad && v[2 * pairs..].iter().all(|x| x.is_finite())
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        v.iter().fold(true, |all, x| all & x.is_finite())
    }
}

/// Where the natural residual is worst: index, value, and the component's name.
#[derive(Debug, PartialEq)]
pub struct WorstComponent {
    /// Flat index.
    pub index: usize,
    /// `|z_i − mid(l_i, u_i, z_i − F_i)|`.
    pub value: f64,
    /// Name of the component (block and component).
    pub name: String,
}

/// Bytes a worst component's name is given room for when it is first stored: a kept record's
/// name then takes a later step's longer one (`contact.sigma[0]` after `desk.nu.vx`) in place,
/// so a step loop into kept storage allocates nothing after its first step.
const NAME_CAPACITY: usize = 64;

/// A name in storage of at least [`NAME_CAPACITY`] bytes.
fn name_storage(name: &str) -> String {
    let mut s = String::with_capacity(name.len().max(NAME_CAPACITY));
    s.push_str(name);
    s
}

/// `clone_from` reuses the name's storage.
impl Clone for WorstComponent {
    fn clone(&self) -> Self {
        WorstComponent {
            index: self.index,
            value: self.value,
            name: name_storage(&self.name),
        }
    }
    fn clone_from(&mut self, source: &Self) {
        self.index = source.index;
        self.value = source.value;
        self.name.clear();
        self.name.push_str(&source.name);
    }
}

/// Evaluates `F` at `z` and reports the natural residual and the worst component.
pub fn diagnose(mcp: &dyn Mcp, z: &[f64]) -> (f64, Option<WorstComponent>) {
    let mut f = vec![0.0; mcp.dim()];
    mcp.evaluate(z, &mut f);
    diagnose_values(mcp, z, &f)
}

/// [`diagnose`] for `F(z)` already evaluated into `f`: the natural residual and the worst
/// component (the first of the largest), whose name is formed once.
pub fn diagnose_values(mcp: &dyn Mcp, z: &[f64], f: &[f64]) -> (f64, Option<WorstComponent>) {
    let mut worst = None;
    let residual = diagnose_values_into(mcp, z, f, &mut worst);
    (residual, worst)
}

/// [`diagnose_values`] into `worst`, whose name's storage is reused
/// ([`Mcp::write_component_name`]): returns the natural residual.
pub fn diagnose_values_into(
    mcp: &dyn Mcp,
    z: &[f64],
    f: &[f64],
    worst: &mut Option<WorstComponent>,
) -> f64 {
    let found = worst_component(z, f, mcp.lower(), mcp.upper());
    write_worst_component(mcp, found, worst);
    // The largest component is the natural residual (see `final_residuals`).
    found.map_or(0.0, |(_, w)| w)
}

/// The first component of the largest natural residual and its value, a NaN counting as `+∞`
/// ([`FinalResiduals::worst`]); its value is [`natural_residual`] bit for bit (`max` returns
/// one of its arguments, and the NaN and non-finite cases are `+∞` in both). `None` when empty.
pub fn worst_component(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> Option<(usize, f64)> {
    let n = z.len();
    let (f, lower, upper) = (&f[..n], &lower[..n], &upper[..n]);
    #[cfg(target_arch = "x86_64")]
    {
        worst_component_sse2(z, f, lower, upper)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        worst_component_scalar(z, f, lower, upper, 0, None)
    }
}

/// [`worst_component`] of a point whose [`natural_residual`] `value` is known (the same `z`
/// and `F`, bit for bit): the first component whose value is `value`, by a scan that stops
/// there. The same index and bits as `worst_component`: `value` is the largest component (a
/// maximum returns one of its arguments; `+∞` for a NaN or infinite one, as here), so its
/// first occurrence is the first of the largest. A `value` that no component has (not this
/// point's) falls back to the full search. A Newton solve's finish knows the residual of its
/// last point (`docs/latency.md`).
pub fn worst_component_of_residual(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    value: f64,
) -> Option<(usize, f64)> {
    let n = z.len();
    let (f, lower, upper) = (&f[..n], &lower[..n], &upper[..n]);
    for i in 0..n {
        let mut c = natural_map_component(z[i], f[i], lower[i], upper[i]).abs();
        if c.is_nan() || f[i].is_nan() || z[i].is_nan() {
            c = f64::INFINITY;
        }
        if c == value {
            return Some((i, c));
        }
    }
    worst_component(z, f, lower, upper)
}

/// [`worst_component`]'s loop from component `from` on, one component at a time, `worst` the
/// worst of the components before it.
#[inline]
fn worst_component_scalar(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    from: usize,
    mut worst: Option<(usize, f64)>,
) -> Option<(usize, f64)> {
    for i in from..z.len() {
        let mut c = natural_map_component(z[i], f[i], lower[i], upper[i]).abs();
        if c.is_nan() || f[i].is_nan() || z[i].is_nan() {
            c = f64::INFINITY;
        }
        if worst.is_none_or(|(_, w)| c > w) {
            worst = Some((i, c));
        }
    }
    worst
}

/// [`worst_component`] two components per instruction (SSE2), the same index and bits as the
/// scalar loop. Each lane keeps the first of its largest components (even indices in one, odd
/// in the other; replaced only by a strictly larger one), so the first of the largest overall is
/// the lane with the larger value, the smaller index on a tie. A component is `+∞` where `z − F`
/// is NaN or `|z − mid|` is not below `∞`: exactly where the scalar loop makes it `+∞` (see
/// [`natural_residual_sse2`]; a NaN `z` or `F` makes `z − F` NaN, and `z − F` NaN with both
/// not NaN means both infinite, where `|z − mid|` is `∞` or NaN). Indices are kept as `f64`
/// (exact below 2⁵³). A Newton solve's finish reports it (`docs/latency.md`).
#[cfg(target_arch = "x86_64")]
fn worst_component_sse2(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
) -> Option<(usize, f64)> {
    use std::arch::x86_64::*;
    let n = z.len();
    let pairs = n / 2;
    if pairs == 0 {
        return worst_component_scalar(z, f, lower, upper, 0, None);
    }
    // SAFETY: SSE2 is part of the `x86_64` baseline; the loads are at `2p, 2p + 1 < n` of
    // slices of length `n` (the caller cut them to `z`'s length).
    unsafe {
        let sign = _mm_set1_pd(-0.0);
        let inf = _mm_set1_pd(f64::INFINITY);
        let two = _mm_set1_pd(2.0);
        // Below every component (each is `≥ +0` or `+∞`): the first pair replaces it.
        let mut best = _mm_set1_pd(-1.0);
        let mut best_index = _mm_setzero_pd();
        let mut index = _mm_set_pd(1.0, 0.0);
        for p in 0..pairs {
            let i = 2 * p;
            let zv = _mm_loadu_pd(z.as_ptr().add(i));
            let x = _mm_sub_pd(zv, _mm_loadu_pd(f.as_ptr().add(i)));
            let m = _mm_min_pd(
                _mm_loadu_pd(upper.as_ptr().add(i)),
                _mm_max_pd(_mm_loadu_pd(lower.as_ptr().add(i)), x),
            );
            let c = _mm_andnot_pd(sign, _mm_sub_pd(zv, m));
            let bad = _mm_or_pd(_mm_cmpunord_pd(x, x), _mm_cmpnlt_pd(c, inf));
            let c = _mm_or_pd(_mm_andnot_pd(bad, c), _mm_and_pd(bad, inf));
            let larger = _mm_cmpgt_pd(c, best);
            best = _mm_or_pd(_mm_and_pd(larger, c), _mm_andnot_pd(larger, best));
            best_index = _mm_or_pd(_mm_and_pd(larger, index), _mm_andnot_pd(larger, best_index));
            index = _mm_add_pd(index, two);
        }
        let (mut values, mut indices) = ([0.0f64; 2], [0.0f64; 2]);
        _mm_storeu_pd(values.as_mut_ptr(), best);
        _mm_storeu_pd(indices.as_mut_ptr(), best_index);
        let lane = usize::from(
            values[1] > values[0] || (values[1] == values[0] && indices[1] < indices[0]),
        );
        let worst = Some((indices[lane] as usize, values[lane]));
        worst_component_scalar(z, f, lower, upper, 2 * pairs, worst)
    }
}

/// The residuals a solve's summary reports of its final point ([`final_residuals`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FinalResiduals {
    /// [`natural_residual`].
    pub natural: f64,
    /// The first component of the largest natural residual and its value (a NaN counting as
    /// `+∞`), as [`diagnose_values`] names it; `None` for an empty problem.
    pub worst: Option<(usize, f64)>,
    /// `‖Φ‖₂²`, summed in component order ([`fb_residual`] is its square root, `+∞` when it is
    /// not finite).
    pub fb_squared: f64,
}

impl FinalResiduals {
    /// From the worst component ([`worst_component`]) and `‖Φ‖₂²` summed in component order
    /// from `0.0`: the natural residual is the worst component's value.
    pub fn new(worst: Option<(usize, f64)>, fb_squared: f64) -> Self {
        FinalResiduals {
            natural: worst.map_or(0.0, |(_, w)| w),
            worst,
            fb_squared,
        }
    }

    /// [`fb_residual`] from the sum of squares.
    pub fn fb_residual(&self) -> f64 {
        if self.fb_squared.is_finite() {
            self.fb_squared.sqrt()
        } else {
            f64::INFINITY
        }
    }
}

/// [`natural_residual`], the worst component of [`diagnose_values`] and the sum of squares of
/// [`fb_residual`] in one pass over the components: bit for bit what the three give.
pub fn final_residuals(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> FinalResiduals {
    let n = z.len();
    let (f, lower, upper) = (&f[..n], &lower[..n], &upper[..n]);
    // The worst component by its vector pass (the first of the largest, a NaN as `+∞`: the
    // scalar loop's, bit for bit), then `Φ`'s squares in component order. One scalar loop for
    // both was PATH's largest item of a desk step's finish (`docs/latency.md`, branch wip-path).
    let worst = worst_component(z, f, lower, upper);
    let mut fb_squared = 0.0;
    for (((&zi, &fi), &li), &ui) in z.iter().zip(f).zip(lower).zip(upper) {
        let p = fb_component(zi, fi, li, ui);
        fb_squared += p * p;
    }
    FinalResiduals::new(worst, fb_squared)
}

/// Writes the worst component `found` (index and value, [`FinalResiduals::worst`]) into
/// `worst`, reusing its name's storage: the one place a result's worst component is named.
pub fn write_worst_component(
    mcp: &dyn Mcp,
    found: Option<(usize, f64)>,
    worst: &mut Option<WorstComponent>,
) {
    match (found, worst.as_mut()) {
        (None, _) => *worst = None,
        (Some((index, value)), Some(w)) => {
            w.index = index;
            w.value = value;
            w.name.clear();
            mcp.write_component_name(index, &mut w.name);
        }
        (Some((index, value)), None) => {
            let mut name = String::with_capacity(NAME_CAPACITY);
            mcp.write_component_name(index, &mut name);
            *worst = Some(WorstComponent { index, value, name });
        }
    }
}

/// The Fischer–Burmeister function `φ(a, b) = √(a² + b²) − a − b`; zero iff `a ≥ 0, b ≥ 0, ab = 0`.
#[inline]
pub fn fischer_burmeister(a: f64, b: f64) -> f64 {
    // hypot avoids overflow; the form below loses no accuracy when a, b > 0. The inline
    // `hypot` has glibc's bits (`model/src/hypot.rs`) without its call.
    let r = crate::hypot(a, b);
    if a > 0.0 && b > 0.0 {
        // √(a²+b²) − (a+b) = −2ab / (√(a²+b²) + a + b), without cancellation.
        -2.0 * a * b / (r + a + b)
    } else {
        r - a - b
    }
}

/// Component `i` of the Fischer–Burmeister reformulation `Φ`
/// (`docs/backends.md#semismooth-newton`): free `F`; lower `φ(z − l, F)`; upper `−φ(u − z, −F)`;
/// box (Billups) `φ(z − l, φ(u − z, −F))`.
#[inline(always)]
pub fn fb_component(z: f64, f: f64, l: f64, u: f64) -> f64 {
    fb_component_of_kind(classify(l, u), z, f, l, u)
}

/// [`fb_component`] for a component whose bounds `(l, u)` are of kind `kind`
/// (`classify(l, u)`).
#[inline(always)]
fn fb_component_of_kind(kind: BoundKind, z: f64, f: f64, l: f64, u: f64) -> f64 {
    match kind {
        BoundKind::Free => f,
        BoundKind::Lower => fischer_burmeister(z - l, f),
        BoundKind::Upper => -fischer_burmeister(u - z, -f),
        BoundKind::Box => fischer_burmeister(z - l, fischer_burmeister(u - z, -f)),
    }
}

/// Fills `phi` with the Fischer–Burmeister reformulation `Φ(z)` given `F(z)`.
pub fn fb_vector(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64], phi: &mut [f64]) {
    for i in 0..z.len() {
        phi[i] = fb_component(z[i], f[i], lower[i], upper[i]);
    }
}

/// [`fb_vector`] with the bounds' kinds given (`kinds[i] = classify(lower[i], upper[i])`): a
/// backend that evaluates `Φ` at every trial point of a solve classifies the bounds once.
pub fn fb_vector_of_kinds(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    kinds: &[BoundKind],
    phi: &mut [f64],
) {
    let n = z.len();
    let (f, lower, upper, kinds, phi) = (
        &f[..n],
        &lower[..n],
        &upper[..n],
        &kinds[..n],
        &mut phi[..n],
    );
    for i in 0..n {
        phi[i] = fb_component_of_kind(kinds[i], z[i], f[i], lower[i], upper[i]);
    }
}

/// [`fb_vector_of_kinds`] that also returns `‖Φ‖² = Σ Φ_i²`, summed in index order from `−0.0`
/// (the bits of the separate sum `phi.iter().map(|p| p * p).sum()`): the sum's serial chain
/// runs beside the components' evaluation instead of in a pass of its own (the merit `Ψ` at
/// every trial point of Newton's line search).
pub fn fb_vector_of_kinds_squared(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    kinds: &[BoundKind],
    phi: &mut [f64],
) -> f64 {
    let n = z.len();
    let (f, lower, upper, kinds, phi) = (
        &f[..n],
        &lower[..n],
        &upper[..n],
        &kinds[..n],
        &mut phi[..n],
    );
    let mut s = -0.0;
    for i in 0..n {
        // A free component's `Φ_i` is `F_i`: tested first, so that it reads `F` alone instead
        // of the four vectors and the kinds' jump table (most of the desk's 31 components;
        // the same value as `fb_component_of_kind`'s arm).
        let (kind, fi) = (kinds[i], f[i]);
        let c = if kind == BoundKind::Free {
            fi
        } else {
            fb_component_of_kind(kind, z[i], fi, lower[i], upper[i])
        };
        phi[i] = c;
        s += c * c;
    }
    s
}

/// The Fischer–Burmeister residual `‖Φ(z)‖₂`; `+∞` for non-finite input.
pub fn fb_residual(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> f64 {
    let mut s = 0.0;
    for i in 0..z.len() {
        let c = fb_component(z[i], f[i], lower[i], upper[i]);
        s += c * c;
    }
    norm_of_squares(s)
}

/// [`fb_residual`] over the components in `rows` alone, `‖Φ_S(z)‖₂`: a lower bound of
/// `fb_residual(z, f, lower, upper)` to the last bit when the ranges are disjoint and in
/// increasing order (rounding to nearest is monotone, so each partial sum of the nonnegative
/// `Φ_i²` taken in index order is at most the full sum's at the same index). A comparison
/// `a < fb_residual_of_rows(..)` therefore implies `a < fb_residual(..)` without the other
/// components of `F`. `+∞` for non-finite input (where `fb_residual` is `+∞` too); `0` (a
/// bound still) for ranges out of order. Only `f` in `rows` is read.
pub fn fb_residual_of_rows(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    rows: impl IntoIterator<Item = std::ops::Range<usize>>,
) -> f64 {
    let mut s = 0.0;
    let mut end = 0;
    for r in rows {
        if r.start < end {
            return 0.0;
        }
        end = r.end;
        for i in r {
            let c = fb_component(z[i], f[i], lower[i], upper[i]);
            s += c * c;
        }
    }
    norm_of_squares(s)
}

/// [`fb_residual`] that also writes `Φ(z)` ([`fb_vector`]) into `phi`: the same components,
/// summed in the same order (a caller that compares residuals keeps `Φ` for a backend,
/// [`Mcp::known_fb_vector`]).
pub fn fb_residual_into(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    phi: &mut [f64],
) -> f64 {
    // Cut to one length (no bounds checks in the loop), and a free component's `Φ_i = F_i`
    // (`fb_component`'s first arm: both bounds not finite) taken before the bounds are
    // classified and the kinds' jump table is taken: most of the desk's components are free,
    // and the warm start's guard calls this at every step (`docs/latency.md`, branch
    // wip-newtonown). The same components summed in the same order.
    let n = z.len();
    let (f, lower, upper, phi) = (&f[..n], &lower[..n], &upper[..n], &mut phi[..n]);
    let mut s = 0.0;
    for i in 0..n {
        let (l, u, fi) = (lower[i], upper[i], f[i]);
        let c = if !l.is_finite() && !u.is_finite() {
            fi
        } else {
            fb_component(z[i], fi, l, u)
        };
        phi[i] = c;
        s += c * c;
    }
    norm_of_squares(s)
}

/// `√s` for the sum `s` of the squared FB components, `+∞` when it is not finite (a NaN or an
/// infinite component): the one ending of [`fb_residual`], [`fb_residual_of_rows`] and
/// [`fb_residual_into`].
fn norm_of_squares(s: f64) -> f64 {
    if s.is_finite() {
        s.sqrt()
    } else {
        f64::INFINITY
    }
}

/// Evaluates `F` at `z` and returns the natural residual (allocates; for reports and tests).
pub fn residual_of(mcp: &dyn Mcp, z: &[f64]) -> f64 {
    let mut f = vec![0.0; mcp.dim()];
    mcp.evaluate(z, &mut f);
    natural_residual(z, &f, mcp.lower(), mcp.upper())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `fb_residual_of_rows` is at most `fb_residual` to the last bit over every split of the
    /// components into increasing ranges, equal to it when the ranges cover every component
    /// (the same sum in the same order), `+∞` where it is, 0 for ranges out of order.
    #[test]
    fn the_residual_of_some_rows_bounds_the_whole_one() {
        let inf = f64::INFINITY;
        let lower = [-inf, 0.0, 0.0, -inf, -1.0, 0.0, -inf, 0.0];
        let upper = [inf, inf, 1.0, 0.0, 1.0, inf, inf, inf];
        let z = [0.3, 1e-3, 0.7, -0.2, 0.9, 0.0, -1e-9, 2.0];
        let f = [1e-4, -0.5, 0.1, 0.3, -2.0, 1e-7, 0.2, 1e-12];
        let whole = fb_residual(&z, &f, &lower, &upper);
        assert!((whole - 1.127_602_5).abs() < 1e-6, "{whole}");
        let n = z.len();
        for a in 0..=n {
            for b in a..=n {
                let some = fb_residual_of_rows(&z, &f, &lower, &upper, std::iter::once(a..b));
                assert!(some <= whole, "{a}..{b}: {some} > {whole}");
                let two = fb_residual_of_rows(&z, &f, &lower, &upper, [0..a, b..n]);
                assert!(two <= whole, "0..{a}, {b}..{n}: {two} > {whole}");
            }
            let split = fb_residual_of_rows(&z, &f, &lower, &upper, [0..a, a..n]);
            assert_eq!(split.to_bits(), whole.to_bits());
        }
        assert_eq!(
            fb_residual_of_rows(&z, &f, &lower, &upper, [4..6, 0..2]),
            0.0
        );
        let mut bad = f;
        bad[1] = f64::NAN;
        assert_eq!(fb_residual(&z, &bad, &lower, &upper), inf);
        assert_eq!(
            fb_residual_of_rows(&z, &bad, &lower, &upper, std::iter::once(0..3)),
            inf
        );
        assert!(fb_residual_of_rows(&z, &bad, &lower, &upper, std::iter::once(2..n)) < inf);
    }

    /// A kept worst component takes a longer name in place (the step loop's zero allocations:
    /// desk step 29's `contact.sigma[0]` after `desk.nu.vx`), and the copy is the source's.
    #[test]
    fn a_kept_worst_component_takes_a_longer_name_in_place() {
        let short = WorstComponent {
            index: 0,
            value: 1e-15,
            name: "desk.nu.vx".to_string(),
        };
        let long = WorstComponent {
            index: 9,
            value: 2e-14,
            name: "contact.sigma[0]".to_string(),
        };
        let mut kept = short.clone();
        let (capacity, storage) = (kept.name.capacity(), kept.name.as_ptr());
        assert!(capacity >= NAME_CAPACITY, "{capacity}");
        kept.clone_from(&long);
        assert_eq!(kept, long);
        assert_eq!(
            (kept.name.capacity(), kept.name.as_ptr()),
            (capacity, storage)
        );
        // A name longer than the reserve is still copied whole.
        let longer = WorstComponent {
            name: "x".repeat(2 * NAME_CAPACITY),
            ..long
        };
        kept.clone_from(&longer);
        assert_eq!(kept, longer);
    }

    /// `final_residuals` gives the bits of the single scalar loop it replaced (the worst
    /// component, the first of ties, a NaN as `+∞`, and `Φ`'s squares summed in order), on
    /// every length 0–12 with free, one-sided and boxed bounds, ties, NaN and infinities.
    #[test]
    fn final_residuals_are_the_single_loops_bits() {
        fn single_loop(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> FinalResiduals {
            let mut worst: Option<(usize, f64)> = None;
            let mut fb_squared = 0.0;
            for i in 0..z.len() {
                let (zi, fi, li, ui) = (z[i], f[i], lower[i], upper[i]);
                let mut c = natural_map_component(zi, fi, li, ui).abs();
                if c.is_nan() || fi.is_nan() || zi.is_nan() {
                    c = f64::INFINITY;
                }
                if worst.is_none_or(|(_, w)| c > w) {
                    worst = Some((i, c));
                }
                let p = fb_component(zi, fi, li, ui);
                fb_squared += p * p;
            }
            FinalResiduals::new(worst, fb_squared)
        }
        let inf = f64::INFINITY;
        let bounds = [
            (0.0, inf),
            (-inf, inf),
            (-1.0, 2.0),
            (-inf, 3.0),
            (0.0, 0.0),
        ];
        let values = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            2.0,
            0.5,
            -2.5,
            1e-300,
            1e300,
            f64::NAN,
            inf,
            -inf,
        ];
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = |m: usize| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % m as u64) as usize
        };
        for n in 0..13 {
            for round in 0..300 {
                let (mut l, mut u, mut z, mut f) = (vec![], vec![], vec![], vec![]);
                for _ in 0..n {
                    let (lo, hi) = bounds[next(bounds.len())];
                    l.push(lo);
                    u.push(hi);
                    // Non-finite values in a tenth of the rounds only, so ties of finite
                    // maxima are common too.
                    let pick = |k: usize| if round % 10 == 0 { k } else { k % 9 };
                    z.push(mid(lo, hi, values[pick(next(values.len()))]));
                    f.push(values[pick(next(values.len()))]);
                }
                let want = single_loop(&z, &f, &l, &u);
                let got = final_residuals(&z, &f, &l, &u);
                assert_eq!(got.natural.to_bits(), want.natural.to_bits(), "{z:?} {f:?}");
                assert_eq!(
                    got.worst.map(|(i, w)| (i, w.to_bits())),
                    want.worst.map(|(i, w)| (i, w.to_bits())),
                    "{z:?} {f:?}"
                );
                // The sum's bits where it is a number; a NaN sum (∞ − ∞ in a component) is a
                // NaN whose sign the compiled operand order picks, and reported as `+∞`.
                if want.fb_squared.is_nan() {
                    assert!(got.fb_squared.is_nan());
                } else {
                    assert_eq!(got.fb_squared.to_bits(), want.fb_squared.to_bits());
                }
                assert_eq!(got.fb_residual().to_bits(), want.fb_residual().to_bits());
            }
        }
    }

    /// `final_residuals` and `worst_component` give the bits of the three separate passes they
    /// replace, NaN and infinite components included.
    #[test]
    fn final_residuals_match_the_separate_passes() {
        let inf = f64::INFINITY;
        let lower = [0.0, -inf, 0.0, -inf, -1.0, 0.0];
        let upper = [inf, inf, 2.0, 3.0, 1.0, inf];
        let cases: [([f64; 6], [f64; 6]); 4] = [
            (
                [0.5, 1.0, 1.5, 2.0, 0.25, 0.0],
                [-0.25, 1e-3, 0.5, -2.0, 3.0, 0.0],
            ),
            ([0.0; 6], [0.0; 6]),
            (
                [0.5, 1.0, 1.5, 2.0, 0.25, 0.0],
                [0.1, f64::NAN, 0.5, -2.0, 3.0, 0.0],
            ),
            (
                [0.5, 1.0, 1.5, 2.0, 0.25, 0.0],
                [0.1, 0.2, -inf, -2.0, 3.0, 0.0],
            ),
        ];
        for (z, f) in cases {
            let all = final_residuals(&z, &f, &lower, &upper);
            let natural = natural_residual(&z, &f, &lower, &upper);
            assert_eq!(all.natural.to_bits(), natural.to_bits(), "{z:?} {f:?}");
            let mcp = FnMcp::dense(lower.to_vec(), upper.to_vec(), |_, _| {}, |_, _| {})
                .unwrap_or_else(|e| panic!("{e}"));
            let (r, worst) = diagnose_values(&mcp, &z, &f);
            assert_eq!(r.to_bits(), natural.to_bits());
            let worst = worst.unwrap_or_else(|| panic!("a worst component"));
            assert_eq!(all.worst, Some((worst.index, worst.value)));
            assert_eq!(worst_component(&z, &f, &lower, &upper), all.worst);
            let fb = fb_residual(&z, &f, &lower, &upper);
            assert_eq!(all.fb_residual().to_bits(), fb.to_bits(), "{z:?} {f:?}");
            // `fb_residual_into`: the same residual, and `Φ` as `fb_vector` writes it.
            let (mut phi, mut want) = ([7.0; 6], [0.0; 6]);
            let fb_into = fb_residual_into(&z, &f, &lower, &upper, &mut phi);
            assert_eq!(fb_into.to_bits(), fb.to_bits(), "{z:?} {f:?}");
            fb_vector(&z, &f, &lower, &upper, &mut want);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&phi), bits(&want), "{z:?} {f:?}");
        }
        let empty = final_residuals(&[], &[], &[], &[]);
        assert_eq!((empty.natural, empty.worst), (0.0, None));
    }

    /// `fb_residual_into` (free components first, the slices cut to one length) gives the bits
    /// of the plain loop over `fb_component` it replaced, residual and `Φ`: every kind of
    /// bounds (a NaN bound counts as not finite, as `classify` takes it), signed zeros, NaN and
    /// infinite `z` and `F`; a longer `F` and `Φ` are read and written up to `z`'s length only.
    #[test]
    fn fb_residual_into_matches_the_plain_loop() {
        fn plain(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64], phi: &mut [f64]) -> f64 {
            let mut s = 0.0;
            for i in 0..z.len() {
                let c = fb_component(z[i], f[i], lower[i], upper[i]);
                phi[i] = c;
                s += c * c;
            }
            norm_of_squares(s)
        }
        let (inf, nan) = (f64::INFINITY, f64::NAN);
        let bounds = [
            (-inf, inf),
            (nan, inf),
            (-inf, nan),
            (0.0, inf),
            (-0.0, inf),
            (-inf, 1.0),
            (-1.0, 1.0),
            (nan, 2.0),
        ];
        let values = [-2.0, -0.5, -0.0, 0.0, 1e-300, 0.5, 3.0, inf, -inf, nan];
        // The bits, but a NaN's sign and payload: Rust leaves them to the compiler (an inlined
        // `r − a − b` with two NaN operands may keep either's), and no caller reads them.
        let bits = |v: &[f64]| {
            (v.iter())
                .map(|x| if x.is_nan() { u64::MAX } else { x.to_bits() })
                .collect::<Vec<_>>()
        };
        // Every (bounds, z, F) as one component, then vectors mixing them.
        let mut zs = Vec::new();
        let mut fs = Vec::new();
        let mut ls = Vec::new();
        let mut us = Vec::new();
        for &(l, u) in &bounds {
            for &z in &values {
                for &f in &values {
                    let (mut got, mut want) = ([7.0], [7.0]);
                    let r = fb_residual_into(&[z], &[f], &[l], &[u], &mut got);
                    let w = plain(&[z], &[f], &[l], &[u], &mut want);
                    assert_eq!(r.to_bits(), w.to_bits(), "l {l} u {u} z {z} f {f}");
                    assert_eq!(bits(&got), bits(&want), "l {l} u {u} z {z} f {f}");
                    if f.is_finite() && z.is_finite() {
                        zs.push(z);
                        fs.push(f);
                        ls.push(l);
                        us.push(u);
                    }
                }
            }
        }
        for len in [0, 1, 2, 5, 31, zs.len()] {
            let (z, l, u) = (&zs[..len], &ls[..len], &us[..len]);
            let mut f = fs[..len].to_vec();
            f.push(nan);
            let (mut got, mut want) = (vec![7.0; len + 1], vec![7.0; len + 1]);
            let r = fb_residual_into(z, &f, l, u, &mut got);
            let w = plain(z, &f, l, u, &mut want);
            assert_eq!(r.to_bits(), w.to_bits(), "length {len}");
            assert_eq!(bits(&got), bits(&want), "length {len}");
            assert_eq!(got[len], 7.0);
            assert_eq!(r.to_bits(), fb_residual(z, &f, l, u).to_bits());
        }
    }

    /// `natural_residual` (one test after the loop) gives the bits of the loop that returned at
    /// the first NaN or non-finite component; `fb_vector_of_kinds` those of `fb_vector`, and
    /// `fb_vector_of_kinds_squared` them and the bits of their separate sum of squares;
    /// `worst_component` the first of the largest components, as the plain scan.
    #[test]
    fn natural_residual_and_classified_fb_match_the_plain_loops() {
        fn natural_with_exits(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64]) -> f64 {
            let mut r: f64 = 0.0;
            for i in 0..z.len() {
                if f[i].is_nan() || z[i].is_nan() {
                    return f64::INFINITY;
                }
                let c = natural_map_component(z[i], f[i], lower[i], upper[i]).abs();
                if !c.is_finite() {
                    return f64::INFINITY;
                }
                r = r.max(c);
            }
            r
        }
        let inf = f64::INFINITY;
        let lower = [0.0, -inf, 0.0, -inf, -1.0, 0.0];
        let upper = [inf, inf, 2.0, 3.0, 1.0, inf];
        let kinds: Vec<BoundKind> = lower
            .iter()
            .zip(&upper)
            .map(|(&l, &u)| classify(l, u))
            .collect();
        let z0 = [0.5, 1.0, 1.5, 2.0, 0.25, 0.0];
        let f0 = [-0.25, 1e-3, 0.5, -2.0, 3.0, -0.0];
        let mut cases = vec![(z0, f0), ([0.0; 6], [0.0; 6]), ([-0.0; 6], [1e-300; 6])];
        for (k, bad) in [f64::NAN, inf, -inf, 1e308].into_iter().enumerate() {
            let (mut z, mut f) = (z0, f0);
            f[k % 6] = bad;
            cases.push((z0, f));
            z[(k + 3) % 6] = bad;
            cases.push((z, f0));
        }
        for (z, f) in cases {
            let got = natural_residual(&z, &f, &lower, &upper);
            let want = natural_with_exits(&z, &f, &lower, &upper);
            assert_eq!(got.to_bits(), want.to_bits(), "{z:?} {f:?}");
            let (mut a, mut b) = ([0.0; 6], [0.0; 6]);
            fb_vector(&z, &f, &lower, &upper, &mut a);
            fb_vector_of_kinds(&z, &f, &lower, &upper, &kinds, &mut b);
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{z:?} {f:?}");
            let mut c = [1.0; 6];
            let squares = fb_vector_of_kinds_squared(&z, &f, &lower, &upper, &kinds, &mut c);
            assert_eq!(a.map(f64::to_bits), c.map(f64::to_bits), "{z:?} {f:?}");
            let sum: f64 = a.iter().map(|p| p * p).sum();
            assert_eq!(squares.to_bits(), sum.to_bits(), "{z:?} {f:?}");
        }
        assert_eq!(natural_residual(&z0, &f0, &lower, &upper), 1.25);
        // Every length (pairs and a last single component), special values at every place.
        let specials = [f64::NAN, inf, -inf, 1e308, -0.0, 0.0];
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for n in 0..40 {
            for trial in 0..40 {
                let mut z: Vec<f64> = (0..n).map(|_| 4.0 * next() - 2.0).collect();
                let mut f: Vec<f64> = (0..n).map(|_| 4.0 * next() - 2.0).collect();
                let l: Vec<f64> = (0..n).map(|i| lower[i % 6]).collect();
                let u: Vec<f64> = (0..n).map(|i| upper[i % 6]).collect();
                if n > 0 && trial % 2 == 1 {
                    let (k, s) = ((trial * 7) % n, specials[trial % specials.len()]);
                    if trial % 4 == 1 { z[k] = s } else { f[k] = s }
                }
                let got = natural_residual(&z, &f, &l, &u);
                let want = natural_with_exits(&z, &f, &l, &u);
                assert_eq!(got.to_bits(), want.to_bits(), "n = {n}: {z:?} {f:?}");
                // Each version of the lanes, whichever the processor picks above.
                #[cfg(target_arch = "x86_64")]
                {
                    let sse2 = natural_residual_sse2(&z, &f, &l, &u);
                    assert_eq!(sse2.to_bits(), want.to_bits(), "n = {n}: {z:?} {f:?}");
                    if std::arch::is_x86_feature_detected!("avx") {
                        // SAFETY: the processor runs AVX.
                        let avx = unsafe { natural_residual_avx(&z, &f, &l, &u) };
                        assert_eq!(avx.to_bits(), want.to_bits(), "n = {n}: {z:?} {f:?}");
                    }
                }
                let worst = worst_component(&z, &f, &l, &u).map(|(i, w)| (i, w.to_bits()));
                let scan = worst_component_scalar(&z, &f, &l, &u, 0, None);
                assert_eq!(
                    worst,
                    scan.map(|(i, w)| (i, w.to_bits())),
                    "n = {n}: {z:?} {f:?}"
                );
                assert_eq!(
                    scan.map(|(_, w)| w.to_bits()),
                    (n > 0).then_some(want.to_bits())
                );
            }
        }
        // Ties: the first of the largest (residuals 0.5, 1, 0, 1 and 2, 2 after a NaN).
        let (l4, u4) = ([0.0; 4], [inf; 4]);
        let worst = worst_component(&[0.5, 1.0, 0.0, 1.0], &[3.0, 5.0, 1.0, 5.0], &l4, &u4);
        assert_eq!(worst, Some((1, 1.0)));
        let worst = worst_component(&[0.0, 2.0, 2.0], &[f64::NAN, 3.0, 3.0], &l4[..3], &u4[..3]);
        assert_eq!(worst, Some((0, inf)));
        assert_eq!(
            worst_component(&[0.0; 3], &[1.0; 3], &l4[..3], &u4[..3]),
            Some((0, 0.0))
        );
        assert_eq!(worst_component(&[], &[], &[], &[]), None);
    }

    /// `worst_component` in lanes gives the scalar loop's index and bits: every length (pairs
    /// and a last single component), ties between the lanes (the first index wins), the largest
    /// in the last single component, special values (NaN, ±∞ counted as `+∞`, ±0) at every place.
    #[test]
    fn worst_component_in_lanes_is_the_first_of_the_largest() {
        let inf = f64::INFINITY;
        let lower = [0.0, -inf, 0.0, -inf, -1.0, 0.0];
        let upper = [inf, inf, 2.0, 3.0, 1.0, inf];
        let specials = [f64::NAN, inf, -inf, 1e308, -0.0, 0.0];
        let mut seed = 11u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut checked = 0;
        for n in 0..40 {
            for trial in 0..60 {
                let l: Vec<f64> = (0..n).map(|i| lower[i % 6]).collect();
                let u: Vec<f64> = (0..n).map(|i| upper[i % 6]).collect();
                // Values on a coarse grid (quarters) make equal components, so ties, common.
                let grid = trial % 3 == 0;
                let mut draw = || {
                    let v = 4.0 * next() - 2.0;
                    if grid { (4.0 * v).round() / 4.0 } else { v }
                };
                let mut z: Vec<f64> = (0..n).map(|_| draw()).collect();
                let mut f: Vec<f64> = (0..n).map(|_| draw()).collect();
                if n > 0 && trial % 2 == 1 {
                    let (k, s) = ((trial * 7) % n, specials[(trial / 2) % specials.len()]);
                    if trial % 4 == 1 {
                        z[k] = s
                    } else {
                        f[k] = s
                    }
                    if trial % 8 == 7 {
                        // A second special value: the first of two `+∞` wins.
                        let k2 = (k + n / 2 + 1) % n;
                        z[k2] = specials[(trial / 8) % specials.len()];
                    }
                }
                if n > 2 && trial % 10 == 4 {
                    // The largest in the last component (odd `n`: the scalar tail).
                    f[n - 1] = 1e6;
                    z[n - 1] = 0.0;
                }
                let got = worst_component(&z, &f, &l, &u);
                let want = worst_component_scalar(&z, &f, &l, &u, 0, None);
                assert_eq!(
                    got.map(|(i, v)| (i, v.to_bits())),
                    want.map(|(i, v)| (i, v.to_bits())),
                    "n = {n}: {z:?} {f:?}"
                );
                if let Some((_, v)) = got {
                    assert_eq!(v.to_bits(), natural_residual(&z, &f, &l, &u).to_bits());
                }
                // Found by the known residual: the same index and bits.
                let by_value =
                    worst_component_of_residual(&z, &f, &l, &u, natural_residual(&z, &f, &l, &u));
                assert_eq!(
                    by_value.map(|(i, v)| (i, v.to_bits())),
                    want.map(|(i, v)| (i, v.to_bits())),
                    "n = {n}: {z:?} {f:?}"
                );
                checked += usize::from(got.is_some());
            }
        }
        assert_eq!(checked, 39 * 60);
        // A tie across the lanes: components 1 and 2 equal and largest, the first (odd lane) wins.
        let (z, f) = ([0.0, 0.0, 0.0, 0.0], [-0.5, -3.0, -3.0, -1.0]);
        let (l, u) = ([0.0; 4], [inf; 4]);
        assert_eq!(worst_component(&z, &f, &l, &u), Some((1, 3.0)));
        assert_eq!(worst_component(&[], &[], &[], &[]), None);
        assert_eq!(
            worst_component_of_residual(&z, &f, &l, &u, 3.0),
            Some((1, 3.0))
        );
        // A value of no component (another point's): the full search.
        assert_eq!(
            worst_component_of_residual(&z, &f, &l, &u, 2.0),
            Some((1, 3.0))
        );
        assert_eq!(worst_component_of_residual(&[], &[], &[], &[], 0.0), None);
    }

    /// `first_non_finite` is the scalar search's index: every length up to 9, each special
    /// value at each place, and two of them (the first found).
    #[test]
    fn first_non_finite_is_the_first_nan_or_infinity() {
        let specials = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
        for n in 0..10 {
            let finite: Vec<f64> = (0..n)
                .map(|i| [1.0, -0.0, 1e308, -2.5e-310][i % 4])
                .collect();
            assert_eq!(first_non_finite(&finite), None);
            for k in 0..n {
                for s in specials {
                    let mut v = finite.clone();
                    v[k] = s;
                    assert_eq!(first_non_finite(&v), Some(k), "{v:?}");
                    v[n - 1 - k.min(n - 1)] = s;
                    assert_eq!(first_non_finite(&v), Some(k.min(n - 1 - k)), "{v:?}");
                }
            }
        }
    }
}

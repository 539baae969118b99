//! The vector loops of the small LU ([`super::small_lu`]), portable and with AVX2, chosen at run
//! time.
//!
//! The default `x86_64` target has SSE2 only, so the compiler's loops are two lanes wide; the
//! machines that run the steps have AVX2 (four lanes). Each loop here is elementwise — `x_i −=
//! l_i s`, `x_i /= d` — with the product rounded before the subtraction (no fused multiply-add,
//! which rounds once and would change the last bit), so both versions give bitwise the same
//! numbers: only the number of lanes per instruction differs (`docs/latency.md`). Runtime
//! dispatch rather than `-C target-cpu` keeps the library and its Python wheels portable.

/// The loops one elimination or solve runs, as a type so that the caller is compiled once per
/// instruction set with them inlined.
pub(super) trait Lanes {
    /// `x_i −= l_i s` for every `i` (the shorter length of `x` and `l`).
    fn sub_scaled(x: &mut [f64], l: &[f64], s: f64);
    /// `x_i /= d` for every `i`.
    fn div(x: &mut [f64], d: f64);
}

/// Plain loops (what the compiler makes of them for the build's target).
pub(super) struct Portable;

impl Lanes for Portable {
    #[inline(always)]
    fn sub_scaled(x: &mut [f64], l: &[f64], s: f64) {
        for (x, l) in x.iter_mut().zip(l) {
            *x -= l * s;
        }
    }
    #[inline(always)]
    fn div(x: &mut [f64], d: f64) {
        for x in x.iter_mut() {
            *x /= d;
        }
    }
}

/// True when the processor runs AVX2 (checked once per process by the standard library's cache).
pub(super) fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Four lanes, then two, then one. Only to be used inside a function compiled with
/// `#[target_feature(enable = "avx2")]` that runs after [`avx2_available`] said yes.
#[cfg(target_arch = "x86_64")]
pub(super) struct Avx2;

#[cfg(target_arch = "x86_64")]
impl Lanes for Avx2 {
    #[inline(always)]
    fn sub_scaled(x: &mut [f64], l: &[f64], s: f64) {
        // SAFETY: `Avx2` is used only inside `#[target_feature(enable = "avx2")]` functions,
        // entered only when `avx2_available()` is true.
        unsafe { sub_scaled_avx2(x, l, s) }
    }
    #[inline(always)]
    fn div(x: &mut [f64], d: f64) {
        // SAFETY: as in `sub_scaled`.
        unsafe { div_avx2(x, d) }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn sub_scaled_avx2(x: &mut [f64], l: &[f64], s: f64) {
    use std::arch::x86_64::*;
    let len = x.len().min(l.len());
    let (xp, lp) = (x.as_mut_ptr(), l.as_ptr());
    let s4 = _mm256_set1_pd(s);
    let mut i = 0;
    // SAFETY: every access is at an index below `len`, within both slices; unaligned loads and
    // stores need no alignment.
    unsafe {
        while i + 4 <= len {
            let p = _mm256_mul_pd(_mm256_loadu_pd(lp.add(i)), s4);
            _mm256_storeu_pd(xp.add(i), _mm256_sub_pd(_mm256_loadu_pd(xp.add(i)), p));
            i += 4;
        }
        if i + 2 <= len {
            let p = _mm_mul_pd(_mm_loadu_pd(lp.add(i)), _mm256_castpd256_pd128(s4));
            _mm_storeu_pd(xp.add(i), _mm_sub_pd(_mm_loadu_pd(xp.add(i)), p));
            i += 2;
        }
        if i < len {
            *xp.add(i) -= *lp.add(i) * s;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn div_avx2(x: &mut [f64], d: f64) {
    use std::arch::x86_64::*;
    let len = x.len();
    let xp = x.as_mut_ptr();
    let d4 = _mm256_set1_pd(d);
    let mut i = 0;
    // SAFETY: every access is at an index below `len`.
    unsafe {
        while i + 4 <= len {
            _mm256_storeu_pd(xp.add(i), _mm256_div_pd(_mm256_loadu_pd(xp.add(i)), d4));
            i += 4;
        }
        while i < len {
            *xp.add(i) /= d;
            i += 1;
        }
    }
}

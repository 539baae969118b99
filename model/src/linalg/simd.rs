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
    /// [`Lanes::sub_scaled`] in vectors aligned to the end of `x` (the odd entry first, then a
    /// pair, then fours): the forward substitution's updates `x[k + 1..n]` then all share their
    /// vector boundaries with the step before, so each load is within one earlier store and is
    /// forwarded from it (`docs/latency.md`, branch wip-lu). The same operation on every entry.
    fn sub_scaled_from_end(x: &mut [f64], l: &[f64], s: f64);
    /// `x_i /= d` for every `i`.
    fn div(x: &mut [f64], d: f64);
    /// The partial pivot of a column `x` (not empty): the first entry of largest magnitude,
    /// NaN entries passed over, 0 when `x_0` is NaN — what the scalar search
    /// `if |x_i| > best { best = |x_i|; p = i }` from `best = |x_0|` finds.
    fn first_largest_magnitude(x: &[f64]) -> usize;
}

/// [`Lanes::first_largest_magnitude`] by the scalar search.
#[inline(always)]
fn first_largest_magnitude_scalar(x: &[f64]) -> usize {
    let mut p = 0;
    let mut best = x[0].abs();
    for (i, v) in x.iter().enumerate().skip(1) {
        if v.abs() > best {
            best = v.abs();
            p = i;
        }
    }
    p
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
    fn sub_scaled_from_end(x: &mut [f64], l: &[f64], s: f64) {
        Self::sub_scaled(x, l, s);
    }
    #[inline(always)]
    fn div(x: &mut [f64], d: f64) {
        for x in x.iter_mut() {
            *x /= d;
        }
    }
    #[inline(always)]
    fn first_largest_magnitude(x: &[f64]) -> usize {
        first_largest_magnitude_scalar(x)
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
    fn sub_scaled_from_end(x: &mut [f64], l: &[f64], s: f64) {
        // SAFETY: as in `sub_scaled`.
        unsafe { sub_scaled_from_end_avx2(x, l, s) }
    }
    #[inline(always)]
    fn div(x: &mut [f64], d: f64) {
        // SAFETY: as in `sub_scaled`.
        unsafe { div_avx2(x, d) }
    }
    #[inline(always)]
    fn first_largest_magnitude(x: &[f64]) -> usize {
        // SAFETY: as in `sub_scaled`.
        unsafe { first_largest_magnitude_avx2(x) }
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
fn sub_scaled_from_end_avx2(x: &mut [f64], l: &[f64], s: f64) {
    use std::arch::x86_64::*;
    let len = x.len().min(l.len());
    let (xp, lp) = (x.as_mut_ptr(), l.as_ptr());
    let s4 = _mm256_set1_pd(s);
    let mut i = 0;
    // SAFETY: every access is at an index below `len`, within both slices; unaligned loads and
    // stores need no alignment.
    unsafe {
        if len % 2 == 1 {
            *xp -= *lp * s;
            i = 1;
        }
        if (len - i) % 4 == 2 {
            let p = _mm_mul_pd(_mm_loadu_pd(lp.add(i)), _mm256_castpd256_pd128(s4));
            _mm_storeu_pd(xp.add(i), _mm_sub_pd(_mm_loadu_pd(xp.add(i)), p));
            i += 2;
        }
        while i < len {
            let p = _mm256_mul_pd(_mm256_loadu_pd(lp.add(i)), s4);
            _mm256_storeu_pd(xp.add(i), _mm256_sub_pd(_mm256_loadu_pd(xp.add(i)), p));
            i += 4;
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

/// [`Lanes::first_largest_magnitude`] in two vector passes: the largest magnitude `m` (NaN
/// passed over: `max_pd` returns its second operand, the running maximum, when either is
/// NaN, and that maximum starts at the finite or infinite `|x_0|`), then the first entry
/// whose magnitude equals `m` (a NaN equals nothing). That entry is the scalar search's: it
/// beats every earlier one and no later one beats it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn first_largest_magnitude_avx2(x: &[f64]) -> usize {
    use std::arch::x86_64::*;
    let len = x.len();
    let first = x[0].abs();
    if first.is_nan() || len < 8 {
        return first_largest_magnitude_scalar(x);
    }
    let xp = x.as_ptr();
    let sign = _mm256_set1_pd(-0.0);
    let mut i = 0;
    let mut m = first;
    // SAFETY: every access is at an index below `len`.
    unsafe {
        let mut m4 = _mm256_set1_pd(first);
        while i + 4 <= len {
            m4 = _mm256_max_pd(_mm256_andnot_pd(sign, _mm256_loadu_pd(xp.add(i))), m4);
            i += 4;
        }
        let mut lanes = [0.0f64; 4];
        _mm256_storeu_pd(lanes.as_mut_ptr(), m4);
        m = lanes.iter().fold(m, |a, &b| if b > a { b } else { a });
        for v in &x[i..] {
            if v.abs() > m {
                m = v.abs();
            }
        }
        let m4 = _mm256_set1_pd(m);
        i = 0;
        while i + 4 <= len {
            let v = _mm256_andnot_pd(sign, _mm256_loadu_pd(xp.add(i)));
            let hit = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_EQ_OQ>(v, m4));
            if hit != 0 {
                return i + hit.trailing_zeros() as usize;
            }
            i += 4;
        }
    }
    match x[i..].iter().position(|v| v.abs() == m) {
        Some(j) => i + j,
        // Not reached: `m` is the magnitude of an entry.
        None => first_largest_magnitude_scalar(x),
    }
}

/// True when every entry of `x` is finite: the exponent fields OR-ed together (an entry is
/// ±∞ or NaN exactly when its exponent field is all ones, and then adding one to that field
/// carries into the sign bit), with no branch per entry, so that the compiler runs it in vector
/// lanes (four with AVX2). A matrix's finiteness test in one pass before its entries are moved,
/// instead of a test in the scatter's loop (`docs/latency.md`, branch wip-lukernel).
pub(super) fn all_finite(x: &[f64]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if avx2_available() {
        // SAFETY: the processor has AVX2.
        return unsafe { all_finite_avx2(x) };
    }
    all_finite_bits(x)
}

/// `x`'s exponent field plus one at the field's lowest bit: the sign bit of the result is set
/// exactly when `x` is ±∞ or NaN. OR-ed over many entries (no branch per entry), the sign bit of
/// the OR says whether any is not finite ([`all_finite`], and the scatter loops that test
/// while they move the entries).
#[inline(always)]
pub(super) fn exponent_carry(x: f64) -> u64 {
    const EXPONENT: u64 = 0x7ff << 52;
    (x.to_bits() & EXPONENT).wrapping_add(1 << 52)
}

/// Whether the OR of [`exponent_carry`] over some entries says that all of them are finite.
#[inline(always)]
pub(super) fn carries_finite(carried: u64) -> bool {
    carried >> 63 == 0
}

#[inline(always)]
fn all_finite_bits(x: &[f64]) -> bool {
    carries_finite(x.iter().fold(0u64, |acc, &v| acc | exponent_carry(v)))
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn all_finite_avx2(x: &[f64]) -> bool {
    all_finite_bits(x)
}

/// `y += Σ_e values[q_e] · rows[j_e]` over `entries = [(j_e, q_e), ..]` in their order, where
/// `rows[j]` is row `j` of the row-major matrix `rows` with `y.len()` columns: a sparse row
/// times a dense row-major matrix (the sensitivities' weak residual slopes,
/// [`crate::sensitivity`]). Each entry of `y` gets the products in the order of `entries`,
/// each rounded before its addition — bitwise the scalar loop `y_k += v · x_jk` column by
/// column — with four lanes where the processor has AVX2.
pub(crate) fn add_row_combination(
    y: &mut [f64],
    rows: &[f64],
    entries: &[(usize, usize)],
    values: &[f64],
) {
    #[cfg(target_arch = "x86_64")]
    if avx2_available() {
        // SAFETY: the processor has AVX2.
        unsafe { add_row_combination_avx2(y, rows, entries, values) };
        return;
    }
    add_row_combination_with::<Portable>(y, rows, entries, values);
}

#[inline(always)]
fn add_row_combination_with<L: Lanes>(
    y: &mut [f64],
    rows: &[f64],
    entries: &[(usize, usize)],
    values: &[f64],
) {
    let k = y.len();
    for &(j, q) in entries {
        // `x − l·(−v)` is `x + l·v` bit for bit: negation is exact and rounding symmetric.
        L::sub_scaled(y, &rows[j * k..(j + 1) * k], -values[q]);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn add_row_combination_avx2(
    y: &mut [f64],
    rows: &[f64],
    entries: &[(usize, usize)],
    values: &[f64],
) {
    add_row_combination_with::<Avx2>(y, rows, entries, values);
}

/// `dst[j·c + k] = src[k·m + j]`: the column-major `m × c` matrix `src` written row-major into
/// `dst` (the sensitivities' θ columns into the rows the small kernel's row-oriented solve works
/// on, and back, [`crate::sensitivity`]); 4 × 4 blocks in registers where the processor has AVX2.
pub(crate) fn transpose(src: &[f64], m: usize, c: usize, dst: &mut [f64]) {
    assert!(src.len() >= m * c && dst.len() >= m * c);
    #[cfg(target_arch = "x86_64")]
    if avx2_available() {
        // SAFETY: the processor has AVX2; the lengths are checked above.
        unsafe { transpose_avx2::<false>(src, m, c, dst) };
        return;
    }
    transpose_scalar(src, m, c, dst);
}

/// [`transpose`], also returning the largest magnitude of the moved entries and whether every
/// one is finite (the sensitivities' right-hand side scale and their checks, in the pass that
/// moves the entries anyway). The magnitude is exact whatever the order; with a NaN it is
/// unspecified (the caller rejects the matrix).
pub(crate) fn transpose_checked(src: &[f64], m: usize, c: usize, dst: &mut [f64]) -> (f64, bool) {
    assert!(src.len() >= m * c && dst.len() >= m * c);
    #[cfg(target_arch = "x86_64")]
    if avx2_available() {
        // SAFETY: the processor has AVX2; the lengths are checked above.
        return unsafe { transpose_avx2::<true>(src, m, c, dst) };
    }
    let (max, nan) = transpose_scalar(src, m, c, dst);
    (max, nan == 0.0)
}

/// [`transpose`] by a scalar loop; the largest magnitude of the entries and `Σ x · 0` (0 when
/// all are finite, NaN otherwise).
fn transpose_scalar(src: &[f64], m: usize, c: usize, dst: &mut [f64]) -> (f64, f64) {
    let (mut max, mut nan) = (0.0f64, 0.0f64);
    for k in 0..c {
        for j in 0..m {
            let x = src[k * m + j];
            dst[j * c + k] = x;
            max = if x.abs() > max { x.abs() } else { max };
            nan += x * 0.0;
        }
    }
    (max, nan)
}

/// [`transpose`] with AVX2; with `CHECK`, [`transpose_checked`]'s magnitude and finiteness
/// (else `(0, true)`). With `m, c ≥ 4` every entry goes through a 4 × 4 block in registers:
/// the last block row and column start at `m − 4` and `c − 4` when 4 does not divide the
/// sizes, overlapping the blocks before them (an entry moved twice is the same value written
/// twice, and seen twice by the checks, which changes neither the largest magnitude nor the
/// finiteness), instead of a scalar loop over the remainders (`docs/latency.md`, branch
/// wip-sens4).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn transpose_avx2<const CHECK: bool>(
    src: &[f64],
    m: usize,
    c: usize,
    dst: &mut [f64],
) -> (f64, bool) {
    use std::arch::x86_64::*;
    if m < 4 || c < 4 {
        let (tail_max, tail_nan) = transpose_scalar(src, m, c, dst);
        return (tail_max, tail_nan == 0.0);
    }
    // The blocks' first rows and columns: 0, 4, … and `m − 4` (`c − 4`) when 4 does not divide.
    let last = |size: usize, at: usize| if at + 4 > size { size - 4 } else { at };
    let (s, d) = (src.as_ptr(), dst.as_mut_ptr());
    let (mut max, mut nan) = (_mm256_setzero_pd(), _mm256_setzero_pd());
    let (mut max_b, mut nan_b) = (_mm256_setzero_pd(), _mm256_setzero_pd());
    let sign = _mm256_set1_pd(-0.0);
    let zero = _mm256_setzero_pd();
    for k in (0..c).step_by(4).map(|k| last(c, k)) {
        for j in (0..m).step_by(4).map(|j| last(m, j)) {
            // SAFETY: rows j..j + 4 ≤ m of columns k..k + 4 ≤ c, within `m · c` entries of
            // both slices (checked by the caller).
            unsafe {
                // Halves of columns k and k + 2 (k + 1 and k + 3) side by side, put together
                // by the loads (`vinsertf128` from memory runs beside the shuffle port), so
                // that one unpack per output row finishes the block: four shuffles, not eight.
                let half = |col: usize, row: usize| _mm_loadu_pd(s.add(col * m + row));
                let r0 =
                    _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(half(k, j)), half(k + 2, j));
                let r1 = _mm256_insertf128_pd::<1>(
                    _mm256_castpd128_pd256(half(k + 1, j)),
                    half(k + 3, j),
                );
                let r2 = _mm256_insertf128_pd::<1>(
                    _mm256_castpd128_pd256(half(k, j + 2)),
                    half(k + 2, j + 2),
                );
                let r3 = _mm256_insertf128_pd::<1>(
                    _mm256_castpd128_pd256(half(k + 1, j + 2)),
                    half(k + 3, j + 2),
                );
                if CHECK {
                    // The block's 16 entries (each once in r0..r3) reduced by a tree, then
                    // into one of two accumulators taken in turn: a chain of one `max` (and
                    // one `add`) per two blocks, so the checks keep pace with the moves.
                    let m01 = _mm256_max_pd(_mm256_andnot_pd(sign, r0), _mm256_andnot_pd(sign, r1));
                    let m23 = _mm256_max_pd(_mm256_andnot_pd(sign, r2), _mm256_andnot_pd(sign, r3));
                    max = _mm256_max_pd(max, _mm256_max_pd(m01, m23));
                    let z01 = _mm256_add_pd(_mm256_mul_pd(r0, zero), _mm256_mul_pd(r1, zero));
                    let z23 = _mm256_add_pd(_mm256_mul_pd(r2, zero), _mm256_mul_pd(r3, zero));
                    nan = _mm256_add_pd(nan, _mm256_add_pd(z01, z23));
                    std::mem::swap(&mut max, &mut max_b);
                    std::mem::swap(&mut nan, &mut nan_b);
                }
                _mm256_storeu_pd(d.add(j * c + k), _mm256_unpacklo_pd(r0, r1));
                _mm256_storeu_pd(d.add((j + 1) * c + k), _mm256_unpackhi_pd(r0, r1));
                _mm256_storeu_pd(d.add((j + 2) * c + k), _mm256_unpacklo_pd(r2, r3));
                _mm256_storeu_pd(d.add((j + 3) * c + k), _mm256_unpackhi_pd(r2, r3));
            }
        }
    }
    if !CHECK {
        return (0.0, true);
    }
    let (max, nan) = (_mm256_max_pd(max, max_b), _mm256_add_pd(nan, nan_b));
    let (mut lanes_max, mut lanes_nan) = ([0.0f64; 4], [0.0f64; 4]);
    // SAFETY: four lanes into four entries.
    unsafe {
        _mm256_storeu_pd(lanes_max.as_mut_ptr(), max);
        _mm256_storeu_pd(lanes_nan.as_mut_ptr(), nan);
    }
    // With a NaN the magnitude is unspecified (`max_pd` returns its second operand when either
    // is NaN; the caller rejects the matrix); the finiteness sum is NaN.
    let largest = lanes_max
        .iter()
        .fold(0.0f64, |acc, &a| if a > acc { a } else { acc });
    let finite = lanes_nan.iter().all(|x| *x == 0.0);
    (largest, finite)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The update in vectors aligned to the end is bitwise the plain loop's, for every length
    /// around the lane widths, `x` longer than `l` and the reverse, signed zeros included.
    #[test]
    fn sub_scaled_from_the_end_is_the_plain_loop() {
        if !avx2_available() {
            return;
        }
        for len in 0..40 {
            for (extra_x, extra_l) in [(0, 0), (3, 0), (0, 2)] {
                let x: Vec<f64> = (0..len + extra_x)
                    .map(|i| match i % 5 {
                        0 => -0.0,
                        1 => 0.0,
                        _ => (i as f64 * 0.7).sin() * 1e3,
                    })
                    .collect();
                let l: Vec<f64> = (0..len + extra_l)
                    .map(|i| {
                        if i % 4 == 3 {
                            -0.0
                        } else {
                            (i as f64 * 1.3).cos()
                        }
                    })
                    .collect();
                for s in [0.37, -2.5e-7, 0.0, -0.0] {
                    let (mut a, mut b) = (x.clone(), x.clone());
                    Portable::sub_scaled(&mut a, &l, s);
                    // SAFETY: the processor has AVX2.
                    unsafe { sub_scaled_from_end_avx2(&mut b, &l, s) };
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&a), bits(&b), "len {len}, s {s}");
                }
            }
        }
    }

    /// The row combination gives bitwise what the scalar loop `y_k += v · x_jk` gives, entry
    /// by entry in the order of the entries, for row lengths around the lane widths.
    #[test]
    fn row_combination_is_bitwise_the_scalar_loop() {
        let mut s = 7u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 10f64.powi((s % 7) as i32 - 3)
        };
        for k in [0, 1, 2, 3, 4, 5, 7, 8, 30, 31] {
            let rows: Vec<f64> = (0..6 * k).map(|_| next()).collect();
            let values: Vec<f64> = (0..9).map(|_| next()).collect();
            let entries = [(2, 0), (0, 3), (5, 8), (2, 1), (4, 4)];
            let y0: Vec<f64> = (0..k).map(|_| next()).collect();
            let mut expected = y0.clone();
            for (c, e) in expected.iter_mut().enumerate() {
                for &(j, q) in &entries {
                    *e += values[q] * rows[j * k + c];
                }
            }
            let mut y = y0.clone();
            add_row_combination(&mut y, &rows, &entries, &values);
            let mut portable = y0;
            add_row_combination_with::<Portable>(&mut portable, &rows, &entries, &values);
            for c in 0..k {
                assert_eq!(y[c].to_bits(), expected[c].to_bits(), "k = {k}, column {c}");
                assert_eq!(portable[c].to_bits(), expected[c].to_bits(), "k = {k}");
            }
        }
    }
    /// The vector pivot search finds the scalar search's entry: small integers (ties
    /// everywhere, both signs, ±0), NaN at the first, a middle and the last entry, and
    /// infinities, for lengths around the lane widths.
    /// The exponent-field test says what `is_finite` says, entry by entry: each special value
    /// (NaN of both signs and a payload, ±∞) at every place of every length 0–40, and the
    /// largest finite, the smallest normal, a subnormal and `−0` (finite) likewise.
    #[test]
    fn all_finite_is_the_entrywise_test() {
        let specials = [
            f64::NAN,
            -f64::NAN,
            f64::from_bits(0x7ff0_0000_0000_0001),
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            -f64::MAX,
            f64::MIN_POSITIVE,
            f64::from_bits(1),
            -0.0,
        ];
        let mut refused = 0;
        for len in 0..=40 {
            let base: Vec<f64> = (0..len).map(|i| (i as f64 * 0.7).sin() * 1e3).collect();
            assert!(all_finite(&base) && all_finite_bits(&base), "len {len}");
            for &v in &specials {
                for at in 0..len {
                    let mut x = base.clone();
                    x[at] = v;
                    let expected = x.iter().all(|v| v.is_finite());
                    assert_eq!(all_finite(&x), expected, "{v} at {at} of {len}");
                    assert_eq!(all_finite_bits(&x), expected, "{v} at {at} of {len}");
                    refused += usize::from(!expected);
                }
            }
        }
        assert_eq!(refused, 5 * (1..=40).sum::<usize>());
    }

    #[test]
    fn pivot_search_is_the_scalar_search() {
        let reference = |x: &[f64]| {
            let (mut p, mut best) = (0, x[0].abs());
            for (i, v) in x.iter().enumerate() {
                if v.abs() > best {
                    best = v.abs();
                    p = i;
                }
            }
            p
        };
        let mut s = 11u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            s >> 33
        };
        let mut cases = 0;
        for len in 1..=40 {
            for round in 0..40 {
                let mut x: Vec<f64> = (0..len)
                    .map(|_| {
                        let v = (next() % 7) as f64 - 3.0;
                        if v == 0.0 && next() % 2 == 0 { -0.0 } else { v }
                    })
                    .collect();
                match round % 5 {
                    1 => x[0] = f64::NAN,
                    2 => x[len / 2] = f64::NAN,
                    3 => {
                        x[len - 1] = f64::NAN;
                        x[(next() as usize) % len] = f64::NEG_INFINITY;
                    }
                    4 => x.iter_mut().for_each(|v| *v *= 0.0),
                    _ => {}
                }
                let expected = reference(&x);
                assert_eq!(Portable::first_largest_magnitude(&x), expected, "{x:?}");
                #[cfg(target_arch = "x86_64")]
                if avx2_available() {
                    // SAFETY: the processor has AVX2.
                    let fast = unsafe { first_largest_magnitude_avx2(&x) };
                    assert_eq!(fast, expected, "{x:?}");
                }
                cases += 1;
            }
        }
        assert_eq!(cases, 1600);
    }

    /// The transpose puts every entry where the index formula says, for sizes around the
    /// block width.
    #[test]
    fn transpose_moves_every_entry() {
        for m in [0, 1, 3, 4, 5, 8, 13, 31] {
            for c in [0, 1, 2, 4, 7, 30] {
                let src: Vec<f64> = (0..m * c).map(|i| i as f64 + 0.5).collect();
                let mut dst = vec![f64::NAN; m * c];
                transpose(&src, m, c, &mut dst);
                for j in 0..m {
                    for k in 0..c {
                        assert_eq!(dst[j * c + k], src[k * m + j], "m = {m}, c = {c}");
                    }
                }
                // The checked transpose: the same entries, their largest magnitude exactly,
                // and a NaN or an infinity anywhere seen.
                let signed: Vec<f64> = src.iter().map(|v| -v).collect();
                let mut checked = vec![f64::NAN; m * c];
                let (max, finite) = transpose_checked(&signed, m, c, &mut checked);
                assert_eq!(checked, dst.iter().map(|v| -v).collect::<Vec<_>>());
                assert!(finite);
                assert_eq!(max, if m * c > 0 { (m * c) as f64 - 0.5 } else { 0.0 });
                // The largest magnitude wherever it lies (every block, both accumulators the
                // checks alternate between).
                for at in 0..m * c {
                    let mut s2 = signed.clone();
                    s2[at] = -1e6;
                    let (max, finite) = transpose_checked(&s2, m, c, &mut checked);
                    assert!(finite);
                    assert_eq!(max, 1e6, "m = {m}, c = {c}, largest at {at}");
                }
                for bad in [f64::NAN, f64::INFINITY] {
                    for at in [0, m * c / 2, (m * c).max(1) - 1] {
                        if m * c == 0 {
                            continue;
                        }
                        let mut s2 = signed.clone();
                        s2[at] = bad;
                        let (_, finite) = transpose_checked(&s2, m, c, &mut checked);
                        assert!(!finite, "m = {m}, c = {c}, {bad} at {at}");
                    }
                }
            }
        }
    }
}

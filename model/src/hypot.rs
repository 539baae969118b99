//! `√(x² + y²)` with the bits of the C library's `hypot` (glibc ≥ 2.35, x86-64, no FMA),
//! its common path inline.
//!
//! `f64::hypot` is a call into glibc (≈ 45 instructions with the call and the ABI's register
//! reloads around it), made once per bounded component by the Fischer–Burmeister function at
//! every point Newton evaluates. glibc 2.35 replaced the old fdlibm `hypot` by a short kernel
//! (C. F. Borges, "An improved algorithm for hypot(a, b)", 2019: `√(ax² + ay²)` corrected by one
//! Newton step on the square's rounding error) with scalings for huge and tiny arguments. This
//! module repeats that kernel operation for operation (IEEE additions, multiplications, one
//! division and `sqrtsd`: no contraction into FMA, which Rust never does uncontracted), so its
//! result has the same bits; the ranges that glibc scales (a huge larger argument, a tiny
//! smaller one that is not negligible), infinities and NaNs are passed to `f64::hypot` itself.
//!
//! The equality holds against the glibc the tests run with: this machine's (Debian 2.36, whose
//! `libm.so.6` `hypot@@GLIBC_2.35` is this non-FMA kernel, checked by disassembly, no IFUNC).
//! On a system whose `hypot` is another algorithm (glibc < 2.35, musl, macOS), the two may
//! differ in the last bit; the tests `inline_hypot_*` below would say so.
//!
//! Proof by test: the module's tests compare [`hypot`] with `f64::hypot` bit for bit on 10⁶
//! pairs (and 10⁸ in an ignored test) over every exponent range, both signs, zeros, subnormals,
//! infinities, NaNs, the thresholds of each branch and their neighbours, and pairs at the
//! kernel's branch boundary `h = 2·ay`.

/// Above this, glibc scales both arguments down (`LARGE_VAL`).
const LARGE_VAL: f64 = f64::from_bits(0x5fe0_0000_0000_0000); // 2^511
/// Below this (the smaller argument), glibc scales both arguments up (`TINY_VAL`).
const TINY_VAL: f64 = f64::from_bits(0x2340_0000_0000_0000); // 2^-459
/// The ratio below which the smaller argument is negligible (`EPS`).
const EPS: f64 = f64::from_bits(0x3c90_0000_0000_0000); // 2^-54

/// glibc's kernel for `ax ≥ ay > 0` whose squares (and that of `ax − ay`) neither overflow nor
/// underflow: `h = √(ax² + ay²)` rounded, then `h − (t1 + t2) / (2h)` with `t1 + t2` the
/// error of `h²`, in glibc's order of operations.
#[inline(always)]
fn kernel(ax: f64, ay: f64) -> f64 {
    let h = (ax * ax + ay * ay).sqrt();
    let (t1, t2);
    if h <= 2.0 * ay {
        let delta = h - ay;
        t1 = ax * (2.0 * delta - ax);
        t2 = (delta - 2.0 * (ax - ay)) * delta;
    } else {
        let delta = h - ax;
        t1 = 2.0 * delta * (ax - 2.0 * ay);
        t2 = (4.0 * delta - ay) * ay + delta * delta;
    }
    h - (t1 + t2) / (2.0 * h)
}

/// The ranges glibc scales, infinities and NaNs: glibc itself (out of line, so the common
/// path keeps its registers).
#[cold]
#[inline(never)]
fn hypot_rare(x: f64, y: f64) -> f64 {
    x.hypot(y)
}

/// `√(x² + y²)` without overflow: the same bits as `x.hypot(y)` (glibc's), its common path
/// inline (see the module documentation).
#[inline(always)]
pub fn hypot(x: f64, y: f64) -> f64 {
    let x_abs = x.abs();
    let y_abs = y.abs();
    // glibc's `ax = x < y ? y : x`, `ay = x < y ? x : y` on the absolute values.
    let (ax, ay) = if x_abs < y_abs {
        (y_abs, x_abs)
    } else {
        (x_abs, y_abs)
    };
    // `ax ≤ 2^511` is false for NaN and ∞ in `ax`; a NaN `ay` (with `ax` not NaN) fails both
    // tests on `ay` below and goes to glibc.
    if ax <= LARGE_VAL {
        if ay >= TINY_VAL {
            // glibc's common case.
            if ay <= ax * EPS {
                return ax + ay;
            }
            return kernel(ax, ay);
        }
        // A tiny (or zero) `ay` negligible beside `ax`: glibc returns `ax + ay` before it
        // scales (`ay / EPS` is exact: a power of two, no overflow below 2^-459).
        if ax >= ay / EPS {
            return ax + ay;
        }
    }
    hypot_rare(x, y)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SplitMix64: a small reproducible generator (no dependency).
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^ (z >> 31)
        }

        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }

        /// A random sign and mantissa with the biased exponent `e` (0: subnormal or zero).
        fn with_exponent(&mut self, e: u64) -> f64 {
            let bits = (self.next() & 0x800f_ffff_ffff_ffff) | (e.min(0x7ff) << 52);
            f64::from_bits(bits)
        }
    }

    /// The special and threshold values, with their neighbours.
    fn specials() -> Vec<f64> {
        let mut base = vec![
            0.0,
            f64::MIN_POSITIVE,
            f64::from_bits(1),
            f64::from_bits(0x000f_ffff_ffff_ffff),
            f64::MAX,
            f64::INFINITY,
            f64::NAN,
            f64::from_bits(0x7ff0_0000_0000_0001), // a signalling NaN
            f64::from_bits(0x7ff8_dead_beef_0001), // a quiet NaN with a payload
            LARGE_VAL,
            TINY_VAL,
            LARGE_VAL * EPS,
            TINY_VAL / EPS,
            1.0,
            2.0,
            3.0,
            4.0,
            5.0,
            3.0f64.sqrt(),
            0.5,
            1e-300,
            1e300,
        ];
        let n = base.len();
        for i in 0..n {
            let v = base[i];
            if v.is_finite() {
                base.push(v.next_up());
                base.push(v.next_down().abs());
            }
        }
        let n = base.len();
        for i in 0..n {
            base.push(-base[i]);
        }
        base
    }

    /// Whether `(x, y)` takes the inline kernel (the path whose bits the test is about).
    fn in_kernel(x: f64, y: f64) -> bool {
        let (ax, ay) = (x.abs().max(y.abs()), x.abs().min(y.abs()));
        ax <= LARGE_VAL && ay >= TINY_VAL && ay > ax * EPS
    }

    fn check(x: f64, y: f64) {
        let want = x.hypot(y);
        let got = hypot(x, y);
        assert_eq!(
            got.to_bits(),
            want.to_bits(),
            "hypot({x:e} [{:#x}], {y:e} [{:#x}]): {got:e} [{:#x}] against glibc's {want:e} [{:#x}]",
            x.to_bits(),
            y.to_bits(),
            got.to_bits(),
            want.to_bits()
        );
    }

    /// `n` pairs of seven kinds (uniform bits; close exponents; the FB range; near the
    /// scaling thresholds; at the kernel's branch boundary `h = 2·ay`, i.e. `ax ≈ √3·ay`; at
    /// the negligible ratio `2^-54`; Pythagorean triples scaled: exact squares, ties), and
    /// every pair of the special values. Returns the number of random pairs that took the
    /// inline kernel.
    fn run(n: u64, seed: u64) -> u64 {
        let mut kernel_pairs = 0;
        let sp = specials();
        for &x in &sp {
            for &y in &sp {
                check(x, y);
            }
        }
        let mut rng = Rng(seed);
        for i in 0..n {
            let (x, y) = match i % 7 {
                // Any bits (all exponents, NaNs and infinities included).
                0 => (f64::from_bits(rng.next()), f64::from_bits(rng.next())),
                // Any exponent, the other within ±60 binades.
                1 => {
                    let e = rng.below(0x800);
                    let d = rng.below(121) as i64 - 60;
                    let f = (e as i64 + d).clamp(0, 0x7ff) as u64;
                    (rng.with_exponent(e), rng.with_exponent(f))
                }
                // The step problem's range: exponents 2^-60 .. 2^20.
                2 => {
                    let e = 1023 - 60 + rng.below(81);
                    let f = 1023 - 60 + rng.below(81);
                    (rng.with_exponent(e), rng.with_exponent(f))
                }
                // Near the scaling thresholds 2^511 and 2^-459 (and subnormals).
                3 => {
                    let centre = [
                        1023 + 511,
                        1023 - 459,
                        1,
                        0,
                        1023 + 511 - 54,
                        1023 - 459 + 54,
                    ][rng.below(6) as usize];
                    let e = (centre as i64 + rng.below(7) as i64 - 3).clamp(0, 0x7fe) as u64;
                    let d = rng.below(121) as i64 - 60;
                    let f = (e as i64 + d).clamp(0, 0x7fe) as u64;
                    (rng.with_exponent(e), rng.with_exponent(f))
                }
                // The kernel's branch boundary: ax ≈ √3·ay, a few ulps either side.
                4 => {
                    let e = 1023 - 40 + rng.below(81);
                    let ay = rng.with_exponent(e).abs();
                    let ax = f64::from_bits(
                        (ay * 3.0f64.sqrt())
                            .to_bits()
                            .wrapping_add(rng.below(9))
                            .wrapping_sub(4),
                    );
                    if rng.below(2) == 0 {
                        (ax, ay)
                    } else {
                        (-ay, ax)
                    }
                }
                // The negligible ratio: ay ≈ ax·2^-54, a few ulps either side.
                5 => {
                    let e = 1 + rng.below(0x7fe);
                    let ax = rng.with_exponent(e);
                    let ay = f64::from_bits(
                        (ax * EPS)
                            .abs()
                            .to_bits()
                            .wrapping_add(rng.below(9))
                            .wrapping_sub(4),
                    );
                    (ax, ay)
                }
                // Pythagorean triples (exact squares and sums) times a power of two, and
                // integers: results exactly representable or at ties of the square root.
                _ => {
                    let m = 1 + rng.below(1 << 20);
                    let k = 1 + rng.below(m);
                    let (a, b) = if rng.below(2) == 0 {
                        ((m * m - k * k) as f64, (2 * m * k) as f64)
                    } else {
                        (m as f64, k as f64)
                    };
                    let s = f64::from_bits((1023 - 80 + rng.below(161)) << 52);
                    (a * s, b * s)
                }
            };
            kernel_pairs += u64::from(in_kernel(x, y));
            check(x, y);
        }
        kernel_pairs
    }

    #[test]
    fn the_thresholds_are_glibcs_powers_of_two() {
        assert_eq!(LARGE_VAL, 2f64.powi(511));
        assert_eq!(TINY_VAL, 2f64.powi(-459));
        assert_eq!(EPS, 2f64.powi(-54));
    }

    #[test]
    fn inline_hypot_has_glibcs_bits_on_a_million_pairs() {
        // Most pairs reach the kernel (uniform bits mostly do not: their exponents differ).
        assert!(run(1_000_000, 0x5eed_0001) > 500_000);
    }

    /// 10⁸ pairs, ≈ 10 s in a release build:
    /// `cargo test --release -p ecp-model --lib hypot -- --ignored`.
    #[test]
    #[ignore]
    fn inline_hypot_has_glibcs_bits_on_a_hundred_million_pairs() {
        assert!(run(100_000_000, 0x5eed_0002) > 50_000_000);
    }
}

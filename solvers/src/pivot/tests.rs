use super::*;

fn lcp_check(m: &[f64], q: &[f64], z: &[f64]) {
    let n = q.len();
    for i in 0..n {
        let w: f64 = q[i] + (0..n).map(|j| m[i * n + j] * z[j]).sum::<f64>();
        assert!(z[i] >= -1e-12, "z[{i}] = {}", z[i]);
        assert!(w >= -1e-10, "w[{i}] = {w}");
        assert!((z[i] * w).abs() <= 1e-10, "z[{i}] w[{i}] = {}", z[i] * w);
    }
}

#[test]
fn lemke_solves_a_small_lcp() {
    // M = [[2, 1], [1, 2]], q = (−1, 1): z = (½, 0), w = (0, 3/2).
    let m = [2.0, 1.0, 1.0, 2.0];
    let q = [-1.0, 1.0];
    let sol = Lemke::new(LemkeSettings::default())
        .solve_lcp(&m, &q)
        .unwrap();
    assert!(
        (sol.z[0] - 0.5).abs() < 1e-14 && sol.z[1] == 0.0,
        "{:?}",
        sol.z
    );
    assert!((sol.w[1] - 1.5).abs() < 1e-14);
    assert!(sol.residual <= 1e-14);
    assert!(sol.pivots >= 1);
}

#[test]
fn lemke_solves_a_trivial_lcp_without_pivots_beyond_the_first() {
    // q ≥ 0: z = 0 solves it; the artificial variable reaches 0 with no basis change.
    let sol = Lemke::new(LemkeSettings::default())
        .solve_lcp(&[1.0, 0.0, 0.0, 1.0], &[1.0, 2.0])
        .unwrap();
    assert_eq!(sol.z, vec![0.0, 0.0]);
    assert_eq!(sol.pivots, 1);
}

#[test]
fn lemke_empty_problem() {
    let sol = Lemke::new(LemkeSettings::default())
        .solve_lcp(&[], &[])
        .unwrap();
    assert!(sol.z.is_empty() && sol.residual == 0.0);
}

#[test]
fn lemke_box_and_free_variables() {
    // Mixed box LCP: z0 ∈ [0, 1], z1 free, z2 ≤ 2 (upper only), z3 fixed at 0.5.
    // M = 3I + skew, q chosen so that z* = (1, −0.4, 2, 0.5) with w* = (−1, 0, −0.5, 7).
    let n = 4;
    #[rustfmt::skip]
    let m = vec![
        3.0, 1.0, 0.0, 0.5,
        -1.0, 3.0, 1.0, 0.0,
        0.0, -1.0, 3.0, 1.0,
        -0.5, 0.0, -1.0, 3.0,
    ];
    let z_star = [1.0, -0.4, 2.0, 0.5];
    let w_star = [-1.0, 0.0, -0.5, 7.0];
    let q: Vec<f64> = (0..n)
        .map(|i| w_star[i] - (0..n).map(|j| m[i * n + j] * z_star[j]).sum::<f64>())
        .collect();
    let lower = [0.0, f64::NEG_INFINITY, f64::NEG_INFINITY, 0.5];
    let upper = [1.0, f64::INFINITY, 2.0, 0.5];
    let problem = AffineMcp {
        m: AffineMatrix::DenseRowMajor { n, values: &m },
        q: &q,
        lower: &lower,
        upper: &upper,
        diagonal_shift: 0.0,
    };
    let mut lemke = Lemke::new(LemkeSettings::default());
    for start in [
        AffineStart::Classical { free_values: None },
        AffineStart::NormalMap(&[0.3, 5.0, -1.0, 0.0]),
        AffineStart::NormalMap(&[-2.0, 0.0, 3.0, 0.5]),
    ] {
        let sol = lemke.solve_affine(&problem, &start).unwrap();
        for i in 0..n {
            assert!((sol.z[i] - z_star[i]).abs() < 1e-12, "{:?}", sol.z);
            assert!((sol.w[i] - w_star[i]).abs() < 1e-12, "{:?}", sol.w);
        }
        assert!(sol.residual <= 1e-12);
    }
}

#[test]
fn lemke_sparse_matrix_and_diagonal_shift() {
    // M = diag(1, 2) in a sparse pattern, shifted by 1: (M + I) z + q with q = (−2, −3).
    let pattern = CscPattern::from_triplets(2, &[(0, 0), (1, 1)]).unwrap();
    let values = [1.0, 2.0];
    let problem = AffineMcp {
        m: AffineMatrix::Sparse {
            pattern: &pattern,
            values: &values,
        },
        q: &[-2.0, -3.0],
        lower: &[0.0, 0.0],
        upper: &[f64::INFINITY, f64::INFINITY],
        diagonal_shift: 1.0,
    };
    let sol = Lemke::new(LemkeSettings::default())
        .solve_affine(&problem, &AffineStart::Classical { free_values: None })
        .unwrap();
    assert!((sol.z[0] - 1.0).abs() < 1e-14 && (sol.z[1] - 1.0).abs() < 1e-14);
}

#[test]
fn lemke_reports_ray_termination_on_an_infeasible_lcp() {
    // w1 = −1 − z2 ≥ 0 is impossible for z ≥ 0: the LCP is infeasible (M copositive-plus).
    let m = [0.0, -1.0, 1.0, 0.0];
    let q = [-1.0, -1.0];
    let err = Lemke::new(LemkeSettings::default())
        .solve_lcp(&m, &q)
        .unwrap_err();
    match err {
        PivotError::RayTermination { pivots, artificial } => {
            assert!(pivots >= 1);
            assert!(artificial > 0.0);
        }
        other => panic!("expected ray termination, got {other:?}"),
    }
    assert!(err.to_string().contains("ray"));
}

#[test]
fn lemke_rejects_bad_input() {
    let mut lemke = Lemke::new(LemkeSettings::default());
    assert!(matches!(
        lemke.solve_lcp(&[1.0, 2.0, 3.0], &[1.0, 2.0]),
        Err(PivotError::InvalidInput(_))
    ));
    assert!(matches!(
        lemke.solve_lcp(&[f64::NAN], &[1.0]),
        Err(PivotError::InvalidInput(_))
    ));
    assert!(matches!(
        lemke.solve_lcp(&[1.0], &[f64::INFINITY]),
        Err(PivotError::InvalidInput(_))
    ));
    let problem = AffineMcp {
        m: AffineMatrix::DenseRowMajor {
            n: 1,
            values: &[1.0],
        },
        q: &[0.0],
        lower: &[1.0],
        upper: &[0.0],
        diagonal_shift: 0.0,
    };
    assert!(matches!(
        lemke.solve_affine(&problem, &AffineStart::Classical { free_values: None }),
        Err(PivotError::InvalidInput(_))
    ));
}

#[test]
fn lemke_reports_a_singular_free_block() {
    // Two free variables with a singular block: no basis exists at the start.
    let problem = AffineMcp {
        m: AffineMatrix::DenseRowMajor {
            n: 2,
            values: &[1.0, 1.0, 1.0, 1.0],
        },
        q: &[1.0, 2.0],
        lower: &[f64::NEG_INFINITY; 2],
        upper: &[f64::INFINITY; 2],
        diagonal_shift: 0.0,
    };
    let err = Lemke::new(LemkeSettings::default())
        .solve_affine(&problem, &AffineStart::Classical { free_values: None })
        .unwrap_err();
    assert!(matches!(err, PivotError::SingularBasis { .. }), "{err:?}");
}

#[test]
fn lemke_path_runs_from_the_start_to_the_solution() {
    let m = [2.0, 1.0, 1.0, 2.0];
    let q = [-1.0, -3.0];
    let lower = [0.0, 0.0];
    let upper = [f64::INFINITY; 2];
    let problem = AffineMcp {
        m: AffineMatrix::DenseRowMajor { n: 2, values: &m },
        q: &q,
        lower: &lower,
        upper: &upper,
        diagonal_shift: 0.0,
    };
    let x0 = [0.5, -0.5];
    let mut path = PivotPath::new();
    let sol = Lemke::new(LemkeSettings::default())
        .solve_affine_with_path(&problem, &AffineStart::NormalMap(&x0), &mut path)
        .unwrap();
    // Solution of this P-matrix LCP: z = (0, 1.5), w = (0.5, 0).
    assert!((sol.z[1] - 1.5).abs() < 1e-14 && sol.z[0] == 0.0);
    assert!(path.len() >= 2);
    // Two pivots (z₀ leaves its box, z₁ enters): the path has a kink.
    assert!(path.len() >= 3, "{}", path.len());
    let (start, s0) = path.breakpoint(0).unwrap();
    assert_eq!((start, s0), (&x0[..], 1.0));
    assert_eq!(path.breakpoint(path.len() - 1).unwrap().1, 0.0);
    assert!(path.breakpoint(path.len()).is_none());
    // Along the path, L(x) = (1 − t) L(x₀) (the homotopy of Ralph's path search).
    let l_of = |x: &[f64]| -> Vec<f64> {
        let z: Vec<f64> = x.iter().map(|v| v.max(0.0)).collect();
        (0..2)
            .map(|i| m[2 * i] * z[0] + m[2 * i + 1] * z[1] + q[i] + x[i] - z[i])
            .collect()
    };
    let l0 = l_of(&x0);
    let mut p = [0.0; 2];
    for t in [0.0, 0.1, 0.37, 0.5, 0.8, 1.0] {
        let used = path.point_at(t, &mut p);
        assert_eq!(used, t);
        let lt = l_of(&p);
        for i in 0..2 {
            assert!((lt[i] - (1.0 - t) * l0[i]).abs() < 1e-12, "t = {t}: {lt:?}");
        }
    }
    // The straight segment from x₀ to the end point is not the path: halfway along it the
    // homotopy is violated (which is why the PATH-like solver backtracks along the path).
    let end = path.breakpoint(path.len() - 1).unwrap().0.to_vec();
    let mid: Vec<f64> = (0..2).map(|i| 0.5 * (x0[i] + end[i])).collect();
    let lm = l_of(&mid);
    assert!((0..2).any(|i| (lm[i] - 0.5 * l0[i]).abs() > 1e-3), "{lm:?}");
    // Wrong output size: left alone.
    assert_eq!(path.point_at(0.5, &mut [0.0; 3]), 0.0);
}

#[test]
fn lemke_refactorises_periodically_without_losing_accuracy() {
    // A 40×40 P-matrix LCP (diagonally dominant) with a short refactorisation period.
    let n = 40;
    let mut m = vec![0.0; n * n];
    let mut q = vec![0.0; n];
    for i in 0..n {
        for j in 0..n {
            m[i * n + j] = (((i * 31 + j * 17) % 11) as f64 - 5.0) / 10.0;
        }
        m[i * n + i] = 30.0;
        q[i] = ((i * 7 % 13) as f64 - 6.0) / 3.0;
    }
    let mut lemke = Lemke::new(LemkeSettings {
        refactorization_period: 3,
        ..LemkeSettings::default()
    });
    let sol = lemke.solve_lcp(&m, &q).unwrap();
    lcp_check(&m, &q, &sol.z);
    assert!(sol.refactorizations >= 2);
    assert!(sol.residual <= 1e-12);
}

#[test]
fn lemke_as_mcp_solver_on_an_affine_problem() {
    let mcp = ecp_model::FnMcp::dense(
        vec![0.0; 2],
        vec![f64::INFINITY; 2],
        |z, f| {
            f[0] = 2.0 * z[0] + z[1] - 1.0;
            f[1] = z[0] + 2.0 * z[1] + 1.0;
        },
        |_z, j| {
            j[0] = 2.0;
            j[1] = 1.0;
            j[2] = 1.0;
            j[3] = 2.0;
        },
    )
    .unwrap();
    let mut solver = Lemke::new(LemkeSettings::default());
    let sol = solver.solve(&mcp, &[3.0, 3.0]).unwrap();
    assert_eq!(sol.summary.solver, "lemke");
    assert!(sol.summary.residual <= 1e-12);
    assert!(sol.summary.counter(Counter::Pivots).unwrap() >= 1);
    assert!((sol.z[0] - 0.5).abs() < 1e-14);
}

#[test]
fn lemke_as_mcp_solver_reports_a_nonlinear_problem_as_not_converged() {
    // F(z) = z² − 1 + … is not affine: the affine model at z0 is solved, the true residual is not
    // small, and the backend says so.
    let mcp = ecp_model::FnMcp::dense(
        vec![0.0],
        vec![f64::INFINITY],
        |z, f| f[0] = z[0] * z[0] - 1.0,
        |z, j| j[0] = 2.0 * z[0],
    )
    .unwrap();
    let err = Lemke::new(LemkeSettings::default())
        .solve(&mcp, &[3.0])
        .unwrap_err();
    let best = err.best().unwrap();
    assert!(best.summary.residual > 1e-3);
    assert!(best.z.iter().all(|v| v.is_finite()));
}

#[test]
fn lemke_pivot_cap_stops_the_path_and_clears() {
    // M = I, q = −1 (n = 5): z = 1, one pivot per variable after the artificial enters.
    let n = 5;
    let mut m = vec![0.0; n * n];
    for i in 0..n {
        m[i * n + i] = 1.0;
    }
    let q = vec![-1.0; n];
    let mut lemke = Lemke::new(LemkeSettings::default());
    let free = lemke.solve_lcp(&m, &q).unwrap();
    assert!(free.pivots > 3, "uncapped path: {} pivots", free.pivots);
    lemke.set_pivot_cap(Some(2));
    match lemke.solve_lcp(&m, &q) {
        Err(PivotError::MaxPivots { pivots }) => assert_eq!(pivots, 2),
        other => panic!("capped path: {other:?}"),
    }
    lemke.set_pivot_cap(None);
    let again = lemke.solve_lcp(&m, &q).unwrap();
    assert_eq!(again.pivots, free.pivots);
    assert!(
        again.z.iter().all(|z| (z - 1.0).abs() < 1e-14),
        "{:?}",
        again.z
    );
}

/// A deterministic LCP of size `n` with an `M` of mixed signs (not a P-matrix: some solves end
/// on a ray) and a `q` of mixed signs, from `seed`.
fn mixed_lcp(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut m: Vec<f64> = (0..n * n).map(|_| next()).collect();
    for i in 0..n {
        // Mostly dominant diagonals, one in three weak (longer, sometimes failing paths).
        m[i * n + i] += if (i as u64 + seed).is_multiple_of(3) {
            0.2
        } else {
            n as f64
        };
    }
    let q: Vec<f64> = (0..n).map(|_| next()).collect();
    (m, q)
}

/// `solve_lcp_into` writes bitwise the `z` and `w` of `solve_lcp` (and the same pivots and
/// residual), on one warm solver whose size changes between solves (n = 1 … 12, up and down),
/// and fails exactly when `solve_lcp` does, leaving the caller's slices untouched.
#[test]
fn solve_lcp_into_writes_the_solution_of_solve_lcp_bitwise() {
    let mut warm = Lemke::new(LemkeSettings::default());
    let (mut solved, mut failed) = (0, 0);
    for (k, n) in [1usize, 3, 10, 12, 10, 2, 7, 12, 5, 10]
        .into_iter()
        .enumerate()
    {
        for seed in 0..6u64 {
            let (m, q) = mixed_lcp(n, 100 * k as u64 + seed);
            let fresh = Lemke::new(LemkeSettings::default()).solve_lcp(&m, &q);
            let (mut z, mut w) = (vec![7.0; n], vec![7.0; n]);
            match (fresh, warm.solve_lcp_into(&m, &q, &mut z, &mut w)) {
                (Ok(a), Ok(b)) => {
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&a.z), bits(&z), "n = {n}, seed {seed}: z");
                    assert_eq!(bits(&a.w), bits(&w), "n = {n}, seed {seed}: w");
                    assert_eq!(
                        (a.pivots, a.residual.to_bits()),
                        (b.pivots, b.residual.to_bits())
                    );
                    assert!(b.z.is_empty() && b.w.is_empty());
                    assert!(a.residual <= 1e-9, "n = {n}: residual {}", a.residual);
                    solved += 1;
                }
                (Err(a), Err(b)) => {
                    assert_eq!(a, b, "n = {n}, seed {seed}");
                    assert!(z.iter().chain(&w).all(|&v| v == 7.0), "slices written");
                    failed += 1;
                }
                (a, b) => panic!("n = {n}, seed {seed}: {a:?} vs {b:?}"),
            }
        }
    }
    // A warm failure too: M = [−1], q = −1 has no solution (ray termination).
    let (mut z, mut w) = (vec![7.0; 1], vec![7.0; 1]);
    let err = warm.solve_lcp_into(&[-1.0], &[-1.0], &mut z, &mut w);
    assert!(
        matches!(err, Err(PivotError::RayTermination { .. })),
        "{err:?}"
    );
    assert_eq!((z[0], w[0]), (7.0, 7.0));
    assert!(solved >= 1, "{solved} solved, {failed} failed");
}

#[test]
fn solve_lcp_into_rejects_slices_of_the_wrong_length() {
    let mut lemke = Lemke::new(LemkeSettings::default());
    let (mut z, mut w) = (vec![0.0; 1], vec![0.0; 2]);
    let err = lemke.solve_lcp_into(&[2.0, 1.0, 1.0, 2.0], &[-1.0, 1.0], &mut z, &mut w);
    assert!(matches!(err, Err(PivotError::InvalidInput(_))), "{err:?}");
    // The solver is still usable, and the answer is M = [[2, 1], [1, 2]], q = (−1, 1): z = (½, 0).
    let mut z = vec![0.0; 2];
    lemke
        .solve_lcp_into(&[2.0, 1.0, 1.0, 2.0], &[-1.0, 1.0], &mut z, &mut w)
        .unwrap();
    assert_eq!(z, vec![0.5, 0.0]);
    assert_eq!(w, vec![0.0, 1.5]);
}

/// `mul_solution` (sums over the nonzero `z_j` only) is bitwise `mul`, also where a row's sum
/// cancels to zero, where `z` has −0 entries, and with a diagonal shift.
#[test]
fn mul_solution_is_mul_bitwise() {
    let n = 6;
    #[rustfmt::skip]
    let m = vec![
        1.0, 5.0, -1.0, 0.0, 2.0, -0.0,
        -0.0, 0.0, 0.0, -0.0, 0.0, 0.0,
        3.0, -2.0, -3.0, 1.0, 0.5, 4.0,
        1e-300, 0.0, 1e-300, 0.0, 0.0, 0.0,
        -1.0, 2.0, 1.0, 7.0, -2.0, 1.0,
        0.25, 0.0, -0.25, 0.0, 0.0, 9.0,
    ];
    let zs: [[f64; 6]; 5] = [
        [1.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        [1.0, -0.0, 1.0, -0.0, 0.0, -0.0],
        [1e-300, 0.0, -1e-300, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, -0.0],
        [1.0, 2.0, 3.0, 4.0, 0.0, 6.0],
    ];
    let a = AffineMatrix::DenseRowMajor { n, values: &m };
    let mut nonzero = Vec::new();
    for z in &zs {
        for shift in [0.0, 0.5] {
            let (mut full, mut sparse) = (vec![0.0; n], vec![0.0; n]);
            a.mul(z, shift, &mut full);
            a.mul_solution(z, shift, &mut sparse, &mut nonzero);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&full), bits(&sparse), "z = {z:?}, shift {shift}");
        }
    }
    // Row 0 at z = (1, 0, 1, 0, 0, 0) cancels to +0 either way.
    let mut out = vec![1.0; n];
    a.mul_solution(&zs[0], 0.0, &mut out, &mut nonzero);
    assert_eq!(out[0].to_bits(), 0.0f64.to_bits());
}

/// `all_finite` by products with zero: every finite magnitude passes (`f64::MAX · 0 = 0`), and
/// one NaN or infinity fails it in any lane of the four sums or in the remainder.
#[test]
fn all_finite_refuses_a_non_finite_entry_in_every_position() {
    assert!(all_finite(&[]));
    let finite = [
        1.0,
        -0.0,
        f64::MAX,
        -f64::MAX,
        f64::MIN_POSITIVE,
        5e-324,
        -3.5,
        0.0,
        1e300,
    ];
    assert!(all_finite(&finite));
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        for k in 0..finite.len() {
            let mut v = finite;
            v[k] = bad;
            assert!(!all_finite(&v), "{bad} at {k}");
            assert!(!all_finite(&v[..=k]), "{bad} last of {}", k + 1);
        }
    }
}

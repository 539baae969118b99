//! Constant Jacobian entries (`ResidualBlock::jacobian_depends_on`): the assembled MCP writes
//! them once per change of the data they read, and its `J` is the same, bit for bit, as that of
//! the same blocks without the declaration; the checker catches a wrong declaration.

use ecp_model::{
    BlockMcp, CheckOptions, DataBlock, Input, JacobianBlocks, Mcp, Params, Problem, ResidualBlock,
    VarBlock, check_residual_block,
};

/// `r = c·x + y²` (inputs x, y, c): `∂r/∂x = c` reads the data c only.
struct Affine;
impl ResidualBlock for Affine {
    fn name(&self) -> &str {
        "affine"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 1, 1]
    }
    fn jacobian_depends_on(&self, k: usize) -> Option<&[usize]> {
        if k == 0 { Some(&[2]) } else { None }
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        let (x, y, c) = (p.block(0)[0], p.block(1)[0], p.block(2)[0]);
        out[0] = c * x + y * y;
    }
    fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let (x, y, c) = (p.block(0)[0], p.block(1)[0], p.block(2)[0]);
        jac.set(0, 0, 0, c);
        jac.set(1, 0, 0, 2.0 * y);
        jac.set(2, 0, 0, x);
    }
}

/// `r = (y₀ − 1, y₁ + 2 w₁)` (inputs y, w, each 2): constant in every input.
struct Shifts;
impl ResidualBlock for Shifts {
    fn name(&self) -> &str {
        "shifts"
    }
    fn num_residuals(&self) -> usize {
        2
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[2, 2]
    }
    fn jacobian_depends_on(&self, _k: usize) -> Option<&[usize]> {
        Some(&[])
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        let (y, w) = (p.block(0), p.block(1));
        out[0] = y[0] - 1.0;
        out[1] = y[1] + 2.0 * w[1];
    }
    fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.add_diagonal(0, 0, 0, 2, 1.0);
        jac.add(1, 1, 1, 2.0);
    }
}

/// `r = x·y` that says, wrongly, its `∂r/∂x` reads nothing.
struct Wrong;
impl ResidualBlock for Wrong {
    fn name(&self) -> &str {
        "wrong"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 1]
    }
    fn jacobian_depends_on(&self, k: usize) -> Option<&[usize]> {
        if k == 0 { Some(&[]) } else { None }
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        out[0] = p.block(0)[0] * p.block(1)[0];
    }
    fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.set(0, 0, 0, p.block(1)[0]);
        jac.set(1, 0, 0, p.block(0)[0]);
    }
}

/// A block without its declaration: the plain path, which zeroes and writes every entry.
struct Undeclared<B>(B);
impl<B: ResidualBlock> ResidualBlock for Undeclared<B> {
    fn name(&self) -> &str {
        self.0.name()
    }
    fn num_residuals(&self) -> usize {
        self.0.num_residuals()
    }
    fn parameter_sizes(&self) -> &[usize] {
        self.0.parameter_sizes()
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        self.0.evaluate(p, out)
    }
    fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        self.0.jacobian(p, jac)
    }
}

/// x (1) paired with `Affine` on `(x, y0, c)`, y (2) with `Shifts` on `(y, x2)`, x2 (2) with
/// `Shifts` on `(x2, y)`, y0 (1) with `Affine` on `(y0, x, c)`; the data c. With `declared`
/// false, the same blocks undeclared.
fn problem(declared: bool) -> (BlockMcp, ecp_model::DataId) {
    let mut p = Problem::new();
    let x = p.add_variable_block(VarBlock::free("x", 1));
    let y = p.add_variable_block(VarBlock::free("y", 2));
    let x2 = p.add_variable_block(VarBlock::free("x2", 2));
    let c = p.add_data_block(DataBlock::new("c", [3.0]));
    let y0 = VarBlock::free("y0", 1);
    let y0 = p.add_variable_block(y0);
    let affine = [Input::Var(x), Input::Var(y0), Input::Data(c)];
    let on_y = [Input::Var(y), Input::Var(x2)];
    let on_x2 = [Input::Var(x2), Input::Var(y)];
    if declared {
        p.add_residual_block(x, Affine, &affine[..]).unwrap();
        p.add_residual_block(y, Shifts, &on_y[..]).unwrap();
        p.add_residual_block(x2, Shifts, &on_x2[..]).unwrap();
        p.add_residual_block(
            y0,
            Affine,
            &[Input::Var(y0), Input::Var(x), Input::Data(c)][..],
        )
        .unwrap();
    } else {
        p.add_residual_block(x, Undeclared(Affine), &affine[..])
            .unwrap();
        p.add_residual_block(y, Undeclared(Shifts), &on_y[..])
            .unwrap();
        p.add_residual_block(x2, Undeclared(Shifts), &on_x2[..])
            .unwrap();
        p.add_residual_block(
            y0,
            Undeclared(Affine),
            &[Input::Var(y0), Input::Var(x), Input::Data(c)][..],
        )
        .unwrap();
    }
    (p.build().unwrap(), c)
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn constant_entries_follow_the_data_and_match_the_plain_jacobian() {
    {
        let (mut mcp, c) = problem(true);
        let (mut plain, pc) = problem(false);
        let nnz = mcp.jacobian_pattern().nnz();
        assert_eq!(nnz, plain.jacobian_pattern().nnz());
        let points = [
            [0.5, -1.0, 2.0, 0.25, -0.75, 1.5],
            [-2.0, 3.0, 0.0, -0.0, 4.0, 0.125],
        ];
        for (step, data) in [3.0, 3.0, -7.5, 0.0].into_iter().enumerate() {
            mcp.set_data(c, &[data]).unwrap();
            plain.set_data(pc, &[data]).unwrap();
            for z in &points {
                // Values that are not zero beforehand: the template overwrites every entry.
                let (mut j, mut jp) = (vec![f64::NAN; nnz], vec![f64::NAN; nnz]);
                mcp.jacobian(z, &mut j);
                plain.jacobian(z, &mut jp);
                assert_eq!(bits(&j), bits(&jp), "step {step}, z {z:?}");
                let (mut f, mut fp) = (vec![0.0; 6], vec![0.0; 6]);
                let (mut j2, mut jp2) = (vec![1.0; nnz], vec![1.0; nnz]);
                mcp.evaluate_with_jacobian(z, &mut f, &mut j2);
                plain.evaluate_with_jacobian(z, &mut fp, &mut jp2);
                assert_eq!(bits(&j2), bits(&j));
                assert_eq!(bits(&jp2), bits(&jp));
                assert_eq!(bits(&f), bits(&fp));
                // ∂r_x/∂x = c, the data just set; ∂r_x/∂y0 = 2 y0.
                let pat = mcp.jacobian_pattern();
                let p = pat.position(0, 0).unwrap();
                assert_eq!(j[p], data);
                let p = pat.position(0, 5).unwrap();
                assert_eq!(j[p], 2.0 * z[5]);
                // The y rows: 1 on the diagonal, 2 on (y₁, x2₁).
                assert_eq!(j[pat.position(2, 2).unwrap()], 1.0);
                assert_eq!(j[pat.position(2, 4).unwrap()], 2.0);
            }
        }
        // Other data than the problem's (a continuation in a parameter): the plain path.
        let mut data = mcp.data_values().to_vec();
        data[0] = 11.0;
        let (mut f, mut j) = (vec![0.0; 6], vec![0.0; nnz]);
        mcp.evaluate_with_jacobian_with_data(&data, &points[0], &mut f, &mut j);
        assert_eq!(j[mcp.jacobian_pattern().position(0, 0).unwrap()], 11.0);
        mcp.jacobian(&points[0], &mut j);
        assert_eq!(j[mcp.jacobian_pattern().position(0, 0).unwrap()], 0.0);
    }
}

#[test]
fn checker_catches_a_wrong_constant_declaration() {
    let opts = CheckOptions::default();
    let good = check_residual_block(&Affine, &[&[0.5], &[-1.0], &[3.0]], &opts).unwrap();
    assert!(good.ok(), "{good}");
    let shifts = check_residual_block(&Shifts, &[&[0.5, 1.0], &[-1.0, 2.0]], &opts).unwrap();
    assert!(shifts.ok(), "{shifts}");
    // Its derivatives are right (the finite differences pass) but ∂r/∂x moves with y.
    let wrong = check_residual_block(&Wrong, &[&[0.5], &[-1.0]], &opts).unwrap();
    assert!(!wrong.ok(), "{wrong}");
    assert_eq!(wrong.failures, 1);
    assert_eq!(wrong.pairs[0].failures, 1);
    assert!(
        wrong.worst[0].location.contains("said to depend on"),
        "{wrong}"
    );
    assert_eq!(
        (wrong.worst[0].analytic, wrong.worst[0].numeric),
        (-1.0, -1.25)
    );
}

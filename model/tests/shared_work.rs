//! Work shared by the blocks of one Jacobian evaluation (`JacobianBlocks::shared`): computed
//! once per evaluation for the blocks reading the same input, again at the next evaluation, the
//! same bits as each block computing its own, and computed by every block outside the assembly.

use std::sync::atomic::{AtomicUsize, Ordering};

use ecp_model::{JacobianBlocks, Mcp, Params, Problem, ResidualBlock, Shared, VarBlock};

/// How many times `expensive` ran.
static COMPUTED: AtomicUsize = AtomicUsize::new(0);

/// A function of `x` alone that the blocks share (two values, so a length is checked).
fn expensive(x: &[f64]) -> [f64; 2] {
    COMPUTED.fetch_add(1, Ordering::SeqCst);
    [x[0].sin() * x[1], x[0] / 3.0 - x[1]]
}

/// `r = s · (g₀(x) y, g₁(x))`, with `g` = `expensive` shared: inputs `x` (2) and `y` (1).
struct UsesShared(f64);
impl ResidualBlock for UsesShared {
    fn name(&self) -> &str {
        "uses_shared"
    }
    fn num_residuals(&self) -> usize {
        2
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[2, 1]
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        let g = expensive(p.block(0));
        out[0] = self.0 * g[0] * p.block(1)[0];
        out[1] = self.0 * g[1];
    }
    fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let g = match jac.shared::<2>(7, p.range(0)) {
            Shared::Hit(v) => *v,
            Shared::Miss(slot) => {
                let g = expensive(p.block(0));
                slot.store(&g);
                g
            }
            Shared::Unshared => expensive(p.block(0)),
        };
        // The shared values written as entries, so the test sees their bits.
        jac.set(0, 0, 0, self.0 * g[0]);
        jac.set(0, 1, 1, self.0 * g[1]);
        jac.set(1, 0, 0, self.0 * g[0] * g[1]);
    }
}

#[test]
fn shared_once_per_jacobian_and_the_same_bits() {
    let mut problem = Problem::new();
    let x = problem.add_variable_block(VarBlock::free("x", 2));
    let y = problem.add_variable_block(VarBlock::free("y", 1));
    let w = problem.add_variable_block(VarBlock::free("w", 2));
    problem
        .add_residual_block(x, UsesShared(1.5), &[x, y])
        .unwrap();
    problem
        .add_residual_block(w, UsesShared(-0.25), &[x, y])
        .unwrap();
    problem.add_residual_block(y, Single, &[y]).unwrap();
    let mcp = problem.build().unwrap();
    let nnz = mcp.jacobian_pattern().nnz();
    for z in [[0.3, -1.2, 0.7, 2.0, -0.5], [1.1, 0.4, -0.2, 0.0, 3.0]] {
        let mut shared = vec![f64::NAN; nnz];
        COMPUTED.store(0, Ordering::SeqCst);
        mcp.jacobian(&z, &mut shared);
        // Both blocks read `x`: one computation per Jacobian, a new one at the next.
        assert_eq!(COMPUTED.load(Ordering::SeqCst), 1);
        COMPUTED.store(0, Ordering::SeqCst);
        let mut f = vec![0.0; 5];
        let mut again = vec![f64::NAN; nnz];
        mcp.evaluate_with_jacobian(&z, &mut f, &mut again);
        // `F` computes its own (2), the Jacobian shares (1).
        assert_eq!(COMPUTED.load(Ordering::SeqCst), 3);
        assert_eq!(bits(&shared), bits(&again));
        // Each block alone (no shared work): the same entries, bit for bit.
        let mut dense = [0.0; 4];
        let col_pos = [0, 2, usize::MAX];
        let block_start = [0, 2, 3];
        let ranges = [
            ecp_model::InputRange::var(0, 2),
            ecp_model::InputRange::var(2, 1),
        ];
        COMPUTED.store(0, Ordering::SeqCst);
        UsesShared(1.5).jacobian(
            Params::new(&z, &[], &ranges),
            &mut JacobianBlocks::new(&mut dense, &col_pos, &block_start, 2),
        );
        assert_eq!(COMPUTED.load(Ordering::SeqCst), 1);
        let mut expect: Vec<u64> = dense.iter().map(|v| v.to_bits()).collect();
        expect.sort_unstable();
        let mut got: Vec<u64> = bits(&shared);
        got.sort_unstable();
        for e in expect {
            assert!(got.contains(&e), "{e:#x} not among the assembled entries");
        }
    }
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// `r = y − 1`.
struct Single;
impl ResidualBlock for Single {
    fn name(&self) -> &str {
        "single"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1]
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        out[0] = p.block(0)[0] - 1.0;
    }
    fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.set(0, 0, 0, 1.0);
    }
}

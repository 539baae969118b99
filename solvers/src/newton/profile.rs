//! Where the Newton backend's time goes on a hard step: factorisations, damping trials and wall
//! time per phase, summed over every iteration of every attempt (`docs/newton.md#wall-time`).
//! Off by default; [`crate::NewtonSolver::with_profile`] turns it on (the clock is read only
//! then), for probes such as `examples/newton_probe.rs`.

use std::time::Instant;

/// The phases of one iteration that the profile times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// `J` (and `F` at the start), the generalised Jacobian `H` and `∇Ψ`.
    Jacobian,
    /// The LU of `H` and the Newton direction.
    NewtonDirection,
    /// The evaluations of the full Newton step and its Armijo search.
    NewtonSearch,
    /// The minimum-norm step: its QR and its trial points.
    MinNorm,
    /// Levenberg–Marquardt: forming and factorising `HᵀH + λD`, solving.
    LmFactor,
    /// Levenberg–Marquardt: evaluating the trial points.
    LmTrial,
    /// The last-resort backtracking and the bookkeeping.
    Other,
}

impl Phase {
    /// Every phase, in the order of [`NewtonProfile::ns`].
    pub const ALL: [Phase; 7] = [
        Phase::Jacobian,
        Phase::NewtonDirection,
        Phase::NewtonSearch,
        Phase::MinNorm,
        Phase::LmFactor,
        Phase::LmTrial,
        Phase::Other,
    ];

    /// Short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Jacobian => "jacobian",
            Phase::NewtonDirection => "newton_lu",
            Phase::NewtonSearch => "newton_search",
            Phase::MinNorm => "min_norm",
            Phase::LmFactor => "lm_factor",
            Phase::LmTrial => "lm_trial",
            Phase::Other => "other",
        }
    }
}

/// Counts and times summed over the solves since the profile was last taken.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NewtonProfile {
    /// Runs of the plain iteration (each stage of a continuation is one).
    pub runs: usize,
    /// Iterations of all runs.
    pub iterations: usize,
    /// Iterations by attempt: plain, damped plain, continuation, damped continuation,
    /// non-monotone plain ([`crate::newton::NewtonSettings::nonmonotone_restart`]).
    pub attempt_iterations: [usize; 5],
    /// Evaluations of `F`.
    pub f_evals: usize,
    /// LU factorisations of `H`.
    pub lu_factorizations: usize,
    /// Of those, the ones by block elimination ([`crate::newton::NewtonSettings::structured_solve`]).
    pub structured_factorizations: usize,
    /// Of those, the ones of the free block alone (held rows left out:
    /// [`crate::newton::NewtonSettings::free_block`]).
    pub free_block_factorizations: usize,
    /// QR factorisations of the minimum-norm step.
    pub min_norm_factorizations: usize,
    /// Levenberg–Marquardt damping trials (each one factorisation of `HᵀH + λD`).
    pub lm_trials: usize,
    /// Iterations that tried Levenberg–Marquardt.
    pub lm_iterations: usize,
    /// Of the damping trials, those that factorised the augmented `2n × 2n` system by sparse LU
    /// (above [`crate::newton::NewtonSettings::dense_max`], when the product's sparse Cholesky
    /// was not chosen: [`crate::newton::NewtonSettings::lm_sparse_product`]).
    pub lm_augmented_factorizations: usize,
    /// Multiplications of the damping trials' sparse Cholesky factorisations of `HᵀH + λI`, by
    /// their symbolic count (`docs/newton.md#cheap-levenberg-marquardt-trials`).
    pub lm_cholesky_flops: f64,
    /// Chord steps taken on a kept LU ([`crate::newton::NewtonSettings::chord_contraction`]).
    pub chord_steps: usize,
    /// Chord steps tried and not kept (the iteration then factorised `H` as without them).
    pub chord_rejections: usize,
    /// Chord steps on the LU kept from the last solve, taken at a solve's first iteration
    /// ([`crate::newton::NewtonSettings::chord_across_solves`]; counted in `chord_steps` too).
    pub kept_lu_steps: usize,
    /// First iterations that had the last solve's LU and refused its chord step (a pair on
    /// another branch, or the step's tests), then factorised.
    pub kept_lu_refusals: usize,
    /// Chord's polishes not taken at the round-off floor
    /// ([`crate::newton::NewtonSettings::chord_round_off_floor`]).
    pub chord_polishes_skipped: usize,
    /// Full Newton steps taken before `∇Ψ` was formed
    /// ([`crate::newton::NewtonSettings::fast_full_step`]).
    pub full_steps_first: usize,
    /// Nanoseconds per phase, in the order of [`Phase::ALL`].
    pub ns: [u64; 7],
}

impl NewtonProfile {
    /// Adds `other` to this profile.
    pub fn add(&mut self, other: &NewtonProfile) {
        self.runs += other.runs;
        self.iterations += other.iterations;
        for (a, b) in self
            .attempt_iterations
            .iter_mut()
            .zip(other.attempt_iterations)
        {
            *a += b;
        }
        self.f_evals += other.f_evals;
        self.lu_factorizations += other.lu_factorizations;
        self.structured_factorizations += other.structured_factorizations;
        self.free_block_factorizations += other.free_block_factorizations;
        self.min_norm_factorizations += other.min_norm_factorizations;
        self.lm_trials += other.lm_trials;
        self.lm_iterations += other.lm_iterations;
        self.lm_augmented_factorizations += other.lm_augmented_factorizations;
        self.lm_cholesky_flops += other.lm_cholesky_flops;
        self.chord_steps += other.chord_steps;
        self.chord_rejections += other.chord_rejections;
        self.kept_lu_steps += other.kept_lu_steps;
        self.kept_lu_refusals += other.kept_lu_refusals;
        self.chord_polishes_skipped += other.chord_polishes_skipped;
        self.full_steps_first += other.full_steps_first;
        for (a, b) in self.ns.iter_mut().zip(other.ns) {
            *a += b;
        }
    }

    /// Total time of the timed phases, in seconds.
    pub fn seconds(&self) -> f64 {
        self.ns.iter().sum::<u64>() as f64 * 1e-9
    }
}

/// A stopwatch that charges the time since its last lap to a phase; does nothing (reads no
/// clock) when profiling is off.
pub(crate) struct Clock {
    last: Option<Instant>,
}

impl Clock {
    pub(crate) fn new(on: bool) -> Self {
        Clock {
            last: on.then(Instant::now),
        }
    }

    /// Charges the time since the last lap to `phase`.
    #[inline]
    pub(crate) fn lap(&mut self, profile: &mut NewtonProfile, phase: Phase) {
        if let Some(last) = self.last {
            let now = Instant::now();
            let i = Phase::ALL.iter().position(|p| *p == phase).unwrap_or(6);
            profile.ns[i] += now.duration_since(last).as_nanos() as u64;
            self.last = Some(now);
        }
    }
}

//! The iterates of the last steps, kept by the driver for warm starts that extrapolate
//! ([`super::StepContext::history`], `docs/latency.md#an-extrapolated-warm-start-branch-wip-warmx-issue-18`).

use nalgebra::Vector3;

/// The iterates after the read-out of the last smooth steps, `z_k` the last step's
/// ([`super::StepContext::history`]).
#[derive(Clone, Copy, Debug)]
pub struct Iterates<'a> {
    /// `z_{k−2}`, when the last three steps were smooth.
    pub older: Option<&'a [f64]>,
    /// `z_{k−1}`.
    pub before: &'a [f64],
    /// `z_k`: the last smooth step's.
    pub last: &'a [f64],
    /// What `z` holds when the span's warm start is first asked for: the last step's iterate,
    /// `last` itself unless steps were taken since `z_k` ([`Iterates::ahead`]).
    pub current: &'a [f64],
    /// How many steps after `z_k`'s this span is: 1, or more after steps returned as their
    /// extrapolated warm start in 0 iterations, which are not kept (`History::skip`).
    pub ahead: usize,
}

/// How many steps' iterates are kept.
const KEPT: usize = 3;

/// The iterates after the read-out of the last [`KEPT`] steps (storage kept across steps, so
/// that a step allocates nothing once it has grown) and how many steps in a row up to the last
/// one were smooth: solved directly, in one piece, from their warm start, with nothing set since.
#[derive(Default)]
pub(super) struct History {
    /// Ring of iterates, `next` the slot of the next one.
    z: [Vec<f64>; KEPT],
    /// The step problem's origin (`StepFormulation::origin`) of each iterate.
    origins: [Vector3<f64>; KEPT],
    /// The backend's iterations on each kept step.
    iterations: [usize; KEPT],
    next: usize,
    streak: usize,
    /// Steps since the last kept one, each returned as its extrapolated warm start (`skip`),
    /// and the last one's iterate.
    gap: usize,
    current: Vec<f64>,
}

impl History {
    /// Forgets the steps kept: a step not solved directly from its warm start, a state,
    /// parameter or data block set, a reset, a rebuild.
    pub(super) fn clear(&mut self) {
        self.streak = 0;
        self.gap = 0;
    }

    /// Steps past `z`, the iterate of a step returned as its extrapolated warm start in 0
    /// iterations: not kept (an unrefined start extrapolated again carries its error into the
    /// next, `docs/latency.md#the-a1-step-where-its-time-goes-branch-wip-a1step-issue-18`); the
    /// next span extrapolates one step further from the steps kept.
    pub(super) fn skip(&mut self, z: &[f64]) {
        self.gap += 1;
        self.current.clear();
        self.current.extend_from_slice(z);
    }

    /// Steps taken since the last one kept ([`History::skip`]).
    pub(super) fn gap(&self) -> usize {
        self.gap
    }

    /// Keeps `z`, the iterate after the read-out of a step solved directly from its warm start
    /// in `iterations`, in coordinates relative to `origin`.
    pub(super) fn push(&mut self, z: &[f64], origin: Vector3<f64>, iterations: usize) {
        // The kept iterates are a step apart: after skipped steps they start again.
        if self.gap > 0 {
            self.clear();
        }
        let slot = self.next;
        self.z[slot].clear();
        self.z[slot].extend_from_slice(z);
        self.origins[slot] = origin;
        self.iterations[slot] = iterations;
        self.next = (slot + 1) % KEPT;
        self.streak += 1;
    }

    /// The most iterations any of the last smooth steps kept took (0 when none is kept).
    pub(super) fn recent_iterations(&self) -> usize {
        (0..self.streak.min(KEPT))
            .map(|back| self.iterations[(self.next + 2 * KEPT - 1 - back) % KEPT])
            .max()
            .unwrap_or(0)
    }

    /// The iterates of the last smooth steps (at least two) for a span that is a `whole_step`,
    /// relative to `origin` and of dimension `dim`.
    pub(super) fn iterates(
        &self,
        whole_step: bool,
        origin: &Vector3<f64>,
        dim: usize,
    ) -> Option<Iterates<'_>> {
        // The `back`-th newest iterate (0: the last), when it fits.
        let at = |back: usize| {
            let slot = (self.next + 2 * KEPT - 1 - back) % KEPT;
            let fits =
                back < self.streak && self.origins[slot] == *origin && self.z[slot].len() == dim;
            fits.then_some(self.z[slot].as_slice())
        };
        if !whole_step {
            return None;
        }
        let last = at(0)?;
        let current = if self.gap > 0 {
            (self.current.len() == dim).then_some(self.current.as_slice())?
        } else {
            last
        };
        Some(Iterates {
            older: at(2),
            before: at(1)?,
            last,
            current,
            ahead: self.gap + 1,
        })
    }
}

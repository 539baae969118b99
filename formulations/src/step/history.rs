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
    /// `z_k`: what `z` holds when the span's warm start is first asked for.
    pub last: &'a [f64],
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
}

impl History {
    /// Forgets the steps kept: a step not solved directly from its warm start, a state,
    /// parameter or data block set, a reset, a rebuild.
    pub(super) fn clear(&mut self) {
        self.streak = 0;
    }

    /// Keeps `z`, the iterate after the read-out of a step solved directly from its warm start
    /// in `iterations`, in coordinates relative to `origin`.
    pub(super) fn push(&mut self, z: &[f64], origin: Vector3<f64>, iterations: usize) {
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
        Some(Iterates {
            older: at(2),
            before: at(1)?,
            last: at(0)?,
        })
    }
}

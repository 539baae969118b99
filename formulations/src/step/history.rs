//! The iterates of the last steps, kept by the driver for warm starts that extrapolate
//! ([`super::StepContext::history`], `docs/latency.md#an-extrapolated-warm-start-branch-wip-warmx-issue-18`).

use std::sync::atomic::{AtomicU64, Ordering};

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
    /// `z_{k−3}`, `z_{k−4}`, `z_{k−5}`, each when the steps back to it were smooth (and every
    /// newer one is given): the extrapolations of orders 3 to 5 and the quadratic one's miss of
    /// the last step (`docs/latency.md`, branch wip-xorder).
    pub earlier: [Option<&'a [f64]>; 3],
    /// Which iterates these are, `(kept, pushed)`: `z_k` is the `pushed`-th iterate of the
    /// driver's store `kept` (a number no other store in the process has; 0 for iterates of no
    /// store), `z_{k−b}` its `(pushed − b)`-th. A kept iterate is never changed, so what a
    /// formulation derived from the iterates of one serial holds for them on a later step
    /// (the hull formulation's run of equal contact modes, `ecp::EcpContacts::warm_start`).
    pub serial: (u64, u64),
}

impl<'a> Iterates<'a> {
    /// The `back`-th newest iterate (0: `z_k`), when given and every newer one is.
    pub fn at(&self, back: usize) -> Option<&'a [f64]> {
        match back {
            0 => Some(self.last),
            1 => Some(self.before),
            _ if back < self.depth() => match back {
                2 => self.older,
                _ => self.earlier[back - 3],
            },
            _ => None,
        }
    }

    /// How many iterates in a row, from `z_k` back, are given (2 to 6, the steps kept).
    pub fn depth(&self) -> usize {
        if self.older.is_none() {
            return 2;
        }
        3 + self.earlier.iter().take_while(|e| e.is_some()).count()
    }

    /// Keeps the iterates from `z_k` back to `z_{k−back}` and drops the older ones (`back ≥ 1`).
    pub fn truncate(&mut self, back: usize) {
        if back < 2 {
            self.older = None;
        }
        for (i, e) in self.earlier.iter_mut().enumerate() {
            if i + 3 > back {
                *e = None;
            }
        }
    }
}

/// How many steps' iterates are kept: six, for the hull formulation's extrapolation of order 5
/// (`guess::MAX_ORDER` in `ecp`).
const KEPT: usize = 6;

/// Over how many of the last smooth steps [`History::recent_iterations`] takes the most
/// iterations (the extrapolated attempt's budget, `max(8, 3 r)`): three, as when three steps
/// were kept.
const RECENT: usize = 3;

/// The iterates after the read-out of the last [`KEPT`] steps (storage kept across steps, so
/// that a step allocates nothing once it has grown) and how many steps in a row up to the last
/// one were smooth: solved directly, in one piece, from their warm start, with nothing set since.
pub(super) struct History {
    /// Ring of iterates, `next` the slot of the next one.
    z: [Vec<f64>; KEPT],
    /// The step problem's origin (`StepFormulation::origin`) of each iterate.
    origins: [Vector3<f64>; KEPT],
    /// The backend's iterations on each kept step.
    iterations: [usize; KEPT],
    next: usize,
    streak: usize,
    /// This store's number ([`Iterates::serial`]), and how many iterates it kept in all.
    id: u64,
    pushed: u64,
}

/// The next store's number ([`Iterates::serial`]; 0 is no store's).
static NEXT_ID: AtomicU64 = AtomicU64::new(1);

impl Default for History {
    fn default() -> Self {
        History {
            z: Default::default(),
            origins: Default::default(),
            iterations: Default::default(),
            next: 0,
            streak: 0,
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            pushed: 0,
        }
    }
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
        if self.z[slot].capacity() < z.len() {
            // Every slot grown at once (their iterates kept), so that a step after the first kept
            // one allocates nothing (`tests/step_allocations.rs`: A1 from its fourth step).
            for kept in &mut self.z {
                kept.reserve(z.len().saturating_sub(kept.len()));
            }
        }
        self.z[slot].clear();
        self.z[slot].extend_from_slice(z);
        self.origins[slot] = origin;
        self.iterations[slot] = iterations;
        self.next = (slot + 1) % KEPT;
        self.streak += 1;
        self.pushed += 1;
    }

    /// The most iterations any of the last smooth steps kept took (0 when none is kept).
    pub(super) fn recent_iterations(&self) -> usize {
        (0..self.streak.min(RECENT))
            .map(|back| self.iterations[(self.next + 2 * KEPT - 1 - back) % KEPT])
            .max()
            .unwrap_or(0)
    }

    /// The iterates of the last smooth steps (at least two, at most [`KEPT`]) for a span that is a
    /// `whole_step`, relative to `origin` and of dimension `dim`.
    pub(super) fn iterates(
        &self,
        whole_step: bool,
        origin: &Vector3<f64>,
        dim: usize,
    ) -> Option<Iterates<'_>> {
        if !whole_step {
            return None;
        }
        // The iterates from the last back while each fits (kept since the last clear, in
        // `origin` and of dimension `dim`): an unbroken run back from `z_k` (an older iterate
        // fits whenever a newer one does, but the run is what counts), in one pass over the ring.
        let mut z: [Option<&[f64]>; KEPT] = [None; KEPT];
        let mut slot = self.next;
        for kept in z.iter_mut().take(self.streak) {
            slot = if slot == 0 { KEPT - 1 } else { slot - 1 };
            if self.origins[slot] != *origin || self.z[slot].len() != dim {
                break;
            }
            *kept = Some(self.z[slot].as_slice());
        }
        let [last, before, older, e3, e4, e5] = z;
        let it = Iterates {
            older,
            before: before?,
            last: last?,
            earlier: [e3, e4, e5],
            serial: (self.id, self.pushed),
        };
        Some(it)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kept iterates come newest first, as far back as the smooth steps go (at most six),
    /// only while they share the origin and dimension; `truncate` and `depth` agree with `at`,
    /// and the budget's iterations are the last three steps' most.
    #[test]
    fn six_iterates_are_kept_newest_first_while_the_run_lasts() {
        let o = Vector3::zeros();
        let mut h = History::default();
        for k in 0..8 {
            h.push(&[k as f64, 0.0], o, 1 + k % 4);
        }
        let it = h
            .iterates(true, &o, 2)
            .unwrap_or_else(|| panic!("no iterates"));
        assert_eq!(it.depth(), KEPT);
        // The serial: this store's number and the count of iterates it kept.
        assert_eq!(it.serial.1, 8);
        assert_ne!(it.serial.0, 0);
        assert_ne!(it.serial.0, History::default().id);
        for back in 0..KEPT {
            assert_eq!(it.at(back).map(|z| z[0]), Some((7 - back) as f64));
        }
        assert!(it.at(KEPT).is_none());
        assert_eq!(h.recent_iterations(), 4); // steps 5, 6, 7: 2, 3, 4 iterations
        let mut short = it;
        short.truncate(3);
        assert_eq!(short.depth(), 4);
        assert!(short.at(4).is_none() && short.earlier[1].is_none());
        short.truncate(1);
        assert_eq!(short.depth(), 2);
        assert!(short.older.is_none());
        // Not for a substep, another dimension; another origin ends the run there.
        assert!(h.iterates(false, &o, 2).is_none());
        assert!(h.iterates(true, &o, 3).is_none());
        h.push(&[8.0, 0.0], Vector3::new(1.0, 0.0, 0.0), 1);
        assert!(h.iterates(true, &o, 2).is_none());
        h.push(&[9.0, 0.0], o, 1);
        assert!(h.iterates(true, &o, 2).is_none());
        h.push(&[10.0, 0.0], o, 1);
        let it = h
            .iterates(true, &o, 2)
            .unwrap_or_else(|| panic!("no iterates"));
        assert_eq!(it.depth(), 2);
        assert_eq!((it.last[0], it.before[0]), (10.0, 9.0));
        assert_eq!(it.serial.1, 11);
        h.clear();
        assert!(h.iterates(true, &o, 2).is_none());
    }
}

//! Typed counters of a solve (`docs/backends.md#counters`): what a backend (or the stepper that
//! called it) counted, by name, so that a report can be read without guessing strings.
//!
//! A counter is a [`Counter`] value, never a free string: asking a [`Counters`] collection for a
//! counter that the backend did not report gives `None`, not a silent 0, and a misspelt built-in
//! counter does not compile. A user's backend reports counters of its own with
//! [`Counter::Custom`]; a custom name equal to a built-in counter's name *is* that counter.
//!
//! ```
//! use ecp_model::{Counter, Counters};
//!
//! let mut c = Counters::new();
//! c.set(Counter::Pivots, 7);
//! c.add(Counter::Retries, 1);
//! c.add(Counter::Retries, 1);
//! c.set(Counter::Custom("cache_hits"), 3);
//! assert_eq!(c.get(Counter::Pivots), Some(7));
//! assert_eq!(c.get(Counter::Retries), Some(2));
//! assert_eq!(c.get(Counter::LevenbergMarquardtSteps), None); // not reported
//! assert_eq!(c.get(Counter::Custom("pivots")), Some(7)); // the built-in name
//! assert_eq!(c.to_string(), "pivots 7, retries 2, cache_hits 3");
//! ```

use std::fmt;
use std::hash::{Hash, Hasher};

/// One counter of a solve. The built-in counters are those the backends of `ecp-solvers` and
/// the steppers of `ecp-formulations` report; [`Counter::as_str`] is the name written in reports
/// and output files.
#[derive(Clone, Copy, Debug)]
pub enum Counter {
    /// Semismooth Newton: generalised Newton steps `H d = −Φ` taken (`"newton_steps"`).
    NewtonSteps,
    /// Semismooth Newton: Levenberg–Marquardt steps (`"lm_steps"`).
    LevenbergMarquardtSteps,
    /// Semismooth Newton: steepest-descent steps on the merit function (`"gradient_steps"`).
    GradientSteps,
    /// Semismooth Newton: minimum-norm least-squares steps (`"min_norm_steps"`).
    MinNormSteps,
    /// Semismooth Newton: solves restarted without minimum-norm steps (`"min_norm_restarts"`).
    MinNormRestarts,
    /// Non-monotone steps accepted by a watchdog (`"nonmonotone_steps"`).
    NonmonotoneSteps,
    /// Returns of a watchdog to its checkpoint (`"watchdog_restores"`).
    WatchdogRestores,
    /// Pivotal methods: basis changes and bound flips (`"pivots"`).
    Pivots,
    /// Pivotal methods: factorisations of the basis (`"refactorizations"`).
    Refactorizations,
    /// PATH-like: projected Newton steps of the crash phase (`"crash_steps"`).
    CrashSteps,
    /// PATH-like: pivotal (path) steps (`"path_steps"`).
    PathSteps,
    /// PATH-like: backtracks of the path search (`"path_backtracks"`).
    PathBacktracks,
    /// PATH-like: proximal perturbations of a singular linearisation
    /// (`"proximal_perturbations"`).
    ProximalPerturbations,
    /// PATH-like: linearisations whose pivoting ended on a ray (`"ray_terminations"`).
    RayTerminations,
    /// PATH-like: restarts from the starting point with other settings (`"restarts"`).
    Restarts,
    /// PATH-like: attempts with the guarded watchdog (`"guarded_attempts"`).
    GuardedAttempts,
    /// PATH-like: attempts on the Fischer–Burmeister merit (`"fischer_attempts"`).
    FischerAttempts,
    /// PATH-like: restarts from the best point of the earlier attempts (`"best_point_restarts"`).
    BestPointRestarts,
    /// Newton and PATH-like: stages of the smoothing continuation after a failed solve
    /// (`"smoothing_stages"`).
    SmoothingStages,
    /// Newton and PATH-like: iterations of the smoothing continuation's stages
    /// (`"smoothing_iterations"`).
    SmoothingIterations,
    /// The per-solve time budget ran out: 1, else 0 (`"time_limit_reached"`).
    TimeLimitReached,
    /// Conic: interior-point iterations of clarabel, summed (`"clarabel_iterations"`).
    ClarabelIterations,
    /// Conic: clarabel's status of the last QP as a stable code (`"clarabel_status"`).
    ClarabelStatus,
    /// Conic: contact-patch vertices in the last QP (`"patch_vertices"`).
    PatchVertices,
    /// Conic: 1 when the solve was Anitescu's relaxation, else 0 (`"anitescu_relaxation"`).
    AnitescuRelaxation,
    /// Conic: semismooth-Newton iterations after the fixed point (`"newton_polish"`).
    NewtonPolish,
    /// Conic: semismooth-Newton iterations of the finish the fixed point hands its iterate to
    /// once it is close (`"newton_handoff"`, `ConicSettings::newton_handoff`).
    NewtonHandoff,
    /// Stepper: solves of the same step repeated from another warm start (`"retries"`).
    Retries,
    /// A counter of a user's backend, by its name (snake case, as the built-in ones).
    Custom(&'static str),
}

impl Counter {
    /// Every built-in counter, in the order of the enum.
    pub const BUILTIN: [Counter; 28] = [
        Counter::NewtonSteps,
        Counter::LevenbergMarquardtSteps,
        Counter::GradientSteps,
        Counter::MinNormSteps,
        Counter::MinNormRestarts,
        Counter::NonmonotoneSteps,
        Counter::WatchdogRestores,
        Counter::Pivots,
        Counter::Refactorizations,
        Counter::CrashSteps,
        Counter::PathSteps,
        Counter::PathBacktracks,
        Counter::ProximalPerturbations,
        Counter::RayTerminations,
        Counter::Restarts,
        Counter::GuardedAttempts,
        Counter::FischerAttempts,
        Counter::BestPointRestarts,
        Counter::SmoothingStages,
        Counter::SmoothingIterations,
        Counter::TimeLimitReached,
        Counter::ClarabelIterations,
        Counter::ClarabelStatus,
        Counter::PatchVertices,
        Counter::AnitescuRelaxation,
        Counter::NewtonPolish,
        Counter::NewtonHandoff,
        Counter::Retries,
    ];

    /// The name written in reports and output files.
    pub fn as_str(&self) -> &'static str {
        match self {
            Counter::NewtonSteps => "newton_steps",
            Counter::LevenbergMarquardtSteps => "lm_steps",
            Counter::GradientSteps => "gradient_steps",
            Counter::MinNormSteps => "min_norm_steps",
            Counter::MinNormRestarts => "min_norm_restarts",
            Counter::NonmonotoneSteps => "nonmonotone_steps",
            Counter::WatchdogRestores => "watchdog_restores",
            Counter::Pivots => "pivots",
            Counter::Refactorizations => "refactorizations",
            Counter::CrashSteps => "crash_steps",
            Counter::PathSteps => "path_steps",
            Counter::PathBacktracks => "path_backtracks",
            Counter::ProximalPerturbations => "proximal_perturbations",
            Counter::RayTerminations => "ray_terminations",
            Counter::Restarts => "restarts",
            Counter::GuardedAttempts => "guarded_attempts",
            Counter::FischerAttempts => "fischer_attempts",
            Counter::BestPointRestarts => "best_point_restarts",
            Counter::SmoothingStages => "smoothing_stages",
            Counter::SmoothingIterations => "smoothing_iterations",
            Counter::TimeLimitReached => "time_limit_reached",
            Counter::ClarabelIterations => "clarabel_iterations",
            Counter::ClarabelStatus => "clarabel_status",
            Counter::PatchVertices => "patch_vertices",
            Counter::AnitescuRelaxation => "anitescu_relaxation",
            Counter::NewtonPolish => "newton_polish",
            Counter::NewtonHandoff => "newton_handoff",
            Counter::Retries => "retries",
            Counter::Custom(name) => name,
        }
    }

    /// The built-in counter called `name`, or `None`.
    pub fn builtin(name: &str) -> Option<Counter> {
        Counter::BUILTIN.into_iter().find(|c| c.as_str() == name)
    }
}

/// Counters are the same when their names are: `Custom("pivots")` is [`Counter::Pivots`].
impl PartialEq for Counter {
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Counter::Custom(_), _) | (_, Counter::Custom(_)) => self.as_str() == other.as_str(),
            // Two built-ins: their names are distinct (tested), so the variant decides, without
            // comparing strings (a backend sets several counters per solve).
            _ => std::mem::discriminant(self) == std::mem::discriminant(other),
        }
    }
}

impl Eq for Counter {}

impl Hash for Counter {
    fn hash<H: Hasher>(&self, state: &mut H) {
        self.as_str().hash(state);
    }
}

impl fmt::Display for Counter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The counters a solve reported, in the order they were first set.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct Counters {
    entries: Vec<(Counter, usize)>,
}

/// `clone_from` reuses the storage.
impl Clone for Counters {
    fn clone(&self) -> Self {
        Counters {
            entries: self.entries.clone(),
        }
    }
    fn clone_from(&mut self, source: &Self) {
        self.entries.clone_from(&source.entries);
    }
}

impl Counters {
    /// No counter.
    pub fn new() -> Self {
        Self::default()
    }

    /// The value of `counter`, `None` when it was not reported.
    pub fn get(&self, counter: Counter) -> Option<usize> {
        self.entries
            .iter()
            .find(|(c, _)| *c == counter)
            .map(|(_, v)| *v)
    }

    /// Sets `counter` to `value` (reported from now on, even when 0).
    pub fn set(&mut self, counter: Counter, value: usize) {
        match self.entries.iter_mut().find(|(c, _)| *c == counter) {
            Some(entry) => entry.1 = value,
            None => self.entries.push((counter, value)),
        }
    }

    /// Adds `value` to `counter` (starting from 0 when it was not reported).
    pub fn add(&mut self, counter: Counter, value: usize) {
        match self.entries.iter_mut().find(|(c, _)| *c == counter) {
            Some(entry) => entry.1 += value,
            None => self.entries.push((counter, value)),
        }
    }

    /// Every reported counter with its value, in the order they were first set.
    pub fn iter(&self) -> impl Iterator<Item = (Counter, usize)> + '_ {
        self.entries.iter().copied()
    }

    /// Forgets every counter, keeping the storage (a backend that fills the counters of a kept
    /// result).
    pub fn clear(&mut self) {
        self.entries.clear();
    }

    /// Forgets every counter and reports `entries` in their order, keeping the storage: what
    /// [`Counters::clear`] followed by a [`Counters::set`] of each entry gives when no counter
    /// is named twice (a backend's fixed list at the end of every solve), without looking each
    /// one up among those set before it (`docs/latency.md`, branch wip-pathfree).
    pub fn set_all<const N: usize>(&mut self, entries: [(Counter, usize); N]) {
        debug_assert!(
            (0..N).all(|i| entries[i + 1..].iter().all(|(c, _)| *c != entries[i].0)),
            "a counter named twice"
        );
        self.entries.clear();
        self.entries.extend_from_slice(&entries);
    }

    /// Number of reported counters.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when nothing was reported.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

impl<const N: usize> From<[(Counter, usize); N]> for Counters {
    fn from(entries: [(Counter, usize); N]) -> Self {
        entries.into_iter().collect()
    }
}

impl FromIterator<(Counter, usize)> for Counters {
    fn from_iter<I: IntoIterator<Item = (Counter, usize)>>(iter: I) -> Self {
        let mut c = Counters::new();
        for (counter, value) in iter {
            c.set(counter, value);
        }
        c
    }
}

/// `name value, name value, …` (empty when nothing was reported).
impl fmt::Display for Counters {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (k, (c, v)) in self.entries.iter().enumerate() {
            if k > 0 {
                f.write_str(", ")?;
            }
            write!(f, "{c} {v}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_names_are_distinct_and_round_trip() {
        for (i, a) in Counter::BUILTIN.iter().enumerate() {
            assert_eq!(Counter::builtin(a.as_str()), Some(*a));
            for b in &Counter::BUILTIN[i + 1..] {
                assert_ne!(a.as_str(), b.as_str());
            }
        }
        assert_eq!(Counter::builtin("pivot"), None);
    }

    #[test]
    fn set_overwrites_add_accumulates_and_absent_is_none() {
        let mut c = Counters::from([(Counter::Pivots, 2), (Counter::Custom("mine"), 0)]);
        c.set(Counter::Pivots, 5);
        c.add(Counter::Custom("mine"), 4);
        c.add(Counter::Retries, 1);
        assert_eq!(c.get(Counter::Pivots), Some(5));
        assert_eq!(c.get(Counter::Custom("mine")), Some(4));
        assert_eq!(c.get(Counter::Retries), Some(1));
        assert_eq!(c.get(Counter::Restarts), None);
        assert_eq!(c.len(), 3);
        assert_eq!(
            c.iter().map(|(k, _)| k.as_str()).collect::<Vec<_>>(),
            ["pivots", "mine", "retries"]
        );
        assert!(Counters::new().is_empty());
        assert_eq!(Counters::new().to_string(), "");
    }

    #[test]
    fn set_all_is_clear_then_set_in_order() {
        let list = [
            (Counter::CrashSteps, 3),
            (Counter::Pivots, 0),
            (Counter::Custom("mine"), 7),
        ];
        let mut by_set = Counters::from([(Counter::Retries, 1), (Counter::Pivots, 9)]);
        by_set.clear();
        for (c, v) in list {
            by_set.set(c, v);
        }
        let mut all = Counters::from([(Counter::Retries, 1), (Counter::Pivots, 9)]);
        all.set_all(list);
        assert_eq!(all, by_set);
        assert_eq!(all.get(Counter::Retries), None);
        assert_eq!(all.get(Counter::Custom("mine")), Some(7));
        assert_eq!(
            all.iter().map(|(k, v)| (k.as_str(), v)).collect::<Vec<_>>(),
            [("crash_steps", 3), ("pivots", 0), ("mine", 7)]
        );
    }
}

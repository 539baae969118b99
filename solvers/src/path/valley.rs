//! The PATH-like backend on the floor of a valley of its merit (`docs/path.md#the-valley-of-the-v-troughs`):
//! the stop of an attempt that no longer makes progress ([`Stall`]).

use super::PathSettings;

/// Watches an attempt's natural residual: the attempt has stalled when its residual has not
/// fallen below `stall_ratio` times the best of the window before for
/// [`PathSettings::stall_window`] iterations.
pub(super) struct Stall {
    window: usize,
    ratio: f64,
    /// The best residual at the start of the current window, and that window's first iteration.
    reference: f64,
    since: usize,
    /// The best residual within the current window.
    best: f64,
}

impl Stall {
    /// Starts watching at `iteration` with the attempt's first residual.
    pub(super) fn new(s: &PathSettings, residual: f64, iteration: usize) -> Self {
        Stall {
            window: s.stall_window,
            ratio: s.stall_ratio,
            reference: residual,
            since: iteration,
            best: residual,
        }
    }

    /// Whether the attempt has stalled by `iteration`, its residual now `residual`.
    pub(super) fn stalled(&mut self, residual: f64, iteration: usize) -> bool {
        if self.window == 0 {
            return false;
        }
        self.best = self.best.min(residual);
        if self.best <= self.ratio * self.reference {
            // Progress within the window: a new window from here.
            self.reference = self.best;
            self.since = iteration;
            return false;
        }
        iteration - self.since >= self.window
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn watch(window: usize, residual: f64) -> Stall {
        let s = PathSettings {
            stall_window: window,
            stall_ratio: 0.5,
            ..PathSettings::default()
        };
        Stall::new(&s, residual, 0)
    }

    #[test]
    fn path_stall_stops_after_a_window_without_halving_the_residual() {
        // Halving by iteration 2 opens a new window there; from then on the residual stays above
        // half of 0.4, so the attempt has stalled at iteration 2 + 3.
        let mut stall = watch(3, 1.0);
        let residuals = [0.9, 0.4, 0.3, 0.35, 0.25, 0.21];
        let stalled: Vec<bool> = (1..=residuals.len())
            .map(|k| stall.stalled(residuals[k - 1], k))
            .collect();
        assert_eq!(stalled, [false, false, false, false, true, true]);
    }

    #[test]
    fn path_stall_with_window_zero_never_stops() {
        let mut stall = watch(0, 1.0);
        assert!((1..1000).all(|k| !stall.stalled(1.0, k)));
    }
}

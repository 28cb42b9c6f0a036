//! The estimate's spin: its recent rotation per frame, smoothed, which carries the turn on
//! through frames where nothing measured it ([`TrackerConfig::coast_rate`]).

use nalgebra::Vector3;

#[cfg(doc)]
use super::TrackerConfig;

/// Largest rotation (radians) between two frames' estimates that counts as the target's
/// motion in its smoothed spin ([`TrackerConfig::coast_rate`]): 0.1 (5.7°), several times the
/// fastest synthetic turn (1.6° a frame). A larger step is a jump (a mismatched fit), which
/// the spin ignores.
pub(super) const SPIN_MAX_STEP: f64 = 0.1;

/// How the estimate moved into a frame, for its smoothed spin ([`smoothed_spin`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Moved {
    /// Tracked, with the rotation measured (a keyframe fit, a fit against the previous
    /// frame, or the rotation between the two frames): the step is the target's motion.
    Tracked,
    /// Tracked with nothing measuring the rotation: the step is the spin's own proposal and
    /// the filter's noise, so the spin keeps its last measured value instead of feeding on
    /// itself.
    Unmeasured,
    /// Reset to where the target was found again (re-anchored, re-posed, re-acquired): the
    /// step corrects the estimate and says nothing of the target's motion.
    Reset,
    /// Lost: no motion is known.
    Lost,
}

/// The estimate's smoothed rotation per frame after a frame whose estimate turned by `step`
/// (a rotation vector) from the previous one: moved by `rate` of the way towards `step` when
/// the frame was tracked and its rotation measured; unchanged when the estimate was reset or
/// the step exceeds [`SPIN_MAX_STEP`] (a correction or a jump, not the target's motion), or
/// when nothing measured the rotation (a gap is bridged at the last measured turn, and a
/// target without texture, never measured, is never turned on by its own noise); at rest
/// when lost.
pub(super) fn smoothed_spin(
    spin: &Vector3<f64>,
    step: &Vector3<f64>,
    rate: f64,
    moved: Moved,
) -> Vector3<f64> {
    match moved {
        Moved::Lost => Vector3::zeros(),
        Moved::Reset | Moved::Unmeasured => *spin,
        Moved::Tracked if step.norm().is_nan() || step.norm() > SPIN_MAX_STEP => *spin,
        Moved::Tracked => spin + (step - spin) * rate,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spin_follows_a_steady_turn_and_ignores_resets_and_jumps() {
        let step = Vector3::new(0.0, 0.02, 0.0);
        let mut spin = Vector3::zeros();
        for _ in 0..30 {
            spin = smoothed_spin(&spin, &step, 1.0 / 3.0, Moved::Tracked);
        }
        assert!((spin - step).norm() < 1e-6, "{spin:?}");
        // One frame's step moves it a third of the way.
        let first = smoothed_spin(&Vector3::zeros(), &step, 1.0 / 3.0, Moved::Tracked);
        assert!((first.y - 0.02 / 3.0).abs() < 1e-12);
        // A reset's correction and a jump beyond the bound are not motion; a lost frame
        // knows none.
        let big = Vector3::new(0.3, 0.0, 0.0);
        assert_eq!(smoothed_spin(&spin, &big, 1.0 / 3.0, Moved::Reset), spin);
        assert_eq!(smoothed_spin(&spin, &big, 1.0 / 3.0, Moved::Tracked), spin);
        let nan = Vector3::new(f64::NAN, 0.0, 0.0);
        assert_eq!(smoothed_spin(&spin, &nan, 1.0 / 3.0, Moved::Tracked), spin);
        assert_eq!(
            smoothed_spin(&spin, &step, 1.0 / 3.0, Moved::Lost),
            Vector3::zeros()
        );
        // Unmeasured frames keep the last measured spin, whatever their own step (the spin's
        // proposal plus the filter's noise): it does not feed on itself.
        assert_eq!(
            smoothed_spin(&spin, &big, 1.0 / 3.0, Moved::Unmeasured),
            spin
        );
        assert_eq!(
            smoothed_spin(&Vector3::zeros(), &step, 1.0 / 3.0, Moved::Unmeasured),
            Vector3::zeros()
        );
        // At rate 1 the spin is the last step.
        let s = smoothed_spin(&spin, &(step * 2.0), 1.0, Moved::Tracked);
        assert!((s - step * 2.0).norm() < 1e-15);
    }
}

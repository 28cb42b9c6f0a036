//! The gain of a fitted rotation against the truth about each camera axis, shared by the
//! examples that measure the keyframe fit's bias.

use nalgebra::Vector3;

/// `Σ ω_fit·ω_true / Σ ω_true²` per camera axis over rotation vectors added in turn: 1 is
/// unbiased, below 1 the fit under-rotates.
#[derive(Debug, Clone, Copy, Default)]
pub struct AxisGain {
    sums: [(f64, f64); 3],
}

impl AxisGain {
    /// Adds one fitted rotation vector `fit` and its truth `truth` (radians).
    pub fn add(&mut self, fit: &Vector3<f64>, truth: &Vector3<f64>) {
        for (axis, s) in self.sums.iter_mut().enumerate() {
            s.0 += fit[axis] * truth[axis];
            s.1 += truth[axis] * truth[axis];
        }
    }

    /// `gain about x X y Y z Z`, three decimals, `-` for an axis the truth never turned about
    /// by a degree in all (it has no gain to speak of).
    pub fn describe(&self) -> String {
        let g = self.sums.map(|(num, den)| {
            if den > (1f64.to_radians()).powi(2) {
                format!("{:.3}", num / den)
            } else {
                "-".to_string()
            }
        });
        format!("gain about x {} y {} z {}", g[0], g[1], g[2])
    }
}

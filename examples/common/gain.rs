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

/// The gain per axis and the mean angle error over fitted pairs, with the summary line the
/// bias examples end with.
#[derive(Debug, Clone, Copy, Default)]
#[allow(dead_code)] // not every example that shares this module tallies pairs
pub struct PairTally {
    gain: AxisGain,
    err_sum: f64,
    pairs: usize,
}

#[allow(dead_code)]
impl PairTally {
    /// Adds one fitted rotation against its truth; returns the angle error (degrees).
    pub fn add(&mut self, fit: &nalgebra::Matrix3<f64>, truth: &nalgebra::Matrix3<f64>) -> f64 {
        use pftrack::filter::rotation_mean::log_so3;
        self.gain.add(&log_so3(fit), &log_so3(truth));
        let err = pftrack::geometry::angle_between(fit, truth).to_degrees();
        self.err_sum += err;
        self.pairs += 1;
        err
    }

    /// `gain about ...  mean error E deg over N pairs`, or an error when no pair was added.
    pub fn summary(&self) -> Result<String, &'static str> {
        if self.pairs == 0 {
            return Err("no pair could be fitted");
        }
        Ok(format!(
            "{}  mean error {:.2} deg over {} pairs",
            self.gain.describe(),
            self.err_sum / self.pairs as f64,
            self.pairs
        ))
    }
}

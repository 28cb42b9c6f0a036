//! Pose accumulation: the pose at frame t is the product of the inter-frame rotations since a
//! known initial pose (SPEC section 2).
//!
//! `R_t` maps object points in the reference pose to the current pose; `ΔR` maps frame-t
//! camera-frame object points to frame t+1, so `R_{t+1} = ΔR · R_t`. The product is
//! re-orthonormalised after every step (polar factor by SVD, which is the nearest rotation), so
//! rounding never lets it drift off `SO(3)`. Drift of the estimate itself (errors of the
//! `ΔR`s adding up) is the method's known weakness.

use nalgebra::Matrix3;

use super::PoseError;
use crate::geometry::Euler;

/// Chains inter-frame rotations into the current pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseAccumulator {
    r: Matrix3<f64>,
    frames: usize,
}

impl Default for PoseAccumulator {
    /// Starts frontal (identity).
    fn default() -> Self {
        Self::new(Matrix3::identity())
    }
}

/// The rotation nearest to `m` (Frobenius): `U diag(1, 1, det(U V^T)) V^T`.
pub fn nearest_rotation(m: &Matrix3<f64>) -> Result<Matrix3<f64>, PoseError> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(PoseError::NonFinite);
    }
    let svd = m.svd(true, true);
    let (u, vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => (u, vt),
        _ => return Err(PoseError::Singular("SVD")),
    };
    let sv = svd.singular_values;
    let mut imin = 0;
    for i in 1..3 {
        if sv[i] < sv[imin] {
            imin = i;
        }
    }
    let mut d = nalgebra::Vector3::new(1.0, 1.0, 1.0);
    d[imin] = (u * vt).determinant().signum();
    Ok(u * Matrix3::from_diagonal(&d) * vt)
}

impl PoseAccumulator {
    /// Starts from a known pose (assumed a rotation; it is re-orthonormalised on the first
    /// step).
    pub fn new(initial: Matrix3<f64>) -> Self {
        Self {
            r: initial,
            frames: 0,
        }
    }

    /// Starts from Euler angles (radians).
    pub fn from_euler(e: Euler) -> Self {
        Self::new(e.matrix())
    }

    /// Applies one inter-frame rotation: `R ← ΔR · R`, re-orthonormalised.
    pub fn apply(&mut self, delta: &Matrix3<f64>) -> Result<Matrix3<f64>, PoseError> {
        let next = nearest_rotation(&(delta * self.r))?;
        self.r = next;
        self.frames += 1;
        Ok(next)
    }

    /// The current pose.
    pub fn rotation(&self) -> Matrix3<f64> {
        self.r
    }

    /// The current pose as Euler angles (radians, SPEC order).
    pub fn euler(&self) -> Euler {
        Euler::from_matrix(&self.r)
    }

    /// Inter-frame rotations applied so far.
    pub fn frames(&self) -> usize {
        self.frames
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::angle_between;

    #[test]
    fn accumulating_exact_deltas_reproduces_the_trajectory() {
        let traj: Vec<Matrix3<f64>> = (0..300)
            .map(|k| {
                let t = k as f64 * 0.05;
                Euler::new(0.4 * t.sin(), 0.6 * (0.7 * t).sin(), 0.2 * (1.3 * t).cos()).matrix()
            })
            .collect();
        let mut acc = PoseAccumulator::new(traj[0]);
        for k in 1..traj.len() {
            let delta = traj[k] * traj[k - 1].transpose();
            let r = acc.apply(&delta).unwrap();
            assert!(angle_between(&r, &traj[k]) < 1e-10, "frame {k}");
        }
        let e = acc.euler();
        let want = Euler::from_matrix(&traj[299]);
        assert!((e.rx - want.rx).abs() < 1e-9 && (e.ry - want.ry).abs() < 1e-9);
        assert_eq!(acc.frames(), 299);
        assert!((acc.rotation() * acc.rotation().transpose() - Matrix3::identity()).norm() < 1e-12);
        assert_eq!(PoseAccumulator::default().rotation(), Matrix3::identity());
    }

    #[test]
    fn reorthonormalises_slightly_invalid_deltas() {
        let mut acc = PoseAccumulator::default();
        let bad = Euler::new(0.1, 0.0, 0.0).matrix() * 1.001;
        for _ in 0..100 {
            acc.apply(&bad).unwrap();
        }
        let r = acc.rotation();
        assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-12);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!(acc.apply(&Matrix3::from_element(f64::NAN)).is_err());
    }
}

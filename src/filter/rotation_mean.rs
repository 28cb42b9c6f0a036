//! Averaging rotations and measuring their differences: the filter works with rotation
//! matrices, never with Euler angles, so angles near ±180° average correctly.

use nalgebra::{Matrix3, Rotation3, Vector3};

/// The rotation vector (axis × angle) of `r`: the inverse of [`exp_so3`].
pub fn log_so3(r: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix_unchecked(*r).scaled_axis()
}

/// The rotation of a rotation vector.
pub fn exp_so3(w: &Vector3<f64>) -> Matrix3<f64> {
    *Rotation3::from_scaled_axis(*w).matrix()
}

/// The nearest rotation (Frobenius norm) to any 3x3 matrix, through its SVD.
pub fn project_to_so3(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Matrix3::identity();
    };
    let d = (u * v_t).determinant().signum();
    u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t
}

/// The weighted chordal L2 mean of rotations: the rotation nearest to `Σ wᵢ Rᵢ`. Exact for
/// identical rotations, and the standard estimate for a concentrated cloud.
pub fn weighted_mean(rots: &[Matrix3<f64>], w: &[f64]) -> Matrix3<f64> {
    let mut m = Matrix3::zeros();
    for (r, &wi) in rots.iter().zip(w) {
        m += r * wi;
    }
    project_to_so3(&m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Euler, angle_between, rot_z};

    #[test]
    fn log_exp_round_trip() {
        for w in [
            Vector3::new(0.1, -0.2, 0.3),
            Vector3::new(0.0, 0.0, 3.0),
            Vector3::zeros(),
        ] {
            assert!((log_so3(&exp_so3(&w)) - w).norm() < 1e-12);
        }
    }

    #[test]
    fn mean_of_symmetric_pair_and_across_pi() {
        let r = Euler::new(0.2, -0.4, 1.0).matrix();
        let a = exp_so3(&Vector3::new(0.05, 0.0, 0.0)) * r;
        let b = exp_so3(&Vector3::new(-0.05, 0.0, 0.0)) * r;
        assert!(angle_between(&weighted_mean(&[a, b], &[0.5, 0.5]), &r) < 1e-9);
        // Roll of +179° and -179° average to 180°, not to 0° as naive angle means would.
        let m = weighted_mean(
            &[rot_z(179f64.to_radians()), rot_z(-179f64.to_radians())],
            &[0.5, 0.5],
        );
        assert!(angle_between(&m, &rot_z(std::f64::consts::PI)) < 1e-9);
    }

    #[test]
    fn projection_fixes_rotations() {
        let r = Euler::new(0.3, 0.2, -0.1).matrix();
        assert!((project_to_so3(&r) - r).norm() < 1e-12);
        let noisy = r + Matrix3::repeat(1e-3);
        let p = project_to_so3(&noisy);
        assert!((p * p.transpose() - Matrix3::identity()).norm() < 1e-12);
        assert!((p.determinant() - 1.0).abs() < 1e-12);
    }
}

//! Averaging rotations and measuring their differences: the filter works with rotation
//! matrices, never with Euler angles, so angles near ±180° average correctly.

use nalgebra::{Matrix3, Rotation3, Vector3};

/// The rotation vector (axis × angle, the angle in `[0, π]`) of `r`: the inverse of
/// [`exp_so3`].
///
/// The angle is `atan2(sin, cos)` of the antisymmetric part and the trace, accurate over the
/// whole range. The acos of the trace alone (nalgebra's `scaled_axis`) loses half the digits
/// near 0 and turns NaN where rounding puts the cosine a hair above 1 while the axis is still
/// there: on the product of a rotation and one a few 1e-9 rad from it, which a fit
/// converging onto its prior's mean forms. Near π the axis comes from the symmetric part,
/// as the antisymmetric part vanishes there (nalgebra reads an exact half turn as no turn).
pub fn log_so3(r: &Matrix3<f64>) -> Vector3<f64> {
    // 2 sin θ · axis, sin θ and cos θ.
    let (v, s, c) = crate::geometry::rotation::turn_parts(r);
    let theta = s.atan2(c);
    if !theta.is_finite() {
        return Vector3::repeat(f64::NAN);
    }
    if c >= 0.0 {
        // θ / sin θ, by its series where sin θ is too small to divide by.
        let k = if theta < 1e-6 {
            1.0 + theta * theta / 6.0
        } else {
            theta / s
        };
        return 0.5 * k * v;
    }
    // (R + Rᵀ) / 2 = cos θ I + (1 - cos θ) n nᵀ: the axis is the column of n nᵀ with the
    // largest diagonal, its sign that of sin θ · n.
    let nn = (0.5 * (r + r.transpose()) - Matrix3::identity() * c) / (1.0 - c);
    let j = (0..3)
        .max_by(|&i, &k| nn[(i, i)].total_cmp(&nn[(k, k)]))
        .unwrap_or(0);
    let mut n = nn.column(j).into_owned();
    let norm = n.norm();
    if norm == 0.0 {
        return Vector3::zeros();
    }
    n /= norm;
    if n.dot(&v) < 0.0 {
        n = -n;
    }
    theta * n
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
/// identical rotations, and the standard estimate for a concentrated cloud. Rotations of
/// zero weight are left out, not multiplied by 0 (a non-finite one would make the sum NaN).
pub fn weighted_mean(rots: &[Matrix3<f64>], w: &[f64]) -> Matrix3<f64> {
    let mut m = Matrix3::zeros();
    for (r, &wi) in rots.iter().zip(w) {
        if wi != 0.0 {
            m += r * wi;
        }
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
    fn log_is_exact_for_tiny_turns_and_half_turns() {
        // A pose times a rotation 1e-9 rad from it: the acos of the trace turned NaN on
        // about one in twenty such products (and erred by percents at 1e-7).
        let mut worst: f64 = 0.0;
        for i in 0..2000 {
            let t = i as f64;
            let p = Euler::new((t * 0.37).sin() * 3.0, (t * 0.11).cos() * 1.5, t * 0.73).matrix();
            for mag in [1e-9, 1e-8, 1e-7, 1e-5] {
                let d = Vector3::new((t * 1.3).sin(), (t * 2.9).cos(), (t * 0.5).sin() + 0.1)
                    .normalize()
                    * mag;
                let w = log_so3(&(exp_so3(&d) * p * p.transpose()));
                let q = exp_so3(&d) * p;
                let w2 = log_so3(&(q * p.transpose()));
                assert!(
                    w.iter().chain(w2.iter()).all(|x| x.is_finite()),
                    "{i} {mag}"
                );
                worst = worst.max((w2 - d).norm());
            }
        }
        // Rounding in forming the product (about 1e-16 an entry) is all that is left.
        assert!(worst < 1e-13, "error {worst:e} rad");
        // Half turns, exact and a hair short of exact, about several axes.
        for axis in [
            Vector3::x(),
            Vector3::y(),
            Vector3::z(),
            Vector3::new(1.0, -2.0, 0.5).normalize(),
        ] {
            for angle in [std::f64::consts::PI, std::f64::consts::PI - 1e-9, 3.0] {
                let w = axis * angle;
                let got = log_so3(&exp_so3(&w));
                // At exactly π, ±axis are the same rotation.
                let err = (got - w).norm().min((got + w).norm());
                assert!(err < 1e-7, "{axis:?} {angle}: {got:?}");
                assert!(angle_between(&exp_so3(&got), &exp_so3(&w)) < 1e-9);
            }
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
    fn zero_weights_leave_a_non_finite_rotation_out() {
        let r = Euler::new(0.3, -0.2, 0.1).matrix();
        let bad = Matrix3::repeat(f64::NAN);
        let m = weighted_mean(&[r, bad], &[1.0, 0.0]);
        assert!(angle_between(&m, &r) < 1e-12, "{m:?}");
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

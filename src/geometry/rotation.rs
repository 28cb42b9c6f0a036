//! Rotation conventions of the project (SPEC section 1), in one place.
//!
//! `R = Rx(rx) · Ry(ry) · Rz(rz)`, right-handed elementary rotations about the camera axes
//! (x right, y down, z forward). `R` maps object points in the reference pose (frame 0) to the
//! current pose. tilt = rx, pan = ry, roll = rz. Radians everywhere inside the code; degrees only
//! at the file and command-line boundary ([`deg`], [`rad`]).

use nalgebra::{Matrix3, Vector3};

/// Degrees to radians.
pub fn rad(deg: f64) -> f64 {
    deg.to_radians()
}

/// Radians to degrees.
pub fn deg(rad: f64) -> f64 {
    rad.to_degrees()
}

/// Elementary rotation about the camera x axis (tilt).
pub fn rot_x(t: f64) -> Matrix3<f64> {
    let (s, c) = t.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

/// Elementary rotation about the camera y axis (pan).
pub fn rot_y(t: f64) -> Matrix3<f64> {
    let (s, c) = t.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

/// Elementary rotation about the camera z axis (roll, in the image plane).
pub fn rot_z(t: f64) -> Matrix3<f64> {
    let (s, c) = t.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// Euler angles (radians) in the project's order: `R = Rx(rx) · Ry(ry) · Rz(rz)`.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Euler {
    /// Tilt: rotation about the camera x axis.
    pub rx: f64,
    /// Pan: rotation about the camera y axis.
    pub ry: f64,
    /// Roll: rotation about the camera z axis.
    pub rz: f64,
}

impl Euler {
    /// Angles in radians.
    pub fn new(rx: f64, ry: f64, rz: f64) -> Self {
        Self { rx, ry, rz }
    }

    /// Angles given in degrees.
    pub fn from_degrees(rx: f64, ry: f64, rz: f64) -> Self {
        Self::new(rad(rx), rad(ry), rad(rz))
    }

    /// The angles in degrees, `[rx, ry, rz]`.
    pub fn to_degrees(self) -> [f64; 3] {
        [deg(self.rx), deg(self.ry), deg(self.rz)]
    }

    /// The rotation matrix `Rx(rx) · Ry(ry) · Rz(rz)`.
    pub fn matrix(self) -> Matrix3<f64> {
        rot_x(self.rx) * rot_y(self.ry) * rot_z(self.rz)
    }

    /// Angles of a rotation matrix, inverse of [`Euler::matrix`].
    ///
    /// `ry` is taken in `[-π/2, π/2]`; `rx`, `rz` in `(-π, π]`. At the gimbal lock
    /// (`|ry| = π/2`) only `rx ± rz` is defined; `rz` is then set to 0.
    pub fn from_matrix(r: &Matrix3<f64>) -> Self {
        // R = [[cb cc, -cb sc, sb], [.., .., -sa cb], [.., .., ca cb]]
        let sb = r[(0, 2)].clamp(-1.0, 1.0);
        let ry = sb.asin();
        let cb = (r[(0, 0)].powi(2) + r[(0, 1)].powi(2)).sqrt();
        // atan2(-0, negative) is -π: the half-turn is given as +π, the range's closed end.
        let half_open = |a: f64| if a == -std::f64::consts::PI { -a } else { a };
        if cb > 1e-9 {
            let rx = half_open((-r[(1, 2)]).atan2(r[(2, 2)]));
            let rz = half_open((-r[(0, 1)]).atan2(r[(0, 0)]));
            Self { rx, ry, rz }
        } else {
            // With rz = 0: r21 = sin rx, r11 = cos rx.
            let rx = half_open(r[(2, 1)].atan2(r[(1, 1)]));
            Self { rx, ry, rz: 0.0 }
        }
    }
}

/// Wraps an angle in radians to `(-π, π]`.
pub fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let mut w = a.rem_euclid(t);
    if w > std::f64::consts::PI {
        w -= t;
    }
    w
}

/// Wraps an angle in degrees to `(-180, 180]`.
pub fn wrap_180(a: f64) -> f64 {
    deg(wrap_pi(rad(a)))
}

/// The angle (radians, in `[0, π]`) of the relative rotation `a · bᵀ`: the geodesic distance
/// between two rotations, the error measure of the paper's Fig. 3.
pub fn angle_between(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    // atan2(sin, cos) keeps full precision near 0 and π, where acos of the trace does not.
    let (_, s, c) = turn_parts(&(a * b.transpose()));
    s.atan2(c)
}

/// The parts of a rotation `r` by `θ` about the unit axis `n` that give its angle and axis
/// accurately: its antisymmetric part as a vector, `2 sin θ · n`, then `sin θ` and `cos θ`
/// (from the trace). [`angle_between`] and the rotation log
/// ([`crate::filter::rotation_mean::log_so3`]) take `θ = atan2(sin θ, cos θ)` from them.
pub fn turn_parts(r: &Matrix3<f64>) -> (Vector3<f64>, f64, f64) {
    let v = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    );
    let s = 0.5 * (v.x * v.x + v.y * v.y + v.z * v.z).sqrt();
    (v, s, (r.trace() - 1.0) / 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Half-turns about x and z come back as +π, not -π (atan2 of a negative zero).
    #[test]
    fn half_turns_read_as_plus_pi() {
        use std::f64::consts::PI;
        let rx = Euler::from_matrix(&Matrix3::from_diagonal(&nalgebra::Vector3::new(
            1.0, -1.0, -1.0,
        )));
        assert_eq!((rx.rx, rx.ry, rx.rz), (PI, 0.0, 0.0));
        let rz = Euler::from_matrix(&Matrix3::from_diagonal(&nalgebra::Vector3::new(
            -1.0, -1.0, 1.0,
        )));
        assert_eq!((rz.rx, rz.rz), (0.0, PI));
        assert_eq!(rz.ry.abs(), 0.0);
        for e in [Euler::new(PI, 0.3, -0.2), Euler::new(0.1, -0.4, PI)] {
            let back = Euler::from_matrix(&e.matrix());
            for a in [back.rx, back.rz] {
                assert!(a > -PI && a <= PI, "{back:?}");
            }
        }
    }

    #[test]
    fn elementary_rotations_are_right_handed() {
        // Rz(90°) takes x to y (image right to image down).
        let v = rot_z(std::f64::consts::FRAC_PI_2) * nalgebra::Vector3::new(1.0, 0.0, 0.0);
        assert!((v - nalgebra::Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
        // Rx(90°) takes y to z; Ry(90°) takes z to x.
        let v = rot_x(std::f64::consts::FRAC_PI_2) * nalgebra::Vector3::new(0.0, 1.0, 0.0);
        assert!((v - nalgebra::Vector3::new(0.0, 0.0, 1.0)).norm() < 1e-12);
        let v = rot_y(std::f64::consts::FRAC_PI_2) * nalgebra::Vector3::new(0.0, 0.0, 1.0);
        assert!((v - nalgebra::Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn euler_round_trip() {
        let mut s = 0.37_f64;
        for _ in 0..500 {
            // a small deterministic pseudo-random walk over the angle ranges
            s = (s * 9301.0 + 49297.0) % 233280.0;
            let u = s / 233280.0;
            let e = Euler::new(
                (u - 0.5) * 6.0,
                (u * 7.3 % 1.0 - 0.5) * 3.0,
                (u * 3.1 % 1.0 - 0.5) * 6.2,
            );
            let r = e.matrix();
            let back = Euler::from_matrix(&r);
            assert!(
                angle_between(&back.matrix(), &r) < 1e-9,
                "{e:?} -> {back:?}"
            );
            assert!((back.ry - e.ry).abs() < 1e-9);
        }
    }

    #[test]
    fn gimbal_lock_keeps_matrix() {
        let e = Euler::new(0.3, std::f64::consts::FRAC_PI_2, 0.2);
        let back = Euler::from_matrix(&e.matrix());
        assert!(angle_between(&back.matrix(), &e.matrix()) < 1e-7);
    }

    #[test]
    fn wraps() {
        assert!((wrap_180(190.0) + 170.0).abs() < 1e-9);
        assert!((wrap_180(-190.0) - 170.0).abs() < 1e-9);
        assert!((wrap_180(180.0) - 180.0).abs() < 1e-9);
        assert!((angle_between(&rot_x(0.4), &rot_x(0.1)) - 0.3).abs() < 1e-12);
        assert!((angle_between(&rot_y(3.0), &rot_y(-0.1)) - 3.1).abs() < 1e-9);
        assert!(angle_between(&rot_z(1e-10), &Matrix3::identity()) < 2e-10);
    }
}

//! The rigid objects (an ellipsoid "head", a box "car"): ray intersection in object
//! coordinates, surface normals, and the analytic perspective outline of an ellipsoid.

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

use super::camera::Camera;

/// A rigid object, centred at its own origin, in object coordinates (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// An ellipsoid `(x/sx)² + (y/sy)² + (z/sz)² = 1` with semi-axes `semi`.
    Ellipsoid {
        /// Semi-axes along the object's x, y, z axes.
        semi: Vector3<f64>,
    },
    /// An axis-aligned box `|x| ≤ hx, |y| ≤ hy, |z| ≤ hz` with half extents `half`.
    Box {
        /// Half extents along the object's x, y, z axes.
        half: Vector3<f64>,
    },
}

/// A ray's first hit on a shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter: the hit is `origin + t · dir`.
    pub t: f64,
    /// The hit point (object coordinates).
    pub point: Vector3<f64>,
    /// Outward unit surface normal at the hit (object coordinates).
    pub normal: Vector3<f64>,
}

impl Shape {
    /// Radius of the smallest sphere about the origin that holds the shape.
    pub fn bounding_radius(&self) -> f64 {
        match self {
            Shape::Ellipsoid { semi } => semi.max(),
            Shape::Box { half } => half.norm(),
        }
    }

    /// First intersection with `t > 0` of the ray `origin + t · dir` (object coordinates).
    pub fn intersect(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        match self {
            Shape::Ellipsoid { semi } => intersect_ellipsoid(semi, origin, dir),
            Shape::Box { half } => intersect_box(half, origin, dir),
        }
    }

    /// Whether the ray `origin + t · dir`, `t > 0`, meets the shape: [`Shape::intersect`]'s
    /// answer without computing the hit (the silhouette's fast path).
    pub fn hits(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> bool {
        match self {
            Shape::Ellipsoid { semi } => {
                let o = origin.component_div(semi);
                let d = dir.component_div(semi);
                let a = d.dot(&d);
                let b = o.dot(&d);
                let c = o.dot(&o) - 1.0;
                let disc = b * b - a * c;
                // roots -b/a ± sqrt(disc)/a: the larger is positive when c < 0 (inside) or b < 0
                a > 0.0 && disc >= 0.0 && (c < 0.0 || b < 0.0)
            }
            Shape::Box { .. } => self.intersect(origin, dir).is_some(),
        }
    }

    /// Whether a point (object coordinates) lies on the surface, within `tol` (metres, roughly).
    pub fn on_surface(&self, p: &Vector3<f64>, tol: f64) -> bool {
        match self {
            Shape::Ellipsoid { semi } => {
                let q = p.component_div(semi);
                (q.norm() - 1.0).abs() * semi.min() <= tol
            }
            Shape::Box { half } => {
                let d = p.abs() - half;
                d.max() <= tol && d.max() >= -tol
            }
        }
    }
}

/// Ray against the ellipsoid: scale to the unit sphere and solve the quadratic.
fn intersect_ellipsoid(
    semi: &Vector3<f64>,
    origin: &Vector3<f64>,
    dir: &Vector3<f64>,
) -> Option<Hit> {
    let o = origin.component_div(semi);
    let d = dir.component_div(semi);
    let a = d.dot(&d);
    let b = o.dot(&d);
    let c = o.dot(&o) - 1.0;
    let disc = b * b - a * c;
    if disc < 0.0 || a <= 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // Numerically stable pair of roots of a t² + 2 b t + c = 0.
    let q = if b > 0.0 { -(b + sq) } else { -b + sq };
    let (mut t0, mut t1) = if q != 0.0 {
        (q / a, c / q)
    } else {
        (-b / a, -b / a)
    };
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    let t = if t0 > 0.0 {
        t0
    } else if t1 > 0.0 {
        t1
    } else {
        return None;
    };
    let point = origin + dir * t;
    let normal = point.component_div(semi).component_div(semi).normalize();
    Some(Hit { t, point, normal })
}

/// Ray against the box: the slab test.
fn intersect_box(half: &Vector3<f64>, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
    let mut tmin = f64::NEG_INFINITY;
    let mut tmax = f64::INFINITY;
    let mut axis_in = 0;
    let mut axis_out = 0;
    for k in 0..3 {
        if dir[k] == 0.0 {
            if origin[k].abs() > half[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / dir[k];
        let mut t0 = (-half[k] - origin[k]) * inv;
        let mut t1 = (half[k] - origin[k]) * inv;
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > tmin {
            tmin = t0;
            axis_in = k;
        }
        if t1 < tmax {
            tmax = t1;
            axis_out = k;
        }
    }
    if tmax < tmin || tmax <= 0.0 {
        return None;
    }
    let (t, axis, sign) = if tmin > 0.0 {
        (tmin, axis_in, -dir[axis_in].signum())
    } else {
        (tmax, axis_out, dir[axis_out].signum())
    };
    let point = origin + dir * t;
    let mut normal = Vector3::zeros();
    normal[axis] = sign;
    Some(Hit { t, point, normal })
}

/// An elliptical image region given by its centre and the covariance of the filled region
/// (a filled ellipse with semi-axes `a`, `b` has covariance eigenvalues `a²/4`, `b²/4`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outline {
    /// Centre `(u, v)` (pixels).
    pub centre: Vector2<f64>,
    /// Covariance of the filled region (pixels²).
    pub cov: Matrix2<f64>,
    /// Area (pixels²).
    pub area: f64,
}

impl Outline {
    /// Semi-axes measured along the frame turned by `theta` (radians, image x towards y):
    /// `a = 2 sqrt(e1ᵀ C e1)`, `b = 2 sqrt(e2ᵀ C e2)` with `e1 = (cos θ, sin θ)`,
    /// `e2 = (-sin θ, cos θ)`. Exact semi-axes of a filled ellipse whose axes lie along that frame.
    pub fn axes_along(&self, theta: f64) -> (f64, f64) {
        let (s, c) = theta.sin_cos();
        let e1 = Vector2::new(c, s);
        let e2 = Vector2::new(-s, c);
        let lx = e1.dot(&(self.cov * e1)).max(0.0);
        let ly = e2.dot(&(self.cov * e2)).max(0.0);
        (2.0 * lx.sqrt(), 2.0 * ly.sqrt())
    }
}

/// The exact perspective outline of an ellipsoid with semi-axes `semi`, orientation
/// `orientation` (object to camera) and centre `centre` (camera coordinates).
///
/// The rays `d` tangent to the ellipsoid `(X - C)ᵀ M (X - C) = 1` form the cone
/// `dᵀ [M C Cᵀ M - (Cᵀ M C - 1) M] d = 0`; with `d = K⁻¹ (u, v, 1)` that is a conic in the
/// image, positive inside the silhouette. `None` when the camera is inside the ellipsoid or the
/// outline is not a bounded ellipse.
pub fn ellipsoid_outline(
    camera: &Camera,
    semi: &Vector3<f64>,
    orientation: &Matrix3<f64>,
    centre: &Vector3<f64>,
) -> Option<Outline> {
    let d2 = Matrix3::from_diagonal(&semi.map(|s| 1.0 / (s * s)));
    let m = orientation * d2 * orientation.transpose();
    let mc = m * centre;
    let k = centre.dot(&mc) - 1.0;
    if k <= 0.0 {
        return None;
    }
    let q = mc * mc.transpose() - m * k;
    let f = camera.focal;
    let kinv = Matrix3::new(
        1.0 / f,
        0.0,
        -camera.pu / f,
        0.0,
        1.0 / f,
        -camera.pv / f,
        0.0,
        0.0,
        1.0,
    );
    let conic = kinv.transpose() * q * kinv;
    let a2 = Matrix2::new(conic[(0, 0)], conic[(0, 1)], conic[(1, 0)], conic[(1, 1)]);
    let bv = Vector2::new(conic[(0, 2)], conic[(1, 2)]);
    let a2inv = a2.try_inverse()?;
    let x0 = -(a2inv * bv);
    let k0 = conic[(2, 2)] + bv.dot(&x0);
    // Inside: (x - x0)ᵀ (-A2 / k0) (x - x0) < 1, a bounded ellipse when -A2/k0 is positive definite.
    let s = -a2 / k0;
    if k0 <= 0.0 || s[(0, 0)] <= 0.0 || s.determinant() <= 0.0 {
        return None;
    }
    let cov = -a2inv * (k0 / 4.0);
    let area = std::f64::consts::PI / s.determinant().sqrt();
    Some(Outline {
        centre: x0,
        cov,
        area,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ellipsoid_hit_is_on_surface_with_outward_normal() {
        let s = Shape::Ellipsoid {
            semi: Vector3::new(0.08, 0.1, 0.09),
        };
        let o = Vector3::new(0.01, -0.02, -1.0);
        let d = Vector3::new(0.0, 0.01, 1.0);
        let h = s.intersect(&o, &d).unwrap();
        assert!(s.on_surface(&h.point, 1e-12));
        assert!(h.normal.dot(&d) < 0.0);
        assert!(h.point.z < 0.0); // the near side
        // A ray that misses.
        assert!(s.intersect(&o, &Vector3::new(0.2, 0.0, 1.0)).is_none());
        // `hits` agrees with `intersect`, including rays pointing away and from inside.
        for i in 0..400 {
            let t = i as f64 * 0.37;
            let d = Vector3::new(
                t.sin() * 0.15,
                (1.7 * t).cos() * 0.15,
                if i % 3 == 0 { -1.0 } else { 1.0 },
            );
            for origin in [
                o,
                Vector3::new(0.0, 0.01, 0.02),
                Vector3::new(0.0, 0.0, 1.0),
            ] {
                assert_eq!(
                    s.hits(&origin, &d),
                    s.intersect(&origin, &d).is_some(),
                    "{origin:?} {d:?}"
                );
            }
        }
        // From inside: the exit point.
        let h = s
            .intersect(&Vector3::zeros(), &Vector3::new(0.0, 0.0, 1.0))
            .unwrap();
        assert!((h.point.z - 0.09).abs() < 1e-12);
    }

    #[test]
    fn box_hit_faces() {
        let s = Shape::Box {
            half: Vector3::new(0.2, 0.05, 0.1),
        };
        let h = s
            .intersect(
                &Vector3::new(0.05, 0.01, -1.0),
                &Vector3::new(0.0, 0.0, 1.0),
            )
            .unwrap();
        assert!((h.point.z + 0.1).abs() < 1e-12);
        assert_eq!(h.normal, Vector3::new(0.0, 0.0, -1.0));
        let h = s
            .intersect(
                &Vector3::new(-1.0, 0.0, 0.0),
                &Vector3::new(1.0, 0.01, 0.02),
            )
            .unwrap();
        assert_eq!(h.normal, Vector3::new(-1.0, 0.0, 0.0));
        assert!(s.on_surface(&h.point, 1e-12));
        assert!(
            s.intersect(&Vector3::new(0.0, 0.3, -1.0), &Vector3::new(0.0, 0.0, 1.0))
                .is_none()
        );
    }

    #[test]
    fn outline_of_a_centred_sphere_is_a_circle() {
        let cam = Camera::new(160, 120);
        let r = 0.1;
        let z = 0.8;
        let o = ellipsoid_outline(
            &cam,
            &Vector3::new(r, r, r),
            &Matrix3::identity(),
            &Vector3::new(0.0, 0.0, z),
        )
        .unwrap();
        // Tangent cone half-angle asin(r/z): radius f·tan(asin(r/z)).
        let rad = cam.focal * (r / z).asin().tan();
        let (a, b) = o.axes_along(0.3);
        assert!((a - rad).abs() < 1e-9 && (b - rad).abs() < 1e-9);
        assert!((o.centre.x - cam.pu).abs() < 1e-9 && (o.centre.y - cam.pv).abs() < 1e-9);
        assert!((o.area - std::f64::consts::PI * rad * rad).abs() < 1e-6);
    }
}

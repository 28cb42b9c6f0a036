//! The pinhole camera of the synthetic scenes.

use nalgebra::{Vector2, Vector3};

use crate::pose::prior::Pinhole;

/// Horizontal field of view of the synthetic camera (degrees): a typical webcam.
pub const HFOV_DEG: f64 = 50.0;

/// A pinhole camera in the SPEC's camera frame (x right, y down, z forward), with square pixels
/// and the principal point at the image centre.
///
/// Pixel `(u, v)` has its origin at the centre of the top-left pixel, so the image centre is
/// `((width - 1) / 2, (height - 1) / 2)`. The focal length (pixels) gives a horizontal field of
/// view of [`HFOV_DEG`], so a scene renders the same at every resolution, only finer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
    /// Focal length (pixels).
    pub focal: f64,
    /// Principal point, x (pixels).
    pub pu: f64,
    /// Principal point, y (pixels).
    pub pv: f64,
}

impl Camera {
    /// The camera of a `width × height` image.
    pub fn new(width: u32, height: u32) -> Self {
        let focal = (width as f64 / 2.0) / (HFOV_DEG.to_radians() / 2.0).tan();
        Self {
            width,
            height,
            focal,
            pu: (width as f64 - 1.0) / 2.0,
            pv: (height as f64 - 1.0) / 2.0,
        }
    }

    /// Perspective projection of a point in camera coordinates (`z > 0`) to pixels.
    pub fn project(&self, p: &Vector3<f64>) -> (f64, f64) {
        (
            self.pu + self.focal * p.x / p.z,
            self.pv + self.focal * p.y / p.z,
        )
    }

    /// The same camera as the keyframe fits take it ([`Pinhole`]): what the tracker's
    /// `--hfov` gives it for a rendered sequence.
    pub fn pinhole(&self) -> Pinhole {
        Pinhole {
            focal: self.focal,
            principal: Vector2::new(self.pu, self.pv),
        }
    }

    /// Direction (camera coordinates, `z = 1`) of the ray through pixel position `(u, v)`.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.pu) / self.focal, (v - self.pv) / self.focal, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pinhole_is_the_one_the_field_of_view_gives() {
        let c = Camera::new(160, 120);
        let p = c.pinhole();
        let q = Pinhole::from_hfov(160, 120, HFOV_DEG).unwrap();
        assert!((p.focal - q.focal).abs() < 1e-9 && (p.principal - q.principal).norm() < 1e-9);
    }

    #[test]
    fn camera_axes_point_right_down_and_forward() {
        // SPEC section 1: x right, y down, z forward; u right, v down.
        let c = Camera::new(160, 120);
        let (u0, v0) = c.project(&Vector3::new(0.0, 0.0, 1.0));
        assert_eq!((u0, v0), (c.pu, c.pv));
        let (u_right, v) = c.project(&Vector3::new(0.1, 0.0, 1.0));
        assert!(u_right > u0 && v == v0, "x right: ({u_right}, {v})");
        let (u, v) = c.project(&Vector3::new(0.0, 0.1, 1.0));
        assert!(v > v0 && u == u0, "y down: ({u}, {v})");
        // Farther along z, the same offset moves the image less.
        let (u_far, _) = c.project(&Vector3::new(0.1, 0.0, 2.0));
        assert!(u0 < u_far && u_far < u_right);
    }

    #[test]
    fn ray_and_projection_are_inverse() {
        let c = Camera::new(160, 120);
        // 50° horizontal field of view: the left and right image borders at ±25°.
        let edge = c.ray(-0.5, c.pv);
        assert!((edge.x.atan().to_degrees() + 25.0).abs() < 1e-9);
        for &(u, v) in &[(0.0, 0.0), (12.3, 99.1), (159.0, 119.0)] {
            let p = c.ray(u, v) * 2.7;
            let (pu, pv) = c.project(&p);
            assert!((pu - u).abs() < 1e-12 && (pv - v).abs() < 1e-12);
        }
        let (u, v) = c.project(&Vector3::new(0.0, 0.0, 1.0));
        assert_eq!((u, v), (79.5, 59.5));
    }
}

//! The tracked region: an ellipse in image pixels (SPEC section 1).

/// An ellipse in image pixel coordinates (u right, v down, origin at the centre of the
/// top-left pixel).
///
/// `a` is the semi-axis along the image x axis and `b` along y when `theta = 0`; `theta`
/// (radians) turns the ellipse clockwise on screen (from +x towards +y, the image's v-down
/// sense), matching a positive roll `rz`.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ellipse {
    /// Centre, image x (pixels).
    pub cx: f64,
    /// Centre, image y (pixels).
    pub cy: f64,
    /// Semi-axis along the ellipse's own x axis (pixels).
    pub a: f64,
    /// Semi-axis along the ellipse's own y axis (pixels).
    pub b: f64,
    /// Orientation in radians (0 when left out of a serialised ellipse).
    #[serde(default)]
    pub theta: f64,
}

/// An axis-aligned box `x, y, w, h` in pixels (x, y the top-left corner).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BoxRect {
    /// Left edge.
    pub x: f64,
    /// Top edge.
    pub y: f64,
    /// Width.
    pub w: f64,
    /// Height.
    pub h: f64,
}

impl BoxRect {
    /// A box from its corner and size.
    pub fn new(x: f64, y: f64, w: f64, h: f64) -> Self {
        Self { x, y, w, h }
    }

    /// Area (0 for an empty or inverted box).
    pub fn area(&self) -> f64 {
        self.w.max(0.0) * self.h.max(0.0)
    }

    /// Intersection over union with another box, 0 when either is empty. The areas are
    /// measured between the corners, as the intersection is, so a box against itself gives
    /// exactly 1 (with `w` its area, `(x + w) − x` rounds off `w`).
    pub fn iou(&self, o: &BoxRect) -> f64 {
        let corners = |b: &BoxRect| (b.x, b.y, b.x + b.w, b.y + b.h);
        let ((ax0, ay0, ax1, ay1), (bx0, by0, bx1, by1)) = (corners(self), corners(o));
        let area = |x0: f64, y0: f64, x1: f64, y1: f64| (x1 - x0).max(0.0) * (y1 - y0).max(0.0);
        let inter = area(ax0.max(bx0), ay0.max(by0), ax1.min(bx1), ay1.min(by1));
        let union = area(ax0, ay0, ax1, ay1) + area(bx0, by0, bx1, by1) - inter;
        if union <= 0.0 { 0.0 } else { inter / union }
    }

    /// Centre of the box.
    pub fn centre(&self) -> (f64, f64) {
        (self.x + self.w / 2.0, self.y + self.h / 2.0)
    }
}

impl Ellipse {
    /// An axis-aligned ellipse.
    pub fn new(cx: f64, cy: f64, a: f64, b: f64) -> Self {
        Self {
            cx,
            cy,
            a,
            b,
            theta: 0.0,
        }
    }

    /// The inscribed ellipse of a box: `cx = x + w/2, cy = y + h/2, a = w/2, b = h/2`.
    pub fn from_box(r: &BoxRect) -> Self {
        Self::new(r.x + r.w / 2.0, r.y + r.h / 2.0, r.w / 2.0, r.h / 2.0)
    }

    /// The box whose inscribed ellipse is this one with its orientation ignored:
    /// `(cx - a, cy - b, 2a, 2b)`, the inverse of [`Ellipse::from_box`]. (The evaluation
    /// scores [`Ellipse::bounding_box`], which is this box at orientation 0.)
    pub fn to_box(&self) -> BoxRect {
        BoxRect::new(
            self.cx - self.a,
            self.cy - self.b,
            2.0 * self.a,
            2.0 * self.b,
        )
    }

    /// Axis-aligned bounding box of the (rotated) ellipse.
    pub fn bounding_box(&self) -> BoxRect {
        let (s, c) = self.theta.sin_cos();
        let hw = ((self.a * c).powi(2) + (self.b * s).powi(2)).sqrt();
        let hh = ((self.a * s).powi(2) + (self.b * c).powi(2)).sqrt();
        BoxRect::new(self.cx - hw, self.cy - hh, 2.0 * hw, 2.0 * hh)
    }

    /// The point `(u, v)` in the ellipse's own normalised frame: `(1, 0)` is the end of the
    /// `a` axis, so a point is inside when `u² + v² ≤ 1`.
    pub fn to_unit(&self, x: f64, y: f64) -> (f64, f64) {
        let (s, c) = self.theta.sin_cos();
        let dx = x - self.cx;
        let dy = y - self.cy;
        ((c * dx + s * dy) / self.a, (-s * dx + c * dy) / self.b)
    }

    /// Whether a pixel centre lies inside or on the ellipse.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let (u, v) = self.to_unit(x, y);
        u * u + v * v <= 1.0
    }

    /// Point on the contour at parameter `phi` (radians).
    pub fn point_at(&self, phi: f64) -> (f64, f64) {
        let (s, c) = self.theta.sin_cos();
        let (sp, cp) = phi.sin_cos();
        let ex = self.a * cp;
        let ey = self.b * sp;
        (self.cx + c * ex - s * ey, self.cy + s * ex + c * ey)
    }

    /// Outward unit normal of the contour at parameter `phi`.
    pub fn normal_at(&self, phi: f64) -> (f64, f64) {
        let (s, c) = self.theta.sin_cos();
        let (sp, cp) = phi.sin_cos();
        // gradient of (x/a)^2 + (y/b)^2 in the ellipse frame
        let nx = cp / self.a;
        let ny = sp / self.b;
        let n = (nx * nx + ny * ny).sqrt();
        let (nx, ny) = (nx / n, ny / n);
        (c * nx - s * ny, s * nx + c * ny)
    }

    /// Area in square pixels.
    pub fn area(&self) -> f64 {
        std::f64::consts::PI * self.a * self.b
    }

    /// Whether all parameters are finite and the semi-axes positive.
    pub fn is_valid(&self) -> bool {
        [self.cx, self.cy, self.a, self.b, self.theta]
            .iter()
            .all(|v| v.is_finite())
            && self.a > 0.0
            && self.b > 0.0
    }

    /// Whether the centre lies inside a `width × height` frame (pixel centres span
    /// `-0.5 ..= width - 0.5`).
    pub fn centre_inside(&self, width: u32, height: u32) -> bool {
        self.cx >= -0.5
            && self.cy >= -0.5
            && self.cx <= width as f64 - 0.5
            && self.cy <= height as f64 - 0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_round_trip_and_iou() {
        let b = BoxRect::new(10.0, 20.0, 30.0, 40.0);
        let e = Ellipse::from_box(&b);
        assert_eq!((e.cx, e.cy, e.a, e.b), (25.0, 40.0, 15.0, 20.0));
        assert_eq!(e.to_box(), b);
        assert!((b.iou(&b) - 1.0).abs() < 1e-12);
        let shifted = BoxRect::new(25.0, 20.0, 30.0, 40.0);
        // overlap 15x40 = 600, union 2400 - 600 = 1800
        assert!((b.iou(&shifted) - 600.0 / 1800.0).abs() < 1e-12);
        assert_eq!(b.iou(&BoxRect::new(100.0, 100.0, 5.0, 5.0)), 0.0);
    }

    #[test]
    fn contour_points_lie_on_ellipse_with_outward_normals() {
        let e = Ellipse {
            cx: 50.0,
            cy: 40.0,
            a: 20.0,
            b: 10.0,
            theta: 0.6,
        };
        for k in 0..36 {
            let phi = k as f64 * 10f64.to_radians();
            let (x, y) = e.point_at(phi);
            let (u, v) = e.to_unit(x, y);
            assert!((u * u + v * v - 1.0).abs() < 1e-9);
            let (nx, ny) = e.normal_at(phi);
            assert!(((nx * nx + ny * ny) - 1.0).abs() < 1e-12);
            assert!(!e.contains(x + 0.5 * nx, y + 0.5 * ny));
            assert!(e.contains(x - 0.5 * nx, y - 0.5 * ny));
        }
    }

    #[test]
    fn the_orientation_turns_the_a_axis_as_rz_turns_the_camera_x_axis() {
        // SPEC section 1: orientation theta0 + rz, and Rz turns x towards y, which points down
        // in the image. At 30 degrees the end of the a axis lies down and to the right.
        let theta = 30f64.to_radians();
        let e = Ellipse {
            cx: 10.0,
            cy: 20.0,
            a: 2.0,
            b: 1.0,
            theta,
        };
        let (x, y) = e.point_at(0.0);
        assert!((x - (10.0 + 3f64.sqrt())).abs() < 1e-12 && (y - 21.0).abs() < 1e-12);
        let (x, y) = e.point_at(std::f64::consts::FRAC_PI_2);
        assert!((x - 9.5).abs() < 1e-12 && (y - (20.0 + 3f64.sqrt() / 2.0)).abs() < 1e-12);
        let turned = crate::geometry::rot_z(theta) * nalgebra::Vector3::new(2.0, 0.0, 0.0);
        let (x, y) = e.point_at(0.0);
        assert!((x - 10.0 - turned.x).abs() < 1e-12 && (y - 20.0 - turned.y).abs() < 1e-12);
        let (u, v) = e.to_unit(x, y);
        assert!((u - 1.0).abs() < 1e-12 && v.abs() < 1e-12, "({u}, {v})");
    }

    #[test]
    fn bounding_box_of_rotated_ellipse() {
        let e = Ellipse {
            cx: 0.0,
            cy: 0.0,
            a: 20.0,
            b: 10.0,
            theta: std::f64::consts::FRAC_PI_2,
        };
        let bb = e.bounding_box();
        assert!((bb.w - 20.0).abs() < 1e-9 && (bb.h - 40.0).abs() < 1e-9);
    }
}

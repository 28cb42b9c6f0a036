//! The tracker's state `x = (cx, cy, a, b, rx, ry, rz)` (SPEC section 3).

use super::ellipse::Ellipse;
use super::rotation::Euler;

/// One pose estimate: the ellipse (centre and semi-axes, pixels) and the rotation
/// (radians, `R = Rx(rx) · Ry(ry) · Rz(rz)`) relative to the reference pose of frame 0.
///
/// The ellipse drawn for this state has orientation `theta0 + rz` (see [`PoseState::ellipse`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseState {
    /// Centre x (pixels).
    pub cx: f64,
    /// Centre y (pixels).
    pub cy: f64,
    /// Semi-axis a (pixels).
    pub a: f64,
    /// Semi-axis b (pixels).
    pub b: f64,
    /// Tilt (radians).
    pub rx: f64,
    /// Pan (radians).
    pub ry: f64,
    /// Roll (radians).
    pub rz: f64,
}

impl PoseState {
    /// A state from an ellipse's centre and axes and a rotation.
    pub fn from_parts(e: &Ellipse, r: Euler) -> Self {
        Self {
            cx: e.cx,
            cy: e.cy,
            a: e.a,
            b: e.b,
            rx: r.rx,
            ry: r.ry,
            rz: r.rz,
        }
    }

    /// The rotation part.
    pub fn euler(&self) -> Euler {
        Euler::new(self.rx, self.ry, self.rz)
    }

    /// The ellipse of this state, turned by `theta0 + rz`.
    pub fn ellipse(&self, theta0: f64) -> Ellipse {
        Ellipse {
            cx: self.cx,
            cy: self.cy,
            a: self.a,
            b: self.b,
            theta: theta0 + self.rz,
        }
    }

    /// The seven components in state order.
    pub fn to_array(&self) -> [f64; 7] {
        [self.cx, self.cy, self.a, self.b, self.rx, self.ry, self.rz]
    }

    /// A state from its seven components in state order.
    pub fn from_array(v: [f64; 7]) -> Self {
        Self {
            cx: v[0],
            cy: v[1],
            a: v[2],
            b: v[3],
            rx: v[4],
            ry: v[5],
            rz: v[6],
        }
    }
}

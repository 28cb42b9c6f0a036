//! Geometry shared by every stage: the rotation conventions, the ellipse, the state.

pub mod ellipse;
pub mod rotation;
pub mod state;

pub use ellipse::{BoxRect, Ellipse};
pub use rotation::{Euler, angle_between, deg, rad, rot_x, rot_y, rot_z, wrap_180, wrap_pi};
pub use state::PoseState;

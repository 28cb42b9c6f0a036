//! Adaptive block matching and least-squares ellipse fitting: the 2D motion of the target.

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    /// Placeholder until the module lands.
    #[error("not implemented yet")]
    Unimplemented,
}

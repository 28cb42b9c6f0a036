//! Rotation from 2D correspondences: Sylvester's equation (SEA), the optimal solver and the baselines.

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum PoseError {
    /// Placeholder until the module lands.
    #[error("not implemented yet")]
    Unimplemented,
}

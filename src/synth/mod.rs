//! Synthetic ground truth: a textured rigid object rendered along a known trajectory.

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// Placeholder until the module lands.
    #[error("not implemented yet")]
    Unimplemented,
}

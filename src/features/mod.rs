//! SIFT keypoints and descriptors, and matching between frames.

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum FeatureError {
    /// Placeholder until the module lands.
    #[error("not implemented yet")]
    Unimplemented,
}

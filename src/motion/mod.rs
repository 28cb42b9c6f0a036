//! The 2D motion of the target: adaptive block matching ([`abm`]) between successive frames
//! and the direct least-squares ellipse fit ([`fit`]) that turns the matched blocks (or
//! points marked around an object) into an ellipse.

pub mod abm;
pub mod fit;

pub use abm::{AbmParams, AbmResult, BlockMatch, BlockStatus, Fallback, block_match};
pub use fit::fit_ellipse;

/// Errors of this module.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum MotionError {
    /// An ellipse fit needs at least `needed` points.
    #[error("ellipse fit needs at least {needed} points, got {got}")]
    TooFewPoints {
        /// The minimum.
        needed: usize,
        /// What was given.
        got: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("point coordinates must be finite")]
    NonFinite,
    /// The points do not determine an ellipse.
    #[error("degenerate ellipse fit: {0}")]
    Degenerate(&'static str),
    /// The region ellipse has a non-finite parameter or a non-positive semi-axis.
    #[error("invalid target region (cx, cy, a, b, theta must be finite, a and b positive)")]
    InvalidRegion,
    /// The two frames differ in size (or one is empty).
    #[error("frames differ in size or are empty: {0}x{1} vs {2}x{3}")]
    FrameSize(u32, u32, u32, u32),
    /// No block of the region lies inside the frame.
    #[error("target region lies outside the frame")]
    RegionOutside,
    /// The region lies in the frame but holds no block of the minimum size.
    #[error("target region is too small for block matching")]
    RegionTooSmall,
    /// The parameters are unusable.
    #[error("invalid block matching parameters: {0}")]
    InvalidParams(&'static str),
}

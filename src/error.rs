//! The crate's error type: one variant per domain, each wrapping that module's typed error.
//!
//! What a caller of the tracker tells apart: a bad start, configuration or frame size is
//! [`Error::Track`] ([`crate::tracker::TrackError`]); a likelihood engine's failure, or a
//! particle count its buffers cannot hold, is [`Error::Likelihood`]; SIFT's, [`Error::Features`].

/// Any error of the library.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Reading frames.
    #[error(transparent)]
    Frames(#[from] crate::frames::FrameError),
    /// Reading or writing the project's file formats.
    #[error(transparent)]
    Format(#[from] crate::io::FormatError),
    /// Synthetic sequences.
    #[error(transparent)]
    Synth(#[from] crate::synth::SynthError),
    /// Scoring.
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
    /// Features.
    #[error(transparent)]
    Features(#[from] crate::features::FeatureError),
    /// Pose estimation.
    #[error(transparent)]
    Pose(#[from] crate::pose::PoseError),
    /// Block matching and ellipse fitting.
    #[error(transparent)]
    Motion(#[from] crate::motion::MotionError),
    /// The particle filter's settings.
    #[error(transparent)]
    Filter(#[from] crate::filter::FilterError),
    /// Likelihood engines (CPU or GPU).
    #[error(transparent)]
    Likelihood(#[from] crate::likelihood::LikelihoodError),
    /// The tracker.
    #[error(transparent)]
    Track(#[from] crate::tracker::TrackError),
    /// Rendered output.
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
}

/// Result with the crate's error.
pub type Result<T, E = Error> = std::result::Result<T, E>;

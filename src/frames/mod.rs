//! Frame sources: a streaming iterator of RGB8 frames from an image directory, a `.y4m` file,
//! or any other video through an `ffmpeg` child process. Never the whole video in memory.

pub mod gray;

pub use gray::GrayF32;

/// One video frame, 8-bit RGB.
pub type Frame = image::RgbImage;

/// Errors of the frame sources.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// The input could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
}

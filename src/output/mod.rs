//! What the tracker shows a person: frames with the ellipse, pan and tilt bars, the angles
//! ([`render_overlay`], drawn with a hand-made bitmap [`font`]), written as PNG files that
//! appear only once complete ([`write_png`]), or as one video through ffmpeg
//! ([`VideoWriter`]).

pub mod draw;
pub mod font;
pub mod overlay;
pub mod video;

use std::path::Path;

use image::RgbImage;
use image::codecs::png::PngEncoder;

use crate::io::{AtomicFile, FormatError};

pub use overlay::{
    Layout, MAX_SCALED_SIDE, Overlay, capped_scale, default_scale, layout, render_overlay,
};
pub use video::{VideoError, VideoWriter};

/// Errors writing output frames.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OutputError {
    /// Creating, writing or renaming the file failed.
    #[error(transparent)]
    File(#[from] FormatError),
    /// PNG encoding failed.
    #[error("{path}: PNG encoding failed: {source}")]
    Encode {
        /// The file.
        path: String,
        /// The cause.
        source: image::ImageError,
    },
}

/// Writes `img` as a PNG file at `path`, atomically ([`AtomicFile`]): the image is encoded to
/// a partial file beside it, synced, and renamed, so `path` never holds a partial image. The
/// parent directory must exist.
pub fn write_png(path: &Path, img: &RgbImage) -> Result<(), OutputError> {
    let mut file = AtomicFile::create(path)?;
    encode_png(&mut file, img)?;
    file.commit()?;
    Ok(())
}

/// How many bytes [`write_png`] writes for `img`: the image encoded as it would be, into a
/// counter instead of a file (to size a run's output before writing it).
pub fn png_len(img: &RgbImage) -> Result<u64, image::ImageError> {
    /// A sink that keeps only the count of what it is given.
    struct Count(u64);
    impl std::io::Write for Count {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0 += buf.len() as u64;
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let mut count = Count(0);
    img.write_with_encoder(PngEncoder::new(&mut count))?;
    Ok(count.0)
}

/// Encodes `img` as PNG into `file`, left for its caller to commit (when it writes several
/// files that appear together).
pub fn encode_png(file: &mut AtomicFile, img: &RgbImage) -> Result<(), OutputError> {
    let path = file.path().to_path_buf();
    img.write_with_encoder(PngEncoder::new(file))
        .map_err(|e| match e {
            // A write error is the file's, not the encoding's.
            image::ImageError::IoError(io) => OutputError::File(FormatError::io(&path, io)),
            e => OutputError::Encode {
                path: path.display().to_string(),
                source: e,
            },
        })
}

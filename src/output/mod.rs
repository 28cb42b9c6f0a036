//! What the tracker shows a person: frames with the ellipse, pan and tilt bars, the angles
//! ([`render_overlay`], drawn with a hand-made bitmap [`font`]), written as PNG files that
//! appear only once complete ([`write_png`]).

pub mod draw;
pub mod font;
pub mod overlay;

use std::io::Write;
use std::path::{Path, PathBuf};

use image::RgbImage;

pub use overlay::{Layout, Overlay, default_scale, layout, render_overlay};

/// Errors writing output frames.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Creating, writing or renaming the file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// PNG encoding failed.
    #[error("{path}: PNG encoding failed: {source}")]
    Encode {
        /// The file.
        path: String,
        /// The cause.
        source: image::ImageError,
    },
    /// The path has no file name.
    #[error("{0}: not a file path")]
    NotAFile(String),
}

/// The temporary name [`write_png`] writes before renaming: `.NAME.partial` beside `path`.
fn temp_path(path: &Path) -> Result<PathBuf, OutputError> {
    let name = path
        .file_name()
        .ok_or_else(|| OutputError::NotAFile(path.display().to_string()))?;
    let mut tmp = std::ffi::OsString::from(".");
    tmp.push(name);
    tmp.push(".partial");
    Ok(path.with_file_name(tmp))
}

/// Writes `img` as a PNG file at `path`, atomically: the image is encoded to a temporary
/// file beside it, synced, and renamed, so `path` never holds a partial image. The parent
/// directory must exist.
pub fn write_png(path: &Path, img: &RgbImage) -> Result<(), OutputError> {
    let tmp = temp_path(path)?;
    let io_err = |p: &Path, e: std::io::Error| OutputError::Io {
        path: p.display().to_string(),
        source: e,
    };
    let result = (|| {
        let file = std::fs::File::create(&tmp).map_err(|e| io_err(&tmp, e))?;
        let mut w = std::io::BufWriter::new(file);
        img.write_to(&mut w, image::ImageFormat::Png)
            .map_err(|e| OutputError::Encode {
                path: path.display().to_string(),
                source: e,
            })?;
        w.flush().map_err(|e| io_err(&tmp, e))?;
        let file = w.into_inner().map_err(|e| io_err(&tmp, e.into_error()))?;
        file.sync_all().map_err(|e| io_err(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| io_err(path, e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

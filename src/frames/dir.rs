//! A directory of images as a video: png, jpg/jpeg, bmp, pgm, ppm (extension matched
//! case-insensitively, every other file ignored), in natural order (`2.png` before `10.png`).
//! Frames are decoded one at a time as the source is iterated. Grayscale images become RGB
//! with three equal channels; 16-bit images are scaled to 8 bits.

use std::cmp::Ordering;
use std::path::{Path, PathBuf};

use super::{Frame, FrameError};

/// Extensions (lower case) read as frames.
pub const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "bmp", "pgm", "ppm"];

/// Whether a path names a file kind this source reads (by its extension, case-insensitive).
pub fn is_image_file(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.iter().any(|k| e.eq_ignore_ascii_case(k)))
}

/// Splits a name into runs of ASCII digits and runs of anything else.
fn chunks(s: &str) -> impl Iterator<Item = &str> {
    let mut rest = s;
    std::iter::from_fn(move || {
        let first = rest.chars().next()?;
        let digit = first.is_ascii_digit();
        let end = rest
            .char_indices()
            .find(|(_, c)| c.is_ascii_digit() != digit)
            .map_or(rest.len(), |(i, _)| i);
        let (head, tail) = rest.split_at(end);
        rest = tail;
        Some(head)
    })
}

/// Natural order of file names: runs of digits compare by numeric value (of any length),
/// other runs case-insensitively; ties fall back to the plain byte order so the order is
/// total (`007` and `7` differ).
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let mut ia = chunks(a);
    let mut ib = chunks(b);
    loop {
        match (ia.next(), ib.next()) {
            (None, None) => return a.cmp(b),
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(x), Some(y)) => {
                let xd = x.as_bytes()[0].is_ascii_digit();
                let yd = y.as_bytes()[0].is_ascii_digit();
                let ord = if xd && yd {
                    let xt = x.trim_start_matches('0');
                    let yt = y.trim_start_matches('0');
                    xt.len().cmp(&yt.len()).then_with(|| xt.cmp(yt))
                } else {
                    x.to_lowercase().cmp(&y.to_lowercase())
                };
                if ord != Ordering::Equal {
                    return ord;
                }
            }
        }
    }
}

/// Lists the image files of `dir` in natural order of their names.
///
/// Hidden files (names starting with `.`, such as a viewer's thumbnails or macOS's `._`
/// resource forks) and folders are not frames. Anything else with an image extension is,
/// a dangling or looping link included: it fails when read, naming itself, rather than
/// being skipped and shifting every later frame's number.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>, FrameError> {
    let io = |e| FrameError::io(dir, e);
    let mut files: Vec<(String, PathBuf)> = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let p = entry.path();
        if !name.starts_with('.') && is_image_file(&p) && !p.is_dir() {
            files.push((name, p));
        }
    }
    files.sort_by(|a, b| natural_cmp(&a.0, &b.0));
    Ok(files.into_iter().map(|(_, p)| p).collect())
}

/// Decodes one image file to RGB8 (format guessed from the content, then the extension); an
/// image with no pixels is an error.
/// A folder is refused by name (the image crate would call it an unknown format).
pub fn decode_rgb(p: &Path) -> Result<Frame, FrameError> {
    let dec = |e: image::ImageError| FrameError::Decode {
        path: p.display().to_string(),
        msg: e.to_string(),
    };
    if p.is_dir() {
        return Err(FrameError::io(
            p,
            std::io::Error::new(
                std::io::ErrorKind::IsADirectory,
                "is a directory, not an image",
            ),
        ));
    }
    let bytes = std::fs::read(p).map_err(|e| FrameError::io(p, e))?;
    let mut reader = image::ImageReader::new(std::io::Cursor::new(&bytes));
    if let Ok(f) = image::ImageFormat::from_path(p) {
        reader.set_format(f);
    }
    let reader = reader
        .with_guessed_format()
        .map_err(|e| FrameError::io(p, e))?;
    let bad = |msg: &str| FrameError::Decode {
        path: p.display().to_string(),
        msg: msg.into(),
    };
    match reader.format() {
        // Neither the content nor the extension names a format.
        None => return Err(bad("not an image (png, jpg, jpeg, bmp, pgm, ppm)")),
        // The JPEG decoder fills a cut-off scan with grey and reports success.
        Some(image::ImageFormat::Jpeg) if !jpeg_scan_ends(&bytes) => {
            return Err(bad(
                "a truncated JPEG: its last scan has no end-of-image marker",
            ));
        }
        Some(_) => {}
    }
    let img = reader.decode().map_err(dec)?.into_rgb8();
    if img.width() == 0 || img.height() == 0 {
        return Err(FrameError::Decode {
            path: p.display().to_string(),
            msg: format!("an empty image ({}x{})", img.width(), img.height()),
        });
    }
    Ok(img)
}

/// Whether a JPEG's last scan (its last start-of-scan marker, `FF DA`) is followed by the
/// end-of-image marker (`FF D9`). Inside a scan a byte `FF` is always followed by `00` or a
/// restart marker, so neither marker occurs there; an EXIF thumbnail's markers come before
/// the image's own scans, and data after the end (some cameras append their own) is allowed.
fn jpeg_scan_ends(bytes: &[u8]) -> bool {
    let last = |m: u8| bytes.windows(2).rposition(|w| w == [0xFF, m]);
    match (last(0xDA), last(0xD9)) {
        (Some(sos), Some(eoi)) => eoi > sos,
        _ => false,
    }
}

/// The size of an image file from its header, without decoding the pixels.
fn image_size(p: &Path) -> Result<(u32, u32), FrameError> {
    image::ImageReader::open(p)
        .map_err(|e| FrameError::io(p, e))?
        .with_guessed_format()
        .map_err(|e| FrameError::io(p, e))?
        .into_dimensions()
        .map_err(|e| FrameError::Decode {
            path: p.display().to_string(),
            msg: e.to_string(),
        })
}

/// The frames of an image directory, decoded lazily.
#[derive(Debug)]
pub(crate) struct DirSource {
    files: Vec<PathBuf>,
    next: usize,
    size: (u32, u32),
}

impl DirSource {
    /// Lists the directory and reads the size of the first image.
    pub(crate) fn open(dir: &Path) -> Result<Self, FrameError> {
        if !dir.is_dir() {
            return Err(FrameError::NotFound {
                path: dir.display().to_string(),
            });
        }
        let files = list_images(dir)?;
        let first = files.first().ok_or_else(|| FrameError::NoImages {
            path: dir.display().to_string(),
        })?;
        let size = image_size(first)?;
        Ok(Self {
            files,
            next: 0,
            size,
        })
    }

    /// The size of every frame (that of the first).
    pub(crate) fn size(&self) -> (u32, u32) {
        self.size
    }

    /// The number of frames.
    pub(crate) fn len(&self) -> usize {
        self.files.len()
    }

    /// Decodes the next frame; `None` after the last.
    pub(crate) fn next_frame(&mut self) -> Result<Option<Frame>, FrameError> {
        let Some(p) = self.files.get(self.next) else {
            return Ok(None);
        };
        self.next += 1;
        let img = decode_rgb(p)?;
        if img.dimensions() != self.size {
            return Err(FrameError::SizeMismatch {
                path: p.display().to_string(),
                found: img.dimensions(),
                expected: self.size,
            });
        }
        Ok(Some(img))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order() {
        let mut v = vec![
            "10.png",
            "2.png",
            "1.png",
            "frame_100.jpg",
            "frame_20.jpg",
            "B3.png",
            "a3.png",
            "0002.png",
            "02.png",
        ];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            [
                "1.png",
                "0002.png",
                "02.png",
                "2.png",
                "10.png",
                "a3.png",
                "B3.png",
                "frame_20.jpg",
                "frame_100.jpg"
            ]
        );
        // Digit runs longer than any integer type still compare by value.
        assert_eq!(
            natural_cmp("x99999999999999999999999", "x100000000000000000000000"),
            Ordering::Less
        );
    }

    #[test]
    fn a_jpeg_scan_must_end() {
        let (sos, eoi) = ([0xFF, 0xDA], [0xFF, 0xD9]);
        let whole = [&[0xFF, 0xD8][..], &sos, &[1, 2, 0xFF, 0x00, 3], &eoi].concat();
        assert!(jpeg_scan_ends(&whole));
        assert!(
            !jpeg_scan_ends(&whole[..whole.len() - 2]),
            "cut in the scan"
        );
        // A thumbnail's end comes before the image's scan; trailing data after the end.
        let thumb = [&[0xFF, 0xD8][..], &sos, &[9], &eoi, &sos, &[1, 2]].concat();
        assert!(!jpeg_scan_ends(&thumb));
        let trailer = [&whole[..], b"camera trailer"].concat();
        assert!(jpeg_scan_ends(&trailer));
        assert!(!jpeg_scan_ends(&[]));
    }

    #[test]
    fn extensions() {
        for ok in ["a.png", "b.JPG", "c.Jpeg", "d.bmp", "e.pgm", "f.PPM"] {
            assert!(is_image_file(Path::new(ok)), "{ok}");
        }
        for no in ["a.txt", "png", "b.gif", "c.png.bak", "groundtruth_rect.txt"] {
            assert!(!is_image_file(Path::new(no)), "{no}");
        }
    }
}

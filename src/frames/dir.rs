//! A directory of images as a video: png, jpg/jpeg, bmp, pgm, ppm, tif/tiff, webp (extension
//! matched case-insensitively, every other file ignored), in natural order (`2.png` before
//! `10.png`). Frames are decoded one at a time as the source is iterated. Grayscale images
//! become RGB with three equal channels; 16-bit images (a machine-vision camera's TIFF) are
//! scaled to 8 bits, and floating-point ones (RGB, or one channel as microscopes write it)
//! taken from 0 to 1.

use std::cmp::Ordering;
use std::path::{Path, PathBuf};

use super::{Frame, FrameError};

/// Extensions (lower case) read as frames.
pub const IMAGE_EXTENSIONS: [&str; 9] = [
    "png", "jpg", "jpeg", "bmp", "pgm", "ppm", "tif", "tiff", "webp",
];

/// Whether a path names a file kind this source reads (by its extension, case-insensitive).
pub fn is_image_file(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.iter().any(|k| e.eq_ignore_ascii_case(k)))
}

/// Extensions (lower case) of image formats this source does not read: a folder of frames
/// holding one is said ([`super::FrameSource::caveats`]), since the file is left out of the
/// sequence.
pub const OTHER_IMAGE_EXTENSIONS: [&str; 10] = [
    "gif", "heic", "heif", "avif", "jxl", "exr", "tga", "qoi", "dng", "raw",
];

/// `name` split at its last run of ASCII digits: what comes before, the digits and what comes
/// after; `None` without a digit.
fn last_number(name: &str) -> Option<(&str, &str, &str)> {
    let end = name.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = name[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    Some((&name[..start], &name[start..end], &name[end..]))
}

/// Where the numbering of `names` (file names in natural order) skips: each pair of
/// neighbours that differ only in their last number, by more than one, in a folder numbered
/// frame by frame (at least half of such pairs a step of one). Neighbours named otherwise are
/// not compared, nor numbers beyond `u64`; names that are timestamps, or every fifth frame,
/// step by other amounts throughout and have no gaps.
pub fn numbering_gaps<S: AsRef<str>>(names: &[S]) -> Vec<(String, String)> {
    let steps: Vec<(&str, &str, u64)> = names
        .windows(2)
        .filter_map(|w| {
            let (a, b) = (w[0].as_ref(), w[1].as_ref());
            let (pa, na, sa) = last_number(a)?;
            let (pb, nb, sb) = last_number(b)?;
            let (na, nb) = (na.parse::<u64>().ok()?, nb.parse::<u64>().ok()?);
            (pa == pb && sa == sb && nb > na).then(|| (a, b, nb - na))
        })
        .collect();
    let ones = steps.iter().filter(|s| s.2 == 1).count();
    if ones * 2 < steps.len() {
        return Vec::new();
    }
    steps
        .into_iter()
        .filter(|s| s.2 > 1)
        .map(|(a, b, _)| (a.to_string(), b.to_string()))
        .collect()
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
/// resource forks), folders, pipes, sockets and devices are not frames. Files with an image
/// extension are, and so are links to them and links that lead nowhere (dangling, a loop):
/// those fail when read, naming themselves, rather than being skipped and shifting every
/// later frame's number.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>, FrameError> {
    Ok(scan(dir)?.frames.into_iter().map(|(_, p)| p).collect())
}

/// What one reading of a frames folder finds.
struct Scan {
    /// The frames ([`list_images`]), each with its file name, in natural order.
    frames: Vec<(String, PathBuf)>,
    /// The names of the images of formats this source does not read
    /// ([`OTHER_IMAGE_EXTENSIONS`]), hidden ones aside, in natural order.
    unread: Vec<String>,
}

/// Reads `dir` once for [`list_images`] and [`DirSource::notes`].
fn scan(dir: &Path) -> Result<Scan, FrameError> {
    let io = |e| FrameError::io(dir, e);
    let (mut frames, mut unread): (Vec<(String, PathBuf)>, Vec<String>) = (Vec::new(), Vec::new());
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let p = entry.path();
        if name.starts_with('.') {
            continue;
        }
        if !is_image_file(&p) {
            let other = p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                OTHER_IMAGE_EXTENSIONS
                    .iter()
                    .any(|k| e.eq_ignore_ascii_case(k))
            });
            if other {
                unread.push(name);
            }
            continue;
        }
        let kind = entry.file_type().map_err(io)?;
        // A link counts when it leads to a file or to nothing that can be read (dangling, a
        // loop); a pipe, socket or device is no frame (reading a pipe would wait for ever).
        let frame = kind.is_file()
            || (kind.is_symlink() && std::fs::metadata(&p).map_or(true, |m| m.is_file()));
        if frame {
            frames.push((name, p));
        }
    }
    frames.sort_by(|a, b| natural_cmp(&a.0, &b.0));
    unread.sort_by(|a, b| natural_cmp(a, b));
    Ok(Scan { frames, unread })
}

/// The notes of [`DirSource::notes`] for `dir`, from its [`scan`].
fn folder_notes(dir: &Path, scan: &Scan) -> Vec<String> {
    let d = dir.display();
    let mut notes = Vec::new();
    let names: Vec<&str> = scan.frames.iter().map(|(n, _)| n.as_str()).collect();
    let gaps = numbering_gaps(&names);
    if let Some((a, b)) = gaps.first() {
        let more = match gaps.len() {
            1 => String::new(),
            n => format!(" and at {} more places", n - 1),
        };
        notes.push(format!(
            "{d}: the frames' numbering skips from {a} to {b}{more}: rows are numbered as the \
             frames are read, so past a gap they run behind the files' numbers"
        ));
    }
    if let Some(first) = scan.unread.first() {
        let more = match scan.unread.len() {
            1 => String::new(),
            n => format!(" and {} more", n - 1),
        };
        notes.push(format!(
            "{d}: {first}{more} left out: only {} files are read as frames (convert the \
             others to png, e.g. with ffmpeg)",
            IMAGE_EXTENSIONS.join(", ")
        ));
    }
    notes
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
    let mut reader = reader
        .with_guessed_format()
        .map_err(|e| FrameError::io(p, e))?;
    let bad = |msg: &str| FrameError::Decode {
        path: p.display().to_string(),
        msg: msg.into(),
    };
    let format = match reader.format() {
        // One channel of floating point, which the image crate does not decode.
        Some(image::ImageFormat::Tiff) if let Some(frame) = grey_float_tiff(&bytes, p)? => {
            return Ok(frame);
        }
        // Neither the content nor the extension names a format.
        None => {
            return Err(bad(&format!(
                "not an image ({})",
                IMAGE_EXTENSIONS.join(", ")
            )));
        }
        // The JPEG decoder fills a cut-off scan with grey and reports success.
        Some(image::ImageFormat::Jpeg) if !jpeg_scan_ends(&bytes) => {
            return Err(bad(
                "a truncated or damaged JPEG: walking its markers never reaches the end of its image",
            ));
        }
        Some(f) => f,
    };
    // The size from the header first: a few bytes can claim a size whose pixels would not
    // fit in memory.
    let (w, h) = image::ImageReader::with_format(std::io::Cursor::new(&bytes), format)
        .into_dimensions()
        .map_err(dec)?;
    if let Some(msg) = too_many_pixels(w, h) {
        return Err(bad(&msg));
    }
    // Within the size checked above, the decoder's own default cap (512 MiB) is lifted: a
    // 16-bit RGB image of 10000x9000 needs 540 MB and was refused as "Memory limit exceeded".
    reader.no_limits();
    // Turned as its Exif orientation says (a phone's photo stored sideways), as viewers show
    // it and as [`image_size`] reports it.
    use image::ImageDecoder;
    let mut decoder = reader.into_decoder().map_err(dec)?;
    let orientation = decoder.orientation().map_err(dec)?;
    let mut img = image::DynamicImage::from_decoder(decoder).map_err(dec)?;
    img.apply_orientation(orientation);
    let img = img.into_rgb8();
    if img.width() == 0 || img.height() == 0 {
        return Err(FrameError::Decode {
            path: p.display().to_string(),
            msg: format!("an empty image ({}x{})", img.width(), img.height()),
        });
    }
    Ok(img)
}

/// Why an image of `w` x `h` is not decoded, where it has more pixels than any frame may
/// ([`super::y4m::MAX_DECODE_PIXELS`]): read from its header, before its pixels are.
fn too_many_pixels(w: u32, h: u32) -> Option<String> {
    (u64::from(w) * u64::from(h) > super::y4m::MAX_DECODE_PIXELS).then(|| {
        format!(
            "{w}x{h} is more than the {} pixels an image may have",
            super::y4m::MAX_DECODE_PIXELS
        )
    })
}

/// A TIFF decoder on `r` when it holds one channel of 32- or 64-bit samples (the `image` crate
/// decodes neither), else `None`.
fn grey_float_tiff_decoder<R: std::io::Read + std::io::Seek>(
    r: R,
) -> Option<tiff::decoder::Decoder<R>> {
    let mut d = tiff::decoder::Decoder::new(r).ok()?;
    matches!(d.colortype().ok()?, tiff::ColorType::Gray(32 | 64)).then_some(d)
}

/// The orientation a TIFF's tag gives (as the `image` crate reads it for the TIFFs it
/// decodes); none, or a value outside 1-8, is no turn.
fn tiff_orientation<R: std::io::Read + std::io::Seek>(
    d: &mut tiff::decoder::Decoder<R>,
) -> image::metadata::Orientation {
    d.find_tag_unsigned::<u16>(tiff::tags::Tag::Orientation)
        .ok()
        .flatten()
        .and_then(|v| image::metadata::Orientation::from_exif(v.min(255) as u8))
        .unwrap_or(image::metadata::Orientation::NoTransforms)
}

/// The size `(w, h)` of an image stored `w` x `h`, as shown turned by `o`.
fn shown_size(w: u32, h: u32, o: image::metadata::Orientation) -> (u32, u32) {
    use image::metadata::Orientation;
    match o {
        Orientation::Rotate90
        | Orientation::Rotate270
        | Orientation::Rotate90FlipH
        | Orientation::Rotate270FlipH => (h, w),
        _ => (w, h),
    }
}

/// A one-channel floating-point TIFF (as microscopes and scientific cameras write it), which
/// the `image` crate does not decode, as RGB with three equal channels: each value taken from
/// 0 to 1 to a level of 255, as `image` takes floating-point RGB (clamped; NaN is 0), and
/// turned as its orientation tag says, as `image` turns the TIFFs it decodes.
/// `Ok(None)` for any other file, left to `image`.
fn grey_float_tiff(bytes: &[u8], p: &Path) -> Result<Option<Frame>, FrameError> {
    let Some(mut d) = grey_float_tiff_decoder(std::io::Cursor::new(bytes)) else {
        return Ok(None);
    };
    let bad = |msg: String| FrameError::Decode {
        path: p.display().to_string(),
        msg,
    };
    let (w, h) = d.dimensions().map_err(|e| bad(e.to_string()))?;
    if let Some(msg) = too_many_pixels(w, h) {
        return Err(bad(msg));
    }
    if w == 0 || h == 0 {
        return Err(bad(format!("an empty image ({w}x{h})")));
    }
    let orientation = tiff_orientation(&mut d);
    // Within the size checked above, the decoder's own cap is lifted, as for `image`'s.
    let mut d = d.with_limits(tiff::decoder::Limits::unlimited());
    let values: Vec<f64> = match d.read_image().map_err(|e| bad(e.to_string()))? {
        tiff::decoder::DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
        tiff::decoder::DecodingResult::F64(v) => v,
        // Integer samples of 32 or 64 bits: not floating point, and not read.
        _ => return Ok(None),
    };
    let n = w as usize * h as usize;
    if values.len() < n {
        return Err(bad(format!("{} samples for {w}x{h} pixels", values.len())));
    }
    let level = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let mut img = image::DynamicImage::ImageRgb8(Frame::from_fn(w, h, |x, y| {
        image::Rgb([level(values[y as usize * w as usize + x as usize]); 3])
    }));
    img.apply_orientation(orientation);
    Ok(Some(img.into_rgb8()))
}

/// Whether a JPEG's image data ends: walking its markers from the start, past each
/// segment by its length and each scan's entropy-coded data (where a byte `FF` is followed
/// only by `00`, by fill bytes `FF`, or by a restart marker), the end-of-image marker
/// `FF D9` is reached before the file ends. Stray bytes between segments are passed over,
/// as decoders do. What follows that marker (a camera's trailer, a motion photo's video) is
/// not looked at.
fn jpeg_scan_ends(bytes: &[u8]) -> bool {
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return false;
    }
    // The next `FF` at or after `i`.
    let next_ff = |i: usize| {
        bytes
            .get(i..)
            .and_then(|r| r.iter().position(|&b| b == 0xFF))
            .map(|off| i + off)
    };
    let mut i = 2;
    loop {
        // A marker: stray bytes, then `FF`, any fill bytes `FF`, the marker's code.
        let Some(ff) = next_ff(i) else {
            return false;
        };
        i = ff;
        while bytes.get(i + 1) == Some(&0xFF) {
            i += 1;
        }
        let Some(&marker) = bytes.get(i + 1) else {
            return false;
        };
        i += 2;
        match marker {
            0xD9 => return true,
            // Markers without a length: restarts, TEM, and a stuffed zero out of place.
            0xD0..=0xD7 | 0x01 | 0x00 => continue,
            _ => {}
        }
        let Some(len) = bytes
            .get(i..i + 2)
            .map(|b| usize::from(u16::from_be_bytes([b[0], b[1]])))
        else {
            return false;
        };
        if len < 2 {
            return false;
        }
        i += len;
        if marker == 0xDA {
            // The scan's data, up to the next marker that is not a stuffed byte or a restart.
            loop {
                let Some(ff) = next_ff(i) else {
                    return false;
                };
                let mut j = ff;
                while bytes.get(j + 1) == Some(&0xFF) {
                    j += 1;
                }
                match bytes.get(j + 1) {
                    None => return false,
                    Some(0x00 | 0xD0..=0xD7) => i = j + 2,
                    Some(_) => {
                        i = j;
                        break;
                    }
                }
            }
        }
    }
}

/// The size of an image file as shown (its Exif orientation applied, as [`decode_rgb`]
/// does), from its header, without decoding the pixels.
fn image_size(p: &Path) -> Result<(u32, u32), FrameError> {
    use image::ImageDecoder;
    let dec = |e: image::ImageError| FrameError::Decode {
        path: p.display().to_string(),
        msg: e.to_string(),
    };
    let reader = image::ImageReader::open(p)
        .map_err(|e| FrameError::io(p, e))?
        .with_guessed_format()
        .map_err(|e| FrameError::io(p, e))?;
    let tiff = reader.format() == Some(image::ImageFormat::Tiff);
    let mut decoder = match reader.into_decoder() {
        Ok(d) => d,
        // One channel of floating point, which the image crate does not decode.
        Err(e) if tiff => {
            let file = std::fs::File::open(p).map_err(|e| FrameError::io(p, e))?;
            return grey_float_tiff_decoder(std::io::BufReader::new(file))
                .and_then(|mut d| {
                    let (w, h) = d.dimensions().ok()?;
                    Some(shown_size(w, h, tiff_orientation(&mut d)))
                })
                .filter(|&(w, h)| w > 0 && h > 0)
                .ok_or_else(|| dec(e));
        }
        Err(e) => return Err(dec(e)),
    };
    let (w, h) = decoder.dimensions();
    // As decoding it would say ([`decode_rgb`]): a frame of no size is not a frame, and the
    // size read here is what a start is checked against.
    if w == 0 || h == 0 {
        return Err(FrameError::Decode {
            path: p.display().to_string(),
            msg: format!("an empty image ({w}x{h})"),
        });
    }
    Ok(shown_size(w, h, decoder.orientation().map_err(dec)?))
}

/// The frames of an image directory, decoded lazily.
#[derive(Debug)]
pub(crate) struct DirSource {
    files: Vec<PathBuf>,
    next: usize,
    size: (u32, u32),
    notes: Vec<String>,
}

impl DirSource {
    /// Lists the directory and reads the size of the first image.
    pub(crate) fn open(dir: &Path) -> Result<Self, FrameError> {
        if !dir.is_dir() {
            return Err(FrameError::NotFound {
                path: dir.display().to_string(),
            });
        }
        let scan = scan(dir)?;
        let notes = folder_notes(dir, &scan);
        let files: Vec<PathBuf> = scan.frames.into_iter().map(|(_, p)| p).collect();
        let first = files.first().ok_or_else(|| FrameError::NoImages {
            path: dir.display().to_string(),
        })?;
        let size = image_size(first)?;
        Ok(Self {
            files,
            next: 0,
            size,
            notes,
        })
    }

    /// What a user should hear about the folder before it is tracked: where the frames'
    /// numbering skips (the rows are numbered as read, so past a gap they run behind the
    /// files' numbers, and a truth file per frame no longer lines up), and images of formats
    /// this source does not read, left out.
    pub(crate) fn notes(&self) -> &[String] {
        &self.notes
    }

    /// The size of every frame (that of the first).
    pub(crate) fn size(&self) -> (u32, u32) {
        self.size
    }

    /// The number of frames.
    pub(crate) fn len(&self) -> usize {
        self.files.len()
    }

    /// Passes over the next frame without decoding it; `false` after the last.
    pub(crate) fn skip_frame(&mut self) -> bool {
        let more = self.next < self.files.len();
        self.next += usize::from(more);
        more
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
    fn gaps_in_the_numbering_are_found_between_like_names() {
        let names = [
            "0001.jpg",
            "0002.jpg",
            "0004.jpg",
            "0005.jpg",
            "0009.jpg",
            "img7.png",
            "img8.png",
            "img10.png",
            "x.png",
            "y.png",
        ];
        assert_eq!(
            numbering_gaps(&names),
            [
                ("0002.jpg".to_string(), "0004.jpg".to_string()),
                ("0005.jpg".to_string(), "0009.jpg".to_string()),
                ("img8.png".to_string(), "img10.png".to_string()),
            ]
        );
        // Timestamps (TUM's, EuRoC's) and a constant stride are no numbering by frame.
        let stamps = [
            "1305031102.175304.png",
            "1305031102.211214.png",
            "1305031102.243211.png",
        ];
        assert!(numbering_gaps(&stamps).is_empty());
        let euroc = ["1403636579763555584.png", "1403636579813555456.png"];
        assert!(numbering_gaps(&euroc).is_empty());
        let fifth = ["0005.png", "0010.png", "0015.png", "0025.png"];
        assert!(numbering_gaps(&fifth).is_empty());
        // Other names between, another extension, a repeat, a number past u64: not gaps.
        for pair in [
            ["0001.jpg", "0003.png"],
            ["a1.png", "b3.png"],
            ["7.png", "007.png"],
            ["1.png", "99999999999999999999999.png"],
            ["frame.png", "frame2.png"],
        ] {
            assert!(numbering_gaps(&pair).is_empty(), "{pair:?}");
        }
        assert_eq!(
            last_number("cam2_0012.png"),
            Some(("cam2_", "0012", ".png"))
        );
        assert_eq!(last_number("none.png"), None);
    }

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
        // SOI, an APP segment whose payload holds marker-like bytes, SOS with its header,
        // entropy data with a stuffed FF and a restart, EOI.
        let head = [0xFF, 0xD8, 0xFF, 0xE1, 0x00, 0x06, 0xFF, 0xD9, 0xFF, 0xDA];
        let scan = [
            0xFF, 0xDA, 0x00, 0x03, 0x01, 7, 0xFF, 0x00, 8, 0xFF, 0xD3, 9,
        ];
        let whole = [&head[..], &scan, &[0xFF, 0xD9]].concat();
        assert!(jpeg_scan_ends(&whole));
        for cut in 1..whole.len() {
            assert!(!jpeg_scan_ends(&whole[..cut]), "cut at {cut}");
        }
        // A progressive image: two scans with a table between them.
        let second = [
            &head[..],
            &scan,
            &[0xFF, 0xC4, 0x00, 0x02],
            &scan,
            &[0xFF, 0xD9],
        ]
        .concat();
        assert!(jpeg_scan_ends(&second));
        // Whatever follows the end is not looked at, marker-like bytes included.
        for tail in [
            &b"camera trailer"[..],
            &[0xFF, 0xDA, 0x00],
            &[0xFF, 0xD8, 0xFF, 0xDA],
        ] {
            assert!(jpeg_scan_ends(&[&whole[..], tail].concat()), "{tail:?}");
        }
        assert!(!jpeg_scan_ends(&[]));
        assert!(!jpeg_scan_ends(b"not a jpeg"));
        // Decoders read past stray bytes between segments and fill bytes before a restart.
        let stray = [&head[..], &[0, 0], &scan, &[0xFF, 0xD9]].concat();
        assert!(jpeg_scan_ends(&stray));
        let filled = [
            &head[..],
            &scan[..10],
            &[0xFF, 0xFF, 0xD4, 5],
            &[0xFF, 0xD9],
        ]
        .concat();
        assert!(jpeg_scan_ends(&filled));
        assert!(!jpeg_scan_ends(&filled[..filled.len() - 2]));
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

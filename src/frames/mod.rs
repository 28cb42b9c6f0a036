//! Frame sources: a streaming iterator of RGB8 frames from an image directory, a `.y4m` file,
//! or any other video through an `ffmpeg` child process. Never the whole video in memory:
//! each frame is decoded when the iterator asks for it.
//!
//! ```no_run
//! use pftrack::frames::{open, SourceOptions};
//! let opts = SourceOptions { resize: Some((128, 96)) };
//! let mut src = open(std::path::Path::new("clip.mp4"), &opts)?;
//! println!("{} ({:?})", src.describe(), src.size());
//! for warning in src.caveats() {
//!     eprintln!("warning: {warning}"); // interlaced, non-square pixels, a gap in a folder
//! }
//! for frame in src.by_ref() {
//!     let frame = frame?; // an RgbImage of 128x96
//! #   let _ = frame;
//! }
//! // A damaged or cut video ends with the frames it gave: say so.
//! if let Some(short) = src.shortfall() {
//!     eprintln!("warning: {short}");
//! }
//! # Ok::<(), pftrack::frames::FrameError>(())
//! ```
//!
//! [`open`] picks the kind: a directory is an image sequence ([`dir`]), a `.y4m` file goes
//! through the project's own parser ([`y4m`]), anything else through ffmpeg ([`ffmpeg`]).
//! After the first error the iterator ends. A source that ends before its first frame is an
//! error ([`FrameError::NoFrames`]).

pub mod dir;
pub mod exposure;
pub mod ffmpeg;
pub mod gray;
pub mod resize;
pub mod view;
pub mod y4m;

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

pub use ffmpeg::FfmpegTools;
pub use gray::GrayF32;
pub use resize::{
    Rescale, WORKING_MIN_SEMI_AXIS, WORKING_SEMI_AXIS, WORKING_SIDE, resize, resize_bilinear,
    working_size,
};
pub use view::{FrameView, PixelFormat};
pub use y4m::{Y4mHeader, Y4mReader};

/// One video frame, 8-bit RGB.
pub type Frame = image::RgbImage;

/// The hint printed when ffmpeg is needed but absent.
pub const FFMPEG_HINT: &str = "install ffmpeg (Debian: apt-get install ffmpeg)";

/// Errors of the frame sources.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// The input could not be read. (The cause is part of the message, not a separate
    /// `source()`, so a printed error chain says it once.)
    #[error("{path}: {cause}")]
    Io {
        /// The file or directory.
        path: String,
        /// The cause.
        cause: std::io::Error,
    },
    /// The input does not exist.
    #[error("{path}: no such file or directory")]
    NotFound {
        /// The path given.
        path: String,
    },
    /// A directory with no image files in it.
    #[error("{path}: no image files ({}) in the directory", dir::IMAGE_EXTENSIONS.join(", "))]
    NoImages {
        /// The directory.
        path: String,
    },
    /// An image file failed to decode.
    #[error("{path}: cannot decode the frame: {msg}")]
    Decode {
        /// The image file.
        path: String,
        /// The decoder's message.
        msg: String,
    },
    /// A frame whose size differs from the first frame's.
    #[error(
        "{path}: frame is {}x{}, but the sequence is {}x{} (the size of its first frame)",
        found.0, found.1, expected.0, expected.1
    )]
    SizeMismatch {
        /// The offending frame.
        path: String,
        /// Its size.
        found: (u32, u32),
        /// The size of the first frame.
        expected: (u32, u32),
    },
    /// A malformed or unsupported y4m stream.
    #[error("{path}: y4m: {msg}")]
    Y4m {
        /// The file.
        path: String,
        /// What is wrong.
        msg: String,
    },
    /// The input ends inside a frame.
    #[error("{path}: truncated: frame {frame} is incomplete ({msg})")]
    Truncated {
        /// The file.
        path: String,
        /// Index of the incomplete frame (from 0).
        frame: usize,
        /// What was missing.
        msg: String,
    },
    /// ffmpeg (or ffprobe) is not on `PATH`.
    #[error("{path}: reading a video needs `{program}`, which is not found: {FFMPEG_HINT}")]
    FfmpegMissing {
        /// The video to be read.
        path: String,
        /// The program that could not be started.
        program: String,
    },
    /// ffmpeg or ffprobe failed.
    #[error("{path}: {msg}")]
    Ffmpeg {
        /// The input.
        path: String,
        /// Exit status and the last line of its stderr.
        msg: String,
    },
    /// The source ended before its first frame.
    #[error("{path}: no frames")]
    NoFrames {
        /// The input.
        path: String,
    },
    /// Frames larger than a source reads ([`y4m::MAX_DECODE_PIXELS`], as stored) or than it
    /// delivers ([`y4m::MAX_PIXELS`], after [`SourceOptions::resize`]).
    #[error(
        "{path}: frames of {}x{} are more than the {limit} pixels a frame may have{}",
        size.0,
        size.1,
        if *resizable { "; scale them down (SourceOptions::resize)" } else { "" }
    )]
    TooLarge {
        /// The input.
        path: String,
        /// The frames' size.
        size: (u32, u32),
        /// The bound passed.
        limit: u64,
        /// Whether scaling the frames down would do (the stored size was within bounds).
        resizable: bool,
    },
    /// A pixel buffer that holds no frame of the size and layout given
    /// ([`view::FrameView::new`]).
    #[error("frame buffer: {msg}")]
    BadView {
        /// What is wrong.
        msg: String,
    },
    /// A bad `WxH` size.
    #[error("bad size '{input}': {msg}")]
    BadSize {
        /// The text given.
        input: String,
        /// What is wrong.
        msg: String,
    },
}

impl FrameError {
    pub(crate) fn io(path: impl AsRef<Path>, cause: std::io::Error) -> Self {
        Self::Io {
            path: path.as_ref().display().to_string(),
            cause,
        }
    }
}

/// How to read a source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SourceOptions {
    /// Resize every frame to `(width, height)` ([`resize()`]: the mean over each pixel's
    /// footprint along an axis that shrinks, bilinear along one that grows).
    pub resize: Option<(u32, u32)>,
}

/// Parses a size written `WxH` (e.g. `128x96`; `X` also accepted), both positive, within the
/// largest frame a source reads: sides of at most [`y4m::MAX_SIDE`] and at most
/// [`y4m::MAX_PIXELS`] pixels in all.
pub fn parse_size(s: &str) -> Result<(u32, u32), FrameError> {
    let (w, h) = parse_wxh(s)?;
    match size_limit(w, h) {
        Some(msg) => Err(FrameError::BadSize {
            input: s.to_string(),
            msg,
        }),
        None => Ok((w, h)),
    }
}

/// What is wrong with a frame size of `w x h` beyond the largest a source reads, if anything.
fn size_limit(w: u32, h: u32) -> Option<String> {
    if w > y4m::MAX_SIDE || h > y4m::MAX_SIDE {
        Some(format!("sides of at most {} pixels", y4m::MAX_SIDE))
    } else if u64::from(w) * u64::from(h) > y4m::MAX_PIXELS {
        Some(format!("at most {} pixels in all", y4m::MAX_PIXELS))
    } else {
        None
    }
}

/// Parses a size written `WxH` (e.g. `128x96`; `X` also accepted), both positive, with no
/// upper bound: for callers that bound the sides themselves (`synth`, `bench`).
pub fn parse_wxh(s: &str) -> Result<(u32, u32), FrameError> {
    let bad = |msg: &str| FrameError::BadSize {
        input: s.to_string(),
        msg: msg.to_string(),
    };
    let (w, h) = s
        .trim()
        .split_once(['x', 'X'])
        .ok_or_else(|| bad("expected WIDTHxHEIGHT, e.g. 128x96"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|_| bad("expected WIDTHxHEIGHT, e.g. 128x96"))
    };
    let (w, h) = (num(w)?, num(h)?);
    if w == 0 || h == 0 {
        return Err(bad("width and height must be positive"));
    }
    Ok((w, h))
}

/// The kind of source behind a [`FrameSource`].
enum Inner {
    Dir(dir::DirSource),
    Y4m(Box<Y4mReader<Box<dyn BufRead + Send>>>, Option<usize>),
    Ffmpeg(Box<ffmpeg::FfmpegSource>),
}

impl std::fmt::Debug for Inner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Inner::Dir(d) => f.debug_tuple("Dir").field(d).finish(),
            Inner::Y4m(r, hint) => f
                .debug_struct("Y4m")
                .field("header", r.header())
                .field("frames_read", &r.frames_read())
                .field("len_hint", hint)
                .finish(),
            Inner::Ffmpeg(x) => f.debug_tuple("Ffmpeg").field(x).finish(),
        }
    }
}

/// A stream of frames (see the module docs). Iterate it for `Result<Frame, FrameError>`.
#[derive(Debug)]
pub struct FrameSource {
    inner: Inner,
    path: String,
    native: (u32, u32),
    out: (u32, u32),
    produced: usize,
    done: bool,
    /// Whether the stream ended normally (not by an error).
    ended: bool,
    /// Where a y4m stream ended inside a frame after complete ones: that frame's index and
    /// what was missing ([`FrameSource::shortfall`]).
    cut: Option<(usize, String)>,
    /// For a y4m file ffmpeg decodes: its whole frames, and where it ends inside one, as its
    /// length says ([`y4m::file_extent`]): ffmpeg ends such a file without a word.
    y4m_extent: Option<y4m::FileExtent>,
}

/// The pixels of `img`, three bytes each, row after row: its buffer's first `3 w h` bytes.
/// An `RgbImage` may hold a longer buffer (`ImageBuffer::from_raw` takes one at least that
/// long), and what follows is no pixel of it: every pass over an image's bytes as a whole
/// goes through here.
pub fn rgb_bytes(img: &image::RgbImage) -> &[u8] {
    let raw = img.as_raw();
    let len = 3 * img.width() as usize * img.height() as usize;
    &raw[..len.min(raw.len())]
}

/// The path [`open`] reads as standard input, a y4m stream (`ffmpeg ... -f yuv4mpegpipe - |
/// pftrack track - ...`).
pub const STDIN: &str = "-";

/// Opens a frame source: a directory → image sequence; a `.y4m` file (extension
/// case-insensitive) → the y4m parser (through ffmpeg where it names a colour space the
/// parser does not read); [`STDIN`] (`-`) → the y4m parser on standard input;
/// anything else → ffmpeg.
pub fn open(path: &Path, opts: &SourceOptions) -> Result<FrameSource, FrameError> {
    if path == Path::new(STDIN) {
        let stdin: Box<dyn BufRead + Send> =
            Box::new(BufReader::with_capacity(1 << 16, std::io::stdin()));
        FrameSource::from_y4m_reader(stdin, "standard input", opts)
    } else if path.is_dir() {
        FrameSource::from_dir(path, opts)
    } else {
        let y4m = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("y4m"));
        if y4m && !y4m_for_ffmpeg(path) {
            return FrameSource::from_y4m(path, opts);
        }
        let mut source = FrameSource::from_video(path, opts, &FfmpegTools::default())?;
        if y4m {
            source.y4m_extent = y4m::file_extent(path);
        }
        Ok(source)
    }
}

/// Whether the y4m file `path` is one for ffmpeg rather than this crate's reader: its header
/// names a colour space the reader does not read ([`y4m::unsupported_colour_space`]) and
/// ffmpeg is there to read it. Any failure to read the header leaves the file to the reader,
/// whose error says what is wrong.
fn y4m_for_ffmpeg(path: &Path) -> bool {
    // A named pipe would lose the bytes read here: only a file is looked into.
    if !path.is_file() {
        return false;
    }
    let Ok(file) = File::open(path) else {
        return false;
    };
    let mut line = String::new();
    let read = std::io::Read::take(BufReader::new(file), 4096).read_line(&mut line);
    read.is_ok()
        && y4m::unsupported_colour_space(line.trim_end()).is_some()
        && FfmpegTools::default().available()
}

/// Which field of an interlaced frame was taken first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldOrder {
    /// The top field (the even rows, counting from 0).
    TopFirst,
    /// The bottom field.
    BottomFirst,
    /// Some frames interlaced, some not, or the order changing (y4m `Im`).
    Mixed,
}

impl FieldOrder {
    fn describe(self) -> &'static str {
        match self {
            Self::TopFirst => "interlaced, top field first",
            Self::BottomFirst => "interlaced, bottom field first",
            Self::Mixed => "interlaced in part",
        }
    }
}

/// How a source's pictures are stored, where that misleads the tracker unless the user acts:
/// interlaced fields and pixels that are not square. Unknown reads as progressive and square.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Layout {
    /// The field order, when the frames are interlaced.
    pub interlaced: Option<FieldOrder>,
    /// A pixel's width to its height, `(n, d)` with both positive, when the source states it.
    pub pixel_aspect: Option<(u32, u32)>,
}

/// A frame size of square pixels for a picture `picture` times as wide as tall: at `height`
/// rows, scaled down (both sides) where that would pass [`y4m::MAX_SIDE`] or
/// [`y4m::MAX_PIXELS`], the sizes `--resize` takes; `None` where a side would then be under
/// a pixel (a shape of thousands to one, which no such size gives square).
fn square_size(picture: f64, height: u32) -> Option<(u32, u32)> {
    let h = f64::from(height);
    let w = h * picture;
    let side = f64::from(y4m::MAX_SIDE);
    let fit = (side / w)
        .min(side / h)
        .min((y4m::MAX_PIXELS as f64 / (w * h)).sqrt());
    // Scaled down, both sides round down, so that rounding cannot pass the limits again.
    let size = |v: f64| {
        let v = if fit < 1.0 {
            (v * fit).floor()
        } else {
            v.round()
        };
        (v >= 1.0).then_some(v as u32)
    };
    Some((size(w)?, size(h)?))
}

impl Layout {
    /// One line for each way `path`'s frames, stored at `native` size and delivered at `out`,
    /// break the tracker's assumptions: each frame one instant, and pixels square as tracked
    /// (within 1 %, or a pixel's rounding), the stored pixels being of the stated shape or,
    /// unstated, square; the line names a `--resize` that squares them at the delivered
    /// height. Empty when neither applies.
    pub fn caveats(&self, path: &str, native: (u32, u32), out: (u32, u32)) -> Vec<String> {
        let mut lines = Vec::new();
        if let Some(order) = self.interlaced {
            lines.push(format!(
                "{path}: the frames are {}: each is tracked as one picture, though its two \
                 fields were taken half a frame apart; deinterlace a moving target first \
                 (ffmpeg -vf bwdif)",
                order.describe()
            ));
        }
        // A stated shape, else square; the picture is W n/d by H in square units. Delivered
        // at w x h its pixels are square when w/h matches, within 1 % or the rounding of
        // either side to whole pixels.
        let (n, d) = self.pixel_aspect.unwrap_or((1, 1));
        let (nw, nh) = (f64::from(native.0), f64::from(native.1));
        let (w, h) = (f64::from(out.0), f64::from(out.1));
        let picture = nw * f64::from(n) / f64::from(d) / nh;
        let square = ((w / h) / picture - 1.0).abs() <= 0.01
            || (w - h * picture).abs() <= 0.5
            || (h - w / picture).abs() <= 0.5;
        if !square {
            let shape = picture / (w / h);
            let what = if out == native {
                format!("its pixels are {n}:{d}")
            } else {
                format!(
                    "resized to {}x{}, its pixels are {shape:.2} times as wide as tall",
                    out.0, out.1
                )
            };
            let fix = match square_size(picture, out.1) {
                Some((sw, sh)) => format!("--resize {sw}x{sh} makes them square"),
                None => format!(
                    "no --resize within {} pixels a side makes them square (is the stated \
                     shape right?)",
                    y4m::MAX_SIDE
                ),
            };
            lines.push(format!(
                "{path}: {what}, not square, and the ellipse and the rotation assume square \
                 ones; {fix}"
            ));
        }
        lines
    }
}

impl FrameSource {
    /// The source over `inner`, whose frames are stored at `native` size: an error when that is
    /// more than [`y4m::MAX_DECODE_PIXELS`], or the size delivered (after the resize) more than
    /// [`y4m::MAX_PIXELS`].
    fn new(
        inner: Inner,
        path: &Path,
        native: (u32, u32),
        opts: &SourceOptions,
    ) -> Result<Self, FrameError> {
        let path = path.display().to_string();
        if u64::from(native.0) * u64::from(native.1) > y4m::MAX_DECODE_PIXELS {
            return Err(FrameError::TooLarge {
                path,
                size: native,
                limit: y4m::MAX_DECODE_PIXELS,
                resizable: false,
            });
        }
        let out = delivered_size(&path, native, opts.resize)?;
        Ok(Self {
            inner,
            path,
            native,
            out,
            produced: 0,
            done: false,
            ended: false,
            cut: None,
            y4m_extent: None,
        })
    }

    /// An image directory (see [`dir`]).
    pub fn from_dir(path: &Path, opts: &SourceOptions) -> Result<Self, FrameError> {
        check_resize(opts)?;
        let d = dir::DirSource::open(path)?;
        let size = d.size();
        Self::new(Inner::Dir(d), path, size, opts)
    }

    /// A y4m file (see [`y4m`]).
    pub fn from_y4m(path: &Path, opts: &SourceOptions) -> Result<Self, FrameError> {
        check_resize(opts)?;
        let file = File::open(path).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                FrameError::NotFound {
                    path: path.display().to_string(),
                }
            } else {
                FrameError::io(path, e)
            }
        })?;
        let file_len = file.metadata().map(|m| m.len()).ok();
        let reader: Box<dyn BufRead + Send> = Box::new(BufReader::with_capacity(1 << 16, file));
        Self::y4m(reader, &path.display().to_string(), opts, file_len)
    }

    /// A y4m stream from any reader (a pipe, a socket, standard input), read as it comes;
    /// `name` labels the source in errors and in [`FrameSource::describe`]. Its length is
    /// not known in advance.
    pub fn from_y4m_reader(
        reader: Box<dyn BufRead + Send>,
        name: &str,
        opts: &SourceOptions,
    ) -> Result<Self, FrameError> {
        check_resize(opts)?;
        Self::y4m(reader, name, opts, None)
    }

    /// A y4m stream whose size in bytes, when known (`len`), hints at its frame count.
    fn y4m(
        reader: Box<dyn BufRead + Send>,
        name: &str,
        opts: &SourceOptions,
        len: Option<u64>,
    ) -> Result<Self, FrameError> {
        let r = Y4mReader::new(reader, name)?;
        let h = r.header();
        let size = (h.width, h.height);
        // A hint: assumes bare `FRAME\n` headers.
        let hint = len.map(|n| {
            (n as usize).saturating_sub(r.header_len()) / (h.frame_bytes() + "FRAME\n".len())
        });
        Self::new(Inner::Y4m(Box::new(r), hint), Path::new(name), size, opts)
    }

    /// Any video ffmpeg reads, with the given programs (see [`ffmpeg`]).
    pub fn from_video(
        path: &Path,
        opts: &SourceOptions,
        tools: &FfmpegTools,
    ) -> Result<Self, FrameError> {
        check_resize(opts)?;
        let f = ffmpeg::FfmpegSource::open(path, tools)?;
        let size = f.size();
        Self::new(Inner::Ffmpeg(Box::new(f)), path, size, opts)
    }

    /// Output frame size `(width, height)`, after any resize.
    pub fn size(&self) -> (u32, u32) {
        self.out
    }

    /// Size of the frames as stored, before any resize.
    pub fn native_size(&self) -> (u32, u32) {
        self.native
    }

    /// Resizes the frames delivered from now on to `size` ([`resize()`]), or delivers them at
    /// the stored size with `None`: for a size chosen once the first frame's target is known
    /// ([`working_size`]), on a source that cannot be opened again (standard input). A size
    /// of no pixels or past [`parse_size`]'s bounds is refused, as [`open`] refuses it, and
    /// the source left as it was.
    pub fn set_resize(&mut self, size: Option<(u32, u32)>) -> Result<(), FrameError> {
        check_resize(&SourceOptions { resize: size })?;
        self.out = delivered_size(&self.path, self.native, size)?;
        Ok(())
    }

    /// The number of frames, when known in advance (image count; y4m estimate from the file
    /// size; the container's count for ffmpeg). Only a hint: the stream decides.
    pub fn len_hint(&self) -> Option<usize> {
        match &self.inner {
            Inner::Dir(d) => Some(d.len()),
            Inner::Y4m(_, hint) => *hint,
            Inner::Ffmpeg(f) => f
                .len_hint()
                .or(self.y4m_extent.as_ref().map(|e| e.complete)),
        }
    }

    /// Frames read from the input so far: those delivered and those passed over with
    /// [`FrameSource::skip_frames`], so the next frame delivered is frame `frames_read()` of the
    /// input (counting from 0).
    pub fn frames_read(&self) -> usize {
        self.produced
    }

    /// Once a video has ended normally: one line saying it gave fewer frames than its
    /// container declares while ffmpeg reported errors (a truncated file, an undecodable
    /// frame), with ffmpeg's first complaint and what that does to the numbering (frames are
    /// counted as they are decoded: past one lost mid-file, a frame's number is lower than
    /// its place in the video); for a y4m stream that ended inside a frame after complete ones,
    /// where it ended (the frames before it are all delivered); `None` for a complete video,
    /// before the end, and for image folders, whose reading fails on a bad frame. A caller
    /// that reports the frames as the whole video should say this too: ffmpeg ends a damaged
    /// file with success.
    /// Fewer frames without a complaint are no shortfall: a clip cut without re-encoding
    /// keeps samples before its start that are decoded but never shown. A container that
    /// declares no count (Matroska, MPEG-TS) cannot be compared: there any complaint is said,
    /// since the frames decoded may not be all of it (a Matroska file cut in half gave 57 of
    /// 180 frames, with success).
    pub fn shortfall(&self) -> Option<String> {
        if let Some((frame, msg)) = &self.cut {
            return Some(format!(
                "{}: the stream ends inside frame {frame} ({msg}); the {} complete frames \
                 before it were read",
                self.path, self.produced
            ));
        }
        let Inner::Ffmpeg(f) = &self.inner else {
            return None;
        };
        if let Some(extent) = self.y4m_extent.as_ref().filter(|_| self.ended) {
            if self.produced < extent.complete {
                return Some(format!(
                    "{}: ffmpeg decoded {} of the {} whole frames the file holds{}",
                    self.path,
                    self.produced,
                    extent.complete,
                    f.complaint().map(|c| format!(" ({c})")).unwrap_or_default()
                ));
            }
            if let Some(msg) = extent
                .cut
                .as_ref()
                .filter(|_| self.produced == extent.complete)
            {
                return Some(format!(
                    "{}: the stream ends inside frame {} ({msg}); the {} complete frames \
                     before it were read",
                    self.path, extent.complete, self.produced
                ));
            }
        }
        let complaint = f.complaint()?;
        if !self.ended {
            return None;
        }
        match f.len_hint() {
            Some(declared) if self.produced < declared => Some(format!(
                "{}: ffmpeg decoded {} of the {declared} frames the file declares, and \
                 complained ({complaint}: not necessarily about the missing frame, which a \
                 container may also mark to be skipped); frames are numbered as decoded, so \
                 if one was lost before the end, the numbers after it run behind the video's",
                self.path, self.produced
            )),
            Some(_) => None,
            None => Some(format!(
                "{}: ffmpeg reported an error ({complaint}) and the file declares no frame \
                 count: the {} frames decoded may not be all of it",
                self.path, self.produced
            )),
        }
    }

    /// Interlaced fields and the shape of a pixel, where the source states them (y4m's `I` and
    /// `A` tags, ffprobe's field order and sample aspect ratio); image folders read as
    /// progressive and square.
    pub fn layout(&self) -> Layout {
        match &self.inner {
            Inner::Dir(_) => Layout::default(),
            Inner::Y4m(r, _) => r.header().layout(),
            Inner::Ffmpeg(f) => f.layout(),
        }
    }

    /// One warning line for each way this source's frames break the tracker's assumptions
    /// (see [`Layout::caveats`]; for an image folder, a gap in its numbering and images of
    /// formats it leaves out): say them before tracking.
    pub fn caveats(&self) -> Vec<String> {
        let mut lines = self.layout().caveats(&self.path, self.native, self.out);
        if let Inner::Dir(d) = &self.inner {
            lines.extend(d.notes().iter().cloned());
        }
        lines
    }

    /// One line saying what this source is.
    pub fn describe(&self) -> String {
        let (w, h) = self.native;
        let n = self.len_hint().map_or_else(
            || "unknown frame count".to_string(),
            |n| format!("{n} frames"),
        );
        let mut s = match &self.inner {
            Inner::Dir(_) => format!("image directory {} ({n}, {w}x{h})", self.path),
            Inner::Y4m(r, _) => {
                let hd = r.header();
                let fps = hd
                    .frame_rate
                    .map_or_else(String::new, |(a, b)| format!(", {a}:{b} fps"));
                format!(
                    "y4m {} ({n}, {w}x{h}, C{}{fps})",
                    self.path,
                    hd.chroma.tag()
                )
            }
            Inner::Ffmpeg(_) => format!("video {} via ffmpeg ({n}, {w}x{h})", self.path),
        };
        if self.out != self.native {
            s.push_str(&format!(", resized to {}x{}", self.out.0, self.out.1));
        }
        s
    }

    /// Passes over up to `n` frames without delivering them, for a track that starts later
    /// in the input; returns how many were passed over, fewer when the input ends first.
    /// Images in a folder are not decoded, nor are a y4m stream's frames converted or a
    /// passed-over frame resized (a video's are decoded by ffmpeg all the same). The frames
    /// delivered after it keep their place in the input ([`FrameSource::frames_read`]). An
    /// input with no frames at all is [`FrameError::NoFrames`], as for the first
    /// [`Iterator::next`]; a y4m stream cut inside a frame ends there, as it does when read
    /// ([`FrameSource::shortfall`]).
    pub fn skip_frames(&mut self, n: usize) -> Result<usize, FrameError> {
        let mut skipped = 0;
        while skipped < n && !self.done {
            let read = match &mut self.inner {
                Inner::Dir(d) => Ok(d.skip_frame().then_some(1)),
                Inner::Y4m(r, _) => r.skip_frame().map(|more| more.then_some(1)),
                // All at once: a decode not yet read from is started past them.
                Inner::Ffmpeg(f) => f.skip(n - skipped).map(|k| (k > 0).then_some(k)),
            };
            if let Some(k) = self.advance(read)? {
                // `advance` counted one of the `k`.
                self.produced += k - 1;
                skipped += k;
            }
        }
        Ok(skipped)
    }

    /// Counts a frame read from the input (`Ok(Some(_))`), or ends the source: at the end of
    /// the input (`Ok(None)`; with no frame read at all, [`FrameError::NoFrames`]), where a
    /// y4m stream is cut inside a frame after complete ones (`Ok(None)`, kept for
    /// [`FrameSource::shortfall`]: it ends after its complete frames, as a damaged video does
    /// through ffmpeg; with none complete it is the error), or on an error.
    fn advance<T>(&mut self, read: Result<Option<T>, FrameError>) -> Result<Option<T>, FrameError> {
        match read {
            Ok(Some(x)) => {
                self.produced += 1;
                Ok(Some(x))
            }
            Ok(None) => {
                self.done = true;
                self.ended = true;
                if self.produced == 0 {
                    return Err(FrameError::NoFrames {
                        path: self.path.clone(),
                    });
                }
                Ok(None)
            }
            Err(FrameError::Truncated { frame, msg, .. })
                if matches!(self.inner, Inner::Y4m(..)) && self.produced > 0 =>
            {
                self.done = true;
                self.ended = true;
                self.cut = Some((frame, msg));
                Ok(None)
            }
            Err(e) => {
                self.done = true;
                Err(e)
            }
        }
    }

    fn next_native(&mut self) -> Result<Option<Frame>, FrameError> {
        match &mut self.inner {
            Inner::Dir(d) => d.next_frame(),
            Inner::Y4m(r, _) => r.read_frame(),
            Inner::Ffmpeg(f) => f.next_frame(),
        }
    }
}

/// The size frames stored at `native` size are delivered at under `resize`: an error past
/// [`y4m::MAX_PIXELS`] (one a resize would mend where none was asked for).
fn delivered_size(
    path: &str,
    native: (u32, u32),
    resize: Option<(u32, u32)>,
) -> Result<(u32, u32), FrameError> {
    let out = resize.unwrap_or(native);
    if u64::from(out.0) * u64::from(out.1) > y4m::MAX_PIXELS {
        return Err(FrameError::TooLarge {
            path: path.to_string(),
            size: out,
            limit: y4m::MAX_PIXELS,
            resizable: resize.is_none(),
        });
    }
    Ok(out)
}

fn check_resize(opts: &SourceOptions) -> Result<(), FrameError> {
    let bad = |w: u32, h: u32, msg: &str| {
        Err(FrameError::BadSize {
            input: format!("{w}x{h}"),
            msg: msg.into(),
        })
    };
    match opts.resize {
        Some((w, h)) if w == 0 || h == 0 => bad(w, h, "width and height must be positive"),
        // As `parse_size` and the y4m reader bound them (a 100000x100000 frame aborted on
        // its 30 GB allocation at the first frame, and 32768x32768 was killed for memory).
        Some((w, h)) => match size_limit(w, h) {
            Some(msg) => bad(w, h, &msg),
            None => Ok(()),
        },
        None => Ok(()),
    }
}

impl Iterator for FrameSource {
    type Item = Result<Frame, FrameError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let read = self.next_native();
        match self.advance(read) {
            Ok(Some(f)) if self.out == self.native => Some(Ok(f)),
            Ok(Some(f)) => Some(Ok(resize(&f, self.out.0, self.out.1))),
            Ok(None) => None,
            Err(e) => Some(Err(e)),
        }
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (0, None)
    }
}

impl std::iter::FusedIterator for FrameSource {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caveats_follow_the_pixel_shape_after_the_resize() {
        let wide = Layout {
            interlaced: None,
            pixel_aspect: Some((12, 11)),
        };
        // 352 × 12/11 = 384: stored at 352x288, the pixels are 12:11.
        let c = wide.caveats("v", (352, 288), (352, 288));
        assert_eq!(c.len(), 1, "{c:?}");
        assert!(c[0].starts_with("v: its pixels are 12:11"), "{}", c[0]);
        assert!(c[0].contains("--resize 384x288"), "{}", c[0]);
        assert!(wide.caveats("v", (352, 288), (384, 288)).is_empty());
        // Within 1 % of square: 383 wide is 0.3 % off.
        assert!(wide.caveats("v", (352, 288), (383, 288)).is_empty());
        // Halved on both axes, still 12:11: squared at the height the user chose.
        let c = wide.caveats("v", (352, 288), (176, 144));
        assert_eq!(c.len(), 1, "{c:?}");
        assert!(
            c[0].starts_with("v: resized to 176x144, its pixels are 1.09 times as wide as tall")
                && c[0].contains("--resize 192x144"),
            "{}",
            c[0]
        );
        // A resize that distorts pixels stored square, stated so or not.
        for l in [
            Layout::default(),
            Layout {
                interlaced: None,
                pixel_aspect: Some((1, 1)),
            },
        ] {
            let c = l.caveats("v", (640, 480), (640, 240));
            assert_eq!(c.len(), 1, "{c:?}");
            assert!(
                c[0].contains("0.50 times as wide as tall") && c[0].contains("--resize 320x240"),
                "{}",
                c[0]
            );
            assert!(l.caveats("v", (640, 480), (320, 240)).is_empty());
        }
        // The size named is one --resize takes: 8K at 4:3 pixels is 10240 wide, 44 million
        // pixels; scaled down to 2^25 pixels in all.
        let c = Layout {
            interlaced: None,
            pixel_aspect: Some((4, 3)),
        }
        .caveats("v", (7680, 4320), (7680, 4320));
        let named = c[0]
            .split("--resize ")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap();
        let (w, h) = parse_size(named).unwrap();
        assert!(
            (f64::from(w) / f64::from(h) - 10240.0 / 4320.0).abs() < 1e-3,
            "{named}"
        );
        assert!(u64::from(w) * u64::from(h) > (1 << 25) - 10_000, "{named}");
        // Whatever the shape, the size named is one --resize takes (12:11 at 8K rounded both
        // sides up to 8067x4160, past 2^25), and its pixels are square.
        for (n, d) in [
            (12, 11),
            (2, 1),
            (64, 45),
            (16, 15),
            (5, 4),
            (6, 5),
            (32, 27),
            (3, 2),
        ] {
            for native in [(7680, 4320), (6144, 3160), (8192, 4096), (5760, 5760)] {
                let l = Layout {
                    interlaced: None,
                    pixel_aspect: Some((n, d)),
                };
                let c = l.caveats("v", native, native);
                let named = c[0].split("--resize ").nth(1).unwrap();
                let named = named.split(' ').next().unwrap();
                let (w, h) =
                    parse_size(named).unwrap_or_else(|e| panic!("{n}:{d} {native:?}: {e}"));
                assert!(
                    l.caveats("v", native, (w, h)).is_empty(),
                    "{n}:{d} {native:?} -> {named}"
                );
            }
        }
        // Tall pixels: 11:12 of 352 is 322.7.
        let tall = Layout {
            interlaced: None,
            pixel_aspect: Some((11, 12)),
        };
        let c = tall.caveats("v", (352, 288), (352, 288));
        assert!(c[0].contains("--resize 323x288"), "{}", c[0]);
        // A shape so far from square that no size --resize takes squares it names none
        // (32768x1 had been named, itself not square).
        for aspect in [(u32::MAX, 1), (100_000, 1), (1, 100_000)] {
            let c = Layout {
                interlaced: None,
                pixel_aspect: Some(aspect),
            }
            .caveats("v", (32, 24), (32, 24));
            assert_eq!(c.len(), 1, "{c:?}");
            assert!(c[0].contains("no --resize"), "{}", c[0]);
            assert!(!c[0].contains("--resize 3"), "{}", c[0]);
        }
        // Square pixels, stated or not, say nothing; nor does an unknown field order.
        for l in [
            Layout::default(),
            Layout {
                interlaced: None,
                pixel_aspect: Some((7, 7)),
            },
        ] {
            assert!(l.caveats("v", (352, 288), (352, 288)).is_empty(), "{l:?}");
        }
        let mixed = Layout {
            interlaced: Some(FieldOrder::Mixed),
            pixel_aspect: None,
        };
        let c = mixed.caveats("v", (8, 8), (8, 8));
        assert_eq!(c.len(), 1);
        assert!(c[0].contains("interlaced in part"), "{}", c[0]);
    }

    #[test]
    fn sources_can_move_to_another_thread() {
        fn assert_send<T: Send>() {}
        assert_send::<FrameSource>();
        assert_send::<FrameError>();
    }

    #[test]
    fn sizes() {
        assert_eq!(parse_size("128x96").unwrap(), (128, 96));
        assert_eq!(parse_size(" 160X120 ").unwrap(), (160, 120));
        for bad in [
            "", "128", "x96", "128x", "0x96", "128x0", "-1x5", "1.5x2", "axb", "9x9x9",
        ] {
            assert!(parse_size(bad).is_err(), "accepted {bad}");
            assert!(parse_wxh(bad).is_err(), "accepted {bad}");
        }
        assert_eq!(parse_size("32768x1").unwrap(), (32768, 1));
        let e = parse_size("32769x1").unwrap_err().to_string();
        assert!(e.contains("32768"), "{e}");
        assert_eq!(parse_wxh("100000x7").unwrap(), (100000, 7));
    }
}

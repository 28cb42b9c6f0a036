//! A YUV4MPEG2 (`.y4m`) reader, written for this project.
//!
//! Header: `YUV4MPEG2` then space-separated tags: `W` width, `H` height, `F` frame rate
//! `n:d` (`0:0`: unknown), `I` interlacing (`p t b m ?`: fields are delivered as the
//! interleaved frame, and [`super::FrameSource::caveats`] says so), `A` pixel aspect `n:d`,
//! `C` colour space, `X` extensions (`XCOLORRANGE=FULL` or `=LIMITED`, which ffmpeg writes,
//! is read; the others are ignored).
//! Colour spaces read: `420jpeg` (the default when `C` is absent), `420` (the same siting),
//! `420mpeg2`, `420paldv`, `444`, and `mono`; all 8-bit. Anything else (`422`, `411`,
//! `444alpha`, the high bit depths `...p10` etc.) is a clear [`FrameError::Y4m`] error here;
//! [`super::open`] reads such a file through ffmpeg instead (a stream on standard input it
//! cannot: the error names the conversion).
//!
//! Each frame is `FRAME` with optional parameters up to a newline, then the planes Y, Cb, Cr
//! (4:2:0 chroma planes are `ceil(W/2) × ceil(H/2)`). A partial frame at the end of the file
//! is a [`FrameError::Truncated`] error here, never a silently shorter video;
//! [`super::FrameSource`] ends such a stream after its complete frames and says where it was
//! cut ([`super::FrameSource::shortfall`]). A blank line after the last frame ends the stream
//! as its end would; anything else where a `FRAME` header belongs is an error.
//!
//! Colour conversion: ITU-R BT.601 (Kr = 0.299, Kb = 0.114), limited ("studio") range, the
//! y4m norm: Y in 16..235 and Cb, Cr in 16..240 map to full-range RGB 0..255 (values outside
//! are clipped). A header with `XCOLORRANGE=FULL` (ffmpeg's for `gray` and the `yuvj`
//! formats of JPEG and MJPEG sources) has Y and Cb, Cr over the whole 0..255 instead. 4:2:0 chroma is upsampled bilinearly with its siting: `420jpeg`/`420` chroma
//! sits between the luma samples in both directions, `420mpeg2` on the even luma columns
//! (and between rows); `420paldv` is read as sited on the even luma columns and rows (the
//! format alternates Cb and Cr rows, which this approximation ignores).

use std::io::{BufRead, Read};

use super::{Frame, FrameError};

/// The longest header or `FRAME` line accepted (bytes), so garbage input cannot make the
/// reader buffer a whole file looking for a newline.
const MAX_LINE: u64 = 4096;

/// The largest width or height accepted.
pub const MAX_SIDE: u32 = 1 << 15;

/// The most pixels a frame delivered to the tracker may have, after any resize (2^25, 33.5
/// million: 8K UHD's 7680x4320 fits). The tracker holds about 60 bytes a pixel of its frame
/// (measured peak resident memory of `pftrack track` at 2000x1500: 197 MB), so about 2 GB at
/// this bound; at 2^26, the bound before, an 8192x8192 track failed to allocate under a 4 GB
/// limit. Larger footage is read when scaled down to it ([`super::SourceOptions::resize`]).
pub const MAX_PIXELS: u64 = 1 << 25;

/// The most pixels a frame may have as stored (2^27, 134 million), so that neither a header
/// nor a file can make the reader allocate more than a few hundred megabytes for one: frames
/// up to this size are read, and scaled down to [`MAX_PIXELS`] by a resize.
pub const MAX_DECODE_PIXELS: u64 = 1 << 27;

/// The chroma layout of a y4m stream (the `C` tag).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chroma {
    /// 4:2:0, chroma between luma samples horizontally and vertically (`C420jpeg`, `C420`).
    C420Jpeg,
    /// 4:2:0, chroma on even luma columns, between rows (`C420mpeg2`).
    C420Mpeg2,
    /// 4:2:0 PAL DV (`C420paldv`), read as sited on even columns and rows.
    C420Paldv,
    /// 4:4:4, full-resolution chroma (`C444`).
    C444,
    /// Luma only (`Cmono`): grey frames.
    Mono,
}

/// The colour space a y4m header line names (its `C` tag's value) when this reader does
/// not read it (a `422`, `411`, `444alpha` or high-bit-depth stream); `None` for one it reads,
/// or a line that names none. [`super::open`] hands such a file to ffmpeg, which reads them.
pub fn unsupported_colour_space(header: &str) -> Option<&str> {
    header
        .split_ascii_whitespace()
        .skip(1)
        .find_map(|t| t.strip_prefix('C'))
        .filter(|v| Chroma::parse(v).is_none())
}

/// Bytes of one frame's pixel data in a colour space ffmpeg reads from y4m (its `C` tag's
/// value: `420jpeg`, `422`, `411`, `444alpha`, `mono16`, `420p10`, ...) at `w × h`; `None`
/// for a name it does not know. Samples above 8 bits take two bytes; chroma planes of a
/// subsampled format are rounded up (`ceil(W/2)`).
pub fn frame_bytes(colour_space: &str, w: u32, h: u32) -> Option<u64> {
    let (w, h) = (u64::from(w), u64::from(h));
    let bits = |rest: &str| -> Option<u64> {
        match rest {
            "" => Some(8),
            _ => rest
                .strip_prefix('p')
                .or(Some(rest))
                .and_then(|b| b.parse::<u64>().ok().filter(|b| (9..=16).contains(b))),
        }
    };
    let luma = w * h;
    // (luma planes, chroma planes of `cw × ch`, bits a sample).
    let (lumas, (cw, ch), depth) = if let Some(rest) = colour_space.strip_prefix("mono") {
        (1, (0, 0), bits(rest)?)
    } else {
        let (base, rest) = colour_space.split_at_checked(3)?;
        let chroma = match base {
            "420" => (w.div_ceil(2), h.div_ceil(2)),
            "422" => (w.div_ceil(2), h),
            "411" => (w.div_ceil(4), h),
            "444" => (w, h),
            _ => return None,
        };
        match (base, rest) {
            ("420", "jpeg" | "mpeg2" | "paldv") => (1, chroma, 8),
            ("444", "alpha") => (2, chroma, 8),
            _ if rest.is_empty() || rest.starts_with('p') => (1, chroma, bits(rest)?),
            _ => return None,
        }
    };
    // Checked: sides near `u32::MAX` pass `u64` (`None` then, as for an unknown space).
    luma.checked_mul(lumas)?
        .checked_add((cw * ch).checked_mul(2)?)?
        .checked_mul(if depth > 8 { 2 } else { 1 })
}

/// The complete frames of a y4m file, and where it ends inside one, found by walking its
/// `FRAME` headers with the pixel data's size ([`frame_bytes`]) and the file's length, none of
/// the pixels read: for a file another decoder reads (ffmpeg ends a y4m cut inside a frame
/// without a word).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileExtent {
    /// Whole frames in the file.
    pub complete: usize,
    /// What the frame after them lacks, when the file ends inside it.
    pub cut: Option<String>,
}

/// Walks the y4m file `path` as [`FileExtent`] says; `None` where it is no regular file (a
/// named pipe would lose the bytes read here), where the header cannot be read or names a
/// colour space of unknown size, or where something other than a `FRAME` header is found
/// where one belongs (the decoder then says what is wrong).
pub fn file_extent(path: &std::path::Path) -> Option<FileExtent> {
    use std::io::{Seek, SeekFrom};
    if !path.is_file() {
        return None;
    }
    let mut file = std::io::BufReader::new(std::fs::File::open(path).ok()?);
    let len = file.get_ref().metadata().ok()?.len();
    let mut line = Vec::new();
    (&mut file)
        .take(MAX_LINE)
        .read_until(b'\n', &mut line)
        .ok()?;
    let header = std::str::from_utf8(line.strip_suffix(b"\n")?).ok()?;
    let tag = |letter: char| {
        header
            .split_ascii_whitespace()
            .skip(1)
            .find_map(|t| t.strip_prefix(letter))
    };
    let side = |letter| tag(letter)?.parse::<u32>().ok().filter(|&n| n > 0);
    let bytes = frame_bytes(tag('C').unwrap_or("420jpeg"), side('W')?, side('H')?)?;
    let mut at = line.len() as u64;
    let mut complete = 0;
    loop {
        if at == len {
            return Some(FileExtent {
                complete,
                cut: None,
            });
        }
        file.seek(SeekFrom::Start(at)).ok()?;
        line.clear();
        (&mut file)
            .take(MAX_LINE)
            .read_until(b'\n', &mut line)
            .ok()?;
        if line.last() != Some(&b'\n') {
            // The file ends inside the header line (what is there must begin one).
            let begins = b"FRAME".starts_with(&line) || line.starts_with(b"FRAME");
            return begins.then(|| FileExtent {
                complete,
                cut: Some("in its FRAME header".into()),
            });
        }
        if line == b"\n" && at + 1 == len {
            // A blank line after the last frame ends the stream as its end would.
            return Some(FileExtent {
                complete,
                cut: None,
            });
        }
        if !line.starts_with(b"FRAME") {
            return None;
        }
        let data = at + line.len() as u64;
        let got = len - data;
        if got < bytes {
            return Some(FileExtent {
                complete,
                cut: Some(format!("{got} of {bytes} bytes of pixel data")),
            });
        }
        at = data + bytes;
        complete += 1;
    }
}

impl Chroma {
    /// Parses the value of a `C` tag.
    fn parse(v: &str) -> Option<Self> {
        Some(match v {
            "420jpeg" | "420" => Self::C420Jpeg,
            "420mpeg2" => Self::C420Mpeg2,
            "420paldv" => Self::C420Paldv,
            "444" => Self::C444,
            "mono" => Self::Mono,
            _ => return None,
        })
    }

    /// The tag value as written in a header.
    pub fn tag(self) -> &'static str {
        match self {
            Self::C420Jpeg => "420jpeg",
            Self::C420Mpeg2 => "420mpeg2",
            Self::C420Paldv => "420paldv",
            Self::C444 => "444",
            Self::Mono => "mono",
        }
    }

    /// Whether chroma is subsampled 2× in both directions.
    pub fn is_420(self) -> bool {
        matches!(self, Self::C420Jpeg | Self::C420Mpeg2 | Self::C420Paldv)
    }
}

/// A parsed y4m stream header.
#[derive(Debug, Clone, PartialEq)]
pub struct Y4mHeader {
    /// Frame width (pixels).
    pub width: u32,
    /// Frame height (pixels).
    pub height: u32,
    /// Chroma layout.
    pub chroma: Chroma,
    /// Frame rate `numerator:denominator`, when given.
    pub frame_rate: Option<(u32, u32)>,
    /// Pixel aspect ratio, when given (`0:0` means unknown).
    pub aspect: Option<(u32, u32)>,
    /// Interlacing letter (`p`, `t`, `b`, `m` or `?`), when given.
    pub interlace: Option<char>,
    /// Whether the samples are full range (`XCOLORRANGE=FULL`), not the y4m norm's limited
    /// range.
    pub full_range: bool,
}

/// Parses `n:d`.
fn ratio(v: &str, tag: char, zero_ok: bool) -> Result<(u32, u32), String> {
    let bad = || format!("tag {tag}{v}: expected n:d");
    let (n, d) = v.split_once(':').ok_or_else(bad)?;
    let n: u32 = n.parse().map_err(|_| bad())?;
    let d: u32 = d.parse().map_err(|_| bad())?;
    if !zero_ok && (n == 0 || d == 0) {
        return Err(format!("tag {tag}{v}: must be positive"));
    }
    Ok((n, d))
}

impl Y4mHeader {
    /// The interlacing (`It`, `Ib`, `Im`) and a stated pixel aspect other than `0:0`.
    pub fn layout(&self) -> super::Layout {
        super::Layout {
            interlaced: match self.interlace {
                Some('t') => Some(super::FieldOrder::TopFirst),
                Some('b') => Some(super::FieldOrder::BottomFirst),
                Some('m') => Some(super::FieldOrder::Mixed),
                _ => None,
            },
            pixel_aspect: self.aspect.filter(|&(n, d)| n > 0 && d > 0),
        }
    }

    /// Parses a header line (without its newline).
    pub fn parse(line: &str) -> Result<Self, String> {
        let mut parts = line.split(' ');
        if parts.next() != Some("YUV4MPEG2") {
            return Err("not a YUV4MPEG2 stream (missing 'YUV4MPEG2' signature)".into());
        }
        let (mut w, mut h) = (None, None);
        let mut hdr = Self {
            width: 0,
            height: 0,
            chroma: Chroma::C420Jpeg,
            frame_rate: None,
            aspect: None,
            interlace: None,
            full_range: false,
        };
        let mut seen = String::new();
        for tag in parts.filter(|t| !t.is_empty()) {
            let mut cs = tag.chars();
            let letter = cs.next().unwrap_or(' ');
            let v = cs.as_str();
            // Each tag once (`X`, the application's own, may repeat): `W160 H120 W320` was
            // read as 320 wide.
            if letter != 'X' && seen.contains(letter) {
                return Err(format!("tag {tag}: {letter} is given twice in the header"));
            }
            seen.push(letter);
            match letter {
                'W' | 'H' => {
                    let n: u32 = v
                        .parse()
                        .ok()
                        .filter(|&n| n > 0 && n <= MAX_SIDE)
                        .ok_or_else(|| {
                            format!(
                                "tag {tag}: a frame side is a whole number from 1 to {MAX_SIDE}"
                            )
                        })?;
                    if letter == 'W' { &mut w } else { &mut h }.replace(n);
                }
                // `0:0`: the rate is not known.
                'F' if v == "0:0" => hdr.frame_rate = None,
                'F' => hdr.frame_rate = Some(ratio(v, 'F', false)?),
                'A' => hdr.aspect = Some(ratio(v, 'A', true)?),
                'I' => match v {
                    "p" | "t" | "b" | "m" | "?" => hdr.interlace = v.chars().next(),
                    _ => return Err(format!("tag {tag}: bad interlacing")),
                },
                'C' => {
                    hdr.chroma = Chroma::parse(v).ok_or_else(|| {
                        format!(
                            "unsupported colour space C{v}: only 8-bit 420jpeg, 420, 420mpeg2, \
                             420paldv, 444 and mono are read here (a file is read through \
                             ffmpeg where it is installed; ffmpeg -pix_fmt yuv420p converts a \
                             stream)"
                        )
                    })?
                }
                'X' => match v {
                    "COLORRANGE=FULL" => hdr.full_range = true,
                    "COLORRANGE=LIMITED" => hdr.full_range = false,
                    _ => {}
                },
                _ => return Err(format!("unknown header tag '{tag}'")),
            }
        }
        hdr.width = w.ok_or("header has no width (W)")?;
        hdr.height = h.ok_or("header has no height (H)")?;
        if hdr.width as u64 * hdr.height as u64 > MAX_DECODE_PIXELS {
            return Err(format!(
                "frame size {}x{} is larger than {MAX_DECODE_PIXELS} pixels",
                hdr.width, hdr.height
            ));
        }
        Ok(hdr)
    }

    /// Size of each chroma plane (columns, rows); `(0, 0)` for mono.
    pub fn chroma_size(&self) -> (usize, usize) {
        let (w, h) = (self.width as usize, self.height as usize);
        match self.chroma {
            Chroma::Mono => (0, 0),
            Chroma::C444 => (w, h),
            _ => (w.div_ceil(2), h.div_ceil(2)),
        }
    }

    /// Bytes of pixel data per frame (after the `FRAME` line; [`frame_bytes`] of its colour
    /// space); saturates at `usize::MAX` for sizes the reader refuses (its sides are at most
    /// [`MAX_SIDE`]).
    pub fn frame_bytes(&self) -> usize {
        frame_bytes(self.chroma.tag(), self.width, self.height)
            .and_then(|b| usize::try_from(b).ok())
            .unwrap_or(usize::MAX)
    }
}

/// BT.601 limited- or full-range YCbCr → RGB in 16.16 fixed point, one table per term.
#[derive(Debug, Clone)]
struct Luts {
    y: [i32; 256],
    r_cr: [i32; 256],
    g_cb: [i32; 256],
    g_cr: [i32; 256],
    b_cb: [i32; 256],
}

/// Luma weights of BT.601.
const KR: f64 = 0.299;
const KB: f64 = 0.114;

impl Luts {
    /// The tables for limited-range samples (Y 16..235, Cb and Cr 16..240) or, with `full`,
    /// samples over the whole 0..255.
    fn new(full: bool) -> Self {
        let kg = 1.0 - KR - KB;
        // Y's scale and black level, and the chroma's scale (twice its half-range's inverse).
        let (ys, y0, cs) = if full {
            (1.0, 0.0, 255.0 / 127.5)
        } else {
            (255.0 / 219.0, 16.0, 255.0 / 112.0)
        };
        let fix = |v: f64| (v * 65536.0).round() as i32;
        let mut l = Self {
            y: [0; 256],
            r_cr: [0; 256],
            g_cb: [0; 256],
            g_cr: [0; 256],
            b_cb: [0; 256],
        };
        for i in 0..256 {
            let c = i as f64 - 128.0;
            l.y[i] = fix(ys * (i as f64 - y0));
            l.r_cr[i] = fix(cs * (1.0 - KR) * c);
            l.g_cb[i] = fix(-cs * KB * (1.0 - KB) / kg * c);
            l.g_cr[i] = fix(-cs * KR * (1.0 - KR) / kg * c);
            l.b_cb[i] = fix(cs * (1.0 - KB) * c);
        }
        l
    }

    #[inline]
    fn rgb(&self, y: u8, cb: u8, cr: u8) -> [u8; 3] {
        let yy = self.y[y as usize] + 32768;
        let px = |v: i32| (v >> 16).clamp(0, 255) as u8;
        [
            px(yy + self.r_cr[cr as usize]),
            px(yy + self.g_cb[cb as usize] + self.g_cr[cr as usize]),
            px(yy + self.b_cb[cb as usize]),
        ]
    }
}

/// Converts one BT.601 limited-range YCbCr sample to RGB (see the module docs).
pub fn ycbcr_to_rgb(y: u8, cb: u8, cr: u8) -> [u8; 3] {
    static LUTS: std::sync::OnceLock<Luts> = std::sync::OnceLock::new();
    LUTS.get_or_init(|| Luts::new(false)).rgb(y, cb, cr)
}

/// One output coordinate's chroma taps, weights in quarters (`w0 + w1 = 4`).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tap {
    i0: usize,
    i1: usize,
    w0: u32,
    w1: u32,
}

/// Chroma taps for `n` luma positions over `m` chroma samples; `centred`: chroma sample `i`
/// sits at luma position `2i + 0.5`, else at `2i`.
fn chroma_taps(n: usize, m: usize, centred: bool) -> Vec<Tap> {
    (0..n)
        .map(|x| {
            // Chroma coordinate in quarters: 4 c = 2 x − 1 (centred) or 2 x.
            let q = 2 * x as i64 - i64::from(centred);
            let i0 = q.div_euclid(4);
            let w1 = q.rem_euclid(4) as u32;
            let clamp = |i: i64| i.clamp(0, m as i64 - 1) as usize;
            Tap {
                i0: clamp(i0),
                i1: clamp(i0 + 1),
                w0: 4 - w1,
                w1,
            }
        })
        .collect()
}

/// Reads y4m frames from any buffered reader.
#[derive(Debug)]
pub struct Y4mReader<R> {
    r: R,
    name: String,
    header: Y4mHeader,
    header_len: usize,
    frames: usize,
    planes: Vec<u8>,
    xt: Vec<Tap>,
    yt: Vec<Tap>,
    luts: Luts,
}

/// Reads one `\n`-terminated line of at most [`MAX_LINE`] bytes; returns the bytes read
/// (including the newline when present).
fn read_line<R: BufRead>(r: &mut R, buf: &mut Vec<u8>) -> std::io::Result<usize> {
    buf.clear();
    r.by_ref().take(MAX_LINE).read_until(b'\n', buf)
}

impl<R: BufRead> Y4mReader<R> {
    /// Reads and checks the stream header; `name` labels errors (the file's path).
    pub fn new(mut r: R, name: &str) -> Result<Self, FrameError> {
        let err = |msg: String| FrameError::Y4m {
            path: name.to_string(),
            msg,
        };
        let mut line = Vec::new();
        read_line(&mut r, &mut line).map_err(|e| FrameError::io(name, e))?;
        if line.last() != Some(&b'\n') {
            return Err(err(if line.is_empty() {
                "empty file".into()
            } else {
                "header line is not terminated (or is not a y4m file)".into()
            }));
        }
        let text = std::str::from_utf8(&line[..line.len() - 1])
            .map_err(|_| err("header is not text (not a y4m file)".into()))?;
        // A header saved with a Windows line end: its last tag would read with a CR in it.
        if text.ends_with('\r') {
            return Err(err(
                "the header line ends in CR LF; a y4m header ends in LF alone (the file was \
                 converted as text)"
                    .into(),
            ));
        }
        let header = Y4mHeader::parse(text).map_err(err)?;
        let (w, h) = (header.width as usize, header.height as usize);
        let (cw, ch) = header.chroma_size();
        let (xt, yt) = match header.chroma {
            Chroma::C420Jpeg => (chroma_taps(w, cw, true), chroma_taps(h, ch, true)),
            Chroma::C420Mpeg2 => (chroma_taps(w, cw, false), chroma_taps(h, ch, true)),
            Chroma::C420Paldv => (chroma_taps(w, cw, false), chroma_taps(h, ch, false)),
            Chroma::C444 | Chroma::Mono => (Vec::new(), Vec::new()),
        };
        let luts = Luts::new(header.full_range);
        Ok(Self {
            r,
            name: name.to_string(),
            header_len: line.len(),
            planes: vec![0; header.frame_bytes()],
            header,
            frames: 0,
            xt,
            yt,
            luts,
        })
    }

    /// The stream header.
    pub fn header(&self) -> &Y4mHeader {
        &self.header
    }

    /// Length of the header line in bytes, newline included.
    pub fn header_len(&self) -> usize {
        self.header_len
    }

    /// Frames read so far.
    pub fn frames_read(&self) -> usize {
        self.frames
    }

    /// Reads and converts the next frame; `Ok(None)` at the clean end of the stream.
    pub fn read_frame(&mut self) -> Result<Option<Frame>, FrameError> {
        if !self.read_planes()? {
            return Ok(None);
        }
        let frame = self.convert();
        self.frames += 1;
        Ok(Some(frame))
    }

    /// Reads the next frame without converting it (a track that starts later in the
    /// stream); `Ok(false)` at the clean end of the stream. Its header and size are checked
    /// as [`Y4mReader::read_frame`] checks them.
    pub fn skip_frame(&mut self) -> Result<bool, FrameError> {
        let read = self.read_planes()?;
        self.frames += usize::from(read);
        Ok(read)
    }

    /// Reads the next frame's header and pixel data into `self.planes`; `Ok(false)` at the
    /// clean end of the stream.
    fn read_planes(&mut self) -> Result<bool, FrameError> {
        let mut line = Vec::new();
        let n = read_line(&mut self.r, &mut line).map_err(|e| FrameError::io(&self.name, e))?;
        if n == 0 {
            return Ok(false);
        }
        let ok_start = line.starts_with(b"FRAME") && matches!(line.get(5), Some(b' ' | b'\n'));
        // A blank line ending the stream (an editor's or `echo`'s newline) ends it cleanly.
        if !ok_start
            && line.iter().all(u8::is_ascii_whitespace)
            && self
                .r
                .fill_buf()
                .map_err(|e| FrameError::io(&self.name, e))?
                .is_empty()
        {
            return Ok(false);
        }
        if !ok_start || line.last() != Some(&b'\n') {
            if b"FRAME".starts_with(&line) || (ok_start && (n as u64) < MAX_LINE) {
                return Err(self.truncated("in its FRAME header".into()));
            }
            return Err(FrameError::Y4m {
                path: self.name.clone(),
                msg: format!("frame {}: expected a FRAME header", self.frames),
            });
        }
        let mut got = 0;
        while got < self.planes.len() {
            match self.r.read(&mut self.planes[got..]) {
                Ok(0) => break,
                Ok(k) => got += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(FrameError::io(&self.name, e)),
            }
        }
        if got < self.planes.len() {
            let msg = format!("{got} of {} bytes of pixel data", self.planes.len());
            return Err(self.truncated(msg));
        }
        Ok(true)
    }

    fn truncated(&self, msg: String) -> FrameError {
        FrameError::Truncated {
            path: self.name.clone(),
            frame: self.frames,
            msg,
        }
    }

    /// Converts the planes in `self.planes` to RGB.
    fn convert(&self) -> Frame {
        let (w, h) = (self.header.width as usize, self.header.height as usize);
        let (cw, ch) = self.header.chroma_size();
        let (yp, rest) = self.planes.split_at(w * h);
        let (cbp, crp) = rest.split_at(cw * ch);
        let mut out = Frame::new(w as u32, h as u32);
        let dst: &mut [u8] = &mut out;
        let l = &self.luts;
        match self.header.chroma {
            Chroma::Mono => {
                for (px, &y) in dst.chunks_exact_mut(3).zip(yp) {
                    px.copy_from_slice(&l.rgb(y, 128, 128));
                }
            }
            Chroma::C444 => {
                let planes = yp.iter().zip(cbp).zip(crp);
                for (px, ((&y, &cb), &cr)) in dst.chunks_exact_mut(3).zip(planes) {
                    px.copy_from_slice(&l.rgb(y, cb, cr));
                }
            }
            _ => {
                // Per output row: interpolate the two chroma rows vertically once (weights in
                // quarters), then horizontally per pixel (quarters again: /16 in all).
                let mut vcb = vec![0u16; cw];
                let mut vcr = vec![0u16; cw];
                for (y, ty) in self.yt.iter().enumerate() {
                    let (a0, a1) = (&cbp[ty.i0 * cw..][..cw], &cbp[ty.i1 * cw..][..cw]);
                    let (b0, b1) = (&crp[ty.i0 * cw..][..cw], &crp[ty.i1 * cw..][..cw]);
                    let (w0, w1) = (ty.w0 as u16, ty.w1 as u16);
                    let rows = a0.iter().zip(a1).zip(b0.iter().zip(b1));
                    for ((vb, vr), ((&p0, &p1), (&q0, &q1))) in
                        vcb.iter_mut().zip(vcr.iter_mut()).zip(rows)
                    {
                        *vb = w0 * p0 as u16 + w1 * p1 as u16;
                        *vr = w0 * q0 as u16 + w1 * q1 as u16;
                    }
                    let yrow = &yp[y * w..][..w];
                    let drow = &mut dst[y * w * 3..][..w * 3];
                    for ((px, tx), &yv) in drow.chunks_exact_mut(3).zip(&self.xt).zip(yrow) {
                        let (w0, w1) = (tx.w0 as u16, tx.w1 as u16);
                        let cb = (w0 * vcb[tx.i0] + w1 * vcb[tx.i1] + 8) >> 4;
                        let cr = (w0 * vcr[tx.i0] + w1 * vcr[tx.i1] + 8) >> 4;
                        px.copy_from_slice(&l.rgb(yv, cb as u8, cr as u8));
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_bytes_of_the_colour_spaces_ffmpeg_writes() {
        // 34x26: chroma 17x13 (4:2:0), 17x26 (4:2:2), 9x26 (4:1:1).
        let cases = [
            ("420jpeg", 884 + 2 * 221),
            ("420paldv", 884 + 2 * 221),
            ("422", 884 + 2 * 442),
            ("411", 884 + 2 * 234),
            ("444", 3 * 884),
            ("444alpha", 4 * 884),
            ("mono", 884),
            ("mono16", 2 * 884),
            ("420p10", 2 * (884 + 2 * 221)),
            ("422p12", 2 * (884 + 2 * 442)),
            ("444p9", 2 * 3 * 884),
        ];
        for (tag, want) in cases {
            assert_eq!(frame_bytes(tag, 34, 26), Some(want), "{tag}");
        }
        for tag in [
            "", "42", "420x", "422jpeg", "444p", "420p8", "420p17", "mono7", "abc",
        ] {
            assert_eq!(frame_bytes(tag, 34, 26), None, "{tag}");
        }
        // Past u64: no size rather than a wrapped one.
        assert_eq!(frame_bytes("444alpha", u32::MAX, u32::MAX), None);
        assert_eq!(frame_bytes("420p16", u32::MAX, u32::MAX), None);
    }

    #[test]
    fn a_files_extent_counts_its_whole_frames_and_finds_where_it_is_cut() {
        let d = std::env::temp_dir().join(format!("pftrack-y4m-extent-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let frame = |params: &str| {
            let mut f = format!("FRAME{params}\n").into_bytes();
            f.extend(std::iter::repeat_n(128u8, 8 * 6 * 2));
            f
        };
        let mut whole = b"YUV4MPEG2 W8 H6 C422 F25:1\n".to_vec();
        whole.extend(frame(""));
        whole.extend(frame(" Ip"));
        whole.extend(frame(""));
        let p = d.join("f.y4m");
        let extent = |bytes: &[u8]| {
            std::fs::write(&p, bytes).unwrap();
            file_extent(&p)
        };
        let done = |complete| {
            Some(FileExtent {
                complete,
                cut: None,
            })
        };
        assert_eq!(extent(&whole), done(3));
        let mut blank = whole.clone();
        blank.push(b'\n');
        assert_eq!(extent(&blank), done(3));
        let last = whole.len() - 96;
        let cut = extent(&whole[..whole.len() - 1]).unwrap();
        assert_eq!(cut.complete, 2);
        assert_eq!(cut.cut.as_deref(), Some("95 of 96 bytes of pixel data"));
        let in_header = extent(&whole[..last - 3]).unwrap();
        assert_eq!(in_header.complete, 2);
        assert_eq!(in_header.cut.as_deref(), Some("in its FRAME header"));
        // Not a FRAME header where one belongs, a size unknown, or no header: left to the
        // decoder.
        let mut junk = whole.clone();
        junk[last - 6..last - 1].copy_from_slice(b"JUNK!");
        assert_eq!(extent(&junk), None);
        assert_eq!(extent(b"YUV4MPEG2 W8 H6 C999\nFRAME\n"), None);
        assert_eq!(extent(b"YUV4MPEG2 W8 H6"), None);
        assert_eq!(extent(b"YUV4MPEG2 W8 H6\n"), done(0));
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn frame_bytes_saturate_beyond_the_readers_sizes() {
        let mut h = Y4mHeader::parse("YUV4MPEG2 W4 H2 C444").unwrap();
        assert_eq!(h.frame_bytes(), 24);
        h.width = u32::MAX;
        h.height = u32::MAX;
        assert_eq!(h.frame_bytes(), usize::MAX);
    }

    #[test]
    fn header_tags() {
        let h = Y4mHeader::parse("YUV4MPEG2 W176 H144 F30000:1001 Ip A1:1 C420mpeg2 XYSCSS=420")
            .unwrap();
        assert_eq!((h.width, h.height), (176, 144));
        assert_eq!(h.chroma, Chroma::C420Mpeg2);
        assert_eq!(h.frame_rate, Some((30000, 1001)));
        assert_eq!(h.aspect, Some((1, 1)));
        assert_eq!(h.interlace, Some('p'));
        assert_eq!(h.frame_bytes(), 176 * 144 * 3 / 2);
        // A tag given twice is refused; the application's X tags may repeat.
        let e = Y4mHeader::parse("YUV4MPEG2 W160 H120 W320").unwrap_err();
        assert!(e.contains("W320: W is given twice"), "{e}");
        assert!(Y4mHeader::parse("YUV4MPEG2 W160 H120 XA=1 XB=2").is_ok());
        let d = Y4mHeader::parse("YUV4MPEG2 H3 W5").unwrap();
        assert_eq!(d.chroma, Chroma::C420Jpeg);
        assert_eq!(d.chroma_size(), (3, 2));
        assert_eq!(d.frame_bytes(), 15 + 12);
        for bad in [
            "YUV4MPEG W5 H5",
            "YUV4MPEG2 W5",
            "YUV4MPEG2 H5",
            "YUV4MPEG2 W0 H5",
            "YUV4MPEG2 Wx H5",
            "YUV4MPEG2 W5 H5 C422",
            "YUV4MPEG2 W5 H5 C420p10",
            "YUV4MPEG2 W5 H5 C444p12",
            "YUV4MPEG2 W5 H5 C444alpha",
            "YUV4MPEG2 W5 H5 F30",
            "YUV4MPEG2 W5 H5 F0:1",
            "YUV4MPEG2 W5 H5 Iq",
            "YUV4MPEG2 W5 H5 Z9",
            "YUV4MPEG2 W32768 H32768",
            "YUV4MPEG2 W40000 H5",
        ] {
            assert!(Y4mHeader::parse(bad).is_err(), "accepted {bad}");
        }
    }

    #[test]
    fn unknown_rate_and_colour_range() {
        let h = Y4mHeader::parse("YUV4MPEG2 W4 H2 F0:0 Cmono XCOLORRANGE=FULL").unwrap();
        assert_eq!(h.frame_rate, None);
        assert!(h.full_range);
        let h = Y4mHeader::parse("YUV4MPEG2 W4 H2 XCOLORRANGE=LIMITED").unwrap();
        assert!(!h.full_range);
        assert!(!Y4mHeader::parse("YUV4MPEG2 W4 H2").unwrap().full_range);
        // A full-range grey of 40 stays 40 (limited range would read it as 28), and every
        // level is its own.
        let stream = |range: &str| {
            let mut b = format!("YUV4MPEG2 W4 H2 F0:0 Cmono{range}\nFRAME\n").into_bytes();
            b.extend([40, 0, 16, 128, 235, 255, 1, 254]);
            let mut r = Y4mReader::new(std::io::Cursor::new(b), "t").unwrap();
            let f = r.read_frame().unwrap().unwrap();
            f.as_raw().chunks(3).map(|p| p[0]).collect::<Vec<u8>>()
        };
        assert_eq!(
            stream(" XCOLORRANGE=FULL"),
            [40, 0, 16, 128, 235, 255, 1, 254]
        );
        assert_eq!(stream("")[..3], [28, 0, 0]);
        // Full-range red (JPEG's Y 76, Cb 85, Cr 255) and the neutral greys.
        let full = Luts::new(true);
        let r = full.rgb(76, 85, 255);
        assert!(r[0] >= 253 && r[1] <= 2 && r[2] <= 2, "{r:?}");
        for y in [0u8, 1, 100, 254, 255] {
            assert_eq!(full.rgb(y, 128, 128), [y; 3]);
        }
    }

    #[test]
    fn bt601_limited_range_anchors() {
        assert_eq!(ycbcr_to_rgb(16, 128, 128), [0, 0, 0]);
        assert_eq!(ycbcr_to_rgb(235, 128, 128), [255, 255, 255]);
        assert_eq!(ycbcr_to_rgb(126, 128, 128), [128, 128, 128]);
        // Pure red in BT.601 limited range: Y 81, Cb 90, Cr 240.
        let r = ycbcr_to_rgb(81, 90, 240);
        assert!(r[0] >= 253 && r[1] <= 2 && r[2] <= 2, "{r:?}");
        // Clipping below black and above white.
        assert_eq!(ycbcr_to_rgb(0, 128, 128), [0, 0, 0]);
        assert_eq!(ycbcr_to_rgb(255, 128, 128), [255, 255, 255]);
    }

    #[test]
    fn chroma_taps_siting() {
        // Centred: luma 0 → c = −0.25 (clamped to sample 0), luma 1 → 0.25, luma 2 → 0.75.
        let t = chroma_taps(6, 3, true);
        assert_eq!((t[0].i0, t[0].i1), (0, 0));
        assert_eq!((t[1].i0, t[1].i1, t[1].w0, t[1].w1), (0, 1, 3, 1));
        assert_eq!((t[2].i0, t[2].i1, t[2].w0, t[2].w1), (0, 1, 1, 3));
        assert_eq!((t[5].i0, t[5].i1), (2, 2));
        // Co-sited: even luma on a sample, odd luma halfway.
        let t = chroma_taps(5, 3, false);
        assert_eq!((t[2].i0, t[2].w0), (1, 4));
        assert_eq!((t[3].i0, t[3].i1, t[3].w0, t[3].w1), (1, 2, 2, 2));
        assert_eq!((t[4].i0, t[4].w0), (2, 4));
    }

    #[test]
    fn frames_and_truncation_in_memory() {
        let mut data = b"YUV4MPEG2 W2 H2 C444\nFRAME\n".to_vec();
        data.extend_from_slice(&[16, 16, 235, 235, 128, 128, 128, 128, 128, 128, 128, 128]);
        data.extend_from_slice(b"FRAME Ixyz\n");
        data.extend_from_slice(&[126, 126, 126, 126, 128, 128, 128, 128, 128, 128, 128, 128]);
        let mut r = Y4mReader::new(&data[..], "mem").unwrap();
        let f0 = r.read_frame().unwrap().unwrap();
        assert_eq!(f0.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(f0.get_pixel(1, 1).0, [255, 255, 255]);
        let f1 = r.read_frame().unwrap().unwrap();
        assert_eq!(f1.get_pixel(1, 0).0, [128, 128, 128]);
        assert!(r.read_frame().unwrap().is_none());
        // Every strict prefix that cuts into a frame is an error.
        for cut in [data.len() - 1, data.len() - 12, data.len() - 16, 30] {
            let mut r = Y4mReader::new(&data[..cut], "mem").unwrap();
            let res: Result<Vec<_>, _> =
                std::iter::from_fn(|| r.read_frame().transpose()).collect();
            assert!(
                matches!(res, Err(FrameError::Truncated { .. })),
                "cut {cut}: {res:?}"
            );
        }
        // Garbage where a FRAME header belongs.
        let mut bad = data.clone();
        bad[21..26].copy_from_slice(b"FRAMX");
        let mut r = Y4mReader::new(&bad[..], "mem").unwrap();
        assert!(matches!(r.read_frame(), Err(FrameError::Y4m { .. })));
        // A header with a Windows line end is named as such.
        let crlf = b"YUV4MPEG2 W2 H2 C444\r\nFRAME\n";
        let e = Y4mReader::new(&crlf[..], "mem").unwrap_err().to_string();
        assert!(e.contains("CR LF"), "{e}");
        // A blank line after the last frame ends the stream; anything else there, or a blank
        // line with more after it, is not a FRAME header.
        for (tail, ends) in [
            (&b"\n"[..], true),
            (b"\r\n", true),
            (b"\n\n", false),
            (b"\nFRAME\n", false),
            (b"x\n", false),
        ] {
            let mut more = data.clone();
            more.extend_from_slice(tail);
            let mut r = Y4mReader::new(&more[..], "mem").unwrap();
            let res: Result<Vec<_>, _> =
                std::iter::from_fn(|| r.read_frame().transpose()).collect();
            assert_eq!(res.is_ok(), ends, "{tail:?}: {res:?}");
            if ends {
                assert_eq!(res.unwrap().len(), 2);
            }
        }
    }
}

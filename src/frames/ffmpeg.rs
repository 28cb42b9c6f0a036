//! Any other video through an `ffmpeg` child process: raw RGB24 frames over a pipe.
//!
//! The size comes first from `ffprobe` (ships with ffmpeg); then
//! `ffmpeg -v error -nostdin -noautorotate -i file:INPUT -map 0:v:0 -fps_mode passthrough
//! -f rawvideo -pix_fmt rgb24 -` streams the first video stream. The `file:` prefix stops
//! ffmpeg from reading a name like `http:x` as a protocol.
//!
//! Turned video (a phone's, stored sideways with a display matrix saying how to show it) is
//! tracked as a player shows it, so that a start picked in a player is where the target is:
//! where ffprobe reports the stream's display rotation, ffmpeg applies it (its autorotation)
//! and the frame size is ffprobe's with the sides swapped for a quarter turn (and the pixel
//! shape with them), the rule ffmpeg turns by. Without a reported rotation `-noautorotate`
//! keeps the frames as stored, so their size is the one ffprobe reports: a rotation ffmpeg
//! found and ffprobe did not would transpose the frames while keeping the byte count, which
//! cannot be detected.
//!
//! `-fps_mode passthrough` hands over each decoded frame once, in order. Without it ffmpeg
//! writes raw video at the container's constant rate, repeating or dropping frames where the
//! timestamps leave a gap, so the k-th frame out is not the video's k-th: on the OpenCV box
//! clip (one undecodable slice) it sent 457 frames for the 455 it decoded, and every frame
//! after the gap was off by one against per-frame ground truth. ffmpeg before 5.1 has no
//! `-fps_mode`: when it rejects the option before sending a frame, the decode restarts with
//! the old spelling, `-vsync passthrough` (which ffmpeg 9 removed).
//!
//! Shutdown: dropping the source kills and waits the child. When ffmpeg exits non-zero, the
//! iterator ends with an error carrying the last line of ffmpeg's stderr (never a short video
//! presented as complete); a partial frame at the end is an error too.

use std::ffi::OsString;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;

use super::{FieldOrder, Frame, FrameError, Layout};

/// The most stderr text kept from a child (the tail), bytes.
const STDERR_KEEP: usize = 16 * 1024;

/// The programs used for video files; the default finds `ffmpeg` and `ffprobe` on `PATH`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FfmpegTools {
    /// The `ffmpeg` program.
    pub ffmpeg: PathBuf,
    /// The `ffprobe` program.
    pub ffprobe: PathBuf,
}

impl Default for FfmpegTools {
    fn default() -> Self {
        Self {
            ffmpeg: PathBuf::from("ffmpeg"),
            ffprobe: PathBuf::from("ffprobe"),
        }
    }
}

impl FfmpegTools {
    /// Whether both programs can be started (runs `ffmpeg -version` and `ffprobe -version`).
    pub fn available(&self) -> bool {
        [&self.ffmpeg, &self.ffprobe].iter().all(|p| {
            Command::new(p)
                .arg("-version")
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        })
    }
}

/// The input argument for ffmpeg/ffprobe: `file:` then the path.
fn file_arg(path: &Path) -> OsString {
    let mut s = OsString::from("file:");
    s.push(path.as_os_str());
    s
}

/// Maps a failure to start a program to the right error.
fn spawn_error(program: &Path, input: &Path, e: std::io::Error) -> FrameError {
    if e.kind() == std::io::ErrorKind::NotFound {
        FrameError::FfmpegMissing {
            path: input.display().to_string(),
            program: program.display().to_string(),
        }
    } else {
        FrameError::io(program, e)
    }
}

/// A line of ffmpeg's log without the address in its prefix (`[h264 @ 0x5585572f2d80]` ->
/// `[h264]`), which differs from run to run.
pub(crate) fn without_address(line: &str) -> String {
    if let Some(at) = line.find(" @ 0x")
        && let Some(end) = line[at..].find(']')
        && line[at + 5..at + end]
            .bytes()
            .all(|b| b.is_ascii_hexdigit())
    {
        return format!("{}{}", &line[..at], &line[at + end..]);
    }
    line.to_string()
}

/// The last non-empty line of a program's stderr, trimmed.
pub(crate) fn last_said(text: &str) -> Option<&str> {
    text.lines().rev().map(str::trim).find(|l| !l.is_empty())
}

/// The last non-empty line of a program's stderr, or a fallback.
fn last_line(text: &str) -> String {
    last_said(text).unwrap_or("(no message)").to_string()
}

/// Reads a child's stderr to its end on a thread of its own (a chatty child would otherwise
/// block on a full pipe), keeping only its tail, [`STDERR_KEEP`] bytes or so.
pub(crate) fn drain_tail(mut stream: impl Read + Send + 'static) -> JoinHandle<String> {
    std::thread::spawn(move || {
        let mut kept: Vec<u8> = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = stream.read(&mut buf) {
            if n == 0 {
                break;
            }
            kept.extend_from_slice(&buf[..n]);
            if kept.len() > 2 * STDERR_KEEP {
                kept.drain(..kept.len() - STDERR_KEEP);
            }
        }
        String::from_utf8_lossy(&kept).into_owned()
    })
}

/// What ffprobe says of a video's first stream.
#[derive(Debug, Clone, PartialEq)]
pub struct Probe {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The frame count, when the container states one.
    pub frames: Option<usize>,
    /// Interlaced fields and the shape of a pixel, where ffprobe reports them.
    pub layout: Layout,
    /// The display rotation in degrees (counter-clockwise, as ffprobe reports it), when the
    /// stream has one. `width`, `height` and `layout` are of the frames as stored.
    pub rotation: Option<f64>,
}

impl Probe {
    /// Whether the display rotation is a quarter turn either way (within 1 degree), which
    /// swaps the frame's sides when applied: ffmpeg transposes there, flips at a half turn
    /// and turns within the frame's own size at any other angle.
    pub fn quarter_turn(&self) -> bool {
        self.rotation
            .is_some_and(|r| (r.rem_euclid(180.0) - 90.0).abs() < 1.0)
    }

    /// The frame size and layout as shown, the display rotation applied.
    pub fn shown(&self) -> ((u32, u32), Layout) {
        if !self.quarter_turn() {
            return ((self.width, self.height), self.layout);
        }
        let layout = Layout {
            pixel_aspect: self.layout.pixel_aspect.map(|(n, d)| (d, n)),
            ..self.layout
        };
        ((self.height, self.width), layout)
    }
}

/// Reads ffprobe's `field_order` (`progressive`, `tt`, `bb`, `tb`, `bt`, `unknown`): the
/// field displayed first (`tb` is coded top first, displayed bottom first).
fn field_order(v: &str) -> Option<FieldOrder> {
    match v {
        "tt" | "bt" => Some(FieldOrder::TopFirst),
        "bb" | "tb" => Some(FieldOrder::BottomFirst),
        _ => None,
    }
}

/// Reads ffprobe's `sample_aspect_ratio` (`n:d`; `0:1` and `N/A` when unknown).
fn sample_aspect(v: &str) -> Option<(u32, u32)> {
    let (n, d) = v.split_once(':')?;
    let (n, d) = (n.parse::<u32>().ok()?, d.parse::<u32>().ok()?);
    (n > 0 && d > 0).then_some((n, d))
}

/// Width, height, frame count (when the container says) and layout of the first video stream.
pub fn probe(tools: &FfmpegTools, path: &Path) -> Result<Probe, FrameError> {
    let out = Command::new(&tools.ffprobe)
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .args([
            "stream=width,height,nb_frames,field_order,sample_aspect_ratio\
             :stream_side_data=rotation:stream_tags=rotate",
            "-of",
            "default=noprint_wrappers=1",
        ])
        .arg(file_arg(path))
        .stdin(Stdio::null())
        .output()
        .map_err(|e| spawn_error(&tools.ffprobe, path, e))?;
    let err = |msg: String| FrameError::Ffmpeg {
        path: path.display().to_string(),
        msg,
    };
    if !out.status.success() {
        return Err(err(format!(
            "ffprobe failed ({}): {}",
            out.status,
            last_line(&String::from_utf8_lossy(&out.stderr))
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let (mut w, mut h, mut n) = (None, None, None);
    let (mut rotation, mut tag) = (None, None);
    let mut layout = Layout::default();
    for line in text.lines() {
        match line.trim().split_once('=') {
            Some(("width", v)) => w = v.parse::<u32>().ok(),
            Some(("height", v)) => h = v.parse::<u32>().ok(),
            Some(("nb_frames", v)) => n = v.parse::<usize>().ok(),
            Some(("field_order", v)) => layout.interlaced = field_order(v),
            Some(("sample_aspect_ratio", v)) => layout.pixel_aspect = sample_aspect(v),
            // The display matrix's rotation; ffmpeg before 5 reported it as a tag instead.
            Some(("rotation", v)) => rotation = v.parse::<f64>().ok().filter(|r| r.is_finite()),
            Some(("TAG:rotate", v)) => {
                // The tag turns clockwise, the matrix counter-clockwise.
                tag = v.parse::<f64>().ok().filter(|r| r.is_finite()).map(|r| -r)
            }
            _ => {}
        }
    }
    let rotation = rotation.or(tag);
    match (w, h) {
        (Some(w), Some(h)) if w > 0 && h > 0 => Ok(Probe {
            width: w,
            height: h,
            frames: n,
            layout,
            rotation,
        }),
        _ if text.trim().is_empty() => Err(err("no video stream".into())),
        _ => Err(err(format!(
            "ffprobe reports no frame size ({})",
            text.trim().replace('\n', ", ")
        ))),
    }
}

/// The decode's frame-rate option: each decoded frame passed through once, never repeated or
/// dropped to a constant rate; `legacy` spells it as ffmpeg before 5.1 did.
fn passthrough_args(legacy: bool) -> [&'static str; 2] {
    if legacy {
        ["-vsync", "passthrough"]
    } else {
        ["-fps_mode", "passthrough"]
    }
}

/// Whether a failed decode's stderr says this ffmpeg does not know `-fps_mode` (before 5.1:
/// "Unrecognized option 'fps_mode'.").
fn rejects_fps_mode(stderr: &str) -> bool {
    stderr
        .lines()
        .any(|l| l.contains("option") && l.contains("fps_mode"))
}

/// A running decode: the child, its stdout, and a thread draining its stderr.
type Decoder = (Process, ChildStdout, JoinHandle<String>);

/// The decode's ffmpeg, which the program's interrupt clean-up kills too
/// ([`crate::io::Stopper`]): passing over the frames before a start (`select`), it writes
/// nothing for seconds, so a signal sent to the program alone (`kill PID`) would leave it
/// decoding after the program has ended, where one that writes dies of the closed pipe.
#[derive(Debug)]
struct Process {
    child: Arc<Mutex<Child>>,
    _stopper: crate::io::Stopper,
}

impl Process {
    fn new(child: Child) -> Self {
        let child = Arc::new(Mutex::new(child));
        let for_stop = Arc::clone(&child);
        let stopper = crate::io::Stopper::register(move || {
            end(&mut for_stop.lock().unwrap_or_else(|e| e.into_inner()));
        });
        Self {
            child,
            _stopper: stopper,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Child> {
        self.child.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Kills it and waits for it.
    fn kill(&self) {
        end(&mut self.lock());
    }

    /// Waits for it to end, holding the lock only to look (the interrupt's clean-up takes
    /// it to kill the child, so a wait holding it would keep a signal waiting for the child).
    fn wait(&self) -> std::io::Result<std::process::ExitStatus> {
        let mut pause = std::time::Duration::from_millis(1);
        loop {
            if let Some(status) = self.lock().try_wait()? {
                return Ok(status);
            }
            std::thread::sleep(pause);
            pause = (pause * 2).min(std::time::Duration::from_millis(20));
        }
    }
}

/// Kills `child` and waits for it. Nothing is signalled once it has been waited for (its
/// number may be another process's by then).
fn end(child: &mut Child) {
    let _ = child.kill();
    let _ = child.wait();
}

/// Starts `ffmpeg` decoding `path`'s first video stream to raw RGB24 on its stdout, turned
/// as its display rotation says where `rotate`, else as stored.
fn spawn_decoder(
    ffmpeg: &Path,
    path: &Path,
    legacy_sync: bool,
    rotate: bool,
    start: usize,
) -> Result<Decoder, FrameError> {
    // The frames before `start` dropped as they leave the decoder, before their conversion to
    // RGB and the pipe (which cost about four times the decode at 720p). The filter counts the
    // frames the decoder gives, as the pipe's reader does with every frame passed through.
    let select = (start > 0).then(|| ["-vf".to_string(), format!("select=gte(n\\,{start})")]);
    let rgb = ["-f", "rawvideo", "-pix_fmt", "rgb24", "-"].map(String::from);
    let output: Vec<String> = select.into_iter().flatten().chain(rgb).collect();
    spawn_decode(ffmpeg, path, legacy_sync, rotate, &output)
}

/// Starts `ffmpeg` decoding `path`'s first video stream as it is timed (`passthrough`), turned
/// as its display rotation says where `rotate`, else as stored, into the `output` given
/// (its options and its name), with its stdout piped and its stderr's tail kept.
fn spawn_decode(
    ffmpeg: &Path,
    path: &Path,
    legacy_sync: bool,
    rotate: bool,
    output: &[String],
) -> Result<Decoder, FrameError> {
    let mut child = Command::new(ffmpeg)
        .args(["-v", "error", "-nostdin"])
        .args((!rotate).then_some("-noautorotate"))
        .arg("-i")
        .arg(file_arg(path))
        .args(["-map", "0:v:0"])
        .args(passthrough_args(legacy_sync))
        .args(output)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| spawn_error(ffmpeg, path, e))?;
    let (Some(stdout), Some(stderr)) = (child.stdout.take(), child.stderr.take()) else {
        end(&mut child);
        return Err(FrameError::io(
            ffmpeg,
            std::io::Error::other("no pipes to the child process"),
        ));
    };
    Ok((Process::new(child), stdout, drain_tail(stderr)))
}

/// A running ffmpeg decode.
#[derive(Debug)]
pub(crate) struct FfmpegSource {
    path: PathBuf,
    /// The `ffmpeg` program, for a restart with the older option.
    ffmpeg: PathBuf,
    /// The decode applies the stream's display rotation.
    rotate: bool,
    /// The decode runs with `-vsync passthrough` (ffmpeg before 5.1).
    legacy_sync: bool,
    child: Process,
    stdout: ChildStdout,
    stderr: Option<JoinHandle<String>>,
    size: (u32, u32),
    frames_hint: Option<usize>,
    /// Interlacing and pixel shape, from the probe.
    layout: Layout,
    /// The input's number of the next frame the decode gives (frames read, and those the
    /// decode was started past).
    frames: usize,
    /// The frames the running decode drops before its first ([`FfmpegSource::skip`]).
    start: usize,
    /// A frame read ahead by [`FfmpegSource::skip`], the next to deliver.
    pending: Option<Frame>,
    /// The child has been waited for.
    reaped: bool,
    /// The first line of ffmpeg's stderr in a decode that ended with success (see
    /// [`Self::complaint`]).
    complaint: Option<String>,
}

impl FfmpegSource {
    /// Probes the size, then starts the decode.
    pub(crate) fn open(path: &Path, tools: &FfmpegTools) -> Result<Self, FrameError> {
        if !path.exists() {
            return Err(FrameError::NotFound {
                path: path.display().to_string(),
            });
        }
        if !path.is_file() {
            // A device, a pipe or a socket (`/dev/null`): ffprobe would wait on or misread it.
            return Err(FrameError::Io {
                path: path.display().to_string(),
                cause: std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    "not a video file, an image folder or a y4m stream (use - for standard input)",
                ),
            });
        }
        let probed = probe(tools, path)?;
        let ((w, h), layout) = probed.shown();
        let rotate = probed.rotation.is_some();
        let (child, stdout, stderr) = spawn_decoder(&tools.ffmpeg, path, false, rotate, 0)?;
        Ok(Self {
            path: path.to_path_buf(),
            ffmpeg: tools.ffmpeg.clone(),
            rotate,
            legacy_sync: false,
            child,
            stdout,
            stderr: Some(stderr),
            size: (w, h),
            frames_hint: probed.frames,
            layout,
            frames: 0,
            start: 0,
            pending: None,
            reaped: false,
            complaint: None,
        })
    }

    /// Frame size.
    pub(crate) fn size(&self) -> (u32, u32) {
        self.size
    }

    /// The container's frame count, when it states one.
    pub(crate) fn len_hint(&self) -> Option<usize> {
        self.frames_hint
    }

    /// Interlacing and pixel shape, as ffprobe reported them.
    pub(crate) fn layout(&self) -> Layout {
        self.layout
    }

    /// The earliest line kept of what ffmpeg wrote to stderr (the last 16 KiB) in a decode
    /// that ended with success, if any: it writes only errors (`-v error`), and the first is
    /// the decoder's own, where later ones can be the muxer's about the gap.
    pub(crate) fn complaint(&self) -> Option<&str> {
        self.complaint.as_deref()
    }

    /// Waits for the child and collects its stderr tail.
    fn finish(&mut self) -> Result<(std::process::ExitStatus, String), FrameError> {
        let status = self
            .child
            .wait()
            .map_err(|e| FrameError::io(&self.path, e))?;
        self.reaped = true;
        let text = self
            .stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default();
        Ok((status, text))
    }

    /// Passes over the next `n` frames; returns how many, fewer when the video ends first.
    /// Before any frame is read the decode is started again dropping the first `n` frames
    /// before they are converted and sent (ffmpeg still decodes them: about five times faster
    /// than reading them at 720p). Where that ends cleanly with no frame (the video is
    /// shorter, or exactly `n` frames long), a decode that converts nothing counts the frames
    /// ([`Self::count_frames`]).
    /// Where either fails or says anything, the video is decoded again from its start and
    /// read through, which counts its frames or meets its error where a plain read would.
    pub(crate) fn skip(&mut self, n: usize) -> Result<usize, FrameError> {
        // Nothing read yet (a frame read ahead follows a restart past frame 0).
        if n > 0 && self.frames == 0 && !self.reaped {
            self.restart(n)?;
            match self.next_frame() {
                Ok(Some(f)) => {
                    self.pending = Some(f);
                    return Ok(n);
                }
                Ok(None) if self.complaint.is_none() => {
                    // At most `n`, or the decode past them would have given one.
                    if let Some(count) = self.count_frames()?.filter(|&c| c <= n) {
                        (self.start, self.frames) = (0, count);
                        return Ok(count);
                    }
                }
                _ => {}
            }
            self.restart(0)?;
        }
        let mut skipped = 0;
        while skipped < n && self.next_frame()?.is_some() {
            skipped += 1;
        }
        Ok(skipped)
    }

    /// The video's frames, counted by a decode of the same stream and timing that converts
    /// and sends none (`-f null`, its count read from `-progress`): about a third of the time
    /// a read through takes at 720p (1.2 s against 3.4 s for 1500 frames). `None` where that
    /// decode fails, says anything on stderr, or reports no count; the caller then reads
    /// through.
    fn count_frames(&self) -> Result<Option<usize>, FrameError> {
        let output = ["-nostats", "-progress", "pipe:1", "-f", "null", "-"].map(String::from);
        // Killed with the program's interrupt clean-up, as the decode is.
        let (process, stdout, said) = spawn_decode(
            &self.ffmpeg,
            &self.path,
            self.legacy_sync,
            self.rotate,
            &output,
        )?;
        let progress = drain_tail(stdout);
        let status = process.wait().map_err(|e| FrameError::io(&self.path, e))?;
        let (said, progress) = (said.join().ok(), progress.join().ok());
        let (Some(said), Some(progress)) = (said, progress) else {
            return Ok(None);
        };
        if !status.success() || !said.trim().is_empty() || !progress.contains("progress=end") {
            return Ok(None);
        }
        Ok(progress
            .lines()
            .rev()
            .find_map(|l| l.trim().strip_prefix("frame="))
            .and_then(|v| v.trim().parse().ok()))
    }

    /// Ends the running decode and starts it again at frame `start`.
    fn restart(&mut self, start: usize) -> Result<(), FrameError> {
        if !self.reaped {
            self.child.kill();
        }
        drop(self.stderr.take());
        let (child, stdout, stderr) = spawn_decoder(
            &self.ffmpeg,
            &self.path,
            self.legacy_sync,
            self.rotate,
            start,
        )?;
        (self.child, self.stdout, self.stderr) = (child, stdout, Some(stderr));
        (self.reaped, self.start, self.frames, self.complaint) = (false, start, start, None);
        Ok(())
    }

    /// Reads the next frame; `Ok(None)` when ffmpeg ends cleanly.
    pub(crate) fn next_frame(&mut self) -> Result<Option<Frame>, FrameError> {
        if let Some(f) = self.pending.take() {
            return Ok(Some(f));
        }
        loop {
            match self.read_frame()? {
                Pipe::Frame(f) => return Ok(Some(f)),
                Pipe::End => return Ok(None),
                Pipe::Restarted => {}
            }
        }
    }

    /// One frame, the end, or a restart of the decode with `-vsync` (see the module
    /// documentation) when this ffmpeg rejected `-fps_mode` before its first frame.
    fn read_frame(&mut self) -> Result<Pipe, FrameError> {
        if self.reaped {
            return Ok(Pipe::End);
        }
        let (w, h) = self.size;
        let mut buf = vec![0u8; w as usize * h as usize * 3];
        let mut got = 0;
        while got < buf.len() {
            match self.stdout.read(&mut buf[got..]) {
                Ok(0) => break,
                Ok(k) => got += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(FrameError::io(&self.path, e)),
            }
        }
        if got == buf.len() {
            self.frames += 1;
            return Frame::from_raw(w, h, buf).map(Pipe::Frame).ok_or_else(|| {
                FrameError::io(&self.path, std::io::Error::other("frame buffer size"))
            });
        }
        let (status, text) = self.finish()?;
        let path = self.path.display().to_string();
        if !status.success()
            && self.frames == self.start
            && got == 0
            && !self.legacy_sync
            && rejects_fps_mode(&text)
        {
            let (child, stdout, stderr) =
                spawn_decoder(&self.ffmpeg, &self.path, true, self.rotate, self.start)?;
            (self.child, self.stdout, self.stderr) = (child, stdout, Some(stderr));
            (self.legacy_sync, self.reaped) = (true, false);
            return Ok(Pipe::Restarted);
        }
        if !status.success() {
            return Err(FrameError::Ffmpeg {
                path,
                msg: format!(
                    "ffmpeg failed ({status}) after {} frames: {}",
                    self.frames,
                    last_line(&text)
                ),
            });
        }
        if got > 0 {
            return Err(FrameError::Truncated {
                path,
                frame: self.frames,
                msg: format!("ffmpeg sent {got} of {} bytes", buf.len()),
            });
        }
        self.complaint = text
            .lines()
            .map(str::trim)
            .find(|l| !l.is_empty())
            .map(without_address);
        Ok(Pipe::End)
    }
}

/// What one read of the decode's pipe gave.
enum Pipe {
    Frame(Frame),
    End,
    /// The decode restarted with the older frame-rate option; read again.
    Restarted,
}

impl Drop for FfmpegSource {
    fn drop(&mut self) {
        if !self.reaped {
            self.child.kill();
        }
        // The stderr thread ends when the pipe closes; it is detached rather than joined, so a
        // grandchild holding the pipe open cannot hang the drop.
        drop(self.stderr.take());
    }
}

#[cfg(test)]
mod tests {
    use super::{
        FfmpegSource, FfmpegTools, FieldOrder, field_order, sample_aspect, without_address,
    };

    /// The count of a video's frames taken without converting them is the number a read
    /// gives, and a start at or past the end is counted with it: the frames skipped are the
    /// count, and nothing is read after them.
    #[test]
    fn a_start_past_the_end_is_counted_without_reading_through() {
        let tools = FfmpegTools::default();
        if !tools.available() {
            assert!(
                std::env::var_os("CI").is_none(),
                "ffmpeg is needed under CI"
            );
            eprintln!("skip: ffmpeg not on PATH");
            return;
        }
        let dir = std::env::temp_dir().join(format!("pftrack-count-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let clip = dir.join("clip.mp4");
        let out = std::process::Command::new(&tools.ffmpeg)
            .args([
                "-v",
                "error",
                "-y",
                "-f",
                "lavfi",
                "-i",
                "testsrc=size=32x24:rate=25",
            ])
            .args(["-frames:v", "9", "-c:v", "mpeg4"])
            .arg(&clip)
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        let open = || FfmpegSource::open(&clip, &tools).unwrap();
        assert_eq!(open().count_frames().unwrap(), Some(9));
        let mut read = open();
        let mut frames = 0;
        while read.next_frame().unwrap().is_some() {
            frames += 1;
        }
        assert_eq!(frames, 9);
        for past in [9, 10, 500] {
            let mut src = open();
            assert_eq!(src.skip(past).unwrap(), 9, "{past}");
            assert_eq!(src.frames, 9);
            assert!(src.next_frame().unwrap().is_none());
            assert!(src.complaint().is_none());
        }
        // Before the end the decode started past the frames goes on from there.
        let mut src = open();
        assert_eq!(src.skip(6).unwrap(), 6);
        assert_eq!(src.frames, 7, "the frame read ahead counted");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn ffprobe_layout_fields_read_as_displayed() {
        // tb: top coded first, bottom displayed first.
        for (v, want) in [
            ("tt", Some(FieldOrder::TopFirst)),
            ("bt", Some(FieldOrder::TopFirst)),
            ("bb", Some(FieldOrder::BottomFirst)),
            ("tb", Some(FieldOrder::BottomFirst)),
            ("progressive", None),
            ("unknown", None),
            ("", None),
        ] {
            assert_eq!(field_order(v), want, "{v}");
        }
        assert_eq!(sample_aspect("128:117"), Some((128, 117)));
        assert_eq!(sample_aspect("1:1"), Some((1, 1)));
        for unknown in ["0:1", "1:0", "N/A", "", "12/11", "-1:2"] {
            assert_eq!(sample_aspect(unknown), None, "{unknown}");
        }
    }

    #[test]
    fn log_lines_lose_their_address() {
        assert_eq!(
            without_address("[h264 @ 0x5585572f2d80] decode_slice_header error"),
            "[h264] decode_slice_header error"
        );
        for kept in [
            "plain line",
            "[h264 @ 0xzz] x",
            "a @ 0x12 without bracket",
            "",
        ] {
            assert_eq!(without_address(kept), kept);
        }
    }
}

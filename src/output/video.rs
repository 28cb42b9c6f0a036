//! Frames written as one video file through an `ffmpeg` child process: raw RGB24 frames over
//! its standard input, encoded in the container the file's extension names.
//!
//! The file appears under its name only once complete, as the project's other outputs do
//! ([`crate::io::AtomicFile`]): ffmpeg writes a partial file beside it,
//! `.NAME.PID-N.partial.EXT` (the extension last, for ffmpeg to choose the container by), which
//! [`VideoWriter::commit`] renames into place. Dropped before that, or on any error, the
//! writer stops ffmpeg and removes the partial file; the partial file is registered
//! ([`crate::io::partial`]) so that an interrupted program can remove it too.
//!
//! ffmpeg starts with the first frame, whose size every later frame must have. Containers
//! players expect in 4:2:0 (`mp4`, `m4v`, `mov`, `mkv`, `webm`, `avi`, `ts`) get
//! `-pix_fmt yuv420p`, and so, as 4:2:0 needs, an odd width or height is padded to the next
//! even one with a black column or row; other extensions take ffmpeg's defaults (`gif`
//! its palette). ffmpeg's own failure (an extension it has no container for, a codec it
//! lacks, a disk full) comes back with the last line it wrote on standard error.

use std::ffi::OsString;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::thread::JoinHandle;

use image::RgbImage;

use crate::frames::FfmpegTools;
use crate::io::{Partial, PartialKind};

/// The lowest and highest frame rate a video is written at (frames per second).
pub const FPS_RANGE: (f64, f64) = (0.01, 1000.0);

/// The extensions whose containers are written in 4:2:0 (`-pix_fmt yuv420p`).
const YUV420_EXTENSIONS: [&str; 7] = ["mp4", "m4v", "mov", "mkv", "webm", "avi", "ts"];

/// The most of ffmpeg's standard error kept (its tail), bytes.
const STDERR_KEEP: usize = 16 * 1024;

/// Writing a video failed: its settings, the frames given, or ffmpeg.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{path}: {message}")]
pub struct VideoError {
    /// The video file, as given.
    pub path: String,
    /// What went wrong.
    pub message: String,
}

/// A video being written; see the module docs.
#[derive(Debug)]
pub struct VideoWriter {
    /// The name the caller gave (for messages).
    target: PathBuf,
    /// The file the partial file replaces: the target, or the file its links end at.
    to: PathBuf,
    partial: PathBuf,
    fps: f64,
    tools: FfmpegTools,
    /// ffmpeg, from the first frame on.
    running: Option<Running>,
    /// The partial file's registration, from the first frame on.
    registered: Option<Partial>,
    /// Width and height of the frames.
    size: Option<(u32, u32)>,
    frames: usize,
    /// Whether ffmpeg has finished and written the partial file whole.
    closed: bool,
}

#[derive(Debug)]
struct Running {
    child: Child,
    stdin: Option<ChildStdin>,
    /// Collects ffmpeg's standard error (its tail).
    stderr: Option<JoinHandle<String>>,
}

impl VideoWriter {
    /// Prepares a video at `path`, `fps` frames a second, written by `tools.ffmpeg`. Checked
    /// now: the frame rate, that `path` names a file with an extension, and that it is not a
    /// folder nor a stream or device (a video is a file of its own, finished by a rename).
    /// ffmpeg itself starts with the first frame ([`VideoWriter::write`]).
    pub fn create(path: &Path, fps: f64, tools: &FfmpegTools) -> Result<Self, VideoError> {
        let fail = |message: String| VideoError {
            path: path.display().to_string(),
            message,
        };
        if !(fps.is_finite() && (FPS_RANGE.0..=FPS_RANGE.1).contains(&fps)) {
            return Err(fail(format!(
                "a frame rate of {fps} frames a second; it must be from {} to {}",
                FPS_RANGE.0, FPS_RANGE.1
            )));
        }
        let to = crate::io::atomic::resolve_links(path)
            .map_err(|e| fail(format!("cannot follow its links: {e}")))?;
        if to
            .extension()
            .is_none_or(|e| e.is_empty() || to.file_stem().is_none())
        {
            return Err(fail(
                "no extension to choose the video's container by (e.g. .mp4, .mkv, .gif)"
                    .to_string(),
            ));
        }
        if crate::frames::dir::is_image_file(&to) {
            return Err(fail(
                "names a still image, not a video (.mp4, .mkv, .webm, .gif, ...)".to_string(),
            ));
        }
        match std::fs::metadata(&to) {
            Ok(m) if m.is_dir() => return Err(fail("is a folder".to_string())),
            Ok(m) if !m.is_file() => {
                return Err(fail(
                    "is not a regular file (a video is written to a file of its own)".to_string(),
                ));
            }
            _ => {}
        }
        let partial = partial_video_path(&to);
        Ok(Self {
            target: path.to_path_buf(),
            to,
            partial,
            fps,
            tools: tools.clone(),
            running: None,
            registered: None,
            size: None,
            frames: 0,
            closed: false,
        })
    }

    /// The name given.
    pub fn path(&self) -> &Path {
        &self.target
    }

    /// Frames written so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    fn error(&self, message: impl Into<String>) -> VideoError {
        VideoError {
            path: self.target.display().to_string(),
            message: message.into(),
        }
    }

    /// Appends `frame`; the first frame starts ffmpeg and sets the size every later one must
    /// have.
    pub fn write(&mut self, frame: &RgbImage) -> Result<(), VideoError> {
        if self.closed {
            return Err(self.error("written to after it was closed"));
        }
        let (w, h) = frame.dimensions();
        match self.size {
            None => {
                if w == 0 || h == 0 {
                    return Err(self.error(format!("a frame of {w}x{h} pixels")));
                }
                self.start(w, h)?;
                self.size = Some((w, h));
            }
            Some((sw, sh)) if (sw, sh) != (w, h) => {
                return Err(self.error(format!(
                    "a frame of {w}x{h} pixels after frames of {sw}x{sh}"
                )));
            }
            Some(_) => {}
        }
        let bytes = crate::frames::rgb_bytes(frame);
        let written = self
            .running
            .as_mut()
            .and_then(|r| r.stdin.as_mut())
            .map(|stdin| stdin.write_all(bytes));
        match written {
            Some(Ok(())) => {
                self.frames += 1;
                Ok(())
            }
            // ffmpeg has stopped reading: its own words say why.
            Some(Err(e)) => Err(self.stop_with_reason(e.to_string())),
            None => Err(self.error("ffmpeg is not running")),
        }
    }

    /// Starts ffmpeg for frames of `w × h`, writing the partial file (made new and
    /// registered first, so that nothing of another's is overwritten).
    fn start(&mut self, w: u32, h: u32) -> Result<(), VideoError> {
        let partial = self.partial.clone();
        let (registered, _) = Partial::create(&partial, PartialKind::File, || {
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&partial)
        })
        .map_err(|e| self.error(e.to_string()))?;
        self.registered = Some(registered);
        let yuv420 = self
            .to
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| YUV420_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
        let mut cmd = Command::new(&self.tools.ffmpeg);
        cmd.args(["-v", "error", "-nostdin", "-y"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
            .arg("-s")
            .arg(format!("{w}x{h}"))
            .arg("-framerate")
            .arg(format!("{}", self.fps))
            .args(["-i", "pipe:0"]);
        if yuv420 {
            if w % 2 == 1 || h % 2 == 1 {
                cmd.args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"]);
            }
            cmd.args(["-pix_fmt", "yuv420p"]);
        }
        let mut out = OsString::from("file:");
        out.push(partial.as_os_str());
        cmd.arg(out)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                self.error(format!(
                    "{} was not found: writing a video needs ffmpeg",
                    self.tools.ffmpeg.display()
                ))
            } else {
                self.error(format!("starting {}: {e}", self.tools.ffmpeg.display()))
            }
        })?;
        let stdin = child.stdin.take();
        let stderr = child.stderr.take().map(|mut s| {
            std::thread::spawn(move || {
                let mut tail = Vec::new();
                let mut buf = [0u8; 4096];
                while let Ok(n) = s.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    tail.extend_from_slice(&buf[..n]);
                    if tail.len() > 2 * STDERR_KEEP {
                        tail.drain(..tail.len() - STDERR_KEEP);
                    }
                }
                String::from_utf8_lossy(&tail).into_owned()
            })
        });
        self.running = Some(Running {
            child,
            stdin,
            stderr,
        });
        Ok(())
    }

    /// Waits for ffmpeg after its input was closed (or it failed) and returns its exit
    /// status's success and the last line of its standard error.
    fn wait(&mut self) -> Option<(bool, String)> {
        let mut r = self.running.take()?;
        drop(r.stdin.take());
        let ok = r.child.wait().is_ok_and(|s| s.success());
        let text = r
            .stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default();
        Some((ok, self.ffmpeg_says(&text)))
    }

    /// What ffmpeg's standard error `text` says went wrong, in the target's terms: its last
    /// line after `ffmpeg: `, with the partial file named as the target, or for an extension
    /// ffmpeg has no container for, that; empty when it said nothing.
    fn ffmpeg_says(&self, text: &str) -> String {
        if text.contains("suitable output format") || text.contains("choose an output format") {
            return format!(
                "ffmpeg knows no container for the extension .{} (.mp4, .mkv, .webm, .gif, ...)",
                self.to.extension().unwrap_or_default().to_string_lossy()
            );
        }
        let last = text
            .lines()
            .rev()
            .map(str::trim)
            .find(|l| !l.is_empty())
            .map(crate::frames::ffmpeg::without_address)
            .unwrap_or_default();
        if last.is_empty() {
            return last;
        }
        let partial = self.partial.display().to_string();
        let said = last
            .replace(
                &format!("file:{partial}"),
                &self.target.display().to_string(),
            )
            .replace(&partial, &self.target.display().to_string());
        format!("ffmpeg: {said}")
    }

    /// The error of a write ffmpeg stopped taking: ffmpeg's last word where it gave one.
    fn stop_with_reason(&mut self, fallback: String) -> VideoError {
        let said = self.wait().map(|(_, l)| l).unwrap_or_default();
        self.error(if said.is_empty() {
            format!("ffmpeg stopped taking frames ({fallback})")
        } else {
            said
        })
    }

    /// Ends the input and waits for ffmpeg to finish the file: an error when no frame was
    /// written or ffmpeg failed. The file is still partial until [`VideoWriter::commit`]; a
    /// caller with other outputs closes every one of them before committing any.
    pub fn close(&mut self) -> Result<(), VideoError> {
        if self.closed {
            return Ok(());
        }
        if self.frames == 0 {
            return Err(self.error("no frame to write"));
        }
        match self.wait() {
            Some((true, _)) => {
                self.closed = true;
                Ok(())
            }
            Some((false, said)) if !said.is_empty() => Err(self.error(said)),
            Some((false, _)) => Err(self.error("ffmpeg failed without a message")),
            None => Err(self.error("ffmpeg is not running")),
        }
    }

    /// Closes the video if it is not yet ([`VideoWriter::close`]), then renames it into
    /// place; returns the frames written. On an error the partial file is removed.
    pub fn commit(mut self) -> Result<usize, VideoError> {
        self.close()?;
        let (partial, to) = (self.partial.clone(), self.to.clone());
        let registered = self.registered.take();
        let renamed = match registered {
            Some(reg) => reg.commit(|| std::fs::rename(&partial, &to)),
            None => Err(std::io::Error::other("nothing was written")),
        };
        renamed.map_err(|e| self.error(format!("moving it into place: {e}")))?;
        Ok(self.frames)
    }
}

impl Drop for VideoWriter {
    fn drop(&mut self) {
        if let Some(r) = self.running.as_mut() {
            drop(r.stdin.take());
            let _ = r.child.kill();
        }
        let _ = self.wait();
        // Still registered: never committed, so the partial file is this writer's to remove.
        if self.registered.take().is_some() {
            let _ = std::fs::remove_file(&self.partial);
        }
    }
}

/// `.NAME.PID-N.partial.EXT` beside `path`: a name of this write's own whose extension is the
/// target's, for ffmpeg to choose the container by.
fn partial_video_path(path: &Path) -> PathBuf {
    static COUNT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = COUNT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut name = OsString::from(".");
    name.push(path.file_name().unwrap_or_default());
    name.push(format!(".{}-{n}.partial.", std::process::id()));
    name.push(path.extension().unwrap_or_default());
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_partial_name_keeps_the_extension_last() {
        let p = partial_video_path(Path::new("/tmp/out/track.mp4"));
        let name = p.file_name().unwrap().to_str().unwrap();
        assert!(name.starts_with(".track.mp4."), "{name}");
        assert!(name.ends_with(".partial.mp4"), "{name}");
        assert_eq!(p.parent(), Some(Path::new("/tmp/out")));
        assert_ne!(p, partial_video_path(Path::new("/tmp/out/track.mp4")));
    }

    /// Frames of an odd size come back padded by a black column and row (4:2:0 needs even
    /// sizes), the picture itself where it was; a frame of another size is refused.
    #[test]
    fn an_odd_size_is_padded_and_the_frames_read_back() {
        let tools = FfmpegTools::default();
        if !tools.available() {
            eprintln!("skip: ffmpeg not on PATH");
            return;
        }
        let dir = std::env::temp_dir().join(format!("pftrack-video-odd-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let target = dir.join("odd.mkv");
        let frame = |k: u8| {
            RgbImage::from_fn(33, 25, |x, y| {
                image::Rgb([(x * 7) as u8 / 2 + k * 20, (y * 9) as u8, 128])
            })
        };
        let mut v = VideoWriter::create(&target, 5.0, &tools).unwrap();
        for k in 0..3 {
            v.write(&frame(k)).unwrap();
        }
        let e = v.write(&RgbImage::new(32, 24)).unwrap_err();
        assert!(e.to_string().contains("after frames of 33x25"), "{e}");
        assert_eq!(v.commit().unwrap(), 3);
        let mut read =
            crate::frames::open(&target, &crate::frames::SourceOptions { resize: None }).unwrap();
        assert_eq!(read.size(), (34, 26));
        let mut n = 0u8;
        for got in read.by_ref() {
            let got = got.unwrap();
            let want = frame(n);
            let mut sum = 0u64;
            for (x, y, p) in want.enumerate_pixels() {
                let q = got.get_pixel(x, y);
                sum += (0..3).map(|c| p[c].abs_diff(q[c]) as u64).sum::<u64>();
            }
            assert!(sum as f64 / (3.0 * 33.0 * 25.0) < 8.0, "frame {n}");
            // The padding is black.
            assert!(got.get_pixel(33, 12).0.iter().all(|&c| c < 24));
            n += 1;
        }
        assert_eq!(n, 3);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_settings_are_refused_before_ffmpeg_starts() {
        let tools = FfmpegTools {
            ffmpeg: PathBuf::from("/nonexistent/ffmpeg"),
            ..FfmpegTools::default()
        };
        let dir = std::env::temp_dir();
        for fps in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e6] {
            let e = VideoWriter::create(&dir.join("a.mp4"), fps, &tools).unwrap_err();
            assert!(e.to_string().contains("frame rate"), "{e}");
        }
        let e = VideoWriter::create(&dir.join("noext"), 25.0, &tools).unwrap_err();
        assert!(e.to_string().contains("extension"), "{e}");
        let e = VideoWriter::create(&dir.join("a.PNG"), 25.0, &tools).unwrap_err();
        assert!(e.to_string().contains("still image"), "{e}");
        let e = VideoWriter::create(&dir.join(".mp4"), 25.0, &tools).unwrap_err();
        assert!(e.to_string().contains("extension"), "{e}");
        let e = VideoWriter::create(&dir, 25.0, &tools).unwrap_err();
        assert!(e.to_string().contains("extension") || e.to_string().contains("folder"));
        // No ffmpeg: said at the first frame, and nothing is left behind.
        let target = dir.join(format!("pftrack-video-{}.mp4", std::process::id()));
        let mut v = VideoWriter::create(&target, 25.0, &tools).unwrap();
        let e = v.write(&RgbImage::new(4, 4)).unwrap_err();
        assert!(e.to_string().contains("needs ffmpeg"), "{e}");
        let partial = v.partial.clone();
        drop(v);
        assert!(!partial.exists() && !target.exists());
    }
}

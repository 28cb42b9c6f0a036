//! Frames written as one video file through an `ffmpeg` child process: raw RGB24 frames over
//! its standard input, encoded in the container the file's extension names
//! ([`CONTAINERS`]).
//!
//! The file appears under its name only once complete: ffmpeg writes it in a hidden staging
//! folder beside the target (`.pftrack-video-PID-NANOS.partial`, a
//! [`crate::io::StagingDir`], registered so that an interrupted program removes it);
//! [`VideoWriter::close`] has ffmpeg finish it and syncs it, with the permissions of a file it
//! will replace, as [`crate::io::AtomicFile`] keeps them, and [`VideoWriter::commit`] renames
//! it into place. Dropped before that, or on any error, the writer stops ffmpeg and removes
//! the staging folder: an ffmpeg that had not yet opened its output then finds no folder to
//! create it in. The target is a file of its own: a folder, a stream, a device or one of the
//! process's descriptors (`/dev/stdout`) is refused, and so is a folder that does not exist.
//! ffmpeg runs in a process group of its own, so that a terminal's Ctrl-C reaches the program
//! alone, and is registered ([`crate::io::Stopper`]) for the program's interrupt handling to
//! kill it, with whatever it started, before it removes the staging folder.
//!
//! ffmpeg starts with the first frame, whose size every later frame must have. The video
//! containers are written in 4:2:0 (`-pix_fmt yuv420p`), so an odd width or height is padded
//! to the next even one with a black column or row; `.gif` takes ffmpeg's palette (and plays
//! at whole hundredths of a second a frame, at most 50 frames a second), `.y4m` 4:4:4. ffmpeg's
//! failure is the writer's: a non-zero exit, or anything it says at its `error` level (it
//! exits 0 after failing to write a trailer to a full disk, and says so), with the last line
//! it wrote.

use std::ffi::OsString;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use image::RgbImage;

use crate::frames::FfmpegTools;
use crate::io::{StagingDir, Stopper};

/// The lowest and highest frame rate a video is written at (frames per second).
pub const FPS_RANGE: (f64, f64) = (0.01, 1000.0);

/// The highest frame rate of a `.gif`: its frames' delays are whole hundredths of a second,
/// and players hold those under two hundredths longer.
pub const GIF_MAX_FPS: f64 = 50.0;

/// The file extensions a video is written with (lower case; any case is taken), each with
/// ffmpeg's container (muxer) and the pixel format it is written in (`None`: ffmpeg's choice).
pub const CONTAINERS: [(&str, &str, Option<&str>); 10] = [
    ("mp4", "mp4", Some("yuv420p")),
    ("m4v", "mp4", Some("yuv420p")),
    ("mov", "mov", Some("yuv420p")),
    ("mkv", "matroska", Some("yuv420p")),
    ("webm", "webm", Some("yuv420p")),
    ("avi", "avi", Some("yuv420p")),
    ("ts", "mpegts", Some("yuv420p")),
    ("nut", "nut", Some("yuv420p")),
    ("gif", "gif", None),
    ("y4m", "yuv4mpegpipe", Some("yuv444p")),
];

/// The extensions of [`CONTAINERS`] as a reader is told them: `.mp4, .m4v, ...`.
fn container_list() -> String {
    CONTAINERS
        .iter()
        .map(|(e, _, _)| format!(".{e}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The staging folders' prefix, for [`StagingDir`].
const STAGING_PREFIX: &str = "pftrack-video";

/// How long a staging folder must have been left untouched to be taken for a killed run's.
const STALE_STAGING: std::time::Duration = std::time::Duration::from_secs(3600);

/// Writing a video failed: its settings, the frames given, or ffmpeg.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{path}: {message}")]
pub struct VideoError {
    /// The video file, as given.
    pub path: String,
    /// What went wrong.
    pub message: String,
}

impl VideoError {
    fn new(path: &Path, message: impl Into<String>) -> Self {
        Self {
            path: path.display().to_string(),
            message: message.into(),
        }
    }
}

/// Whether `fps` is a frame rate a video is written at ([`FPS_RANGE`]).
pub fn fps_in_range(fps: f64) -> bool {
    fps.is_finite() && (FPS_RANGE.0..=FPS_RANGE.1).contains(&fps)
}

/// A video being written; see the module docs.
#[derive(Debug)]
pub struct VideoWriter {
    /// The name the caller gave (for messages).
    target: PathBuf,
    /// The file the video replaces: the target, or the file its links end at.
    to: PathBuf,
    /// ffmpeg's container and pixel format for the target's extension.
    muxer: &'static str,
    pix_fmt: Option<&'static str>,
    /// The staging folder the video is written in, and the file in it.
    staging: StagingDir,
    partial: PathBuf,
    fps: f64,
    tools: FfmpegTools,
    /// ffmpeg, from the first frame on.
    running: Option<Running>,
    /// Width and height of the frames.
    size: Option<(u32, u32)>,
    frames: usize,
    /// Whether ffmpeg has finished and written the file whole.
    closed: bool,
}

/// What the checks of a target give ([`VideoWriter::check`]).
struct Target {
    /// The file the video replaces: the target, or the file its links end at.
    to: PathBuf,
    /// Its extension, lower case.
    ext: String,
    muxer: &'static str,
    pix_fmt: Option<&'static str>,
}

#[derive(Debug)]
struct Running {
    /// Shared with the interrupt's stop ([`Stopper`]), which kills it.
    child: Arc<Mutex<Child>>,
    stdin: Option<ChildStdin>,
    /// Collects ffmpeg's standard error (its tail).
    stderr: Option<JoinHandle<String>>,
    /// Registered while ffmpeg runs.
    _stopper: Stopper,
}

impl VideoWriter {
    /// Prepares a video at `path`, `fps` frames a second, written by `tools.ffmpeg`. Checked
    /// now, before any frame: the frame rate, that `path` names a file in an existing folder
    /// with an extension of [`CONTAINERS`], and that it is not a folder, a stream, a device
    /// nor one of the process's descriptors; the staging folder is made beside it. ffmpeg
    /// itself starts with the first frame ([`VideoWriter::write`]).
    pub fn create(path: &Path, fps: f64, tools: &FfmpegTools) -> Result<Self, VideoError> {
        let fail = |message: String| VideoError::new(path, message);
        let Target {
            to,
            ext,
            muxer,
            pix_fmt,
        } = Self::target(path, fps)?;
        let folder = match to.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if !folder.is_dir() {
            return Err(fail(format!("no folder {}", folder.display())));
        }
        StagingDir::sweep_stale(&folder, STAGING_PREFIX, STALE_STAGING);
        let staging = StagingDir::create(&folder, STAGING_PREFIX)
            .map_err(|e| fail(format!("cannot write in {}: {e}", folder.display())))?;
        let partial = staging.path().join(format!("video.{ext}"));
        Ok(Self {
            target: path.to_path_buf(),
            to,
            muxer,
            pix_fmt,
            staging,
            partial,
            fps,
            tools: tools.clone(),
            running: None,
            size: None,
            frames: 0,
            closed: false,
        })
    }

    /// Checks what [`VideoWriter::create`] checks of `path` and `fps` but the folder (which
    /// a caller may be about to make), making nothing: for a program to refuse a bad target
    /// before it starts its work.
    pub fn check(path: &Path, fps: f64) -> Result<(), VideoError> {
        Self::target(path, fps).map(|_| ())
    }

    /// The checks of the target and frame rate, and what they give.
    fn target(path: &Path, fps: f64) -> Result<Target, VideoError> {
        let fail = |message: String| VideoError::new(path, message);
        if !fps_in_range(fps) {
            return Err(fail(format!(
                "a frame rate of {fps} frames a second; it must be from {} to {}",
                FPS_RANGE.0, FPS_RANGE.1
            )));
        }
        let spelled = path.as_os_str().to_string_lossy();
        if spelled == "-" {
            return Err(fail(
                "a video is written to a file of its own, not to standard output".to_string(),
            ));
        }
        if spelled.ends_with('/') || path.file_name().is_none() {
            return Err(fail("names a folder, not a file".to_string()));
        }
        if crate::io::atomic::through_descriptor(path) {
            return Err(fail(
                "is one of the process's descriptors: a video is written to a file of its own"
                    .to_string(),
            ));
        }
        let to = crate::io::atomic::resolve_links(path)
            .map_err(|e| fail(format!("cannot follow its links: {e}")))?;
        match std::fs::metadata(&to) {
            Ok(m) if m.is_dir() => return Err(fail("is a folder".to_string())),
            Ok(m) if !m.is_file() => {
                return Err(fail(
                    "is not a regular file (a stream or a device): a video is written to a file \
                     of its own"
                        .to_string(),
                ));
            }
            _ => {}
        }
        let ext = to
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        let Some(&(_, muxer, pix_fmt)) = CONTAINERS.iter().find(|(e, _, _)| *e == ext) else {
            let through = if to == path {
                String::new()
            } else {
                format!(" (its link names {})", to.display())
            };
            return Err(fail(format!(
                "a video is written as {} (its extension chooses the container){through}",
                container_list()
            )));
        };
        if muxer == "gif" && fps > GIF_MAX_FPS {
            return Err(fail(format!(
                "a GIF plays at most {GIF_MAX_FPS} frames a second (each frame's delay is whole \
                 hundredths of a second), not {fps}"
            )));
        }
        Ok(Target {
            to,
            ext,
            muxer,
            pix_fmt,
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
        VideoError::new(&self.target, message)
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

    /// Starts ffmpeg for frames of `w × h`, writing the file in the staging folder.
    fn start(&mut self, w: u32, h: u32) -> Result<(), VideoError> {
        let mut cmd = Command::new(&self.tools.ffmpeg);
        // `-xerror`: an error ends ffmpeg with a failure.
        cmd.args(["-v", "error", "-xerror", "-nostdin", "-y"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
            .arg("-s")
            .arg(format!("{w}x{h}"))
            .arg("-framerate")
            .arg(format!("{}", self.fps))
            .args(["-i", "pipe:0"]);
        if let Some(fmt) = self.pix_fmt {
            if fmt == "yuv420p" && (w % 2 == 1 || h % 2 == 1) {
                cmd.args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"]);
            }
            cmd.args(["-pix_fmt", fmt]);
        }
        cmd.args(["-f", self.muxer]);
        let mut out = OsString::from("file:");
        out.push(self.partial.as_os_str());
        cmd.arg(out)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        // A process group of its own: a terminal's Ctrl-C is the program's to handle.
        #[cfg(unix)]
        std::os::unix::process::CommandExt::process_group(&mut cmd, 0);
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
        let stderr = child.stderr.take().map(crate::frames::ffmpeg::drain_tail);
        let child = Arc::new(Mutex::new(child));
        let for_stop = Arc::clone(&child);
        // An interrupt kills it before removing the staging folder: in a process group of its
        // own, it would otherwise go on encoding after the program has ended.
        let stopper = Stopper::register(move || {
            let mut c = for_stop.lock().unwrap_or_else(|e| e.into_inner());
            kill_group(&mut c);
            let _ = c.wait();
        });
        self.running = Some(Running {
            child,
            stdin,
            stderr,
            _stopper: stopper,
        });
        Ok(())
    }

    /// Waits for ffmpeg after its input was closed (or it failed) and returns whether it
    /// succeeded and what went wrong: the last line of its standard error, or how it ended.
    fn wait(&mut self) -> Option<(bool, String)> {
        let mut r = self.running.take()?;
        drop(r.stdin.take());
        // Polled, the lock held only for a look, so that an interrupt's stop can take it.
        let status = loop {
            let looked = r.child.lock().unwrap_or_else(|e| e.into_inner()).try_wait();
            match looked {
                Ok(Some(status)) => break Some(status),
                Ok(None) => std::thread::sleep(std::time::Duration::from_millis(2)),
                Err(_) => break None,
            }
        };
        let text = r
            .stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default();
        let exited = status.is_some_and(|s| s.success());
        // At the `error` level whatever ffmpeg says is a failure, even when it exits 0.
        let ok = exited && text.trim().is_empty();
        let said = self.ffmpeg_says(&text);
        let said = match status {
            _ if !said.is_empty() => said,
            Some(s) if !s.success() => format!("ffmpeg ended ({s}) without a message"),
            _ => said,
        };
        Some((ok, said))
    }

    /// What ffmpeg's standard error `text` says went wrong, in the target's terms: its last
    /// line after `ffmpeg: `, with the file in the staging folder named as the target; empty
    /// when it said nothing.
    fn ffmpeg_says(&self, text: &str) -> String {
        let Some(last) = crate::frames::ffmpeg::last_said(text) else {
            return String::new();
        };
        let last = crate::frames::ffmpeg::without_address(last);
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

    /// Ends the input, waits for ffmpeg to finish the file and syncs it (giving it the
    /// permissions of a file it will replace): an error when no frame was written or ffmpeg
    /// failed. The video is then whole but still in the staging folder until
    /// [`VideoWriter::commit`] renames it, which a caller with other outputs does last.
    pub fn close(&mut self) -> Result<(), VideoError> {
        if self.closed {
            return Ok(());
        }
        if self.frames == 0 {
            return Err(self.error("no frame to write"));
        }
        match self.wait() {
            Some((true, _)) => {}
            Some((false, said)) if !said.is_empty() => return Err(self.error(said)),
            Some((false, _)) => return Err(self.error("ffmpeg failed without a message")),
            None => return Err(self.error("ffmpeg is not running")),
        }
        // Read-only is enough to sync and to set the mode, whatever the umask gave the file.
        let synced = std::fs::File::open(&self.partial).and_then(|f| {
            if let Ok(old) = std::fs::symlink_metadata(&self.to)
                && old.is_file()
            {
                f.set_permissions(old.permissions())?;
            }
            f.sync_all()
        });
        synced.map_err(|e| self.error(format!("finishing it: {e}")))?;
        self.closed = true;
        Ok(())
    }

    /// Closes the video if it is not yet ([`VideoWriter::close`]) and renames it into place;
    /// returns the frames written. On an error the staging folder is removed, with the video
    /// in it.
    pub fn commit(mut self) -> Result<usize, VideoError> {
        self.close()?;
        let (partial, to) = (self.partial.clone(), self.to.clone());
        self.staging
            .commit(|| std::fs::rename(&partial, &to))
            .map_err(|e| self.error(format!("moving it into place: {e}")))?;
        Ok(self.frames)
    }
}

impl Drop for VideoWriter {
    fn drop(&mut self) {
        if let Some(r) = self.running.as_mut() {
            drop(r.stdin.take());
            kill_group(&mut r.child.lock().unwrap_or_else(|e| e.into_inner()));
        }
        let _ = self.wait();
        // The staging folder goes with the writer (its own drop), the video in it unless
        // committed.
    }
}

/// Kills ffmpeg and whatever it started: its whole process group, which is its own (an
/// `ffmpeg` on the path may be a script that runs the real one as its child). Without the
/// command line's `libc`, or off Unix, ffmpeg alone.
fn kill_group(child: &mut Child) {
    #[cfg(all(unix, feature = "cli"))]
    if let Ok(pgid) = libc::pid_t::try_from(child.id())
        && child.try_wait().is_ok_and(|done| done.is_none())
    {
        // SAFETY: `killpg` only sends a signal; the group is the child's own (made with
        // `process_group(0)`, so its id is the child's), which has not been reaped yet (just
        // checked), so the id names no other process group.
        unsafe {
            libc::killpg(pgid, libc::SIGKILL);
        }
    }
    let _ = child.kill();
}

#[cfg(test)]
mod tests {
    use super::*;

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
        // A file replaced keeps its permissions.
        std::fs::write(&target, b"old").unwrap();
        #[cfg(unix)]
        std::fs::set_permissions(&target, std::os::unix::fs::PermissionsExt::from_mode(0o600))
            .unwrap();
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
        assert!(staging_left(&dir).is_empty());
        #[cfg(unix)]
        assert_eq!(
            std::os::unix::fs::PermissionsExt::mode(
                &std::fs::metadata(&target).unwrap().permissions()
            ) & 0o777,
            0o600
        );
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

    /// The staging folders `VideoWriter`s left in `dir`.
    fn staging_left(dir: &Path) -> Vec<String> {
        std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(&format!(".{STAGING_PREFIX}-")))
            .collect()
    }

    /// An ffmpeg that says it failed but exits 0 (as ffmpeg 5.1 does when the trailer does
    /// not fit on a full disk) fails the video: nothing under the target's name, nothing left.
    #[cfg(unix)]
    #[test]
    fn what_ffmpeg_says_at_its_error_level_is_a_failure_even_with_exit_0() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("pftrack-video-fake-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fake = dir.join("ffmpeg");
        // Reads its input, writes a short file where it was told, complains, exits 0.
        std::fs::write(
            &fake,
            "#!/bin/sh\nfor a; do out=$a; done\ncat > /dev/null\nprintf x > \"${out#file:}\"\n\
             echo \"[mp4 @ 0x5555] Error writing trailer of ${out}: No space left on device\" >&2\n\
             exit 0\n",
        )
        .unwrap();
        std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
        let tools = FfmpegTools {
            ffmpeg: fake,
            ..FfmpegTools::default()
        };
        let target = dir.join("full.mp4");
        let mut v = VideoWriter::create(&target, 25.0, &tools).unwrap();
        v.write(&RgbImage::new(8, 8)).unwrap();
        let e = v.commit().unwrap_err().to_string();
        assert!(e.contains("No space left on device"), "{e}");
        // Named as the target, not as the file in the staging folder.
        assert!(
            e.contains(&format!("trailer of {}", target.display())) && !e.contains("partial"),
            "{e}"
        );
        assert!(!target.exists() && staging_left(&dir).is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_settings_are_refused_before_ffmpeg_starts() {
        let tools = FfmpegTools {
            ffmpeg: PathBuf::from("/nonexistent/ffmpeg"),
            ..FfmpegTools::default()
        };
        let dir = std::env::temp_dir().join(format!("pftrack-video-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for fps in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e6] {
            let e = VideoWriter::create(&dir.join("a.mp4"), fps, &tools).unwrap_err();
            assert!(e.to_string().contains("frame rate"), "{e}");
        }
        for (name, needle) in [
            ("noext", "container"),
            ("a.PNG", "container"),
            ("a.m3u8", "container"),
            ("o%d.tif", "container"),
            (".mp4", "container"),
            ("sub/a.mp4", "no folder"),
            ("a.mp4/", "folder"),
        ] {
            let e = VideoWriter::create(&dir.join(name), 25.0, &tools).unwrap_err();
            assert!(e.to_string().contains(needle), "{name}: {e}");
        }
        let e = VideoWriter::create(&dir, 25.0, &tools).unwrap_err();
        assert!(e.to_string().contains("folder"), "{e}");
        std::fs::create_dir(dir.join("d.mkv")).unwrap();
        let e = VideoWriter::create(&dir.join("d.mkv"), 25.0, &tools).unwrap_err();
        assert!(e.to_string().contains("is a folder"), "{e}");
        #[cfg(unix)]
        {
            let e = VideoWriter::create(Path::new("/dev/stdout"), 25.0, &tools).unwrap_err();
            assert!(e.to_string().contains("descriptors"), "{e}");
        }
        assert!(staging_left(&dir).is_empty());
        // No ffmpeg: said at the first frame, and nothing is left behind.
        let target = dir.join("a.MP4");
        let mut v = VideoWriter::create(&target, 25.0, &tools).unwrap();
        assert_eq!(staging_left(&dir).len(), 1);
        let e = v.write(&RgbImage::new(4, 4)).unwrap_err();
        assert!(e.to_string().contains("needs ffmpeg"), "{e}");
        drop(v);
        assert!(staging_left(&dir).is_empty() && !target.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

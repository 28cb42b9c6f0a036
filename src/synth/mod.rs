//! Synthetic ground truth: a textured rigid object rendered along a known trajectory.
//!
//! The scene: a pinhole [`Camera`] (50° horizontal field of view, principal point at the image
//! centre, SPEC axes x right, y down, z forward) looks at a rigid [`Shape`] (an ellipsoid "head"
//! or a box "car") in front of a static, textured background. The object carries a solid
//! procedural texture evaluated at object-frame surface points (so it moves rigidly), is lit by
//! an ambient and a slowly turning directional light under a slowly changing exposure, and the
//! frame gets mild sensor noise. Each pixel is ray cast against the analytic shape at 2×2
//! subsamples (antialiased edges). Everything is a pure function of (seed, frame, pixel), so
//! frames render in parallel and are byte-identical for a seed.
//!
//! # Truth (binding; tests and evaluation rely on it)
//! - `rx, ry, rz`: `Euler::from_matrix(R_t)` where `R_t` maps object points in the frame-0 pose
//!   to the current pose, about the object centre, axes parallel to the camera's
//!   (`R = Rx·Ry·Rz`). Frame 0 is the reference: `R_0 = I`, angles 0. The object's orientation
//!   (object to camera coordinates) is `R_t · R_obj0` ([`Renderer::reference_orientation`]).
//! - `cx, cy`: the perspective projection of the object centre. Under perspective this is not
//!   the silhouette's centroid: they differ by under 0.5 px for the head along every scenario,
//!   by up to 3.6 px for the car (a box, its near end looking bigger) at 160x120 (tested).
//! - `a, b`: from the silhouette's second moments, measured in the frame turned by `rz` (the
//!   ellipse's own axes, orientation `theta = rz`): with `C` the covariance of the silhouette
//!   (sampled at 4×4 points per pixel, unclipped by the image border), `e1 = (cos rz, sin rz)`,
//!   `e2 = (-sin rz, cos rz)`, `a = 2 sqrt(e1ᵀ C e1)` and `b = 2 sqrt(e2ᵀ C e2)`. A filled ellipse
//!   with semi-axes `a`, `b` along that frame has exactly these moments (its variance along an
//!   axis is a quarter of the squared semi-axis), so for the head's near-elliptical outline
//!   `a, b` are its semi-axes. The truth's ellipse turns with `rz`, as the SPEC has the
//!   tracker's do; an outline whose own axes turn otherwise is not matched in orientation.
//!   The box's does: as the car turns, its outline's long axis goes from +5 to -9 degrees
//!   while `rz` goes to -24, so the truth's ellipse overlaps the car's outline less as it
//!   turns (IoU 0.83 at frame 0, 0.74 at the end, at 160x120; one with the outline's own
//!   moments would keep about 0.88). The head's outline follows `rz` closely (`combo`: IoU
//!   0.96 or more). Angles are scored on `rx, ry, rz`, which this does not touch.
//! - `init.txt`: `cx, cy, a, b` of frame 0 (orientation 0), and the camera's horizontal field
//!   of view (`hfov,50`, [`crate::io::InitFile`]), which `pftrack track` then uses.

mod camera;
mod render;
mod shape;
mod texture;
mod trajectory;

use std::path::{Path, PathBuf};

pub use camera::{Camera, HFOV_DEG};
pub use render::Renderer;
pub use shape::{Hit, Outline, Shape, ellipsoid_outline};
pub use texture::{Background, Material, SolidTexture, hash, noise};
pub use trajectory::{CAR_DEPTH, HEAD_DEPTH, ObjectPose, Trajectory, smoothstep};

use crate::geometry::Ellipse;
use crate::io::atomic::Prepared;
use crate::io::init::format_init;
use crate::io::partial::StagingDir;
use crate::io::{AtomicFile, FormatError, InitFile, PoseRecord, format_pose_csv};

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SynthError {
    /// The scenario name is not one of [`Scenario::all`].
    #[error("unknown scenario '{name}' (valid: {valid})")]
    UnknownScenario {
        /// The name given.
        name: String,
        /// The valid names, comma separated.
        valid: String,
    },
    /// The configuration is out of range (no frames, a bad size).
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),
    /// A file or directory could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A frame could not be encoded.
    #[error("{path}: {source}")]
    Image {
        /// The frame file.
        path: String,
        /// The cause.
        source: image::ImageError,
    },
    /// Writing `truth.csv` or `init.txt` failed.
    #[error(transparent)]
    Format(#[from] FormatError),
}

impl SynthError {
    fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            source,
        }
    }
}

/// A synthetic scenario: which object moves how.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Scenario {
    /// Head nodding: tilt `rx = 35° sin(2π s)` (`s` runs 0 → 1 over the sequence), ±35°.
    Nod,
    /// Head turning: pan `ry = 60° sin(2π s)`, ±60°.
    Pan,
    /// Head rolling in the image plane: `rz = 45° sin(2π s)`, ±45°.
    Roll,
    /// Head moving on all three axes (±25°, ±40°, ±20°, different frequencies) while
    /// translating (±5 cm sideways, ±2.5 cm up and down, +12 % depth) with changing speed.
    Combo,
    /// Head approaching to 0.6 of its initial depth and receding to 1.4 of it, no rotation.
    Depth,
    /// A box "car" seen from 15° above: translating (and approaching) throughout, turning
    /// 60° about its own up axis between 45 % and 90 % of the sequence, then holding. The turn
    /// is a 60° rotation about an axis tilted 15° from the camera's vertical, so its Euler
    /// angles at the end are about (rx, ry, rz) = (-13°, -57°, -24°), a car turning on a ground
    /// plane seen from above. (`rz` is that rotation's roll in `Rx Ry Rz`, not how far the
    /// car's outline turns in the image, about 14°: see the truth's ellipse above.)
    Car,
    /// A long sequence (default 2400 frames, the length of the paper's Lab sequence) of smooth
    /// random head motion on all axes (rx ±30°, ry ±45°, rz ±25°, plus translation), at a fixed
    /// speed per frame whatever the frame count.
    Long,
}

impl Scenario {
    /// All scenarios.
    pub fn all() -> &'static [Scenario] {
        &[
            Scenario::Nod,
            Scenario::Pan,
            Scenario::Roll,
            Scenario::Combo,
            Scenario::Depth,
            Scenario::Car,
            Scenario::Long,
        ]
    }

    /// The scenario's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Nod => "nod",
            Scenario::Pan => "pan",
            Scenario::Roll => "roll",
            Scenario::Combo => "combo",
            Scenario::Depth => "depth",
            Scenario::Car => "car",
            Scenario::Long => "long",
        }
    }

    /// The scenario of a name (case-insensitive).
    pub fn from_name(name: &str) -> Result<Scenario, SynthError> {
        let lower = name.trim().to_ascii_lowercase();
        Self::all()
            .iter()
            .copied()
            .find(|s| s.name() == lower)
            .ok_or_else(|| SynthError::UnknownScenario {
                name: name.to_string(),
                valid: Self::all()
                    .iter()
                    .map(|s| s.name())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// Default number of frames.
    pub fn default_frames(self) -> usize {
        match self {
            Scenario::Nod | Scenario::Pan => 180,
            Scenario::Roll | Scenario::Depth => 150,
            Scenario::Combo => 240,
            Scenario::Car => 200,
            Scenario::Long => 2400,
        }
    }

    /// The object this scenario moves.
    pub fn shape(self) -> Shape {
        match self {
            Scenario::Car => Shape::Box {
                half: nalgebra::Vector3::new(0.2, 0.065, 0.09),
            },
            _ => Shape::Ellipsoid {
                semi: nalgebra::Vector3::new(0.075, 0.1, 0.085),
            },
        }
    }
}

impl std::fmt::Display for Scenario {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Largest accepted image side (pixels).
pub const MAX_SIDE: u32 = 8192;
/// Most pixels of one frame: those the tracker reads without `--resize`
/// ([`crate::frames::y4m::MAX_PIXELS`], 8192x4096), so that every sequence rendered can be
/// tracked as it is.
pub const MAX_PIXELS: u64 = crate::frames::y4m::MAX_PIXELS;
/// Smallest accepted image side (pixels): the smallest at which every scenario's first
/// ellipse has semi-axes of 2 px or more, as a tracker's start needs (at 16 px the heads'
/// were 1.8 px wide, at 20 px the car's 2.0 px high).
pub const MIN_SIDE: u32 = 24;
/// Most frames of one sequence: 100000 frames of 160x120 are about 4 GB of PNG files, an
/// hour at 25 frames a second.
pub const MAX_FRAMES: usize = 100_000;

/// What to render.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SynthConfig {
    /// The scenario.
    pub scenario: Scenario,
    /// Number of frames (1 to [`MAX_FRAMES`]).
    pub frames: usize,
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels); width × height at most [`MAX_PIXELS`].
    pub height: u32,
    /// Seed of the textures, the noise and `long`'s motion.
    pub seed: u64,
}

impl SynthConfig {
    /// The scenario's defaults: its default frame count, 160x120 (the paper's size), seed 1.
    pub fn new(scenario: Scenario) -> Self {
        Self {
            scenario,
            frames: scenario.default_frames(),
            width: 160,
            height: 120,
            seed: 1,
        }
    }

    /// Checks the frame count and the size (sides and pixels).
    pub fn validate(&self) -> Result<(), SynthError> {
        if !(1..=MAX_FRAMES).contains(&self.frames) {
            return Err(SynthError::InvalidConfig(format!(
                "{} frames: the number of frames must be from 1 to {MAX_FRAMES}",
                self.frames
            )));
        }
        for (what, v) in [("width", self.width), ("height", self.height)] {
            if !(MIN_SIDE..=MAX_SIDE).contains(&v) {
                return Err(SynthError::InvalidConfig(format!(
                    "{what} {v} is outside {MIN_SIDE}..={MAX_SIDE}"
                )));
            }
        }
        check_pixels(self.width, self.height)
    }
}

/// Refuses a frame of more than [`MAX_PIXELS`] pixels.
fn check_pixels(w: u32, h: u32) -> Result<(), SynthError> {
    if u64::from(w) * u64::from(h) > MAX_PIXELS {
        return Err(SynthError::InvalidConfig(format!(
            "{w}x{h} is more than the {MAX_PIXELS} pixels a frame may have, as `track` reads them"
        )));
    }
    Ok(())
}

/// Parses an image size `WxH` (e.g. `160x120`), each side in [`MIN_SIDE`]`..=`[`MAX_SIDE`]
/// and at most [`MAX_PIXELS`] pixels in all.
pub fn parse_size(s: &str) -> Result<(u32, u32), SynthError> {
    let (w, h) =
        crate::frames::parse_wxh(s).map_err(|e| SynthError::InvalidConfig(e.to_string()))?;
    for v in [w, h] {
        if !(MIN_SIDE..=MAX_SIDE).contains(&v) {
            return Err(SynthError::InvalidConfig(format!(
                "size '{s}': each side must be within {MIN_SIDE}..={MAX_SIDE}"
            )));
        }
    }
    check_pixels(w, h)?;
    Ok((w, h))
}

/// Where a sequence [`write_sequence`] wrote into a folder lies in it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SequencePaths {
    /// The frames, `DIR/frames` (open with [`crate::frames::open`]).
    pub frames: PathBuf,
    /// The start and the camera, `DIR/init.txt` ([`crate::io::read_init`]): to track as
    /// `pftrack track DIR` does, start from its ellipse and set
    /// [`crate::tracker::TrackerConfig::camera_hfov_deg`] to its `hfov_deg`.
    pub init: PathBuf,
    /// The ground truth, `DIR/truth.csv` ([`crate::io::read_pose_csv`]), when there.
    pub truth: Option<PathBuf>,
}

impl SequencePaths {
    /// The sequence in `dir`, when `dir` holds one (a `frames` folder and an `init.txt`).
    pub fn find(dir: &Path) -> Option<Self> {
        let (frames, init, truth) = (
            dir.join("frames"),
            dir.join("init.txt"),
            dir.join("truth.csv"),
        );
        (frames.is_dir() && init.is_file()).then(|| Self {
            frames,
            init,
            truth: truth.is_file().then_some(truth),
        })
    }
}

/// What [`write_sequence`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthSummary {
    /// The configuration rendered.
    pub config: SynthConfig,
    /// The frames directory (`DIR/frames`).
    pub frames_dir: PathBuf,
    /// `DIR/truth.csv`.
    pub truth: PathBuf,
    /// `DIR/init.txt`.
    pub init_file: PathBuf,
    /// The initial ellipse written to `init.txt`.
    pub init: Ellipse,
}

/// The file name of frame `k`: `00000.png`, `00001.png`, ...
pub fn frame_name(k: usize) -> String {
    format!("{k:05}.png")
}

/// Renders a whole sequence into `dir`: `dir/frames/00000.png ...`, then `dir/truth.csv` (pose
/// CSV) and `dir/init.txt` (`cx,cy,a,b` of frame 0).
///
/// A render in progress is never mistaken for a finished one, and a failed or interrupted
/// render leaves an earlier sequence in `dir` whole: the frames are rendered into a hidden
/// staging folder inside `dir/frames` (registered with [`crate::io::partial`], so an interrupt
/// removes it) and the truth and init file beside their names, and only when all are written
/// do they replace what `dir` held, in one move an interrupt waits for: the old `truth.csv`
/// and `init.txt` are removed, the frames moved into `dir/frames`, frames `00000.png`... of a
/// longer earlier render removed (regular files only), and the init file then the truth moved
/// in last; staging left by renders killed outright (unchanged for an hour) goes too. The
/// sequence's own files replace whatever has their names, a link included (not followed).
/// What would stop the move (a `frames` that is not a folder, a folder named like a frame),
/// and frames in `dir/frames` without a `truth.csv` or `init.txt` beside them (not a
/// render's, which it would replace or remove), are refused before anything is rendered or
/// moved; only an I/O error in the move itself could leave `dir` without a `truth.csv`, which
/// reads as unfinished. Folders this render made are removed again when it fails. Frames
/// render in parallel (rayon); `progress` shows an indicatif bar on stderr.
pub fn write_sequence(
    cfg: &SynthConfig,
    dir: &Path,
    progress: bool,
) -> Result<SynthSummary, SynthError> {
    stage_sequence(cfg, dir, progress)?.commit(&[])
}

/// A sequence rendered by [`stage_sequence`] and not yet in place: its frames in a hidden
/// staging folder inside `DIR/frames` ([`StagedSequence::frames_dir`], where they can be read
/// meanwhile), its truth and init file held. [`StagedSequence::commit`] moves it into place as
/// [`write_sequence`] does, with other outputs of the caller's in the same move; dropped
/// uncommitted, it is removed and `DIR` is as it was.
#[derive(Debug)]
pub struct StagedSequence {
    stage: Staging,
    truth: Vec<PoseRecord>,
    init_text: String,
    summary: SynthSummary,
}

impl StagedSequence {
    /// The folder the frames are in until the commit (`00000.png`, `00001.png`, ...).
    pub fn frames_dir(&self) -> &Path {
        self.stage.stage.path()
    }

    /// The init file's ellipse (frame 0's) as the file holds it, rounded as written, so that
    /// a track started from it is the track `pftrack track DIR` gives.
    pub fn init(&self) -> Result<Ellipse, SynthError> {
        Ok(crate::io::init::parse_init(&self.init_text, &self.summary.init_file)?.ellipse)
    }

    /// The camera's horizontal field of view in degrees, as the init file gives it.
    pub fn hfov_deg(&self) -> f64 {
        HFOV_DEG
    }

    /// Moves the sequence into place (see [`write_sequence`]) and writes each `(path, text)`
    /// of `also` (files of the caller's, outside the sequence's own names) in the same move:
    /// each written beside its name first, then renamed in under the lock an interrupt waits
    /// for, so that an interrupt finds the new sequence with them or the old one with what
    /// they replace. Returns where the sequence went.
    pub fn commit(self, also: &[(&Path, &str)]) -> Result<SynthSummary, SynthError> {
        let frames = self.summary.config.frames;
        self.stage.finish(
            frames,
            &format_pose_csv(&self.truth, false),
            &self.init_text,
            also,
        )?;
        Ok(self.summary)
    }
}

/// Renders a sequence as [`write_sequence`] does but leaves it staged ([`StagedSequence`]):
/// for a caller that reads the frames and commits its own outputs together with them (the
/// `demo` command's poses beside its sequence).
pub fn stage_sequence(
    cfg: &SynthConfig,
    dir: &Path,
    progress: bool,
) -> Result<StagedSequence, SynthError> {
    use rayon::prelude::*;

    let renderer = Renderer::new(cfg)?;
    let stage = Staging::create(dir, cfg.frames)?;

    let bar = if progress {
        let bar = indicatif::ProgressBar::new(cfg.frames as u64);
        if let Ok(style) =
            indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} frames ({eta})")
        {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(format!("synth {}", cfg.scenario));
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };

    let truth: Vec<crate::geometry::PoseState> = (0..cfg.frames)
        .into_par_iter()
        .map(|k| {
            let (img, state) = renderer.render(k);
            write_png(&img, &stage.frame(k))?;
            bar.inc(1);
            Ok(state)
        })
        .collect::<Result<_, SynthError>>()?;
    bar.finish_and_clear();

    let records: Vec<PoseRecord> = truth
        .iter()
        .enumerate()
        .map(|(frame, state)| PoseRecord {
            frame,
            state: *state,
            score: None,
            lost: None,
            theta: None,
        })
        .collect();
    let s0 = truth[0];
    let init = Ellipse::new(s0.cx, s0.cy, s0.a, s0.b);
    let init_text = format_init(&InitFile {
        ellipse: init,
        hfov_deg: Some(HFOV_DEG),
    });
    Ok(StagedSequence {
        stage,
        truth: records,
        init_text,
        summary: SynthSummary {
            config: *cfg,
            frames_dir: dir.join("frames"),
            truth: dir.join(TRUTH),
            init_file: dir.join(INIT),
            init,
        },
    })
}

/// The truth's file name in a sequence folder.
const TRUTH: &str = "truth.csv";
/// The init file's name in a sequence folder.
const INIT: &str = "init.txt";

/// The hidden folder inside `DIR/frames` that a render writes its frames into
/// ([`StagingDir`]), moved into place by [`Staging::finish`]; dropped unfinished, it is
/// removed, with the folders this render made when nothing else is in them.
#[derive(Debug)]
struct Staging {
    /// The sequence folder.
    dir: PathBuf,
    /// `DIR/frames`.
    frames_dir: PathBuf,
    /// The staging folder inside it: on the same file system as the frames' places, however
    /// `frames` is linked, so the frames move in by renaming.
    stage: StagingDir,
}

impl Staging {
    /// Checks that the frames of a `frames`-long sequence can be moved into `dir`, then makes
    /// `dir/frames` as need be (registering what it makes) and the staging folder inside.
    fn create(dir: &Path, frames: usize) -> Result<Self, SynthError> {
        let frames_dir = dir.join("frames");
        for d in [dir, frames_dir.as_path()] {
            // A link to nothing is not a folder, and cannot be made one.
            if std::fs::symlink_metadata(d).is_ok() && !d.is_dir() {
                return Err(SynthError::io(d, not_a_folder()));
            }
        }
        // Frames where no sequence of ours is (neither truth nor init file beside them) are
        // someone else's: a render would replace them, and remove those past its length.
        if !dir.join(TRUTH).exists()
            && !dir.join(INIT).exists()
            && let Some(found) = first_frame_file(&frames_dir)
        {
            return Err(SynthError::io(
                &frames_dir,
                std::io::Error::new(
                    std::io::ErrorKind::AlreadyExists,
                    format!(
                        "holds {found} but no {TRUTH} or {INIT} is beside it, so these are not \
                         frames a render left: choose another folder, or empty this one"
                    ),
                ),
            ));
        }
        let names = (0..frames).map(|k| frames_dir.join(frame_name(k)));
        for to in names.chain([TRUTH, INIT].map(|n| dir.join(n))) {
            if to.is_dir() {
                return Err(SynthError::io(&to, is_a_folder()));
            }
        }
        let stage = StagingDir::create(&frames_dir, "pftrack-synth")
            .map_err(|e| SynthError::io(&frames_dir, e))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            frames_dir,
            stage,
        })
    }

    /// Where frame `k` is rendered.
    fn frame(&self, k: usize) -> PathBuf {
        self.stage.path().join(frame_name(k))
    }

    /// Writes the truth and the init file beside their names, then moves the sequence into
    /// place (see [`write_sequence`]) under the registry's lock, so that an interrupt waits
    /// for it and finds either the old sequence or the new.
    fn finish(
        mut self,
        frames: usize,
        truth: &str,
        init: &str,
        also: &[(&Path, &str)],
    ) -> Result<(), SynthError> {
        // Beside their names, named after this render's staging folder so that two renders
        // into one folder do not share them; a link of that name is replaced, not followed.
        let staging = self.stage.path().file_name().unwrap_or_default();
        let staging = staging.to_string_lossy().into_owned();
        let prepare = |name: &str, text: &str| -> Result<Prepared, SynthError> {
            let path = self.dir.join(name);
            let partial = self.dir.join(format!("{staging}-{name}"));
            let mut f = AtomicFile::create_replacing(&path, partial)?;
            std::io::Write::write_all(&mut f, text.as_bytes())
                .map_err(|e| SynthError::io(&path, e))?;
            Ok(f.prepare()?)
        };
        let mut init = prepare(INIT, init)?;
        let mut truth = prepare(TRUTH, truth)?;
        let mut others = also
            .iter()
            .map(|&(path, text)| -> Result<Prepared, SynthError> {
                let mut f = AtomicFile::create(path)?;
                std::io::Write::write_all(&mut f, text.as_bytes())
                    .map_err(|e| SynthError::io(path, e))?;
                Ok(f.prepare()?)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let (dir, frames_dir) = (&self.dir, &self.frames_dir);
        let stage_path = self.stage.path().to_path_buf();
        self.stage.commit(|| -> Result<(), SynthError> {
            for name in [TRUTH, INIT] {
                let p = dir.join(name);
                match std::fs::remove_file(&p) {
                    Ok(()) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(e) => return Err(SynthError::io(&p, e)),
                }
            }
            for k in 0..frames {
                let to = frames_dir.join(frame_name(k));
                std::fs::rename(stage_path.join(frame_name(k)), &to)
                    .map_err(|e| SynthError::io(&to, e))?;
            }
            remove_stale_frames(frames_dir, frames)?;
            init.rename_now()?;
            truth.rename_now()?;
            for f in &mut others {
                f.rename_now()?;
            }
            let _ = std::fs::remove_dir(&stage_path);
            Ok(())
        })?;
        remove_abandoned(&self.frames_dir, &self.dir);
        Ok(())
    }
}

/// How long a staging folder or file goes unchanged before a render takes it for one a
/// killed render left (a render adds a frame every few milliseconds).
const ABANDONED_AFTER: std::time::Duration = std::time::Duration::from_secs(3600);

/// Removes what renders killed outright (no clean-up runs on `SIGKILL` or a power cut) left
/// in `frames_dir` and `dir`: `.pftrack-synth-*` staging folders and files unchanged for
/// [`ABANDONED_AFTER`]. A render in progress in the same folder keeps changing its own.
fn remove_abandoned(frames_dir: &Path, dir: &Path) {
    for folder in [frames_dir, dir] {
        let Ok(entries) = std::fs::read_dir(folder) else {
            continue;
        };
        for entry in entries.flatten() {
            let name = entry.file_name();
            if !name.to_string_lossy().starts_with(".pftrack-synth-") {
                continue;
            }
            let old = entry
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| t.elapsed().ok())
                .is_some_and(|age| age > ABANDONED_AFTER);
            if old {
                let p = entry.path();
                let _ = if p.is_dir() {
                    std::fs::remove_dir_all(&p)
                } else {
                    std::fs::remove_file(&p)
                };
            }
        }
    }
}

fn not_a_folder() -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::NotADirectory, "not a folder")
}

fn is_a_folder() -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::IsADirectory,
        "is a folder: the sequence's file of that name cannot replace it",
    )
}

/// Writes a frame as PNG, complete or not at all ([`crate::output::write_png`]).
fn write_png(img: &image::RgbImage, path: &Path) -> Result<(), SynthError> {
    crate::output::write_png(path, img).map_err(|e| match e {
        crate::output::OutputError::File(f) => SynthError::Format(f),
        crate::output::OutputError::Encode { path, source } => SynthError::Image { path, source },
    })
}

/// The index of a file named like a frame ([`frame_name`]: `NNNNN.png`), or `None` for
/// any other name.
fn frame_index(name: &str) -> Option<usize> {
    let stem = name.strip_suffix(".png")?;
    if stem.len() == 5 && stem.bytes().all(|b| b.is_ascii_digit()) {
        stem.parse().ok()
    } else {
        None
    }
}

/// The name of a file (not a folder) named like a frame in `frames_dir`, if it holds one.
fn first_frame_file(frames_dir: &Path) -> Option<String> {
    let entries = std::fs::read_dir(frames_dir).ok()?;
    entries.flatten().find_map(|e| {
        let name = e.file_name().to_str()?.to_string();
        let file = e.file_type().is_ok_and(|t| !t.is_dir());
        (file && frame_index(&name).is_some()).then_some(name)
    })
}

/// Removes `NNNNN.png` frames (regular files) with an index of `frames` or more (from an earlier,
/// longer render)
/// and the temporary files of frames an interrupted render left behind.
fn remove_stale_frames(frames_dir: &Path, frames: usize) -> Result<(), SynthError> {
    let entries = std::fs::read_dir(frames_dir).map_err(|e| SynthError::io(frames_dir, e))?;
    for entry in entries {
        let entry = entry.map_err(|e| SynthError::io(frames_dir, e))?;
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        // the temporary file of a frame whose render was interrupted (`.NNNNN.png.partial`
        // before 2026-12-06, `.NNNNN.png.PID-N.partial` since)
        let partial = name.strip_prefix('.').is_some_and(|n| {
            n.strip_suffix(".partial")
                .and_then(|n| n.get(..9))
                .is_some_and(|frame| frame_index(frame).is_some())
        });
        if partial {
            let p = entry.path();
            std::fs::remove_file(&p).map_err(|e| SynthError::io(&p, e))?;
            continue;
        }
        if frame_index(name).is_some_and(|k| k >= frames)
            && entry.file_type().is_ok_and(|t| t.is_file())
        {
            let p = entry.path();
            std::fs::remove_file(&p).map_err(|e| SynthError::io(&p, e))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scenario_names_round_trip() {
        for &s in Scenario::all() {
            assert_eq!(Scenario::from_name(s.name()).unwrap(), s);
            assert_eq!(Scenario::from_name(&s.name().to_uppercase()).unwrap(), s);
        }
        let e = Scenario::from_name("wobble").unwrap_err().to_string();
        assert!(
            e.contains("wobble") && e.contains("nod") && e.contains("long"),
            "{e}"
        );
    }

    #[test]
    fn sizes() {
        assert_eq!(parse_size("160x120").unwrap(), (160, 120));
        assert_eq!(parse_size(" 640X480 ").unwrap(), (640, 480));
        for bad in [
            "", "160", "160x", "x120", "0x120", "160x0", "-1x5", "axb", "99999x10", "8x8",
        ] {
            assert!(parse_size(bad).is_err(), "accepted {bad:?}");
        }
    }

    #[test]
    fn config_validation() {
        let mut c = SynthConfig::new(Scenario::Nod);
        assert!(c.validate().is_ok());
        c.frames = 0;
        assert!(c.validate().is_err());
        c.frames = 1;
        c.width = 4;
        assert!(c.validate().is_err());
    }
}

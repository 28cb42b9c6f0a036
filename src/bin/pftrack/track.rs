//! `pftrack track`: tracks an object and estimates its pose through a video.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use pftrack::frames::Rescale;
use pftrack::frames::{self, SourceOptions};
use pftrack::geometry::{BoxRect, Ellipse, Euler};
use pftrack::io::StagingDir;
use pftrack::io::{InitFile, PoseCsvWriter};
// Rendered frames are numbered as synthetic ones are: NNNNN.png.
use pftrack::likelihood::{Backend, create_engine};
use pftrack::output::{Overlay, VideoWriter, default_scale, render_overlay, write_png};
use pftrack::synth::frame_name;
use pftrack::tracker::{
    ColourUpdate, Estimate, Init, InitFault, InitRefine, MAX_WEIGHT, Mode, TrackError, Tracker,
    TrackerConfig, refined_start,
};

use crate::values;

/// Arguments of `pftrack track`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct TrackArgs {
    /// A directory of frames, a .y4m file, `-` for a y4m stream on standard input, or any
    /// video ffmpeg reads. A directory written by `pftrack synth` (with frames/ and init.txt)
    /// is accepted as is.
    pub input: PathBuf,
    /// Initial ellipse `cx,cy,a,b[,angle_deg]` in pixels.
    #[arg(
        long,
        value_name = "CX,CY,A,B[,ANGLE]",
        group = "init",
        allow_hyphen_values = true,
        value_parser = values::four_or_five
    )]
    pub init_ellipse: Option<String>,
    /// Initial box `x,y,w,h` (top-left corner, pixels); its inscribed ellipse is tracked.
    /// Corners are in the README's pixel coordinates, which put the top-left pixel's centre
    /// at 0,0: a box of whole pixels from column x0 (OpenCV's `Rect`, `selectROI`) starts at
    /// x0 - 0.5 (an OTB file's 1-based x at x - 1.5, as `--init-truth` reads it).
    #[arg(
        long,
        value_name = "X,Y,W,H",
        group = "init",
        allow_hyphen_values = true,
        value_parser = values::four
    )]
    pub init_box: Option<String>,
    /// Points around the object `"x1,y1;x2,y2;..."` (at least 5): a least-squares ellipse.
    #[arg(
        long,
        value_name = "X,Y;X,Y;...",
        group = "init",
        allow_hyphen_values = true,
        value_parser = values::points
    )]
    pub init_points: Option<String>,
    /// An init file `cx,cy,a,b[,angle]` (what `pftrack synth` writes).
    #[arg(long, value_name = "FILE", group = "init")]
    pub init_file: Option<PathBuf>,
    /// Ground truth to start from: the row of a pose CSV for the frame tracking starts on
    /// (frame 0, or --start-frame's; its ellipse and pose) or that frame's box in an OTB box
    /// file.
    #[arg(long, value_name = "FILE", group = "init")]
    pub init_truth: Option<PathBuf>,
    /// Initial pose `rx,ry,rz` in degrees, each within 360 either way [default: frontal
    /// 0,0,0, or that of the start frame's row with `--init-truth` on a pose CSV].
    #[arg(
        long,
        value_name = "RX,RY,RZ",
        allow_hyphen_values = true,
        value_parser = values::three
    )]
    pub init_pose: Option<String>,
    /// Number of particles.
    #[arg(long, default_value_t = 200)]
    pub particles: usize,
    /// Share of the particles proposed at their previous centre and size instead of where
    /// block matching and the keyframe fits moved them (their rotation still as measured; 0
    /// to under 1, 0 by default, as in the paper): a guard against one wrong motion
    /// measurement, for footage at a low frame rate or with jumps (0.2: car4 with every
    /// fourth frame, success AUC 0.40 -> 0.55), at some cost to the angles on smooth footage
    /// (see `FilterParams::still_share`).
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    pub still_share: Option<f64>,
    /// Seed of the filter (runs are reproducible for a seed on the CPU).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The system: sea (full), optimal (certified solver), tpe (tracking then pose), rls.
    #[arg(long, default_value = "sea", value_parser = values::mode)]
    pub mode: Mode,
    /// Likelihood engine: auto (the GPU if a hardware Vulkan adapter exists, or the one PFTRACK_ADAPTER names, an error if it names none; else the CPU), cpu or gpu (any Vulkan adapter, software ones too).
    #[arg(
        long,
        default_value = "auto",
        hide_possible_values = true,
        ignore_case = true
    )]
    pub backend: Backend,
    /// The camera's horizontal field of view in degrees, for the perspective form of the
    /// keyframe depth prior and of the turned first view; when absent, the --init-file's
    /// (`hfov,DEG`, which `pftrack synth` writes), else that of the input directory's
    /// `init.txt` (however the target is initialised), else weak perspective (the paper's
    /// model).
    /// Weak perspective over-reads the tilt of a near head by about a tenth (see
    /// `TrackerConfig::camera_hfov_deg`).
    #[arg(long, value_name = "DEG", conflicts_with = "weak_perspective")]
    pub hfov: Option<f64>,
    /// Weak perspective even when the init file gives the camera.
    #[arg(long)]
    pub weak_perspective: bool,
    /// Depth relief of the target's visible surface relative to its size, for the feature
    /// term and the keyframe fits: 1 for a head (the default), less for a flatter target,
    /// e.g. about 0.25 for a car's rear seen from behind. Too much depth lets sideways motion
    /// pass for a turn.
    #[arg(long, value_name = "R", default_value_t = 1.0)]
    pub depth_ratio: f64,
    /// Edge threshold of the contour term (luma per pixel, half the luma step across a pixel
    /// pair; the library's default, 0.05, when absent): weaker gradient maxima are not edges.
    /// 0.1 tracks real footage much better and synthetic footage worse; see
    /// `LikelihoodParams::edge_threshold` for the figures.
    #[arg(long, value_name = "T")]
    pub edge_threshold: Option<f64>,
    /// Fit each frame's rotation against the keyframes by least squares alone, without
    /// holding it to the previous estimate (the motion prior, on by default; see
    /// `TrackerConfig::fit_pixel_sigma`).
    #[arg(long)]
    pub no_fit_prior: bool,
    /// σ in pixels of the keyframe fits' centre about where block matching predicts it, in
    /// the motion prior: it keeps a turn from passing for a shift (see
    /// `TrackerConfig::fit_centre_sigma`).
    #[arg(
        long,
        value_name = "PX",
        default_value_t = 0.5,
        conflicts_with_all = ["no_fit_centre_prior", "no_fit_prior"]
    )]
    pub fit_centre_sigma: f64,
    /// Leave the keyframe fits' centre free in the motion prior (the prior then holds the
    /// rotation alone).
    #[arg(long, conflicts_with = "no_fit_prior")]
    pub no_fit_centre_prior: bool,
    /// Measure each frame only against the keyframes nearest the previous estimate, without
    /// the free fit against the first view that resets the chain's drift when it fits tightly
    /// (see `TrackerConfig::anchor_refit`).
    #[arg(long)]
    pub no_anchor_refit: bool,
    /// Fit every keyframe on the ellipsoid alone, without adjusting its features' depths
    /// with the views that matched it (see `TrackerConfig::bundle`).
    #[arg(long)]
    pub no_bundle: bool,
    /// Learn over the keyframes' adjustments how much flatter or deeper than its ellipsoid
    /// the object is, with this σ on the factor's log, and lift every fit's features with
    /// it: for objects that are not head-shaped (1 for a vehicle or a box; it costs heads'
    /// pans; from 0.001 to 1000). Off by default; see `TrackerConfig::bundle`.
    #[arg(long, value_name = "SIGMA", conflicts_with = "no_bundle")]
    pub relief_sigma: Option<f64>,
    /// Hold the rotation still on frames where nothing measured it, as the paper's random
    /// walk does, instead of carrying on the estimate's recent turn (see
    /// `TrackerConfig::coast_rate`).
    #[arg(long)]
    pub no_coast: bool,
    /// How the colour model adapts: after each confident frame it moves this share (0.1 is a
    /// memory of about ten frames) towards the colours inside the estimate, for targets whose
    /// colours change as they turn or the light changes (see `TrackerConfig::colour_update`).
    /// 0 keeps the first frame's model throughout, as the paper does.
    #[arg(long, value_name = "R", default_value_t = ColourUpdate::default().rate)]
    pub colour_rate: f64,
    /// The colour model adapts only while its Bhattacharyya similarity with the colours of a
    /// ring around the target is at most this (1 adapts whatever the surroundings look
    /// like): where they look like the target, a drift onto them would pass unnoticed and be
    /// learnt (see `ColourUpdate::max_ring_similarity`).
    #[arg(long, value_name = "RHO", default_value_t = ColourUpdate::default().max_ring_similarity)]
    pub colour_max_ring: f64,
    /// Widen the range of shapes the ellipse may take by this factor: by default its aspect
    /// stays within what the object model's outlines can show (the first ellipse, as deep as
    /// `--depth-ratio` says; see `TrackerConfig::aspect_slack`).
    #[arg(
        long,
        value_name = "K",
        default_value_t = 1.0,
        conflicts_with = "no_aspect_bound"
    )]
    pub aspect_slack: f64,
    /// Leave the ellipse's aspect free, as the paper does.
    #[arg(long)]
    pub no_aspect_bound: bool,
    /// Undo a change of light over the whole frame of more than this share from one frame
    /// to the next (a camera's exposure stepping, a light switched), so the colour model
    /// still recognises the target (see `TrackerConfig::exposure_jump`).
    #[arg(
        long,
        value_name = "SHARE",
        default_value_t = 0.15,
        conflicts_with = "no_exposure"
    )]
    pub exposure_jump: f64,
    /// Take every frame's light as it comes, as the paper does.
    #[arg(long)]
    pub no_exposure: bool,
    /// While the target is uncertain (lost, or after a frame below --trust-above), keep the
    /// ellipse's semi-axes within this factor of the last trusted estimate's, so a
    /// likelihood that has lost the target cannot shrink it to a few pixels (see
    /// `TrackerConfig::size_hold`).
    #[arg(
        long,
        value_name = "K",
        default_value_t = 1.2,
        conflicts_with = "no_size_hold"
    )]
    pub size_hold: f64,
    /// Leave the ellipse's size free while the target is uncertain, as the paper does.
    #[arg(long)]
    pub no_size_hold: bool,
    /// Trust a frame's estimate from this confidence on: its size is the one --size-hold
    /// holds later frames near (below it the size is held), and its rotation the one a lost
    /// target is looked for in; 0.5 tracks as before 2026-12-07 (see
    /// `TrackerConfig::trust_above`).
    #[arg(long, value_name = "C", default_value_t = 0.7)]
    pub trust_above: f64,
    /// Once lost, count the target as found again only on a frame with at least this
    /// confidence (or when a search finds it with at least this confidence), so that a
    /// confidence hovering about the lost threshold does not flip the flag (see
    /// `TrackerConfig::found_above`).
    #[arg(long, value_name = "C", default_value_t = 0.5)]
    pub found_above: f64,
    /// A lost target searched for is recognised by its grey levels when they correlate at
    /// least this much with its template, as well as by its features (see
    /// `TrackerConfig::reacquire_ncc`).
    #[arg(
        long,
        value_name = "NCC",
        default_value_t = 0.5,
        conflicts_with = "no_template_reacquire"
    )]
    pub reacquire_ncc: f64,
    /// Recognise a lost target searched for by its features alone.
    #[arg(long)]
    pub no_template_reacquire: bool,
    /// Re-anchor the target on its first view where that is found beside the estimate at
    /// least this correlation, and clearly better than the estimate explains it (see
    /// `TrackerConfig::reanchor`).
    #[arg(
        long,
        value_name = "NCC",
        default_value_t = 0.7,
        conflicts_with = "no_reanchor"
    )]
    pub reanchor_ncc: f64,
    /// Leave the estimate to the filter: no re-anchoring on the first view.
    #[arg(long)]
    pub no_reanchor: bool,
    /// Refine the initial ellipse on the first frame onto the nearest edges and colour
    /// boundary before anything is learnt from it: for a start drawn by hand, a few pixels
    /// off the object (see `TrackerConfig::init_refine`). The first row of the poses gives
    /// the ellipse used.
    #[arg(long)]
    pub refine_init: bool,
    /// Search targets at least this large (equal-area diameter `2·sqrt(a b)`, pixels) for SIFT
    /// features without the doubled first octave: about half the time on large targets,
    /// with the same accuracy (see `TrackerConfig::sift_upsample_below`).
    #[arg(
        long,
        value_name = "PX",
        default_value_t = 120.0,
        conflicts_with = "sift_always_upsample"
    )]
    pub sift_upsample_below: f64,
    /// Double the first SIFT octave whatever the target's size, as Lowe's SIFT does.
    #[arg(long)]
    pub sift_always_upsample: bool,
    /// Estimate the rotation between successive frames from any 3 or more matches, as the
    /// paper does, instead of from at least 5 that one affine map carries to within 1 px
    /// (see `pose::Consensus`).
    #[arg(long)]
    pub no_interframe_consensus: bool,
    /// Scale the ellipse in the proposal by the size change block matching and the keyframe
    /// fits measure between frames. Off by default, as in the paper: on real footage that
    /// change follows the background too (see `TrackerConfig::motion_scale`).
    #[arg(long)]
    pub motion_scale: bool,
    /// Weight of the contrast term: the target's colours against a ring around it, which
    /// keeps the ellipse to the target's size (see `tracker::Contrast`). 0 leaves the
    /// paper's three terms alone.
    #[arg(long, value_name = "W", default_value_t = pftrack::tracker::Contrast::default().weight)]
    pub contrast_weight: f64,
    /// Weight of the feature term in the particle weights. Higher follows the rotation more
    /// closely on sharp, well-textured footage and loses blurred real footage sooner; 0
    /// weighs the particles by colour and contour alone (see
    /// `TrackerConfig::feature_weight` for the measurements).
    #[arg(long, value_name = "W", default_value_t = TrackerConfig::default().feature_weight)]
    pub feature_weight: f64,
    /// Weight of the appearance-template term: the normalised cross-correlation of the grey
    /// levels inside each particle's ellipse with a template of the target (see
    /// `likelihood::template`). 0 leaves the histogram, contour and feature terms alone.
    #[arg(long, value_name = "W", default_value_t = pftrack::tracker::TemplateTerm::default().weight)]
    pub template_weight: f64,
    /// Share per confident frame by which the template follows the target's view; 0 keeps
    /// the first frame's.
    #[arg(long, value_name = "R", default_value_t = pftrack::tracker::TemplateTerm::default().rate)]
    pub template_rate: f64,
    /// Weight of the first view turned with each particle's rotation and compared with the
    /// frame (`TemplateTerm::anchor_weight`): it counts where the first view is recognised
    /// (correlation above 0.65), and sees the rotation. 0 leaves it out; it needs the template
    /// term on. 40 by default, 80 when the camera is known
    /// (`TemplateTerm::anchor_weight_camera`).
    #[arg(long, value_name = "W")]
    pub anchor_weight: Option<f64>,
    /// The tracker's settings from a JSON file, in place of the flags that tune them (which
    /// it cannot be given with): the fields of the library's `TrackerConfig`, any left out
    /// taking their defaults, e.g. `{"seed": 3, "filter": {"particles": 500}, "bundle":
    /// null}`; a name that is not a setting is refused, and a nested part given in part
    /// keeps the defaults of the rest of it. --hfov and --weak-perspective still choose the
    /// camera; without them it is the file's `camera_hfov_deg`, or where the file gives none
    /// (or `null`) the init file's, as without --config.
    #[arg(
        long,
        value_name = "FILE",
        conflicts_with_all = [
            "particles", "still_share", "seed", "mode", "depth_ratio", "edge_threshold", "no_fit_prior",
            "fit_centre_sigma", "no_fit_centre_prior", "no_anchor_refit", "no_bundle", "relief_sigma",
            "no_coast", "colour_rate", "colour_max_ring", "aspect_slack", "no_aspect_bound",
            "exposure_jump", "no_exposure",
            "size_hold", "no_size_hold", "trust_above", "found_above", "reacquire_ncc",
            "no_template_reacquire", "reanchor_ncc", "no_reanchor", "refine_init",
            "sift_upsample_below", "sift_always_upsample", "no_interframe_consensus",
            "motion_scale", "contrast_weight", "feature_weight", "template_weight",
            "template_rate", "anchor_weight",
        ]
    )]
    pub config: Option<PathBuf>,
    /// Resize every frame to WxH first (shrinking, each pixel the mean of those it covers).
    /// The start (--init-*) is read, and the poses are written, in the input's own pixels;
    /// the rendered frames (--render) are the resized ones, and settings in pixels (a
    /// --config file's filter bounds and noise, --fit-centre-sigma, --sift-upsample-below)
    /// are of the resized frames. Without it, frames longer than 800 px are tracked shrunk
    /// toward 640 px on their longer side, as far as the start keeps semi-axes of 64 and 16
    /// px (faster, and as accurate as at full size), and not where the settings would refuse
    /// the start there.
    #[arg(
        long,
        value_name = "WxH",
        value_parser = values::size,
        allow_hyphen_values = true,
        conflicts_with = "full_size"
    )]
    pub resize: Option<String>,
    /// Track the frames at the input's own size (frames longer than 800 px are otherwise
    /// tracked shrunk: see --resize; over 2^25 pixels, --resize is still needed).
    #[arg(long)]
    pub full_size: bool,
    /// Start tracking at frame N of the input (counting from 0; the frames before it are
    /// passed over, an image folder's without decoding them: only the first image's header
    /// is read, for the size every frame must have). The start (--init-*) describes
    /// frame N (--init-truth reads its row or box for frame N), the angles are measured from
    /// --init-pose there, and the poses keep the input's frame numbers (the first row is
    /// frame N); frames drawn with --render are numbered from 00000.png, each showing its
    /// frame number in the input.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub start_frame: usize,
    /// Stop after this many frames (counted from the start, --start-frame).
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Pose CSV to write (`frame,cx,cy,a,b,rx,ry,rz,score,lost,theta`); standard output if absent
    /// or `-`. Either way the poses are written once the whole track is done, so that a run
    /// that fails part-way writes none (see --stream for rows as they come).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Write each pose row to standard output as soon as its frame is tracked, flushed, instead
    /// of all at the end: for live input, such as a camera through ffmpeg (`ffmpeg -f v4l2 -i
    /// /dev/video0 -f yuv4mpegpipe - | pftrack track - --init-box ... --stream`). A run that
    /// fails part-way has then written the rows of the frames before the failure, and its
    /// error says how many; it still exits non-zero. Not with --out FILE, which is written
    /// whole or not at all.
    #[arg(long)]
    pub stream: bool,
    /// Write each frame with the ellipse, pan/tilt bars and angles drawn, as PNG (NNNNN.png),
    /// here. The frames are drawn into a hidden folder inside and moved into place when the
    /// whole track is done: a run that fails leaves the folder as it found it, as it writes no
    /// pose CSV. One that succeeds replaces an earlier render there: its frames that follow
    /// this track's last are removed. A folder holding frames that no render of pftrack's
    /// left (no `.pftrack-render` in it) is refused. Frames under 320 px wide are drawn
    /// scaled up to at least 320, at most 4 times (160x120 twice, 128x96 three times); all
    /// at one size, so `ffmpeg -i DIR/%05d.png` makes a video of them. The frames drawn are
    /// those tracked: shrunk where the input's are (see --resize; --full-size draws them at
    /// the input's size).
    #[arg(long, value_name = "DIR")]
    pub render: Option<PathBuf>,
    /// Write the frames as --render draws them (the ellipse, the bars, the angles) as one
    /// video through ffmpeg, in the container FILE's extension names: .mp4, .m4v, .mov, .mkv,
    /// .webm, .avi, .ts or .nut (4:2:0, an odd size padded by a pixel), .gif (at most 50
    /// frames a second) or .y4m, at --render-fps. With or without --render. Like the pose CSV
    /// it appears only once the whole track is done: ffmpeg finishes it before the CSV is
    /// written, and it moves in after, so a run that fails leaves neither.
    #[arg(long, value_name = "FILE")]
    pub render_video: Option<PathBuf>,
    /// Frame rate of --render-video, frames a second.
    #[arg(
        long,
        value_name = "FPS",
        default_value_t = 25.0,
        requires = "render_video"
    )]
    pub render_fps: f64,
}

pub fn parse_floats(s: &str, n: &[usize], what: &str) -> anyhow::Result<Vec<f64>> {
    values::numbers(s, n).map_err(|e| anyhow::anyhow!("{what}: {e}"))
}

/// The input's frames and init file, accepting a `pftrack synth` directory as is; one whose
/// `init.txt` is gone (the start given by a flag instead) still reads its `frames` folder,
/// where the directory itself holds no image.
fn resolve_input(input: &Path) -> (PathBuf, Option<PathBuf>) {
    if let Some(s) = pftrack::synth::SequencePaths::find(input) {
        return (s.frames, Some(s.init));
    }
    let frames = input.join("frames");
    let holds_none = |d: &Path| pftrack::frames::dir::list_images(d).is_ok_and(|f| f.is_empty());
    if input.is_dir() && frames.is_dir() && holds_none(input) && !holds_none(&frames) {
        return (frames, None);
    }
    (input.to_path_buf(), None)
}

/// The initial ellipse from whichever option was given, else from the `init.txt` of a
/// directory written by `synth`, with the camera's horizontal field of view when an init file
/// gives it, and the pose when the option gives one (`--init-truth` on a pose CSV). The
/// camera belongs to the footage: that directory gives its own however the target is
/// initialised, unless the init file given, `--hfov` or `--weak-perspective` decides it (its
/// file is then not read).
pub fn initial_ellipse(
    a: &TrackArgs,
    synth_init: Option<&Path>,
) -> anyhow::Result<(InitFile, Option<Euler>)> {
    // The sequence's own init file named as the start of a later frame.
    if let (Some(p), Some(f)) = (synth_init, a.init_file.as_deref())
        && a.start_frame > 0
        && crate::paths::same(f, p)
    {
        return Err(frame_zero_init(a.start_frame, p));
    }
    match (given_init(a)?, synth_init) {
        (Some((given, pose)), Some(p))
            if given.hfov_deg.is_none() && a.hfov.is_none() && !a.weak_perspective =>
        {
            let dir = pftrack::io::read_init(p)
                .with_context(|| format!("reading the camera in {}", p.display()))?;
            let file = InitFile {
                hfov_deg: dir.hfov_deg,
                ..given
            };
            Ok((file, pose))
        }
        (Some(given), _) => Ok(given),
        // The sequence's init file is its frame 0's.
        (None, Some(p)) if a.start_frame > 0 => Err(frame_zero_init(a.start_frame, p)),
        (None, Some(p)) => Ok((pftrack::io::read_init(p)?, None)),
        (None, None) => Err(crate::UsageError(
            "no initial ellipse: give one of --init-ellipse, --init-box, --init-points, \
             --init-file, --init-truth"
                .into(),
        )
        .into()),
    }
}

/// The refusal of a synthetic sequence's init file `init` (its frame 0's start) as the start of
/// frame `start`; `--init-truth` is suggested where the sequence's truth is there to read.
fn frame_zero_init(start: usize, init: &Path) -> anyhow::Error {
    let truth = init.with_file_name("truth.csv");
    let from_truth = if truth.is_file() {
        format!(
            "--init-truth {} reads it from the sequence's truth, or ",
            truth.display()
        )
    } else {
        String::new()
    };
    crate::UsageError(format!(
        "--start-frame {start}: {} gives the start of frame 0; give the start of frame {start} \
         ({from_truth}one of --init-ellipse, --init-box, --init-points)",
        init.display(),
    ))
    .into()
}

/// Where the start came from, for its errors: the option (with its file) that gave the
/// ellipse, or the sequence's init file; and what gave the pose.
struct StartSource {
    ellipse: String,
    /// `--init-pose`, or `--init-truth`'s row where it gave the pose; `None` for the default
    /// (frontal) pose.
    pose: Option<String>,
}

impl StartSource {
    fn of(a: &TrackArgs, synth_init: Option<&Path>) -> Self {
        let file = |flag: &str, p: &Path| format!("{flag} {}", p.display());
        let truth_row = a
            .init_truth
            .as_deref()
            .map(|p| format!("{}, frame {}", file("--init-truth", p), a.start_frame));
        let ellipse = if a.init_ellipse.is_some() {
            "--init-ellipse".to_string()
        } else if a.init_box.is_some() {
            "--init-box".to_string()
        } else if a.init_points.is_some() {
            "--init-points".to_string()
        } else if let Some(p) = &a.init_file {
            file("--init-file", p)
        } else if let Some(t) = &truth_row {
            t.clone()
        } else if let Some(p) = synth_init {
            p.display().to_string()
        } else {
            "no option".to_string()
        };
        let pose = match a.init_pose {
            Some(_) => Some("--init-pose".to_string()),
            None => truth_row,
        };
        Self { ellipse, pose }
    }

    /// The refusal of the start, named by the option that gave the value refused.
    fn name(&self, e: TrackError) -> anyhow::Error {
        let by = match (&e, &self.pose) {
            (
                TrackError::BadInit {
                    fault: InitFault::PoseOutOfRange,
                    ..
                },
                Some(pose),
            ) => pose,
            _ => &self.ellipse,
        };
        anyhow::Error::new(e).context(by.clone())
    }
}

/// The initial ellipse of the option given (`None` for none), with the camera when it is an
/// init file that gives one, and the pose of `--init-truth`'s row for the frame tracking
/// starts on (`--start-frame`) when it is a pose CSV.
fn given_init(a: &TrackArgs) -> anyhow::Result<Option<(InitFile, Option<Euler>)>> {
    let start = a.start_frame;
    let no_camera = |ellipse| InitFile {
        ellipse,
        hfov_deg: None,
    };
    if let Some(s) = &a.init_ellipse {
        let v = parse_floats(s, &[4, 5], "--init-ellipse")?;
        let e = Ellipse {
            cx: v[0],
            cy: v[1],
            a: v[2],
            b: v[3],
            theta: v.get(4).copied().unwrap_or(0.0).to_radians(),
        };
        return Ok(Some((no_camera(e), None)));
    }
    if let Some(s) = &a.init_box {
        let v = parse_floats(s, &[4], "--init-box")?;
        if !(v[2] > 0.0 && v[3] > 0.0) {
            bail!(
                "--init-box {s}: the width and height must be positive, got {} x {}",
                v[2],
                v[3]
            );
        }
        let e = Ellipse::from_box(&BoxRect::new(v[0], v[1], v[2], v[3]));
        return Ok(Some((no_camera(e), None)));
    }
    if let Some(s) = &a.init_points {
        let pts: anyhow::Result<Vec<[f64; 2]>> = s
            .split(';')
            .filter(|t| !t.trim().is_empty())
            .map(|t| parse_floats(t, &[2], "--init-points").map(|v| [v[0], v[1]]))
            .collect();
        let pts = pts?;
        return pftrack::motion::fit_ellipse(&pts)
            .map(|e| Some((no_camera(e), None)))
            .context("--init-points: no ellipse fits these points");
    }
    if let Some(p) = &a.init_file {
        return Ok(Some((pftrack::io::read_init(p)?, None)));
    }
    if let Some(p) = &a.init_truth {
        return Ok(Some(match pftrack::eval::load_truth(p)? {
            // The start is the row of the frame tracking starts on: a CSV whose rows begin
            // later (a track's tail) has no start for it.
            pftrack::eval::Truth::Poses(r) => match r.iter().find(|row| row.frame == start) {
                Some(row) => (no_camera(row.ellipse()), Some(row.state.euler())),
                None => bail!(
                    "--init-truth {}: no row for frame {start}, the frame tracking starts on \
                     ({})",
                    p.display(),
                    match r.len() {
                        1 => format!("its one row is of frame {}", r[0].frame),
                        n => format!(
                            "its {n} rows run from frame {} to {}",
                            r[0].frame,
                            r[n - 1].frame
                        ),
                    }
                ),
            },
            pftrack::eval::Truth::Boxes(b) => {
                let Some(first) = b.get(start) else {
                    bail!(
                        "--init-truth {}: no box for frame {start}, the frame tracking starts \
                         on (it has {} box{}, for frames 0 to {})",
                        p.display(),
                        b.len(),
                        if b.len() == 1 { "" } else { "es" },
                        b.len() - 1
                    );
                };
                // OTB marks a frame without the target by a box of no size.
                if !(first.w > 0.0 && first.h > 0.0) {
                    bail!(
                        "--init-truth {}: the box of frame {start} has no size ({} x {}): the \
                         target is not in the frame tracking starts on",
                        p.display(),
                        first.w,
                        first.h
                    );
                }
                (no_camera(Ellipse::from_box(first)), None)
            }
        }));
    }
    Ok(None)
}

/// The tracker's settings from the tuning flags, and the camera `hfov` (degrees; `None` for
/// weak perspective).
fn flag_config(a: &TrackArgs, hfov: Option<f64>) -> anyhow::Result<TrackerConfig> {
    let mut cfg = config(a.mode, a.particles, a.seed)?;
    apply_hfov(&mut cfg, hfov)?;
    apply_depth_ratio(&mut cfg, a.depth_ratio)?;
    apply_edge_threshold(&mut cfg, a.edge_threshold)?;
    if a.no_fit_prior {
        cfg.fit_pixel_sigma = None;
    }
    cfg.fit_centre_sigma = (!a.no_fit_centre_prior).then_some(a.fit_centre_sigma);
    if a.no_anchor_refit {
        cfg.anchor_refit = None;
    }
    if a.no_bundle {
        cfg.bundle = None;
    }
    apply_relief_sigma(&mut cfg, a.relief_sigma)?;
    if let Some(s) = a.still_share {
        let range = pftrack::filter::STILL_SHARE_RANGE;
        if !range.contains(&s) {
            bail!(
                "--still-share must lie in [{}, {}), got {s}",
                range.start,
                range.end
            );
        }
        cfg.filter.still_share = s;
    }
    if a.no_coast {
        cfg.coast_rate = None;
    }
    cfg.aspect_slack = (!a.no_aspect_bound).then_some(a.aspect_slack);
    cfg.exposure_jump = (!a.no_exposure).then_some(a.exposure_jump);
    cfg.size_hold = (!a.no_size_hold).then_some(a.size_hold);
    cfg.trust_above = a.trust_above;
    cfg.found_above = a.found_above;
    cfg.reacquire_ncc = (!a.no_template_reacquire).then_some(a.reacquire_ncc);
    cfg.reanchor = (!a.no_reanchor).then_some(pftrack::tracker::Reanchor {
        min_ncc: a.reanchor_ncc,
        ..Default::default()
    });
    cfg.sift_upsample_below = (!a.sift_always_upsample).then_some(a.sift_upsample_below);
    cfg.init_refine = a.refine_init.then(InitRefine::default);
    cfg.motion_scale = a.motion_scale;
    if a.no_interframe_consensus {
        cfg.interframe_consensus = None;
    }
    cfg.contrast = if a.contrast_weight == 0.0 {
        None
    } else {
        Some(pftrack::tracker::Contrast {
            weight: a.contrast_weight,
            ..Default::default()
        })
    };
    apply_feature_weight(&mut cfg, a.feature_weight)?;
    apply_template(
        &mut cfg,
        a.template_weight,
        a.template_rate,
        a.anchor_weight,
    )?;
    if !(0.0..=1.0).contains(&a.colour_max_ring) {
        bail!("--colour-max-ring {} is not in [0, 1]", a.colour_max_ring);
    }
    if a.colour_rate == 0.0 && a.colour_max_ring != ColourUpdate::default().max_ring_similarity {
        bail!(
            "--colour-max-ring {} has no effect: --colour-rate 0 keeps the first frame's colour \
             model",
            a.colour_max_ring
        );
    }
    cfg.colour_update = if a.colour_rate == 0.0 {
        None
    } else {
        Some(ColourUpdate {
            rate: a.colour_rate,
            max_ring_similarity: a.colour_max_ring,
            ..Default::default()
        })
    };
    Ok(cfg)
}

/// The most a `--config` file may hold (a whole configuration is about 3 KiB): `/dev/zero`
/// given as one used to be read until memory ran out.
const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// The tracker's settings from `--config FILE`: a JSON object laid over the defaults, nested
/// objects field by field, so that a part given in part keeps the defaults of the rest of it
/// (`{"bundle": {"params": {"huber": 2}}}` keeps the tracker's rotation σ, not
/// `BundleParams`'s own default).
fn read_config(path: &Path) -> anyhow::Result<TrackerConfig> {
    use std::io::Read;
    let ctx = || format!("--config {}", path.display());
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(MAX_CONFIG_BYTES + 1).read_to_end(&mut bytes))
        .with_context(ctx)?;
    if bytes.len() as u64 > MAX_CONFIG_BYTES {
        bail!(
            "--config {}: more than {} bytes, not a settings file",
            path.display(),
            MAX_CONFIG_BYTES
        );
    }
    let text = String::from_utf8(bytes).with_context(ctx)?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let NoRepeats(given) = serde_json::from_str(text).with_context(ctx)?;
    // serde would also take a struct as a list of its fields in order: `[]` was the defaults.
    if !given.is_object() {
        bail!(
            "--config {}: the settings must be a JSON object, {{\"name\": value, ...}}",
            path.display()
        );
    }
    let mut merged = serde_json::to_value(TrackerConfig::default()).with_context(ctx)?;
    overlay(&mut merged, given);
    serde_json::from_value(merged).with_context(ctx)
}

/// A JSON value whose objects name each key once: serde_json keeps the last of a repeated
/// key, so `{"filter": {"particles": 0, "particles": 300}}` ran, its invalid first value
/// unseen. A repeat is an error naming the key (serde_json adds its line and column).
struct NoRepeats(serde_json::Value);

impl<'de> serde::Deserialize<'de> for NoRepeats {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(NoRepeatsVisitor).map(NoRepeats)
    }
}

struct NoRepeatsVisitor;

impl<'de> serde::de::Visitor<'de> for NoRepeatsVisitor {
    type Value = serde_json::Value;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Self::Value, E> {
        Ok(v.into())
    }

    fn visit_i64<E>(self, v: i64) -> Result<Self::Value, E> {
        Ok(v.into())
    }

    fn visit_u64<E>(self, v: u64) -> Result<Self::Value, E> {
        Ok(v.into())
    }

    fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Self::Value, E> {
        serde_json::Number::from_f64(v)
            .map(serde_json::Value::Number)
            .ok_or_else(|| E::custom(format!("{v} is not a finite number")))
    }

    fn visit_str<E>(self, v: &str) -> Result<Self::Value, E> {
        Ok(v.into())
    }

    fn visit_unit<E>(self) -> Result<Self::Value, E> {
        Ok(serde_json::Value::Null)
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut items = Vec::new();
        while let Some(NoRepeats(v)) = seq.next_element()? {
            items.push(v);
        }
        Ok(serde_json::Value::Array(items))
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let mut out = serde_json::Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if out.contains_key(&key) {
                return Err(serde::de::Error::custom(format!(
                    "`{key}` is given twice in one object"
                )));
            }
            let NoRepeats(v) = map.next_value()?;
            out.insert(key, v);
        }
        Ok(serde_json::Value::Object(out))
    }
}

/// Lays `given` over `base`: objects field by field, anything else replaced.
fn overlay(base: &mut serde_json::Value, given: serde_json::Value) {
    match (base, given) {
        (serde_json::Value::Object(b), serde_json::Value::Object(g)) => {
            for (k, v) in g {
                match b.get_mut(&k) {
                    Some(slot) => overlay(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// Builds the tracker configuration from the arguments.
pub fn config(mode: Mode, particles: usize, seed: u64) -> anyhow::Result<TrackerConfig> {
    let max = pftrack::filter::MAX_PARTICLES;
    if !(1..=max).contains(&particles) {
        bail!("--particles must lie in 1..={max}, got {particles}");
    }
    let mut cfg = TrackerConfig {
        mode,
        seed,
        ..TrackerConfig::default()
    };
    cfg.filter.particles = particles;
    Ok(cfg)
}

/// Checks and applies `--hfov`.
pub fn apply_hfov(cfg: &mut TrackerConfig, hfov: Option<f64>) -> anyhow::Result<()> {
    let range = pftrack::tracker::HFOV_RANGE_DEG;
    if let Some(h) = hfov
        && !range.contains(&h)
    {
        bail!(
            "--hfov must lie between {} and {} degrees, got {h}",
            range.start(),
            range.end()
        );
    }
    cfg.camera_hfov_deg = hfov;
    Ok(())
}

/// Checks and applies `--depth-ratio`.
pub fn apply_depth_ratio(cfg: &mut TrackerConfig, r: f64) -> anyhow::Result<()> {
    let max = pftrack::tracker::MAX_DEPTH_RATIO;
    if !(r.is_finite() && (0.0..=max).contains(&r)) {
        bail!("--depth-ratio must lie between 0 and {max}, got {r}");
    }
    cfg.likelihood.depth_ratio = r as f32;
    Ok(())
}

/// Checks and applies `--relief-sigma` (`None`: the default's, no relief learnt).
pub fn apply_relief_sigma(cfg: &mut TrackerConfig, sigma: Option<f64>) -> anyhow::Result<()> {
    let Some(sigma) = sigma else {
        return Ok(());
    };
    let range = pftrack::pose::bundle::RELIEF_SIGMA_RANGE;
    if !range.contains(&sigma) {
        bail!(
            "--relief-sigma must lie from {} to {}, got {sigma}",
            range.start(),
            range.end()
        );
    }
    if let Some(b) = cfg.bundle.as_mut() {
        b.params.relief_sigma = Some(sigma);
    }
    Ok(())
}

/// Checks and applies `--feature-weight`.
pub fn apply_feature_weight(cfg: &mut TrackerConfig, w: f64) -> anyhow::Result<()> {
    if !(0.0..=MAX_WEIGHT).contains(&w) {
        bail!("--feature-weight must lie between 0 and {MAX_WEIGHT:e}, got {w}");
    }
    cfg.feature_weight = w;
    Ok(())
}

/// Checks and applies `--template-weight`, `--template-rate` and `--anchor-weight` (template
/// weight 0: the term off, and the anchor with it). A given anchor weight holds with and
/// without a camera; none keeps the library's two defaults.
pub fn apply_template(
    cfg: &mut TrackerConfig,
    weight: f64,
    rate: f64,
    anchor_weight: Option<f64>,
) -> anyhow::Result<()> {
    if !(0.0..=MAX_WEIGHT).contains(&weight) {
        bail!("--template-weight must lie between 0 and {MAX_WEIGHT:e}, got {weight}");
    }
    if !(0.0..=1.0).contains(&rate) {
        bail!("--template-rate must lie between 0 and 1, got {rate}");
    }
    if let Some(w) = anchor_weight
        && !(0.0..=MAX_WEIGHT).contains(&w)
    {
        bail!("--anchor-weight must lie between 0 and {MAX_WEIGHT:e}, got {w}");
    }
    if let Some(w) = anchor_weight
        && w > 0.0
        && weight == 0.0
    {
        bail!("--anchor-weight {w} needs the template term, which --template-weight 0 turns off");
    }
    // A setting of a term that is off would do nothing: said, not silently taken.
    if weight == 0.0 && rate != pftrack::tracker::TemplateTerm::default().rate {
        bail!(
            "--template-rate {rate} has no effect: --template-weight 0 turns the template term off"
        );
    }
    let base = cfg.template.unwrap_or_default();
    cfg.template = (weight > 0.0).then(|| pftrack::tracker::TemplateTerm {
        weight,
        rate,
        anchor_weight: anchor_weight.unwrap_or(base.anchor_weight),
        anchor_weight_camera: anchor_weight.unwrap_or(base.anchor_weight_camera),
        ..base
    });
    Ok(())
}

/// Checks and applies `--edge-threshold` (none: the default stays).
pub fn apply_edge_threshold(cfg: &mut TrackerConfig, t: Option<f64>) -> anyhow::Result<()> {
    if let Some(t) = t {
        if !(t.is_finite() && (0.0..=1.0).contains(&t)) {
            bail!("--edge-threshold must lie between 0 and 1, got {t}");
        }
        cfg.likelihood.edge_threshold = t as f32;
    }
    Ok(())
}

/// The library settings the command line's flags set, each with its flag and what the
/// command line offers where the library would take `None`; a configuration error is
/// about the one its [`TrackError::BadConfig`]'s `setting` names.
const FLAG_OF_SETTING: [(&str, &str, &str); 11] = [
    (
        "fit_centre_sigma",
        "--fit-centre-sigma",
        "--no-fit-centre-prior leaves the fits' centre free",
    ),
    (
        "colour_update",
        "--colour-rate",
        "--colour-rate 0 keeps the first frame's colours",
    ),
    (
        "aspect_slack",
        "--aspect-slack",
        "--no-aspect-bound leaves the ellipse's aspect free",
    ),
    (
        "size_hold",
        "--size-hold",
        "--no-size-hold leaves the ellipse's size free",
    ),
    (
        "reacquire_ncc",
        "--reacquire-ncc",
        "--no-template-reacquire recognises a re-acquired target by its features alone",
    ),
    (
        "reanchor",
        "--reanchor-ncc",
        "--no-reanchor leaves the estimate to the filter",
    ),
    (
        "sift_upsample_below",
        "--sift-upsample-below",
        "--sift-always-upsample keeps one SIFT setting for every size",
    ),
    (
        "contrast",
        "--contrast-weight",
        "--contrast-weight 0 weighs without the contrast term",
    ),
    (
        "exposure_jump",
        "--exposure-jump",
        "--no-exposure takes every frame's light as it comes",
    ),
    ("found_above", "--found-above", ""),
    ("trust_above", "--trust-above", ""),
];

/// A configuration error in the command line's terms: the flag behind the setting first,
/// and the flag that turns the part off in place of the library's "set it to None". An
/// error about a setting no flag sets (only `--config` does) is the library's own.
fn flag_error(e: &TrackError) -> String {
    let TrackError::BadConfig { setting, why, .. } = e else {
        return e.to_string();
    };
    let Some((_, flag, off)) = FLAG_OF_SETTING.iter().find(|(s, _, _)| s == setting) else {
        return e.to_string();
    };
    let head = why.split_once("; set ").map_or(why.as_str(), |(h, _)| h);
    if off.is_empty() {
        format!("{flag}: {head}")
    } else {
        format!("{flag}: {head} ({off})")
    }
}

/// A progress bar on a terminal, hidden otherwise.
pub fn progress(len: Option<usize>) -> indicatif::ProgressBar {
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let pb = match len {
        Some(n) => indicatif::ProgressBar::new(n as u64),
        None => indicatif::ProgressBar::no_length(),
    };
    // The rate to a tenth of a frame a second (indicatif's own `per_sec` shows four decimals).
    let style = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames {fps} {msg}")
        .map(|s| {
            s.with_key(
                "fps",
                |state: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                    let _ = write!(w, "{:.1}/s", state.per_sec());
                },
            )
        })
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
    pb.set_style(style);
    pb
}

/// A spinner saying `what` on standard error while it turns, where that is a terminal.
fn spinner(what: &str) -> indicatif::ProgressBar {
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new_spinner().with_message(what.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(100));
    pb
}

/// Runs the command.
pub fn run(mut a: TrackArgs) -> anyhow::Result<()> {
    // `-` is standard output, as it is standard input for the input.
    if a.out.as_deref() == Some(Path::new(frames::STDIN)) {
        a.out = None;
    }
    if a.stream
        && let Some(o) = &a.out
    {
        bail!(
            "--stream writes the poses to standard output as they come, and --out {} is written \
             whole or not at all: give one of them",
            o.display()
        );
    }
    if a.max_frames == Some(0) {
        bail!("--max-frames must be at least 1 (the first frame is the initial estimate)");
    }
    let (frames_path, synth_init) = resolve_input(&a.input);
    check_outputs(&a, &frames_path, synth_init.as_deref())?;
    let (init, cfg) = configure(&a, synth_init.as_deref())?;
    let Opened {
        mut source,
        first,
        init,
        to_frames,
        start,
        unshrunk,
    } = open_at_start(
        &a,
        &frames_path,
        init,
        &cfg,
        &StartSource::of(&a, synth_init.as_deref()),
    )?;
    // Said once the track has started, so that an error before it stays the only line.
    let loose = loose_start_note(&a, &cfg, &first, &init);
    let (engine, notice) = create_engine(a.backend)?;
    if let Some(n) = notice {
        errln!("pftrack: {}", crate::in_cli_terms(&n));
    }
    // The render's folder first: the video may be meant to go into it.
    let staging = a.render.as_deref().map(RenderStaging::create).transpose()?;
    let video = a
        .render_video
        .as_deref()
        .map(|p| VideoWriter::create(p, a.render_fps, &frames::FfmpegTools::default()))
        .transpose()?;
    let mut tracker = Tracker::with_engine(cfg, engine, &first, init)?;
    let ((w, h), (nw, nh)) = (source.size(), source.native_size());
    if a.resize.is_none() && (w, h) != (nw, nh) {
        errln!(
            "pftrack: note: tracking at {w}x{h}, shrunk from {nw}x{nh} (as accurate, and \
             faster; --full-size tracks at {nw}x{nh})"
        );
    }
    if let Some((sw, sh)) = unshrunk {
        errln!(
            "pftrack: note: tracking at the input's {nw}x{nh}: the settings refuse the start \
             in the frames shrunk to {sw}x{sh}, which would track as accurately and faster \
             (their bounds in pixels are the tracked frames')"
        );
    }
    if let Some(note) = loose {
        errln!("pftrack: note: {note}");
    }
    // On an error the staging folder is dropped with the frames drawn so far, which would
    // read as a whole track's, as the pose CSV is never moved into place.
    let Tracked {
        frames: written,
        moves,
        video,
        signals,
    } = run_loop(
        &a,
        &mut source,
        &mut tracker,
        &first,
        Drawn {
            render: staging.as_ref(),
            video,
        },
        to_frames.inverse(),
    )?;
    let video_note = match video {
        Some(v) => {
            let path = v.path().display().to_string();
            v.commit()?;
            format!(", video in {path}")
        }
        None => String::new(),
    };
    if let Some(s) = staging {
        let dir = s.dir.clone();
        let removed = s.finish(moves, written)?;
        if removed > 0 {
            errln!(
                "pftrack: removed {removed} frame{} of an earlier render from {}",
                if removed == 1 { "" } else { "s" },
                dir.display()
            );
        }
    }
    report(
        &a,
        &tracker,
        &source,
        (start, written, &signals),
        &video_note,
    );
    Ok(())
}

/// Checks, before any work, that the outputs (`--out`, `--render`, `--render-video`) have
/// places of their own: none an input (the frames, a settings or init file, a synthetic
/// sequence's truth), none another, the video's container and frame rate usable.
fn check_outputs(
    a: &TrackArgs,
    frames_path: &Path,
    synth_init: Option<&Path>,
) -> anyhow::Result<()> {
    let read: Vec<&Path> = [
        a.config.as_deref(),
        a.init_file.as_deref(),
        a.init_truth.as_deref(),
        synth_init,
    ]
    .into_iter()
    .flatten()
    .collect();
    // `-` names standard output elsewhere (`--out -`); frames cannot go there.
    if a.render.as_deref() == Some(Path::new("-")) {
        bail!(
            "--render -: frames go to a folder, not to standard output (./- names a folder called -)"
        );
    }
    crate::paths::track_outputs(frames_path, &read, a.out.as_deref(), a.render.as_deref())?;
    if !pftrack::output::video::fps_in_range(a.render_fps) {
        bail!(
            "--render-fps {}: a frame rate from {} to {} frames a second",
            a.render_fps,
            pftrack::output::video::FPS_RANGE.0,
            pftrack::output::video::FPS_RANGE.1
        );
    }
    if let Some(v) = a.render_video.as_deref() {
        if a.out.as_deref().is_some_and(|o| crate::paths::same(v, o)) {
            bail!(
                "--out and --render-video both name {}: the poses and the video need places of their own",
                v.display()
            );
        }
        let mut inputs = vec![frames_path, a.input.as_path()];
        inputs.extend(&read);
        crate::paths::not_an_input("--render-video", v, &inputs)?;
        if a.render
            .as_deref()
            .is_some_and(|r| crate::paths::same(v, r))
        {
            bail!(
                "--render and --render-video both name {}: the frames and the video need places of their own",
                v.display()
            );
        }
        // The container and the frame rate too, before any work.
        VideoWriter::check(v, a.render_fps)?;
    }
    // A folder written by `synth` (its `frames` read, with or without its init file, or its
    // `frames` folder named with its `init.txt`): its ground truth is not read by the track,
    // but is what the track is scored against. Beside a `frames` folder or an `init.txt`, a
    // `truth.csv` that is there.
    let synth_file = |p: &Path, name: &str| p.file_name().is_some_and(|n| n == name);
    let frames_dir = std::fs::canonicalize(frames_path).ok();
    let beside = [
        frames_dir
            .as_deref()
            .filter(|f| synth_file(f, "frames"))
            .and_then(Path::parent)
            .map(|d| d.join("truth.csv")),
        a.init_file
            .as_deref()
            .filter(|f| synth_file(f, "init.txt"))
            .map(|f| f.with_file_name("truth.csv")),
    ];
    let truths = [
        synth_init.map(|init| init.with_file_name("truth.csv")),
        (frames_path != a.input).then(|| a.input.join("truth.csv")),
    ]
    .into_iter()
    .chain(beside)
    .map(|t| t.filter(|t| t.is_file()));
    if let Some(o) = a.out.as_deref()
        && truths.flatten().any(|t| crate::paths::same(o, &t))
    {
        bail!(
            "--out {} is the sequence's ground truth: it would be overwritten",
            o.display()
        );
    }
    Ok(())
}

/// The start (`--init-*`, `--init-pose`) and the tracker's settings (`--config`, or the
/// flags), checked, each error naming the flag or the file it came from.
fn configure(a: &TrackArgs, synth_init: Option<&Path>) -> anyhow::Result<(Init, TrackerConfig)> {
    let (init_file, truth_pose) = initial_ellipse(a, synth_init)?;
    let pose = match &a.init_pose {
        Some(p) => {
            let v = parse_floats(p, &[3], "--init-pose")?;
            Euler::from_degrees(v[0], v[1], v[2])
        }
        None => truth_pose.unwrap_or_default(),
    };
    let init = Init {
        ellipse: init_file.ellipse,
        pose,
    };
    let camera = if a.weak_perspective {
        None
    } else {
        a.hfov.or(init_file.hfov_deg)
    };
    let cfg = match &a.config {
        Some(path) => {
            let mut cfg = read_config(path)?;
            if a.weak_perspective || a.hfov.is_some() || cfg.camera_hfov_deg.is_none() {
                apply_hfov(&mut cfg, camera)?;
            }
            cfg
        }
        None => flag_config(a, camera)?,
    };
    // A setting's error names its flag, or the file it came from.
    match &a.config {
        // In the file's own terms: JSON's `null` where the library says `None`.
        Some(p) => cfg.check().map_err(|e| {
            anyhow::anyhow!(
                "--config {}: {}",
                p.display(),
                e.to_string().replace(" None", " null")
            )
        })?,
        None => cfg.check().map_err(|e| anyhow::anyhow!(flag_error(&e)))?,
    }
    Ok((init, cfg))
}

/// The overlap (intersection over union of the boxes `cx ± a, cy ± b`, the angle left aside)
/// between a start given by hand and the same start refined on its frame, under which `track`
/// says the start is loose. Starts from ground truth overlap their refinement by 0.86-0.98
/// (girl's and car4's first OTB boxes, carphone's box in the README, the synthetic scenarios'
/// `init.txt`), the box in the README's OpenCV box clip by 0.67 (measured 2026-12-07).
const LOOSE_START_IOU: f64 = 0.8;

/// A note for a start given by hand (`--init-ellipse`, `--init-box`, `--init-points`) that
/// [`pftrack::tracker::refined_start`] would move far (its box and the refined one's overlap
/// under [`LOOSE_START_IOU`]): every model is learnt inside the start, so what it takes in
/// around the target is tracked as the target, and a start off the outline reads as a turn.
/// It names `--refine-init`, or the settings file's `init_refine` under `--config`. `None`
/// where the start came from a file, the refinement is on already, or it fails (a refinement
/// the tracker is not asked for: nothing to report).
fn loose_start_note(
    a: &TrackArgs,
    cfg: &TrackerConfig,
    first: &image::RgbImage,
    init: &Init,
) -> Option<String> {
    let by_hand = a.init_ellipse.is_some() || a.init_box.is_some() || a.init_points.is_some();
    if !by_hand || cfg.init_refine.is_some() {
        return None;
    }
    let refined = refined_start(cfg, &InitRefine::default(), first, *init).ok()?;
    let (given, outline) = (init.ellipse.to_box(), refined.ellipse.to_box());
    let overlap = given.iou(&outline);
    if overlap >= LOOSE_START_IOU {
        return None;
    }
    let what = if outline.area() < given.area() {
        "takes in much around the target"
    } else {
        "lies off the target's outline"
    };
    let how = match &a.config {
        Some(p) => format!("\"init_refine\": {{}} in {} tracks from there", p.display()),
        None => "--refine-init tracks from there".to_string(),
    };
    // Rounded down, so that an overlap just under the bar never reads as the bar.
    Some(format!(
        "the start {what}: refined onto the edges and colours of its outline, its box and the \
         given one overlap by {:.2} (intersection over union); {how}",
        (100.0 * overlap).floor() / 100.0
    ))
}

/// The input opened and passed over to its start frame, and the start checked against it.
struct Opened {
    /// The frames after the first.
    source: frames::FrameSource,
    /// The frame to start on.
    first: image::RgbImage,
    /// The start, in the tracked frames' pixels.
    init: Init,
    /// The input's pixels to the tracked frames' (`--resize`).
    to_frames: Rescale,
    /// The first frame's index in the input (`--start-frame`).
    start: usize,
    /// The working size the frames were not shrunk to, the settings refusing the start
    /// there.
    unshrunk: Option<(u32, u32)>,
}

/// Opens the input, checks the start against it (first in the input's pixels, as given, then
/// as the tracker will see the resized frames), says what its layout misleads, and passes
/// over the frames before `--start-frame`. The start is checked before the engine is opened,
/// so a bad one is the only line printed.
fn open_at_start(
    a: &TrackArgs,
    frames_path: &Path,
    init: Init,
    cfg: &TrackerConfig,
    given_by: &StartSource,
) -> anyhow::Result<Opened> {
    let resize = a.resize.as_deref().map(frames::parse_size).transpose()?;
    // Its errors name the input themselves.
    let mut source = frames::open(frames_path, &SourceOptions { resize })?;
    // The start and the poses are in the input's own pixels; the tracker sees the resized
    // frames (`--resize`). The start is checked before the engine is opened, so a bad one is
    // the only line printed: first in the input's pixels, as given, then as the tracker will
    // see it.
    let (nw, nh) = source.native_size();
    init.check(nw, nh).map_err(|e| given_by.name(e))?;
    // Large frames are tracked at a working size (`frames::working_size`) unless `--resize`
    // chooses one or `--full-size` keeps the input's. A size chosen for speed must not fail
    // a run: where the settings refuse the start there (a bound in pixels, such as a
    // settings file's filter.min_axis), the frames are tracked as they are.
    let working = match (&a.resize, a.full_size) {
        (None, false) => frames::working_size((nw, nh), &init.ellipse),
        _ => None,
    };
    let shrunk = working.filter(|&(w, h)| {
        let ellipse = Rescale::new((nw, nh), (w, h)).ellipse(&init.ellipse);
        Init { ellipse, ..init }.check_for(cfg, w, h).is_ok()
    });
    if shrunk.is_some() {
        source.set_resize(shrunk)?;
    }
    // Said once the track has started, as the working size is.
    let unshrunk = working.filter(|_| shrunk.is_none());
    let (w, h) = source.size();
    let to_frames = Rescale::new((nw, nh), (w, h));
    let init = Init {
        ellipse: to_frames.ellipse(&init.ellipse),
        ..init
    };
    let checked = init.check_for(cfg, w, h).map_err(|e| given_by.name(e));
    if a.resize.is_none() || to_frames.is_identity() {
        checked?;
    } else {
        checked.with_context(|| format!("the start resized to {w}x{h} (--resize)"))?;
    }
    // What the frames' layout misleads (interlaced fields, pixels not square), once the
    // start is known to be good.
    for caveat in source.caveats() {
        errln!("pftrack: warning: {caveat}");
    }
    let start = a.start_frame;
    // A long video's frames take a while to pass over (about a millisecond each at 720p):
    // said on a terminal, so that the wait does not read as a hang.
    let passing = match start {
        0 => indicatif::ProgressBar::hidden(),
        s => spinner(&format!("passing over frames 0 to {}", s - 1)),
    };
    let skipped = source.skip_frames(start);
    passing.finish_and_clear();
    let skipped = skipped?;
    let first = match source.next() {
        Some(f) => f.with_context(|| format!("reading frame {start}"))?,
        None if start > 0 => bail!(
            "--start-frame {start}: the input has only {skipped} frame{} (frames 0 to {}){}",
            if skipped == 1 { "" } else { "s" },
            skipped.saturating_sub(1),
            source
                .shortfall()
                .map(|s| format!("; {s}"))
                .unwrap_or_default()
        ),
        None => bail!("the input has no frames"),
    };
    Ok(Opened {
        source,
        first,
        init,
        to_frames,
        start,
        unshrunk,
    })
}

/// What `track` says at its end: what was tracked and where it went, the mean confidence and
/// the frames flagged lost, the relief learnt, and the warnings of the whole track (a short
/// video, frames relit, frames without SIFT). The tuple is the first frame, the frames written
/// and their signals.
fn report(
    a: &TrackArgs,
    tracker: &Tracker,
    source: &frames::FrameSource,
    (start, written, signals): (usize, usize, &Signals),
    video_note: &str,
) {
    let cfg = tracker.config();
    let camera = match cfg.camera_hfov_deg {
        Some(h) => format!("camera hfov {h}°"),
        None => "weak perspective".to_string(),
    };
    let mode = cfg.mode;
    // Where the frames were tracked at another size than the input's, which one.
    let size = match (source.size(), source.native_size()) {
        (out, native) if out == native => String::new(),
        ((w, h), (nw, nh)) if a.resize.is_none() => {
            format!(" at {w}x{h} (shrunk from {nw}x{nh})")
        }
        ((w, h), _) => format!(" at {w}x{h}"),
    };
    errln!(
        "pftrack: tracked {written} frame{}{}{size} with {} ({}, {}){}{video_note}",
        if written == 1 { "" } else { "s" },
        match (start, written) {
            (0, _) => String::new(),
            (s, 1) => format!(" (frame {s})"),
            (s, n) => format!(" (frames {s} to {})", s + n - 1),
        },
        tracker.engine_name(),
        mode.name(),
        camera,
        a.out
            .as_ref()
            .map(|p| format!(", poses in {}", p.display()))
            .unwrap_or_default()
    );
    errln!("pftrack: {}", signals.line());
    if tracker
        .config()
        .bundle
        .is_some_and(|b| b.params.relief_sigma.is_some())
    {
        errln!(
            "pftrack: relief learnt: {:.2} times the ellipsoid's",
            tracker.relief()
        );
    }
    // ffmpeg ends a truncated or damaged video with success: the track is of what it decoded.
    if let Some(short) = source.shortfall() {
        errln!("pftrack: warning: {short}");
    }
    let relit = tracker.frames_relit();
    if relit > 0 {
        let g = tracker.exposure_gain();
        errln!(
            "pftrack: {relit} frame{} in other light over the whole frame than the start's, \
             brought back to it before tracking (the last frame's gain: R {:.2}, G {:.2}, B \
             {:.2}; --no-exposure takes them as they come)",
            if relit == 1 { " was" } else { "s were" },
            g[0],
            g[1],
            g[2],
        );
    }
    let unseen = tracker.frames_without_sift();
    if unseen > 0 {
        errln!(
            "pftrack: warning: {unseen} frame{} tracked without SIFT: its scale space around \
             the target would pass sift.max_scale_space_bytes ({}), so colour, contour and \
             template alone weighed them",
            if unseen == 1 { " was" } else { "s were" },
            tracker.config().sift.max_scale_space_bytes
        );
    }
}

/// Where `--render` draws its frames until the track is done: a hidden folder inside the
/// render folder ([`StagingDir`]), removed when dropped (with the render folder, when this run
/// created it and it is still empty).
struct RenderStaging {
    /// The render folder.
    dir: PathBuf,
    /// The hidden folder inside it, registered for an interrupt to remove it
    /// ([`pftrack::io::partial`]), with the folders this run made for the render.
    stage: StagingDir,
}

impl RenderStaging {
    /// Creates the render folder (if need be) and an empty staging folder inside it. A folder
    /// that holds frames (`NNNNN.png`) without [`RENDER_MARK`] is refused: those frames are
    /// not a render of pftrack's, and replacing or trimming them would destroy them.
    fn create(dir: &Path) -> anyhow::Result<Self> {
        if dir.exists() && !dir.is_dir() {
            bail!("--render {}: not a folder", dir.display());
        }
        let mark = dir.join(RENDER_MARK);
        if std::fs::symlink_metadata(&mark).is_ok_and(|m| !m.is_file()) {
            bail!(
                "--render {}: {} is not a file (a render leaves a file of that name there)",
                dir.display(),
                mark.display()
            );
        }
        if dir.is_dir() && !mark.is_file() {
            let listing = || format!("--render {}", dir.display());
            for entry in std::fs::read_dir(dir).with_context(listing)? {
                let name = entry.with_context(listing)?.file_name();
                if name.to_str().is_some_and(is_frame_name) {
                    bail!(
                        "--render {}: holds {} but no {}, which a render by pftrack leaves \
                         (those before 2026-12-06 did not): remove its frames, or give an \
                         empty or a new folder",
                        dir.display(),
                        name.to_string_lossy(),
                        RENDER_MARK
                    );
                }
            }
        }
        // Staging folders of runs killed outright, left for an hour.
        let swept = StagingDir::sweep_stale(dir, "pftrack-render", STALE_STAGING);
        if swept > 0 {
            errln!(
                "pftrack: removed {swept} staging folder{} left in {} by an earlier run that \
                 was killed",
                if swept == 1 { "" } else { "s" },
                dir.display()
            );
        }
        // What it makes is registered: an interrupt never removes a folder the user made,
        // empty or not.
        let stage = StagingDir::create(dir, "pftrack-render")
            .with_context(|| format!("cannot write rendered frames into {}", dir.display()))?;
        // The mark moves in with the frames, all of them or none.
        let mark = stage.path().join(RENDER_MARK);
        std::fs::write(&mark, RENDER_MARK_TEXT)
            .with_context(|| format!("cannot write rendered frames into {}", dir.display()))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            stage,
        })
    }

    /// Where frame `n` is drawn.
    fn frame(&self, n: usize) -> PathBuf {
        self.stage.path().join(frame_name(n))
    }

    /// The frames drawn, with where each goes; an error when one of those places holds
    /// something a frame cannot replace (a folder), found before anything is moved.
    fn moves(&self) -> anyhow::Result<Vec<(PathBuf, PathBuf)>> {
        let listing = || format!("listing {}", self.stage.path().display());
        let mut moves = Vec::new();
        for entry in std::fs::read_dir(self.stage.path()).with_context(listing)? {
            let entry = entry.with_context(listing)?;
            let to = self.dir.join(entry.file_name());
            if to.is_dir() {
                bail!(
                    "{} is a folder: the rendered frame of that name cannot replace it",
                    to.display()
                );
            }
            moves.push((entry.path(), to));
        }
        // The mark first: a move that fails part-way leaves it with the frames moved.
        moves.sort_by_key(|(from, _)| from.file_name() != Some(std::ffi::OsStr::new(RENDER_MARK)));
        Ok(moves)
    }

    /// Moves the frames drawn into the render folder, replacing those of the same names, then
    /// removes the frames of an earlier, longer render into the same folder that follow this
    /// track's last (`frame_name(n)` for `n` from `frames` on, as long as they run), which a
    /// reader of the sequence (`ffmpeg -i DIR/%05d.png`) would take as part of this track.
    /// Nothing else in the folder is touched. Returns how many were removed; one that cannot be
    /// removed is warned of, and it and those after it stay.
    fn finish(mut self, moves: Vec<(PathBuf, PathBuf)>, frames: usize) -> anyhow::Result<usize> {
        // All moved, or (on an error) none more, before an interrupt may clean up.
        let move_all = || -> anyhow::Result<()> {
            for (from, to) in moves {
                std::fs::rename(from, &to)
                    .with_context(|| format!("moving the rendered frame to {}", to.display()))?;
            }
            Ok(())
        };
        self.stage.commit(move_all)?;
        // The track and its frames are in place by now (the poses committed before): an
        // earlier render's frame that cannot be removed is said, not made the run's failure,
        // which would present the outputs written as those of a failed run.
        let mut removed = 0;
        for n in frames.. {
            let stale = self.dir.join(frame_name(n));
            if !std::fs::symlink_metadata(&stale).is_ok_and(|m| m.is_file()) {
                break;
            }
            if let Err(e) = std::fs::remove_file(&stale) {
                errln!(
                    "pftrack: warning: {} and the frames after it, an earlier render's past \
                     this track's {frames}, stay: removing it: {e}",
                    stale.display()
                );
                break;
            }
            removed += 1;
        }
        Ok(removed)
    }
}

/// How long a render's staging folder must have been left untouched to be taken for a killed
/// run's: a running render adds a frame every few milliseconds to seconds.
const STALE_STAGING: std::time::Duration = std::time::Duration::from_secs(3600);

/// The file that marks a folder as rendered by `track --render`, so that a later render may
/// replace its frames.
pub(crate) const RENDER_MARK: &str = ".pftrack-render";

/// What [`RENDER_MARK`] says to a reader who finds it.
const RENDER_MARK_TEXT: &str = "The frames here were rendered by `pftrack track --render`; a \
                                later render into this folder replaces them.\n";

/// Whether `name` is a rendered frame's name, `frame_name(n)` for an `n` of five digits: a
/// render replaces and trims frames counting from 0, so a longer name (`20240101.png`, a
/// date) is out of its reach.
pub(crate) fn is_frame_name(name: &str) -> bool {
    // `frame_name(n) == name` already refuses a sign or a number written otherwise.
    name.len() == "00000.png".len()
        && name
            .strip_suffix(".png")
            .and_then(|d| d.parse::<usize>().ok())
            .is_some_and(|n| frame_name(n) == name)
}

/// What [`run_loop`] leaves for its caller: the frames tracked, the rendered frames' moves
/// into place and the video, finished, to move in; the pose CSV is in place already.
struct Tracked {
    frames: usize,
    moves: Vec<(PathBuf, PathBuf)>,
    video: Option<VideoWriter>,
    signals: Signals,
}

/// The tracker's own signals over a whole track, for its last line: the mean confidence and
/// the frames flagged lost, as runs of the input's frame numbers.
#[derive(Debug, Default)]
struct Signals {
    frames: usize,
    confidence: f64,
    /// The frames flagged lost, as runs of the input's numbers (first and last).
    lost: Vec<(usize, usize)>,
}

impl Signals {
    /// Most runs of lost frames the line names.
    const RUNS_NAMED: usize = 8;

    /// Counts frame `frame` (the input's number; frames come in order).
    fn add(&mut self, frame: usize, confidence: f64, lost: bool) {
        self.frames += 1;
        self.confidence += confidence;
        if lost {
            pftrack::eval::extend_runs(&mut self.lost, frame);
        }
    }

    /// `mean confidence C; never flagged lost` or `...; flagged lost on N frames: A-B, C, ...`
    /// (the first [`Self::RUNS_NAMED`] runs, then how many more).
    fn line(&self) -> String {
        let mean = self.confidence / self.frames.max(1) as f64;
        if self.lost.is_empty() {
            return format!("mean confidence {mean:.2}; never flagged lost");
        }
        format!(
            "mean confidence {mean:.2}; flagged lost on {}",
            pftrack::eval::runs_text(&self.lost, Self::RUNS_NAMED)
        )
    }
}

/// Tracks every frame, writes the poses and draws the frames; with `--stream`, an error says
/// which rows went out before it, whatever failed (a frame, the render, the video).
fn run_loop(
    a: &TrackArgs,
    source: &mut frames::FrameSource,
    tracker: &mut Tracker,
    first: &image::RgbImage,
    drawn: Drawn<'_>,
    to_input: Rescale,
) -> anyhow::Result<Tracked> {
    // With --stream: the rows written, or `None` before the header is.
    let mut streamed: Option<usize> = None;
    let drawing = drawn.render.is_some() || drawn.video.is_some();
    let result = track_all(a, source, tracker, first, drawn, to_input, &mut streamed);
    result.map_err(|e| {
        if e.chain().any(crate::closed_pipe) {
            // The reader has what it wanted, and the run ends quietly; what else was asked
            // for is not written, which is said.
            if drawing {
                errln!(
                    "pftrack: standard output closed: the track stopped there, and wrote no \
                     rendered frames or video"
                );
            }
            return e;
        }
        match streamed {
            _ if !a.stream => e,
            None => e.context("before the pose CSV's header (--stream)"),
            Some(0) => e.context("before any pose row, after the header (--stream)"),
            Some(k) => e.context(format!(
                "after the pose rows of frames {} to {} (written to standard output as they \
                 came, --stream)",
                a.start_frame,
                a.start_frame + k - 1
            )),
        }
    })
}

/// [`run_loop`]'s work; `streamed` counts the rows written with `--stream`, once the header
/// is.
fn track_all(
    a: &TrackArgs,
    source: &mut frames::FrameSource,
    tracker: &mut Tracker,
    first: &image::RgbImage,
    mut drawn: Drawn<'_>,
    to_input: Rescale,
    streamed: &mut Option<usize>,
) -> anyhow::Result<Tracked> {
    let render = drawn.render;
    let limit = a.max_frames.unwrap_or(usize::MAX);
    // The tracker counts its frames from the start; the input's numbers are `start` on.
    let start = a.start_frame;
    let pb = progress(
        source
            .len_hint()
            .map(|n| n.saturating_sub(start).min(limit)),
    );
    let mut csv_out = match &a.out {
        Some(p) => Some(PoseCsvWriter::create(p, true)?),
        None => None,
    };
    let mut stdout_rows = Vec::new();
    let mut signals = Signals::default();
    if a.stream {
        outln!("{}", pftrack::io::pose_csv_header(true))?;
        crate::flush_stdout()?;
        *streamed = Some(0);
    }
    let mut emit = |e: &Estimate, frame: &image::RgbImage| -> anyhow::Result<()> {
        // Drawn first: a render that fails is the failure of this frame, whose row then is
        // not written (with --stream, not sent).
        drawn.draw(e, frame, start)?;
        let mut r = to_input.record(&e.to_record());
        r.frame += start;
        signals.add(r.frame, e.confidence, e.lost);
        match csv_out.as_mut() {
            Some(w) => w.write(&r)?,
            None if a.stream => {
                outln!("{}", pftrack::io::format_pose_row(&r, true))?;
                crate::flush_stdout()?;
                *streamed = Some(streamed.map_or(1, |k| k + 1));
            }
            None => stdout_rows.push(r),
        }
        pb.inc(1);
        Ok(())
    };
    let mut n = 1;
    let mut track = || -> anyhow::Result<()> {
        emit(&tracker.initial_estimate(), first)?;
        while n < limit {
            let Some(frame) = source.next() else { break };
            let at = start + n;
            let frame = frame.with_context(|| format!("reading frame {at}"))?;
            let est = tracker
                .step(&frame)
                .with_context(|| format!("tracking frame {at}"))?;
            if let Some(notice) = tracker.take_engine_notice() {
                let notice = crate::in_cli_terms(&notice);
                pb.suspend(|| errln!("pftrack: frame {at}: {notice}"));
            }
            emit(&est, &frame)?;
            n += 1;
        }
        Ok(())
    };
    let tracked = track();
    pb.finish_and_clear();
    tracked?;
    // The rendered frames' places are checked before the poses are committed: a render that
    // cannot be moved in fails the run with no pose CSV.
    let moves = render
        .map(RenderStaging::moves)
        .transpose()?
        .unwrap_or_default();
    // So is the video finished (ffmpeg done, the file synced): ffmpeg's failure fails the run
    // with no pose CSV. It moves in after the poses, as the rendered frames do.
    let mut video = drawn.video.take();
    if let Some(v) = video.as_mut() {
        v.close()?;
    }
    match csv_out {
        Some(w) => w.finish()?,
        None if a.stream => {}
        None => out!("{}", pftrack::io::format_pose_csv(&stdout_rows, true))?,
    }
    Ok(Tracked {
        frames: n,
        moves,
        video,
        signals,
    })
}

/// Where each frame is drawn with its estimate: the render's staging folder (`--render`), the
/// video (`--render-video`), both or neither.
struct Drawn<'a> {
    render: Option<&'a RenderStaging>,
    video: Option<VideoWriter>,
}

impl Drawn<'_> {
    /// Draws the estimate's frame with it, once, into each: the render's `e.frame`-th
    /// frame, labelled frame `start + e.frame` of the input.
    fn draw(&mut self, e: &Estimate, frame: &image::RgbImage, start: usize) -> anyhow::Result<()> {
        if self.render.is_none() && self.video.is_none() {
            return Ok(());
        }
        let o = Overlay {
            frame_index: start + e.frame,
            ellipse: e.ellipse,
            angles_deg: e.angles_deg(),
            score: e.confidence,
            lost: e.lost,
        };
        let drawn = render_overlay(frame, &o, default_scale(frame.width()));
        if let Some(dir) = self.render {
            write_png(&dir.frame(e.frame), &drawn)?;
        }
        if let Some(v) = self.video.as_mut() {
            v.write(&drawn)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The last line's signals: the mean confidence, and the lost frames as runs of the
    /// input's numbers, the first eight named.
    #[test]
    fn the_signals_line_gives_the_mean_confidence_and_the_lost_runs() {
        let mut s = Signals::default();
        for f in 5..9 {
            s.add(f, 0.5, false);
        }
        assert_eq!(s.line(), "mean confidence 0.50; never flagged lost");
        s.add(9, 0.1, true);
        assert_eq!(s.line(), "mean confidence 0.42; flagged lost on 1 frame: 9");
        s.add(10, 0.1, true);
        s.add(11, 0.9, false);
        s.add(12, 0.2, true);
        assert_eq!(s.frames, 8);
        assert_eq!(
            s.line(),
            "mean confidence 0.41; flagged lost on 3 frames: 9-10, 12"
        );
        for f in (14..40).step_by(2) {
            s.add(f, 0.0, true);
        }
        let line = s.line();
        assert!(
            line.ends_with(
                "flagged lost on 16 frames: 9-10, 12, 14, 16, 18, 20, 22, 24, and 7 more runs"
            ),
            "{line}"
        );
        // No frame at all (a track always has its first): no division by zero.
        assert_eq!(
            Signals::default().line(),
            "mean confidence 0.00; never flagged lost"
        );
    }

    /// A `--config` file is laid over the tracker's defaults field by field, and must be an
    /// object of settings of bounded size.
    #[test]
    fn a_settings_file_is_laid_over_the_defaults() {
        let dir = std::env::temp_dir().join(format!("pftrack-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = |name: &str, text: &[u8]| {
            let p = dir.join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        // A part given in part keeps the tracker's defaults for the rest of it: the bundle
        // adjustment's rotation σ stays the tracker's (0.07), not `BundleParams`'s own.
        let cfg = read_config(&file(
            "a.json",
            br#"{"bundle": {"params": {"huber": 2.0}}}"#,
        ))
        .unwrap();
        let want = pftrack::tracker::BundleAdjust::default();
        let got = cfg.bundle.unwrap();
        assert_eq!(got.params.huber, 2.0);
        assert_eq!(got.params.rotation_sigma, want.params.rotation_sigma);
        assert_eq!(got.min_views, want.min_views);
        // `null` switches a part off; a number replaces the default's `null`.
        let cfg = read_config(&file(
            "b.json",
            br#"{"bundle": null, "camera_hfov_deg": 40}"#,
        ))
        .unwrap();
        assert_eq!((cfg.bundle, cfg.camera_hfov_deg), (None, Some(40.0)));
        // Angles are degrees in the file (SPEC), under names that say so; radians once read.
        let cfg = read_config(&file(
            "deg.json",
            br#"{"max_rotation_step_deg": 10, "filter": {"proposal": {"centre": 1.5, "axes": 0.4, "rotation_deg": [1, 2, 3]}}}"#,
        ))
        .unwrap();
        assert_eq!(cfg.max_rotation_step, 10f64.to_radians());
        assert_eq!(
            cfg.filter.proposal.rotation,
            [1f64, 2.0, 3.0].map(f64::to_radians)
        );
        let err = format!(
            "{:#}",
            read_config(&file("rad.json", br#"{"max_rotation_step": 0.2}"#)).unwrap_err()
        );
        assert!(err.contains("max_rotation_step"), "{err}");
        assert_eq!(
            read_config(&file("c.json", b"{}")).unwrap(),
            TrackerConfig::default()
        );
        // A list of fields in order is not taken for the settings.
        for text in [&b"[]"[..], b"[\"tpe\", 5]", b"7"] {
            let err = read_config(&file("d.json", text)).unwrap_err();
            assert!(format!("{err:#}").contains("a JSON object"), "{err:#}");
        }
        let err = read_config(&file(
            "e.json",
            &vec![b' '; (MAX_CONFIG_BYTES + 1) as usize],
        ))
        .unwrap_err();
        assert!(format!("{err:#}").contains("more than"), "{err:#}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn depth_ratio_is_checked_and_applied() {
        let mut cfg = TrackerConfig::default();
        assert_eq!(cfg.likelihood.depth_ratio, 1.0);
        apply_depth_ratio(&mut cfg, 0.25).unwrap();
        assert_eq!(cfg.likelihood.depth_ratio, 0.25);
        for bad in [-0.1, f64::NAN, f64::INFINITY, 11.0] {
            let e = apply_depth_ratio(&mut cfg, bad).unwrap_err().to_string();
            assert!(e.starts_with("--depth-ratio must lie"), "{e}");
        }
        assert_eq!(cfg.likelihood.depth_ratio, 0.25);
    }

    #[test]
    fn edge_threshold_is_checked_and_applied() {
        let mut cfg = TrackerConfig::default();
        let default = cfg.likelihood.edge_threshold;
        apply_edge_threshold(&mut cfg, None).unwrap();
        assert_eq!(cfg.likelihood.edge_threshold, default);
        apply_edge_threshold(&mut cfg, Some(0.05)).unwrap();
        assert_eq!(cfg.likelihood.edge_threshold, 0.05);
        for bad in [-0.01, 1.5, f64::NAN, f64::NEG_INFINITY] {
            let e = apply_edge_threshold(&mut cfg, Some(bad))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("--edge-threshold must lie"), "{e}");
        }
        assert_eq!(cfg.likelihood.edge_threshold, 0.05);
    }

    #[test]
    fn template_settings_are_checked_and_applied() {
        let mut cfg = TrackerConfig::default();
        apply_template(&mut cfg, 35.0, 0.1, Some(25.0)).unwrap();
        let t = cfg.template.unwrap();
        assert_eq!(
            (t.weight, t.rate, t.anchor_weight, t.anchor_weight_camera),
            (35.0, 0.1, 25.0, 25.0)
        );
        // The anchor rides on the template term: none without it.
        let rate = pftrack::tracker::TemplateTerm::default().rate;
        let e = apply_template(&mut cfg, 0.0, rate, Some(25.0)).unwrap_err();
        assert!(
            e.to_string().contains("--template-weight 0 turns off"),
            "{e}"
        );
        apply_template(&mut cfg, 0.0, rate, Some(0.0)).unwrap();
        assert!(cfg.template.is_none());
        apply_template(&mut cfg, 35.0, 0.1, Some(25.0)).unwrap();
        apply_template(&mut cfg, 0.0, rate, None).unwrap();
        assert!(cfg.template.is_none());
        // Nor its rate: a rate other than the default with the term off is refused.
        let e = apply_template(&mut cfg, 0.0, rate + 0.1, None).unwrap_err();
        assert!(e.to_string().contains("has no effect"), "{e}");
        apply_template(&mut cfg, 10.0, 0.0, Some(0.0)).unwrap();
        assert_eq!(
            cfg.template.map(|t| (t.weight, t.rate, t.anchor_weight)),
            Some((10.0, 0.0, 0.0))
        );
        // No --anchor-weight: the library's defaults, with and without a camera.
        let mut cfg = TrackerConfig::default();
        apply_template(&mut cfg, 20.0, 0.05, None).unwrap();
        let (d, t) = (
            pftrack::tracker::TemplateTerm::default(),
            cfg.template.unwrap(),
        );
        assert_eq!(
            (t.anchor_weight, t.anchor_weight_camera),
            (d.anchor_weight, d.anchor_weight_camera)
        );
        assert!(t.anchor_weight_for(true) > t.anchor_weight_for(false));
        for (w, r, a, flag) in [
            (-1.0, 0.1, None, "--template-weight"),
            (f64::NAN, 0.1, None, "--template-weight"),
            (f64::INFINITY, 0.1, Some(40.0), "--template-weight"),
            (20.0, -0.1, None, "--template-rate"),
            (20.0, 1.5, None, "--template-rate"),
            (20.0, f64::NAN, None, "--template-rate"),
            (20.0, 0.1, Some(-1.0), "--anchor-weight"),
            (20.0, 0.1, Some(f64::NAN), "--anchor-weight"),
        ] {
            let e = apply_template(&mut cfg, w, r, a).unwrap_err().to_string();
            assert!(e.starts_with(flag), "{e}");
        }
    }

    #[test]
    fn feature_weight_is_checked_and_applied() {
        let mut cfg = TrackerConfig::default();
        apply_feature_weight(&mut cfg, 20.0).unwrap();
        assert_eq!(cfg.feature_weight, 20.0);
        apply_feature_weight(&mut cfg, 0.0).unwrap();
        assert_eq!(cfg.feature_weight, 0.0);
        for bad in [-1.0, f64::NAN, f64::INFINITY, 2e6] {
            let e = apply_feature_weight(&mut cfg, bad).unwrap_err().to_string();
            assert!(
                e.starts_with("--feature-weight must lie between 0 and 1e6"),
                "{e}"
            );
        }
        assert_eq!(cfg.feature_weight, 0.0);
    }

    #[test]
    fn hfov_is_checked() {
        let mut cfg = TrackerConfig::default();
        apply_hfov(&mut cfg, Some(60.0)).unwrap();
        assert_eq!(cfg.camera_hfov_deg, Some(60.0));
        assert!(apply_hfov(&mut cfg, Some(180.0)).is_err());
        assert!(apply_hfov(&mut cfg, Some(0.0)).is_err());
    }
}

//! Scoring an estimate against ground truth: angle RMSE/MAE, centre error, precision, success
//! AUC.
//!
//! Truth is either a pose CSV (exact angles: synthetic sequences) or an OTB box file (boxes
//! only: real footage, frames indexed from 0 in file order). The estimate is a pose CSV.
//!
//! Measures, per truth frame `f` with an estimate:
//! - angle errors `wrap_180(est − truth)` in degrees per axis (only when the truth has poses),
//!   summarised as RMSE and MAE over the evaluated frames, and as a gain: the least-squares
//!   slope of the estimate against the truth (the estimate taken as `truth + error`, so
//!   wrapping never breaks the line), 1 when the estimate follows the truth's swing, above 1
//!   when it over-reads the turn and below when it under-reads it; an axis about which the
//!   truth hardly turns (standard deviation under [`GAIN_MIN_SPREAD_DEG`]) has none;
//! - the rotation error: the angle of `R_est · R_truthᵀ` in degrees (the geodesic distance
//!   between the two rotations, the measure of the paper's Fig. 3), summarised as RMSE, mean
//!   and maximum. It does not depend on how the angles are written (a pan past 90 degrees
//!   written with the tilt and roll half a turn round is the same rotation), and it is the
//!   single figure of the whole turn's error where the per-axis errors are three;
//! - centre error: distance between the estimated centre `(cx, cy)` and the truth centre
//!   (pose centre, or box centre), mean over the evaluated frames;
//! - IoU between the estimate's box, the axis-aligned bounding box of its ellipse turned by
//!   its orientation (the CSV's `theta`, or `rz` where a file has no `theta`), and the truth
//!   box (the same construction for a pose truth). At orientation 0 that box is
//!   `(cx − a, cy − b, 2a, 2b)`, the box whose inscribed ellipse a box start gives.
//!
//! Over all truth frames (OTB protocol; those from a first frame on with [`evaluate_from`],
//! OTB's temporal robustness evaluation), where a frame with no estimate is a failure (centre
//! error infinite, IoU 0), not skipped:
//! - precision: share of frames with centre error `≤ 20` px;
//! - success rate at threshold `t`: share of frames with IoU `> t`, for the 21 thresholds
//!   `t = 0, 0.05, …, 1`; the AUC is the mean of the 21 rates. As in OTB (and GOT-10k,
//!   pytracking), IoU `> 1` never holds, so a perfect estimate scores `20/21 ≈ 0.952`, the
//!   protocol's maximum, and published AUCs are comparable with ours.
//!
//! A box of no size in an OTB file (`0,0,0,0`) is how OTB marks a frame without the target:
//! such a frame is not scored at all, neither in the averages nor in the shares, and
//! [`Report::absent`] counts them. (Scored as a box at the origin, one such row written into a
//! copy of girl's first 15 boxes moved a track's mean centre error from 1.73 to 7.64 px;
//! girl's and car4's own files have none.)
//!
//! The averages (RMSE, MAE, mean centre error, mean IoU over evaluated frames) cover the frames
//! present; [`Report::missing`] says how many truth frames had no estimate. Estimate frames
//! with no truth frame are ignored and counted ([`Report::ignored`]). The tracker's `lost`
//! flag does not change the scores: a lost frame is scored by its estimate like any other,
//! and the number of lost frames is reported. Where the target is absent, the flag is what
//! a tracker should raise: [`Report::absent_lost`] counts the absent frames it was raised on
//! (a target that vanished or left the frame, and a track that says so or goes on as if it
//! were there).
//!
//! How far the tracker's own signals can be trusted, over the evaluated frames, each of which
//! is on the target (IoU `≥` [`ON_TARGET_IOU`], OTB's usual success bar) or off it:
//! - the confidence's AUROC ([`Report::score_auroc`]): the chance that a frame on the target,
//!   drawn at random, has a higher `score` than a frame off it (ties count a half), 1 for a
//!   confidence that a bar separates perfectly, 0.5 for one that says nothing;
//! - the lost flag on and off the target ([`Report::lost_on_target`]): a flag raised on the
//!   target is a false alarm, and the frames off it that are not flagged are the drift the
//!   flag missed.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use crate::geometry::{BoxRect, Euler, angle_between, deg, wrap_180};
use crate::io::boxes::parse_otb_boxes;
use crate::io::pose_csv::parse_pose_csv;
use crate::io::{FormatError, PoseRecord};

/// Centre-error threshold of the precision score (pixels).
pub const PRECISION_THRESHOLD_PX: f64 = 20.0;

/// The IoU from which an estimate is on the target, for judging the tracker's confidence and
/// lost flag ([`Report::score_auroc`], [`Report::on_target`]): OTB's conventional success.
pub const ON_TARGET_IOU: f64 = 0.5;

/// Least standard deviation of the truth's angle about an axis (degrees) for that axis to
/// have a gain ([`Report::angle_gain`]): about a still axis the slope measures only noise.
pub const GAIN_MIN_SPREAD_DEG: f64 = 1.0;

/// Number of IoU thresholds of the success plot: `0, 0.05, …, 1`.
pub const SUCCESS_STEPS: usize = 21;

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EvalError {
    /// The truth file could not be read. (The cause is part of the message, not a separate
    /// `source()`, so a printed error chain says it once.)
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        cause: std::io::Error,
    },
    /// A malformed truth or estimate file.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The truth has no frames.
    #[error("the truth has no frames")]
    EmptyTruth,
    /// The truth has no frames from the one scoring starts on ([`evaluate_from`]).
    #[error("the truth has no frames from frame {from} on (its last is frame {last})")]
    NoTruthFrom {
        /// The first frame to score.
        from: usize,
        /// The truth's last frame.
        last: usize,
    },
    /// A frame listed twice.
    #[error("the {what} lists frame {frame} twice")]
    DuplicateFrame {
        /// `truth` or `estimate`.
        what: &'static str,
        /// The frame.
        frame: usize,
    },
    /// Every frame of the truth scored (all, or those from the frame scoring starts on,
    /// [`evaluate_from`]) marks the target absent (OTB boxes of no size): nothing to score.
    #[error(
        "every truth frame{} marks the target absent (a box of no size): nothing to score",
        match from { 0 => String::new(), f => format!(" from frame {f} on") }
    )]
    AllAbsent {
        /// The first frame scored.
        from: usize,
    },
    /// Truth and estimate share no frame.
    #[error(
        "no frames in common: the truth has the target in frames {}, the estimate frames {}",
        span(*truth), span(*estimate)
    )]
    NoCommonFrames {
        /// First and last truth frame.
        truth: Option<(usize, usize)>,
        /// First and last estimate frame (`None`: no records).
        estimate: Option<(usize, usize)>,
    },
}

fn span(s: Option<(usize, usize)>) -> String {
    match s {
        Some((a, b)) => format!("{a}..={b}"),
        None => "(none)".into(),
    }
}

/// Ground truth of a sequence.
#[derive(Debug, Clone, PartialEq)]
pub enum Truth {
    /// Full poses (a pose CSV): angles are scored.
    Poses(Vec<PoseRecord>),
    /// Boxes (an OTB file), frame `i` is the `i`-th box: only position and overlap are scored.
    Boxes(Vec<BoxRect>),
}

/// What the truth holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TruthKind {
    /// A pose CSV.
    Poses,
    /// An OTB box file.
    Boxes,
}

impl Truth {
    /// Number of truth frames.
    pub fn len(&self) -> usize {
        match self {
            Truth::Poses(p) => p.len(),
            Truth::Boxes(b) => b.len(),
        }
    }

    /// Whether there are no truth frames.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// What the truth holds.
    pub fn kind(&self) -> TruthKind {
        match self {
            Truth::Poses(_) => TruthKind::Poses,
            Truth::Boxes(_) => TruthKind::Boxes,
        }
    }

    /// Every truth frame.
    fn frames(&self) -> Vec<TruthFrame> {
        match self {
            Truth::Poses(p) => p
                .iter()
                .map(|r| {
                    let s = &r.state;
                    TruthFrame {
                        frame: r.frame,
                        bbox: pose_box(r),
                        centre: (s.cx, s.cy),
                        angles: Some([s.rx, s.ry, s.rz]),
                        absent: false,
                    }
                })
                .collect(),
            Truth::Boxes(b) => b
                .iter()
                .enumerate()
                .map(|(frame, bbox)| TruthFrame {
                    frame,
                    bbox: *bbox,
                    centre: bbox.centre(),
                    angles: None,
                    absent: !(bbox.w > 0.0 && bbox.h > 0.0),
                })
                .collect(),
        }
    }
}

/// One truth frame, whatever the file held.
struct TruthFrame {
    frame: usize,
    bbox: BoxRect,
    centre: (f64, f64),
    /// Radians, when the truth has poses.
    angles: Option<[f64; 3]>,
    /// A box of no size: the target is not in the frame.
    absent: bool,
}

/// The box a pose record is scored by: the axis-aligned bounding box of its ellipse, turned
/// by its orientation ([`PoseRecord::ellipse`]). (Scored with the orientation ignored, a track
/// started at 90 degrees, its `a` and `b` swapped, had a third of its success AUC taken away
/// while on the target.)
pub fn pose_box(r: &PoseRecord) -> BoxRect {
    r.ellipse().bounding_box()
}

/// Reads ground truth: a pose CSV when the first non-blank line starts with `frame`, otherwise
/// an OTB box file (see [`crate::io::boxes`]).
pub fn load_truth(path: &Path) -> Result<Truth, EvalError> {
    let text = crate::io::read_text(path).map_err(|cause| EvalError::Io {
        path: path.display().to_string(),
        cause,
    })?;
    let first = text
        .lines()
        .map(|l| l.trim_start_matches('\u{feff}').trim())
        .find(|l| !l.is_empty())
        .unwrap_or("");
    if first.to_ascii_lowercase().starts_with("frame") {
        Ok(Truth::Poses(parse_pose_csv(&text, path)?))
    } else {
        Ok(Truth::Boxes(parse_otb_boxes(&text, path)?))
    }
}

/// Per-axis values in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Axes {
    /// Tilt.
    pub rx: f64,
    /// Pan.
    pub ry: f64,
    /// Roll.
    pub rz: f64,
}

impl Axes {
    fn from_array(v: [f64; 3]) -> Self {
        Self {
            rx: v[0],
            ry: v[1],
            rz: v[2],
        }
    }
}

/// The rotation error's summary ([`Report::rotation_error_deg`]), in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RotationError {
    /// Root mean square over the evaluated frames.
    pub rmse: f64,
    /// Mean over the evaluated frames.
    pub mean: f64,
    /// Largest over the evaluated frames.
    pub max: f64,
}

/// The angle in degrees, in `[0, 180]`, of the rotation taking the truth's pose to the
/// estimate's (`R_est · R_truthᵀ`), from Euler angles in radians.
pub fn rotation_error_deg(est: Euler, truth: Euler) -> f64 {
    deg(angle_between(&est.matrix(), &truth.matrix()))
}

/// Per-axis gains of the estimated angles ([`Report::angle_gain`]); `None` on an axis about
/// which the truth hardly turns.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Gains {
    /// Tilt.
    pub rx: Option<f64>,
    /// Pan.
    pub ry: Option<f64>,
    /// Roll.
    pub rz: Option<f64>,
}

/// The least-squares slope of `truth + error` against `truth` over `(truth, error)` pairs in
/// degrees, `None` when the truth's standard deviation is under [`GAIN_MIN_SPREAD_DEG`].
pub fn gain(pairs: &[(f64, f64)]) -> Option<f64> {
    let n = pairs.len() as f64;
    if pairs.is_empty() {
        return None;
    }
    let (mt, md) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), &(t, d)| (a + t / n, b + d / n));
    let (stt, std) = pairs.iter().fold((0.0, 0.0), |(a, b), &(t, d)| {
        (a + (t - mt) * (t - mt), b + (t - mt) * (d - md))
    });
    ((stt / n).sqrt() >= GAIN_MIN_SPREAD_DEG).then(|| 1.0 + std / stt)
}

/// The scores of an estimate (see the module docs for the definitions).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// What the truth holds (`poses` or `boxes`).
    pub truth_kind: TruthKind,
    /// The first truth frame scored: 0, or where [`evaluate_from`] was told to start (the
    /// counts and shares below are of the truth frames from it on).
    pub scored_from: usize,
    /// Frames in the truth (from [`Report::scored_from`] on), those marking the target
    /// [`Report::absent`] included (before 2026-12-06 no frame was absent: this was the
    /// number scored). The shares (precision, success) are over `truth_frames − absent`.
    pub truth_frames: usize,
    /// Truth frames with an estimate.
    pub evaluated: usize,
    /// Truth frames with no estimate: failures in precision and success.
    pub missing: usize,
    /// The missing frames.
    pub missing_frames: Vec<usize>,
    /// Estimate frames with no truth frame, or before [`Report::scored_from`] (not scored).
    pub ignored: usize,
    /// Truth frames marking the target absent (an OTB box of no size): not scored.
    pub absent: usize,
    /// Of the [`Report::absent`] frames, those with an estimate.
    pub absent_estimated: usize,
    /// Of the [`Report::absent_estimated`] frames, those the estimate flags as lost, when it
    /// has a `lost` column: the frames without the target where the tracker said so. The rest
    /// are estimates of a target that is not there.
    pub absent_lost: Option<usize>,
    /// Angle RMSE per axis (degrees, over evaluated frames); `None` for box truth.
    pub angle_rmse_deg: Option<Axes>,
    /// Angle MAE per axis (degrees, over evaluated frames); `None` for box truth.
    pub angle_mae_deg: Option<Axes>,
    /// Gain of the estimated angle per axis (the slope of estimate against truth, over
    /// evaluated frames); `None` for box truth.
    pub angle_gain: Option<Gains>,
    /// The angle of `R_est · R_truthᵀ` (degrees, over evaluated frames): the whole rotation's
    /// error, whichever way its angles are written; `None` for box truth.
    pub rotation_error_deg: Option<RotationError>,
    /// Mean centre error over evaluated frames (pixels).
    pub mean_centre_error_px: f64,
    /// Share of truth frames with centre error `≤ 20` px (missing frames fail).
    pub precision_20px: f64,
    /// Success rates at IoU thresholds `0, 0.05, …, 1` (missing frames fail).
    pub success_rates: Vec<f64>,
    /// Mean of [`Report::success_rates`].
    pub success_auc: f64,
    /// Mean IoU over evaluated frames.
    pub mean_iou: f64,
    /// Evaluated frames the estimate flags as lost, when it has a `lost` column.
    pub lost: Option<usize>,
    /// Mean `score` over evaluated frames, when the estimate has a `score` column.
    pub mean_score: Option<f64>,
    /// Evaluated frames on the target: IoU at least [`ON_TARGET_IOU`]. The others are off it.
    pub on_target: usize,
    /// Where the estimate is off the target: the evaluated frames (those with an estimate;
    /// [`Report::missing_frames`] apart, and absent ones not scored) with IoU under
    /// [`ON_TARGET_IOU`], as runs of consecutive frame numbers, first and last
    /// ([`frame_runs`]). A missing frame between two off the target splits their run.
    pub off_target_runs: Vec<(usize, usize)>,
    /// Of the [`Report::lost`] frames, those on the target (false alarms), when the estimate
    /// has a `lost` column. The rest of the lost frames are off it.
    pub lost_on_target: Option<usize>,
    /// How well the `score` tells the frames on the target from those off it: the area under
    /// the ROC curve, the chance that a frame on it drawn at random scores higher than one off
    /// it (ties counted a half). `None` without a `score` column, where every evaluated
    /// frame is on the target or every one off it, or where a score is not finite (which a
    /// pose CSV refuses, but a program's records may hold).
    pub score_auroc: Option<f64>,
}

/// Frames in ascending order gathered into runs of consecutive numbers, each its first and
/// last: `[3, 4, 5, 9]` -> `[(3, 5), (9, 9)]`.
pub fn frame_runs(frames: impl IntoIterator<Item = usize>) -> Vec<(usize, usize)> {
    let mut runs = Vec::new();
    for f in frames {
        extend_runs(&mut runs, f);
    }
    runs
}

/// Adds `frame` to `runs` (see [`frame_runs`]): it lengthens the last run where it follows
/// it, and starts a new one otherwise. For frames that arrive in order, one at a time.
pub fn extend_runs(runs: &mut Vec<(usize, usize)>, frame: usize) {
    match runs.last_mut() {
        Some((_, last)) if last.checked_add(1) == Some(frame) => *last = frame,
        _ => runs.push((frame, frame)),
    }
}

/// Runs of frames for a person: `N frames: 3-5, 9, ...`, the first `named` runs written out
/// and then how many more (`and 4 more runs`); `none` where there are none. A run is its
/// first and last frame, as [`frame_runs`] gives them (a run given backwards counts as one
/// frame; the count saturates).
pub fn runs_text(runs: &[(usize, usize)], named: usize) -> String {
    if runs.is_empty() {
        return "none".to_string();
    }
    let count = runs.iter().fold(0usize, |n, &(a, b)| {
        n.saturating_add(b.saturating_sub(a).saturating_add(1))
    });
    let mut parts: Vec<String> = runs
        .iter()
        .take(named)
        .map(|&(a, b)| {
            if a == b {
                a.to_string()
            } else {
                format!("{a}-{b}")
            }
        })
        .collect();
    let more = runs.len().saturating_sub(named);
    if more > 0 {
        parts.push(format!(
            "and {more} more run{}",
            if more == 1 { "" } else { "s" }
        ));
    }
    format!(
        "{count} frame{}: {}",
        if count == 1 { "" } else { "s" },
        parts.join(", ")
    )
}

/// The 21 IoU thresholds of the success plot.
pub fn success_thresholds() -> [f64; SUCCESS_STEPS] {
    std::array::from_fn(|k| k as f64 / (SUCCESS_STEPS - 1) as f64)
}

/// Success rates over `n` frames of which `ious` are the evaluated ones (the other
/// `n − ious.len()` frames fail every threshold): share with IoU `> t` per threshold.
pub fn success_rates(ious: &[f64], n: usize) -> Vec<f64> {
    success_thresholds()
        .iter()
        .map(|&t| ious.iter().filter(|&&v| v > t).count() as f64 / n as f64)
        .collect()
}

/// Angle error `wrap_180(est − truth)` in degrees, from angles in radians.
pub fn angle_error_deg(est: f64, truth: f64) -> f64 {
    wrap_180(deg(est) - deg(truth))
}

/// The truth's angles in degrees by frame, unwrapped in frame order (each within 180 degrees
/// of the frame before it that has angles), for the gain's regression.
fn unwrapped_truth_deg(tf: &[TruthFrame]) -> BTreeMap<usize, [f64; 3]> {
    let mut with_angles: Vec<(usize, [f64; 3])> = tf
        .iter()
        .filter_map(|t| t.angles.map(|a| (t.frame, a.map(deg))))
        .collect();
    with_angles.sort_by_key(|&(f, _)| f);
    let mut out = BTreeMap::new();
    let mut prev: Option<[f64; 3]> = None;
    for (f, a) in with_angles {
        let u = match prev {
            Some(p) => std::array::from_fn(|k| p[k] + wrap_180(a[k] - p[k])),
            None => a,
        };
        prev = Some(u);
        out.insert(f, u);
    }
    out
}

/// `(first, last)` of a sorted list of frames.
fn first_last(frames: impl Iterator<Item = usize>) -> Option<(usize, usize)> {
    let mut it = frames;
    let first = it.next()?;
    Some((first, it.last().unwrap_or(first)))
}

/// Scores `est` against `truth`.
pub fn evaluate(truth: &Truth, est: &[PoseRecord]) -> Result<Report, EvalError> {
    evaluate_from(truth, est, 0)
}

/// Scores `est` against the truth's frames from `from` on, as OTB's temporal robustness
/// evaluation (TRE) scores a track started later in the sequence: the truth frames before it
/// are not scored at all (neither missing nor failures), and the estimate's rows before it
/// are ignored ([`Report::ignored`]). [`evaluate`] is `from` 0.
pub fn evaluate_from(truth: &Truth, est: &[PoseRecord], from: usize) -> Result<Report, EvalError> {
    let all = truth.frames();
    let last = all.iter().map(|t| t.frame).max();
    let tf: Vec<TruthFrame> = all.into_iter().filter(|t| t.frame >= from).collect();
    match last {
        None => return Err(EvalError::EmptyTruth),
        Some(last) if tf.is_empty() => return Err(EvalError::NoTruthFrom { from, last }),
        Some(_) => {}
    }
    let mut seen = std::collections::BTreeSet::new();
    for t in &tf {
        if !seen.insert(t.frame) {
            return Err(EvalError::DuplicateFrame {
                what: "truth",
                frame: t.frame,
            });
        }
    }
    let mut by_frame: BTreeMap<usize, &PoseRecord> = BTreeMap::new();
    for r in est {
        if by_frame.insert(r.frame, r).is_some() {
            return Err(EvalError::DuplicateFrame {
                what: "estimate",
                frame: r.frame,
            });
        }
    }
    let absent = tf.iter().filter(|t| t.absent).count();
    // The frames scored: those where the target is present.
    let n = tf.len() - absent;
    let mut missing_frames = Vec::new();
    let mut centre_errs = Vec::with_capacity(n);
    let mut ious = Vec::with_capacity(n);
    let mut sq = [0.0f64; 3];
    let mut abs = [0.0f64; 3];
    let mut swings: [Vec<(f64, f64)>; 3] = Default::default();
    let mut turn_errs = Vec::with_capacity(n);
    let (mut lost, mut any_lost_col) = (0usize, false);
    // Each evaluated frame's score, and whether the estimate is on the target there.
    let mut scores: Vec<(f64, bool)> = Vec::new();
    let (mut on_target, mut lost_on_target) = (0usize, 0usize);
    let mut off_target = Vec::new();
    let unwrapped = unwrapped_truth_deg(&tf);
    for t in tf.iter().filter(|t| !t.absent) {
        let Some(r) = by_frame.get(&t.frame) else {
            missing_frames.push(t.frame);
            continue;
        };
        let s = &r.state;
        let (tcx, tcy) = t.centre;
        centre_errs.push((s.cx - tcx).hypot(s.cy - tcy));
        // Clamped: rounding can put the IoU of identical boxes a hair above 1.
        let iou = pose_box(r).iou(&t.bbox).clamp(0.0, 1.0);
        ious.push(iou);
        let on = iou >= ON_TARGET_IOU;
        on_target += usize::from(on);
        if !on {
            off_target.push(t.frame);
        }
        if let Some(angles) = t.angles {
            let swing = unwrapped.get(&t.frame);
            for (k, e) in [s.rx, s.ry, s.rz].into_iter().enumerate() {
                let d = angle_error_deg(e, angles[k]);
                sq[k] += d * d;
                abs[k] += d.abs();
                // The truth unwrapped: one written -179 after 179 has turned 2 degrees, not
                // 358, and would otherwise swell the spread the gain divides by.
                swings[k].push((swing.map_or(deg(angles[k]), |u| u[k]), d));
            }
            let [rx, ry, rz] = angles;
            turn_errs.push(rotation_error_deg(
                Euler::new(s.rx, s.ry, s.rz),
                Euler::new(rx, ry, rz),
            ));
        }
        if let Some(l) = r.lost {
            any_lost_col = true;
            lost += usize::from(l);
            lost_on_target += usize::from(l && on);
        }
        if let Some(sc) = r.score {
            scores.push((sc, on));
        }
    }
    // Where the target is absent, only whether the tracker says so.
    let (mut absent_estimated, mut absent_lost) = (0usize, 0usize);
    for r in tf
        .iter()
        .filter(|t| t.absent)
        .filter_map(|t| by_frame.get(&t.frame))
    {
        absent_estimated += 1;
        if let Some(l) = r.lost {
            any_lost_col = true;
            absent_lost += usize::from(l);
        }
    }
    let evaluated = centre_errs.len();
    if n == 0 {
        return Err(EvalError::AllAbsent { from });
    }
    if evaluated == 0 {
        // The truth's frames with the target present, which are the ones scored.
        return Err(EvalError::NoCommonFrames {
            truth: first_last(tf.iter().filter(|t| !t.absent).map(|t| t.frame)),
            estimate: first_last(by_frame.keys().copied()),
        });
    }
    let ignored = by_frame
        .keys()
        .filter(|&&f| f < from || !seen.contains(&f))
        .count();
    let m = evaluated as f64;
    let has_angles = matches!(truth, Truth::Poses(_));
    let rates = success_rates(&ious, n);
    Ok(Report {
        truth_kind: truth.kind(),
        scored_from: from,
        truth_frames: tf.len(),
        evaluated,
        missing: missing_frames.len(),
        missing_frames,
        ignored,
        absent,
        absent_estimated,
        absent_lost: any_lost_col.then_some(absent_lost),
        angle_rmse_deg: has_angles.then(|| Axes::from_array(sq.map(|v| (v / m).sqrt()))),
        angle_mae_deg: has_angles.then(|| Axes::from_array(abs.map(|v| v / m))),
        angle_gain: has_angles.then(|| Gains {
            rx: gain(&swings[0]),
            ry: gain(&swings[1]),
            rz: gain(&swings[2]),
        }),
        rotation_error_deg: has_angles.then(|| RotationError {
            rmse: (turn_errs.iter().map(|e| e * e).sum::<f64>() / m).sqrt(),
            mean: turn_errs.iter().sum::<f64>() / m,
            max: turn_errs.iter().copied().fold(0.0, f64::max),
        }),
        mean_centre_error_px: centre_errs.iter().sum::<f64>() / m,
        precision_20px: centre_errs
            .iter()
            .filter(|&&e| e <= PRECISION_THRESHOLD_PX)
            .count() as f64
            / n as f64,
        success_auc: rates.iter().sum::<f64>() / rates.len() as f64,
        success_rates: rates,
        mean_iou: ious.iter().sum::<f64>() / m,
        lost: any_lost_col.then_some(lost),
        mean_score: (!scores.is_empty())
            .then(|| scores.iter().map(|(sc, _)| sc).sum::<f64>() / scores.len() as f64),
        on_target,
        off_target_runs: {
            // A truth built by a program may come in any order.
            off_target.sort_unstable();
            off_target.dedup();
            frame_runs(off_target)
        },
        lost_on_target: any_lost_col.then_some(lost_on_target),
        score_auroc: {
            let of = |side: bool| -> Vec<f64> {
                scores
                    .iter()
                    .filter(|(_, on)| *on == side)
                    .map(|(sc, _)| *sc)
                    .collect()
            };
            auroc(&of(true), &of(false))
        },
    })
}

/// The area under the ROC curve of a score telling `pos` from `neg`: the share of the pairs
/// (one of each) in which the one from `pos` scores higher, ties counted a half (the
/// Mann-Whitney statistic over `|pos| · |neg|`). `None` where either is empty or a score is
/// not finite.
pub fn auroc(pos: &[f64], neg: &[f64]) -> Option<f64> {
    if pos.is_empty() || neg.is_empty() || pos.iter().chain(neg).any(|v| !v.is_finite()) {
        return None;
    }
    let mut neg = neg.to_vec();
    neg.sort_by(f64::total_cmp);
    // For each positive: the negatives below it, and half those equal to it.
    let wins: f64 = pos
        .iter()
        .map(|&p| {
            let below = neg.partition_point(|&v| v < p);
            let up_to = neg.partition_point(|&v| v <= p);
            below as f64 + 0.5 * (up_to - below) as f64
        })
        .sum();
    Some(wins / (pos.len() as f64 * neg.len() as f64))
}

impl Report {
    /// A small aligned table for people.
    pub fn to_table(&self) -> String {
        let mut s = String::new();
        let kind = match self.truth_kind {
            TruthKind::Poses => "poses",
            TruthKind::Boxes => "boxes",
        };
        let row = |s: &mut String, k: &str, v: String| {
            let _ = writeln!(s, "{k:<18}{v}");
        };
        let from = match self.scored_from {
            0 => String::new(),
            f => format!(", frames {f} on"),
        };
        row(
            &mut s,
            "truth frames",
            format!("{} ({kind}{from})", self.truth_frames),
        );
        row(&mut s, "evaluated", self.evaluated.to_string());
        let missing = if self.missing == 0 {
            "0".to_string()
        } else {
            let shown: Vec<String> = self
                .missing_frames
                .iter()
                .take(8)
                .map(|f| f.to_string())
                .collect();
            let more = if self.missing > 8 { ", ..." } else { "" };
            format!(
                "{}  <-- failures in precision and success (frames {}{more})",
                self.missing,
                shown.join(", ")
            )
        };
        row(&mut s, "MISSING", missing);
        // The means are over the frames evaluated: with frames missing, say so where they
        // are read.
        let over =
            (self.missing > 0).then(|| format!("over the {} frames evaluated", self.evaluated));
        if self.ignored > 0 {
            row(
                &mut s,
                "ignored",
                format!("{} estimate frames with no truth", self.ignored),
            );
        }
        if self.absent > 0 {
            row(
                &mut s,
                "absent",
                format!(
                    "{} truth frame{} without the target (not scored){}",
                    self.absent,
                    if self.absent == 1 { "" } else { "s" },
                    match self.absent_lost {
                        Some(_) if self.absent_estimated == 0 => {
                            "; none with an estimate".to_string()
                        }
                        Some(l) => format!(
                            "; flagged lost on {l} of the {} with an estimate",
                            self.absent_estimated
                        ),
                        None => String::new(),
                    }
                ),
            );
        }
        row(
            &mut s,
            "centre error",
            match &over {
                Some(o) => format!("{} px (mean, {o})", fixed(self.mean_centre_error_px, 3)),
                None => format!("{} px (mean)", fixed(self.mean_centre_error_px, 3)),
            },
        );
        row(
            &mut s,
            "precision@20px",
            format!("{:.4}", self.precision_20px),
        );
        row(
            &mut s,
            "success AUC",
            format!("{:.4}  (OTB: IoU > t, 21 t in [0, 1])", self.success_auc),
        );
        row(
            &mut s,
            "mean IoU",
            match &over {
                Some(o) => format!("{:.4}  ({o})", self.mean_iou),
                None => format!("{:.4}", self.mean_iou),
            },
        );
        let off = self.evaluated - self.on_target;
        row(
            &mut s,
            "off the target",
            format!(
                "{}  (evaluated, IoU < {ON_TARGET_IOU})",
                runs_text(&self.off_target_runs, 8)
            ),
        );
        if let Some(l) = self.lost {
            let split = match self.lost_on_target {
                Some(_) if l > 0 && off == 0 => " (all on the target)".to_string(),
                Some(on) if l > 0 => {
                    format!(" ({on} on the target, {} of the {off} off it)", l - on)
                }
                _ => String::new(),
            };
            row(&mut s, "lost frames", format!("{l}{split}"));
        }
        if let Some(sc) = self.mean_score {
            row(&mut s, "mean score", format!("{sc:.4}"));
        }
        if self.mean_score.is_some() {
            let bar = ON_TARGET_IOU;
            row(
                &mut s,
                "score AUROC",
                match self.score_auroc {
                    Some(a) => format!(
                        "{a:.4}  (the score telling the {} frames on the target, IoU >= {bar}, \
                         from the {off} off it)",
                        self.on_target
                    ),
                    None if off == 0 => {
                        format!("-  (every evaluated frame is on the target, IoU >= {bar})")
                    }
                    None if self.on_target == 0 => {
                        format!("-  (every evaluated frame is off the target, IoU < {bar})")
                    }
                    None => "-  (a score that is not a number)".to_string(),
                },
            );
        }
        if let (Some(r), Some(m)) = (self.angle_rmse_deg, self.angle_mae_deg) {
            let g = self.angle_gain.unwrap_or_default();
            let _ = writeln!(
                s,
                "\n{:<6}{:>12}{:>12}{:>8}",
                "axis", "RMSE (deg)", "MAE (deg)", "gain"
            );
            for (name, a, b, g) in [
                ("rx", r.rx, m.rx, g.rx),
                ("ry", r.ry, m.ry, g.ry),
                ("rz", r.rz, m.rz, g.rz),
            ] {
                let g = g.map_or_else(|| "-".to_string(), |g| format!("{g:.3}"));
                let _ = writeln!(s, "{name:<6}{:>12}{:>12}{g:>8}", fixed(a, 3), fixed(b, 3));
            }
        }
        if let Some(t) = self.rotation_error_deg {
            let _ = writeln!(
                s,
                "{:<6}{:>12}{:>12}{:>8}\n(turn: the angle of R_est R_truth^T; its largest {} deg)",
                "turn",
                fixed(t.rmse, 3),
                fixed(t.mean, 3),
                "-",
                fixed(t.max, 3)
            );
        }
        s
    }
}

/// `x` with `decimals` decimals, or in exponent form when too large for a table (an
/// estimate a tracker threw 1e300 px away would print 300 digits).
fn fixed(x: f64, decimals: usize) -> String {
    if x.abs() < 1e9 || !x.is_finite() {
        format!("{x:.decimals$}")
    } else {
        format!("{x:.decimals$e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{PoseState, rad, rot_y};

    #[test]
    fn huge_values_are_shown_in_exponent_form() {
        assert_eq!(fixed(1.23456, 3), "1.235");
        assert_eq!(fixed(-12345.0, 1), "-12345.0");
        assert_eq!(fixed(1e300, 3), "1.000e300");
        assert_eq!(fixed(f64::NAN, 3), "NaN");
    }

    fn rec(frame: usize, cx: f64, rx_deg: f64) -> PoseRecord {
        PoseRecord {
            frame,
            state: PoseState {
                cx,
                cy: 40.0,
                a: 10.0,
                b: 15.0,
                rx: rad(rx_deg),
                ry: rad(-20.0),
                rz: rad(5.0),
            },
            score: None,
            lost: None,
            theta: None,
        }
    }

    #[test]
    fn thresholds_and_rates() {
        let t = success_thresholds();
        assert_eq!(t[0], 0.0);
        assert_eq!(t[20], 1.0);
        assert!((t[1] - 0.05).abs() < 1e-15);
        // IoU exactly 0 fails t = 0; IoU 1 fails t = 1; one missing frame (n = 3).
        let r = success_rates(&[0.0, 1.0], 3);
        assert_eq!(r[0], 1.0 / 3.0);
        assert_eq!(r[19], 1.0 / 3.0);
        assert_eq!(r[20], 0.0);
    }

    #[test]
    fn angle_errors_wrap() {
        assert!((angle_error_deg(rad(-179.0), rad(179.0)) - 2.0).abs() < 1e-9);
        assert!((angle_error_deg(rad(10.0), rad(350.0)) - 20.0).abs() < 1e-9);
        assert_eq!(angle_error_deg(rad(33.0), rad(33.0)), 0.0);
    }

    #[test]
    fn wrapped_angles_in_a_report() {
        let truth = Truth::Poses(vec![rec(0, 50.0, 179.0), rec(1, 50.0, -90.0)]);
        let est = vec![rec(0, 50.0, -179.0), rec(1, 50.0, -94.0)];
        let r = evaluate(&truth, &est).unwrap();
        let rmse = r.angle_rmse_deg.unwrap();
        assert!((rmse.rx - 10f64.sqrt()).abs() < 1e-9, "{}", rmse.rx);
        assert!((r.angle_mae_deg.unwrap().rx - 3.0).abs() < 1e-9);
        assert_eq!(rmse.ry, 0.0);
        // Only the tilt differs, so the whole rotation's error is the tilt's: 2 and 4 degrees.
        let t = r.rotation_error_deg.unwrap();
        assert!((t.rmse - 10f64.sqrt()).abs() < 1e-9, "{t:?}");
        assert!(
            (t.mean - 3.0).abs() < 1e-9 && (t.max - 4.0).abs() < 1e-9,
            "{t:?}"
        );
    }

    #[test]
    fn the_rotation_error_does_not_depend_on_how_the_angles_are_written() {
        // R = Rx(a) Ry(b) Rz(c) = Rx(a + 180) Ry(180 - b) Rz(c + 180): one rotation, every
        // angle of it written another way.
        let (a, b, c) = (20.0, 70.0, -35.0);
        let one = Euler::from_degrees(a, b, c);
        let other = Euler::from_degrees(a + 180.0, 180.0 - b, c + 180.0);
        assert!((one.matrix() - other.matrix()).abs().max() < 1e-12);
        let pose = |frame, e: Euler| {
            let mut r = rec(frame, 50.0, 0.0);
            (r.state.rx, r.state.ry, r.state.rz) = (e.rx, e.ry, e.rz);
            r
        };
        let truth = Truth::Poses(vec![pose(0, one), pose(1, one)]);
        // Frame 1 is off by 5 degrees about y, written the same way as the truth.
        let off = Euler::from_matrix(&(rot_y(rad(5.0)) * one.matrix()));
        let r = evaluate(&truth, &[pose(0, other), pose(1, off)]).unwrap();
        let t = r.rotation_error_deg.unwrap();
        assert!(
            (t.mean - 2.5).abs() < 1e-9 && (t.max - 5.0).abs() < 1e-9,
            "{t:?}"
        );
        assert!((t.rmse - 12.5f64.sqrt()).abs() < 1e-9, "{t:?}");
        // The per-axis errors see frame 0's angles as 180 degrees apart.
        assert!(r.angle_mae_deg.unwrap().rx > 89.0, "{:?}", r.angle_mae_deg);
        assert!(rotation_error_deg(one, other) < 1e-9);
        // A box truth has none.
        let boxes = Truth::Boxes(vec![BoxRect::new(40.0, 25.0, 20.0, 30.0)]);
        assert_eq!(
            evaluate(&boxes, &[rec(0, 50.0, 0.0)])
                .unwrap()
                .rotation_error_deg,
            None
        );
    }

    #[test]
    fn the_gain_is_the_slope_of_the_estimate_against_the_truth() {
        // Tilt read 1.1 times its swing and 2° high; pan still in the truth.
        let truth: Vec<PoseRecord> = (0..40)
            .map(|k| rec(k, 50.0, 30.0 * (k as f64 * 0.3).sin()))
            .collect();
        let est: Vec<PoseRecord> = truth
            .iter()
            .map(|t| rec(t.frame, 50.0, 1.1 * deg(t.state.rx) + 2.0))
            .collect();
        let r = evaluate(&Truth::Poses(truth.clone()), &est).unwrap();
        let g = r.angle_gain.unwrap();
        assert!((g.rx.unwrap() - 1.1).abs() < 1e-9, "{:?}", g.rx);
        assert_eq!((g.ry, g.rz), (None, None));
        // An estimate equal to the truth has gain 1; the table shows it, and "-" for a
        // still axis.
        let same = evaluate(&Truth::Poses(truth.clone()), &truth).unwrap();
        assert!((same.angle_gain.unwrap().rx.unwrap() - 1.0).abs() < 1e-12);
        let table = same.to_table();
        assert!(table.contains("gain"), "{table}");
        assert!(
            table
                .lines()
                .any(|l| l.starts_with("ry") && l.ends_with('-'))
        );
        // Across ±180°: the truth swinging 170° → 190° and the estimate following it
        // exactly, however either writes the angle.
        let wrap_t: Vec<PoseRecord> = (0..21).map(|k| rec(k, 50.0, 170.0 + k as f64)).collect();
        let wrap_e: Vec<PoseRecord> = (0..21)
            .map(|k| rec(k, 50.0, wrap_180(170.0 + k as f64)))
            .collect();
        let w = evaluate(&Truth::Poses(wrap_t), &wrap_e).unwrap();
        assert!((w.angle_gain.unwrap().rx.unwrap() - 1.0).abs() < 1e-9);
        // The truth written wrapped (-170° for 190°), turning 2° a frame, read half of it:
        // the gain is 0.5 whichever way the truth is written, in whatever row order.
        let half = |wrap: bool| {
            let t = |k: usize| 170.0 + 2.0 * k as f64;
            let mut truth: Vec<PoseRecord> = (0..21)
                .map(|k| rec(k, 50.0, if wrap { wrap_180(t(k)) } else { t(k) }))
                .collect();
            truth.reverse();
            let est: Vec<PoseRecord> = (0..21)
                .map(|k| rec(k, 50.0, wrap_180(170.0 + k as f64)))
                .collect();
            let r = evaluate(&Truth::Poses(truth), &est).unwrap();
            r.angle_gain.unwrap().rx.unwrap()
        };
        assert!((half(false) - 0.5).abs() < 1e-9, "{}", half(false));
        assert!((half(true) - 0.5).abs() < 1e-9, "{}", half(true));
        // A truth that hardly turns has no gain, nor an empty one.
        assert_eq!(gain(&[(0.0, 1.0), (0.5, 2.0), (1.0, 0.0)]), None);
        assert_eq!(gain(&[]), None);
    }

    #[test]
    fn errors() {
        let truth = Truth::Poses(vec![rec(0, 1.0, 0.0), rec(1, 1.0, 0.0)]);
        let e = evaluate(&truth, &[rec(5, 1.0, 0.0), rec(9, 1.0, 0.0)]).unwrap_err();
        assert!(matches!(e, EvalError::NoCommonFrames { .. }));
        assert_eq!(
            e.to_string(),
            "no frames in common: the truth has the target in frames 0..=1, the estimate frames 5..=9"
        );
        let e = evaluate(&truth, &[]).unwrap_err();
        assert!(e.to_string().contains("(none)"), "{e}");
        assert!(matches!(
            evaluate(&Truth::Boxes(vec![]), &[rec(0, 1.0, 0.0)]),
            Err(EvalError::EmptyTruth)
        ));
        let e = evaluate(&truth, &[rec(0, 1.0, 0.0), rec(0, 1.0, 0.0)]).unwrap_err();
        assert!(matches!(
            e,
            EvalError::DuplicateFrame {
                what: "estimate",
                frame: 0
            }
        ));
        let dup = Truth::Poses(vec![rec(3, 1.0, 0.0), rec(3, 1.0, 0.0)]);
        assert!(matches!(
            evaluate(&dup, &[rec(3, 1.0, 0.0)]),
            Err(EvalError::DuplicateFrame { what: "truth", .. })
        ));
    }

    #[test]
    fn lost_and_score_columns() {
        let truth = Truth::Poses(vec![rec(0, 1.0, 0.0), rec(1, 1.0, 0.0), rec(2, 1.0, 0.0)]);
        let mut est = vec![rec(0, 1.0, 0.0), rec(1, 1.0, 0.0), rec(7, 1.0, 0.0)];
        for (i, r) in est.iter_mut().enumerate() {
            r.score = Some(0.25 * i as f64);
            r.lost = Some(i == 1 || i == 2);
        }
        let r = evaluate(&truth, &est).unwrap();
        // Frame 7 has no truth: ignored, and neither its score nor its lost flag counts.
        assert_eq!(r.ignored, 1);
        assert_eq!(r.lost, Some(1));
        assert_eq!(r.mean_score, Some(0.125));
        assert_eq!(r.missing_frames, vec![2]);
        let plain = evaluate(&truth, &[rec(0, 1.0, 0.0)]).unwrap();
        assert_eq!((plain.lost, plain.mean_score), (None, None));
    }

    #[test]
    fn frames_gather_into_runs_and_read_as_text() {
        assert_eq!(frame_runs([3, 4, 5, 9]), vec![(3, 5), (9, 9)]);
        assert_eq!(frame_runs([]), vec![]);
        assert_eq!(
            frame_runs([0, 2, 3, usize::MAX]),
            vec![(0, 0), (2, 3), (usize::MAX, usize::MAX)]
        );
        assert_eq!(runs_text(&[], 8), "none");
        assert_eq!(runs_text(&[(7, 7)], 8), "1 frame: 7");
        assert_eq!(runs_text(&[(3, 5), (9, 9)], 8), "4 frames: 3-5, 9");
        let many: Vec<_> = (0..12).map(|k| (10 * k, 10 * k + 1)).collect();
        assert_eq!(
            runs_text(&many, 2),
            "24 frames: 0-1, 10-11, and 10 more runs"
        );
        assert_eq!(
            runs_text(&many[..3], 2),
            "6 frames: 0-1, 10-11, and 1 more run"
        );
        // Given by hand, backwards or the whole range: no overflow.
        assert_eq!(runs_text(&[(5, 3)], 8), "1 frame: 5-3");
        assert_eq!(
            runs_text(&[(0, usize::MAX), (0, 1)], 8),
            format!("{} frames: 0-{}, 0-1", usize::MAX, usize::MAX)
        );
        let mut runs = Vec::new();
        for f in [4, 5, 7] {
            extend_runs(&mut runs, f);
        }
        assert_eq!(runs, vec![(4, 5), (7, 7)]);
    }

    #[test]
    fn auroc_known_answers() {
        // Perfectly separated either way, and a score that says nothing.
        assert_eq!(auroc(&[0.9, 0.8], &[0.1, 0.2, 0.3]), Some(1.0));
        assert_eq!(auroc(&[0.1, 0.2], &[0.8, 0.9]), Some(0.0));
        assert_eq!(auroc(&[0.5, 0.5], &[0.5]), Some(0.5));
        // By hand: pairs (pos, neg) over {0.2, 0.6, 0.9} x {0.1, 0.6, 0.7}: 0.2 beats 0.1
        // (1); 0.6 beats 0.1, ties 0.6 (1.5); 0.9 beats all three (3). 5.5 of 9.
        assert_eq!(auroc(&[0.2, 0.6, 0.9], &[0.7, 0.1, 0.6]), Some(5.5 / 9.0));
        // Symmetric: swapping the classes gives one minus it.
        let (p, n) = ([0.3, 0.35, 0.8, 0.1], [0.3, 0.5, 0.05]);
        let (a, b) = (auroc(&p, &n).unwrap(), auroc(&n, &p).unwrap());
        assert!((a + b - 1.0).abs() < 1e-15, "{a} {b}");
        assert_eq!(auroc(&[], &[0.5]), None);
        assert_eq!(auroc(&[0.5], &[]), None);
        assert_eq!(auroc(&[f64::NAN], &[0.5]), None);
    }

    #[test]
    fn the_score_and_the_lost_flag_are_judged_on_and_off_the_target() {
        // Truth boxes 20x30 at cx = 50; estimates on it (IoU 1), 10 px to its side (IoU 1/3:
        // off the target) or far from it (IoU 0).
        let truth = Truth::Poses((0..6).map(|f| rec(f, 50.0, 0.0)).collect());
        let cxs = [50.0, 50.0, 60.0, 200.0, 50.0, 200.0];
        let scores = [0.9, 0.7, 0.8, 0.2, 0.6, 0.75];
        let lost = [false, true, false, true, false, false];
        let est: Vec<PoseRecord> = (0..6)
            .map(|f| PoseRecord {
                score: Some(scores[f]),
                lost: Some(lost[f]),
                ..rec(f, cxs[f], 0.0)
            })
            .collect();
        let r = evaluate(&truth, &est).unwrap();
        assert_eq!(r.on_target, 3);
        assert_eq!(r.off_target_runs, vec![(2, 3), (5, 5)]);
        // A truth a program built backwards: the same runs.
        let backwards = Truth::Poses((0..6).rev().map(|f| rec(f, 50.0, 0.0)).collect());
        let b = evaluate(&backwards, &est).unwrap();
        assert_eq!(b.off_target_runs, r.off_target_runs);
        assert_eq!((r.lost, r.lost_on_target), (Some(2), Some(1)));
        // On: 0.9, 0.7, 0.6; off: 0.8, 0.2, 0.75. Wins: 0.9 beats 3, 0.7 beats 1, 0.6 beats 1.
        assert_eq!(r.score_auroc, Some(5.0 / 9.0));
        let table = r.to_table();
        assert!(
            table.contains("2 (1 on the target, 1 of the 3 off it)"),
            "{table}"
        );
        assert!(table.contains("score AUROC       0.5556"), "{table}");
        assert!(
            table.contains("off the target    3 frames: 2-3, 5  (evaluated, IoU < 0.5)"),
            "{table}"
        );
        let json = serde_json::to_string(&r).unwrap();
        assert!(
            json.contains("\"off_target_runs\":[[2,3],[5,5]]")
                && json.contains("\"on_target\":3")
                && json.contains("\"lost_on_target\":1")
                && json.contains("\"score_auroc\":0.5555"),
            "{json}"
        );
        // Every frame on the target: no AUROC, and the table says why.
        let on = evaluate(&truth, &est[..2]).unwrap();
        assert_eq!((on.on_target, on.score_auroc), (2, None));
        let table = on.to_table();
        assert!(
            table.contains("every evaluated frame is on the target"),
            "{table}"
        );
        assert!(table.contains("1 (all on the target)"), "{table}");
        assert!(
            table.contains("off the target    none  (evaluated, IoU < 0.5)"),
            "{table}"
        );
        // A score that is not a number: no AUROC, and not blamed on the frames.
        let mut nan = est.clone();
        nan[0].score = Some(f64::NAN);
        let n = evaluate(&truth, &nan).unwrap();
        assert_eq!(n.score_auroc, None);
        assert!(n.to_table().contains("a score that is not a number"));
        // No columns: nothing judged.
        let plain = evaluate(&truth, &[rec(0, 50.0, 0.0)]).unwrap();
        assert_eq!((plain.lost_on_target, plain.score_auroc), (None, None));
        assert!(!plain.to_table().contains("AUROC"));
    }
}

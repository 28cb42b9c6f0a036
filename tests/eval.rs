//! `pftrack eval`: exact answers on known perturbations, box truth, and the CLI.

mod shared_data;

use std::path::{Path, PathBuf};
use std::process::Command;

use pftrack::eval::{EvalError, Report, Truth, evaluate, evaluate_from, load_truth};
use pftrack::geometry::{BoxRect, Ellipse, Euler, PoseState, rad};
use pftrack::io::boxes::parse_otb_boxes;
use pftrack::io::pose_csv::write_pose_csv;
use pftrack::io::{PoseRecord, read_pose_csv};

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pftrack-eval-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A 10-frame truth: moving centre, 20×30 box, rx crossing ±180°.
fn truth_records() -> Vec<PoseRecord> {
    (0..10)
        .map(|k| PoseRecord {
            frame: k,
            state: PoseState {
                cx: 50.0 + 3.0 * k as f64,
                cy: 40.0 - 0.5 * k as f64,
                a: 10.0,
                b: 15.0,
                rx: rad(175.0 + k as f64),
                ry: rad(-30.0 + 2.0 * k as f64),
                rz: rad(10.0),
            },
            score: None,
            lost: None,
            theta: None,
        })
        .collect()
}

const AUC_MAX: f64 = 20.0 / 21.0;

fn close(a: f64, b: f64, what: &str) {
    assert!((a - b).abs() < 1e-9, "{what}: {a} vs {b}");
}

#[test]
fn truth_against_itself_is_exactly_perfect() {
    let d = scratch("self");
    let p = d.join("truth.csv");
    write_pose_csv(&p, &truth_records(), false).unwrap();
    let truth = load_truth(&p).unwrap();
    assert!(matches!(truth, Truth::Poses(_)));
    let est = read_pose_csv(&p).unwrap();
    let r = evaluate(&truth, &est).unwrap();
    assert_eq!(
        (r.truth_frames, r.evaluated, r.missing, r.ignored),
        (10, 10, 0, 0)
    );
    let (rmse, mae) = (r.angle_rmse_deg.unwrap(), r.angle_mae_deg.unwrap());
    for v in [rmse.rx, rmse.ry, rmse.rz, mae.rx, mae.ry, mae.rz] {
        assert_eq!(v, 0.0);
    }
    assert_eq!(r.mean_centre_error_px, 0.0);
    assert_eq!(r.precision_20px, 1.0);
    assert_eq!(r.mean_iou, 1.0);
    // OTB counts IoU > t: every threshold but t = 1 succeeds, the protocol's maximum.
    assert!(r.success_rates[..20].iter().all(|&v| v == 1.0));
    assert_eq!(r.success_rates[20], 0.0);
    assert_eq!(r.success_auc, AUC_MAX);
    assert_eq!((r.lost, r.mean_score), (None, None));
    std::fs::remove_dir_all(&d).unwrap();
}

/// +3° on rx for every frame, +2 px in cx for frames 0..5, frame 9 dropped, and an extra
/// estimate frame 12 beyond the truth.
fn perturbed() -> Vec<PoseRecord> {
    let mut est: Vec<PoseRecord> = truth_records()
        .into_iter()
        .filter(|r| r.frame != 9)
        .map(|mut r| {
            r.state.rx += rad(3.0);
            if r.frame < 5 {
                r.state.cx += 2.0;
            }
            r
        })
        .collect();
    let mut extra = est[0].clone();
    extra.frame = 12;
    est.push(extra);
    est
}

/// The numbers of [`perturbed`], worked out by hand:
/// - 9 of 10 frames evaluated, frame 9 missing, 1 ignored;
/// - rx: error 3° everywhere (175° + 3° wraps past 180° for the last frames: still 3°);
/// - centre error 2 px in 5 frames, 0 in 4: mean 10/9 px; all within 20 px, but the missing
///   frame fails: precision 9/10;
/// - the box scored is the 10×15 ellipse's turned by `rz` = 10°, `W = 2 sqrt(10² cos² 10° +
///   15² sin² 10°)` ≈ 20.37 px wide; its IoU shifted 2 px along x is `(W − 2) / (W + 2)` ≈
///   0.821; success rate 9/10 for t = 0 … 0.80 (17 thresholds), 4/10 for t = 0.85, 0.90,
///   0.95 (only the unshifted frames), 0 at t = 1; AUC = (17·0.9 + 3·0.4)/21 = 16.5/21.
fn check_perturbed(r: &Report) {
    assert_eq!(
        (r.truth_frames, r.evaluated, r.missing, r.ignored),
        (10, 9, 1, 1)
    );
    assert_eq!(r.missing_frames, vec![9]);
    let (rmse, mae) = (r.angle_rmse_deg.unwrap(), r.angle_mae_deg.unwrap());
    close(rmse.rx, 3.0, "rmse rx");
    close(mae.rx, 3.0, "mae rx");
    for v in [rmse.ry, rmse.rz, mae.ry, mae.rz] {
        close(v, 0.0, "other axes");
    }
    close(r.mean_centre_error_px, 10.0 / 9.0, "centre error");
    close(r.precision_20px, 0.9, "precision");
    for (k, &v) in r.success_rates.iter().enumerate() {
        let want = match k {
            0..=16 => 0.9,
            17..=19 => 0.4,
            _ => 0.0,
        };
        close(v, want, &format!("success at t = {}", k as f64 / 20.0));
    }
    close(r.success_auc, 16.5 / 21.0, "auc");
    let (s, c) = rad(10.0).sin_cos();
    let w = 2.0 * (100.0 * c * c + 225.0 * s * s).sqrt();
    close(
        r.mean_iou,
        (5.0 * (w - 2.0) / (w + 2.0) + 4.0) / 9.0,
        "mean iou",
    );
}

/// The box scored is the ellipse's turned by its orientation: the truth's ellipse written
/// with `a` and `b` swapped and turned a quarter turn (`theta`, as a start at 90 degrees gives)
/// is the same ellipse, and scores as the truth does; with its orientation ignored it had
/// scored an IoU of a half at every frame.
#[test]
fn an_estimate_is_scored_by_its_ellipse_turned() {
    let truth = Truth::Poses(truth_records());
    let est: Vec<PoseRecord> = truth_records()
        .into_iter()
        .map(|mut r| {
            let (a, b) = (r.state.a, r.state.b);
            (r.state.a, r.state.b) = (b, a);
            r.theta = Some(r.state.rz + rad(90.0));
            r
        })
        .collect();
    let r = evaluate(&truth, &est).unwrap();
    assert!((r.mean_iou - 1.0).abs() < 1e-9, "{}", r.mean_iou);
    assert_eq!(r.success_auc, AUC_MAX);
    // Without `theta` the orientation is `rz`: the same ellipse turned back a quarter turn.
    let flat: Vec<PoseRecord> = est
        .into_iter()
        .map(|r| PoseRecord { theta: None, ..r })
        .collect();
    let r = evaluate(&truth, &flat).unwrap();
    assert!(r.mean_iou < 0.7, "{}", r.mean_iou);
}

#[test]
fn centre_error_takes_both_axes_and_precision_counts_20_px() {
    // Frame 0 off by (12, 16): 20 px exactly, within the precision threshold (≤ 20); frame 1
    // by (12, 16.001): 20.0008 px, outside; frame 2 by 3 px in y alone; the rest exact.
    let off = |mut r: PoseRecord, dx: f64, dy: f64| {
        r.state.cx += dx;
        r.state.cy += dy;
        r
    };
    let est: Vec<PoseRecord> = truth_records()
        .into_iter()
        .map(|r| match r.frame {
            0 => off(r, 12.0, 16.0),
            1 => off(r, 12.0, 16.001),
            2 => off(r, 0.0, 3.0),
            _ => r,
        })
        .collect();
    let r = evaluate(&Truth::Poses(truth_records()), &est).unwrap();
    let second = (12.0f64 * 12.0 + 16.001 * 16.001).sqrt();
    close(
        r.mean_centre_error_px,
        (20.0 + second + 3.0) / 10.0,
        "centre error",
    );
    close(r.precision_20px, 0.9, "precision");
}

#[test]
fn frames_without_the_target_are_not_scored() {
    // An OTB box of no size marks a frame without the target: the report of a truth with one
    // is that of the truth without it, but for the count of such frames.
    let boxes = "10,10,20,30\n12,10,20,30\n0,0,0,0\n14,10,20,30\n";
    let truth = Truth::Boxes(parse_otb_boxes(boxes, Path::new("t.txt")).unwrap());
    let est: Vec<PoseRecord> = (0..4)
        .map(|k| {
            let mut r = truth_records()[0].clone();
            r.frame = k;
            (r.state.cx, r.state.cy, r.state.a, r.state.b) = (20.0 + k as f64, 23.5, 10.0, 15.0);
            r
        })
        .collect();
    let r = evaluate(&truth, &est).unwrap();
    assert_eq!(
        (r.truth_frames, r.absent, r.evaluated, r.missing),
        (4, 1, 3, 0)
    );
    let present = Truth::Boxes(
        parse_otb_boxes(
            "10,10,20,30\n12,10,20,30\n14,10,20,30\n",
            Path::new("p.txt"),
        )
        .unwrap(),
    );
    let kept: Vec<PoseRecord> = [0, 1, 3]
        .iter()
        .enumerate()
        .map(|(i, &k)| {
            let mut e = est[k].clone();
            e.frame = i;
            e
        })
        .collect();
    let p = evaluate(&present, &kept).unwrap();
    close(
        r.mean_centre_error_px,
        p.mean_centre_error_px,
        "centre error",
    );
    close(r.success_auc, p.success_auc, "auc");
    close(r.precision_20px, p.precision_20px, "precision");
    close(r.mean_iou, p.mean_iou, "mean iou");
    assert!(r.to_table().contains("absent"), "{}", r.to_table());
    // Only absent frames in common, or none present at all: said as such.
    let e = evaluate(&truth, &est[2..3]).unwrap_err().to_string();
    assert_eq!(
        e,
        "no frames in common: the truth has the target in frames 0..=3, the estimate frames 2..=2"
    );
    let none = Truth::Boxes(parse_otb_boxes("0,0,0,0\n0,0,0,0\n", Path::new("z.txt")).unwrap());
    let e = evaluate(&none, &est).unwrap_err().to_string();
    assert!(
        e.contains("every truth frame marks the target absent"),
        "{e}"
    );
}

#[test]
fn known_perturbation_gives_known_numbers() {
    let truth = Truth::Poses(truth_records());
    check_perturbed(&evaluate(&truth, &perturbed()).unwrap());
    // The same through files (6 decimals in the CSV).
    let d = scratch("perturbed");
    let (tp, ep) = (d.join("truth.csv"), d.join("est.csv"));
    write_pose_csv(&tp, &truth_records(), false).unwrap();
    write_pose_csv(&ep, &perturbed(), true).unwrap();
    let r = evaluate(&load_truth(&tp).unwrap(), &read_pose_csv(&ep).unwrap()).unwrap();
    check_perturbed(&r);
    assert_eq!(r.lost, Some(0));
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_tilt_of_the_wrong_sign_costs_twice_the_tilt() {
    // Estimating the mirror of a tilt (the Necker ambiguity) must cost 2|rx| on rx alone.
    let with_rx = |rx_deg: f64| -> Vec<PoseRecord> {
        truth_records()
            .into_iter()
            .map(|mut r| {
                r.state.rx = rad(rx_deg);
                r
            })
            .collect()
    };
    let rep = evaluate(&Truth::Poses(with_rx(12.0)), &with_rx(-12.0)).unwrap();
    close(rep.angle_mae_deg.unwrap().rx, 24.0, "mirror mae");
    close(rep.angle_rmse_deg.unwrap().rx, 24.0, "mirror rmse");
    close(rep.angle_mae_deg.unwrap().ry, 0.0, "ry");
    assert_eq!(rep.success_auc, AUC_MAX);
}

/// Writes an OTB box file (1-based `x<TAB>y<TAB>w<TAB>h`, CRLF) and returns the boxes in the
/// project's pixel convention.
fn write_otb(p: &Path, n: usize) -> Vec<BoxRect> {
    let mut text = String::new();
    let mut boxes = Vec::new();
    for k in 0..n {
        let (x, y, w, h) = (57 + k, 21 + k / 2, 31, 45 - k % 3);
        text.push_str(&format!("{x}\t{y}\t{w}\t{h}\r\n"));
        boxes.push(BoxRect::new(
            x as f64 - 1.5,
            y as f64 - 1.5,
            w as f64,
            h as f64,
        ));
    }
    std::fs::write(p, text).unwrap();
    boxes
}

fn from_boxes(boxes: &[BoxRect]) -> Vec<PoseRecord> {
    boxes
        .iter()
        .enumerate()
        .map(|(frame, b)| {
            let e = Ellipse::from_box(b);
            PoseRecord {
                frame,
                state: PoseState::from_parts(&e, Euler::default()),
                score: Some(1.0),
                lost: Some(false),
                theta: None,
            }
        })
        .collect()
}

/// A track started at frame 5 (OTB's temporal robustness evaluation): scored from there, the
/// frames before it are neither missing nor failures, and its scores are those of the same
/// rows against the truth cut to begin there; rows before the start are ignored.
#[test]
fn a_track_started_later_is_scored_from_its_start() {
    let d = scratch("segment");
    let p = d.join("groundtruth_rect.txt");
    let boxes = write_otb(&p, 12);
    let truth = load_truth(&p).unwrap();
    let mut est = from_boxes(&boxes);
    // Every estimate off by 4 px to the right, so the overlaps are not all perfect.
    for r in &mut est {
        r.state.cx += 4.0;
    }
    let late = &est[5..];
    let whole = evaluate(&truth, late).unwrap();
    assert_eq!(
        (whole.scored_from, whole.truth_frames, whole.missing),
        (0, 12, 5)
    );
    let seg = evaluate_from(&truth, late, 5).unwrap();
    assert_eq!(
        (
            seg.scored_from,
            seg.truth_frames,
            seg.evaluated,
            seg.missing,
            seg.ignored
        ),
        (5, 7, 7, 0, 0)
    );
    // The same rows, renumbered from 0, against the truth's boxes from frame 5 on.
    let cut = Truth::Boxes(boxes[5..].to_vec());
    let renumbered: Vec<PoseRecord> = late
        .iter()
        .map(|r| PoseRecord {
            frame: r.frame - 5,
            ..r.clone()
        })
        .collect();
    let alone = evaluate(&cut, &renumbered).unwrap();
    assert_eq!(seg.success_rates, alone.success_rates);
    assert_eq!(seg.precision_20px, alone.precision_20px);
    close(seg.mean_iou, alone.mean_iou, "mean IoU");
    // Missing frames fail: the whole sequence's AUC is 7/12 of the segment's.
    close(whole.success_auc, seg.success_auc * 7.0 / 12.0, "AUC");
    assert!(
        seg.to_table().contains("7 (boxes, frames 5 on)"),
        "{}",
        seg.to_table()
    );
    // The whole track scored from 5: its first five rows are ignored.
    let r = evaluate_from(&truth, &est, 5).unwrap();
    assert_eq!((r.evaluated, r.ignored), (7, 5));
    assert_eq!(r.success_rates, seg.success_rates);
    // The target absent from frame 5 on: nothing to score from there.
    let mut gone = boxes.clone();
    for b in &mut gone[5..] {
        *b = BoxRect::new(0.0, 0.0, 0.0, 0.0);
    }
    let err = evaluate_from(&Truth::Boxes(gone), late, 5).unwrap_err();
    assert!(matches!(err, EvalError::AllAbsent { from: 5 }), "{err}");
    assert!(
        err.to_string()
            .contains("every truth frame from frame 5 on"),
        "{err}"
    );
    // Nothing from frame 12 on.
    let err = evaluate_from(&truth, late, 12).unwrap_err();
    assert!(
        matches!(err, EvalError::NoTruthFrom { from: 12, last: 11 }),
        "{err}"
    );
    assert!(
        err.to_string().contains("no frames from frame 12 on"),
        "{err}"
    );
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn otb_box_truth_against_the_same_boxes() {
    let d = scratch("otb");
    let p = d.join("groundtruth_rect.txt");
    let boxes = write_otb(&p, 12);
    let truth = load_truth(&p).unwrap();
    assert_eq!(truth, Truth::Boxes(boxes.clone()));
    let r = evaluate(&truth, &from_boxes(&boxes)).unwrap();
    assert_eq!((r.truth_frames, r.evaluated, r.missing), (12, 12, 0));
    assert!(r.angle_rmse_deg.is_none() && r.angle_mae_deg.is_none() && r.angle_gain.is_none());
    assert!(r.mean_centre_error_px < 1e-12);
    assert_eq!(r.precision_20px, 1.0);
    assert_eq!(r.success_auc, AUC_MAX);
    assert_eq!((r.lost, r.mean_score), (Some(0), Some(1.0)));
    // Frames count from 0 in file order: shifting the estimate by one frame misaligns it.
    let mut shifted = from_boxes(&boxes);
    for r in &mut shifted {
        r.frame += 1;
    }
    let r = evaluate(&truth, &shifted).unwrap();
    assert_eq!((r.evaluated, r.missing, r.ignored), (11, 1, 1));
    assert!(r.mean_centre_error_px > 0.5);
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn real_girl_truth_against_itself() {
    let Some(p) = shared_data::path("girl/groundtruth_rect.txt") else {
        return;
    };
    // Read as `io::read_otb_boxes` reads it (CRLF, tabs): 500 boxes, each with a size.
    let read = pftrack::io::read_otb_boxes(&p).unwrap();
    assert_eq!(read.len(), 500);
    assert!(read.iter().all(|r| r.w > 0.0 && r.h > 0.0));
    let truth = load_truth(&p).unwrap();
    let Truth::Boxes(boxes) = &truth else {
        panic!("girl truth read as poses")
    };
    assert_eq!(boxes, &read);
    let r = evaluate(&truth, &from_boxes(boxes)).unwrap();
    assert_eq!(r.evaluated, 500);
    assert!(r.mean_centre_error_px < 1e-12);
    assert_eq!(r.success_auc, AUC_MAX);
}

// ---------------------------------------------------------------- CLI

fn pftrack(args: &[&Path]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_pftrack"))
        .arg("eval")
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn cli_table_and_json() {
    let d = scratch("cli");
    let (tp, ep) = (d.join("truth.csv"), d.join("est.csv"));
    write_pose_csv(&tp, &truth_records(), false).unwrap();
    write_pose_csv(&ep, &perturbed(), true).unwrap();

    let (code, out, err) = pftrack(&[&tp, &ep]);
    assert_eq!(code, 0, "{err}");
    for want in [
        "truth frames",
        "MISSING           1  <-- failures in precision and success",
        "(mean, over the 9 frames evaluated)",
        "(over the 9 frames evaluated)",
        "precision@20px    0.9000",
        "success AUC       0.7857",
        "rx           3.000       3.000",
        "ry           0.000       0.000",
        "turn         3.000       3.000       -",
    ] {
        assert!(out.contains(want), "missing '{want}' in:\n{out}");
    }

    let json = Path::new("--json");
    let (code, out, err) = pftrack(&[&tp, &ep, json]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.trim().lines().count(), 1, "one JSON object: {out}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["truth_kind"], "poses");
    assert_eq!(v["missing"], 1);
    assert_eq!(v["evaluated"], 9);
    assert_eq!(v["ignored"], 1);
    assert_eq!(v["success_rates"].as_array().unwrap().len(), 21);
    close(v["success_auc"].as_f64().unwrap(), 16.5 / 21.0, "json auc");
    close(
        v["angle_rmse_deg"]["rx"].as_f64().unwrap(),
        3.0,
        "json rmse",
    );
    close(
        v["rotation_error_deg"]["max"].as_f64().unwrap(),
        3.0,
        "json turn",
    );

    // OTB truth: no angle table, `null` angles in JSON.
    let otb = d.join("boxes.txt");
    let boxes = write_otb(&otb, 5);
    let bp = d.join("boxes-est.csv");
    write_pose_csv(&bp, &from_boxes(&boxes), false).unwrap();
    let (code, out, _) = pftrack(&[&otb, &bp, json]);
    assert_eq!(code, 0);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["truth_kind"], "boxes");
    assert!(v["angle_rmse_deg"].is_null() && v["rotation_error_deg"].is_null());
    let (code, out, _) = pftrack(&[&otb, &bp]);
    assert_eq!(code, 0);
    assert!(!out.contains("RMSE"), "{out}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn cli_bad_input_is_one_line_and_non_zero() {
    let d = scratch("clibad");
    let tp = d.join("truth.csv");
    write_pose_csv(&tp, &truth_records(), false).unwrap();
    let malformed = d.join("malformed.csv");
    std::fs::write(&malformed, "frame,cx,cy,a,b,rx,ry,rz\n0,1,2,3,4,5,6\n").unwrap();
    let bad_boxes = d.join("bad-boxes.txt");
    std::fs::write(&bad_boxes, "1,2,3\n").unwrap();
    let far = d.join("far.csv");
    let far_recs: Vec<PoseRecord> = truth_records()
        .into_iter()
        .map(|mut r| {
            r.frame += 100;
            r
        })
        .collect();
    write_pose_csv(&far, &far_recs, false).unwrap();
    let empty = d.join("empty.csv");
    std::fs::write(&empty, "").unwrap();
    let absent = d.join("absent.csv");

    let cases: [(&[&Path], &str); 7] = [
        (&[&absent, &tp], "absent.csv"),
        (&[&tp, &absent], "absent.csv"),
        (&[&tp, &malformed], "malformed.csv:2"),
        (&[&malformed, &tp], "malformed.csv:2"),
        (&[&bad_boxes, &tp], "bad-boxes.txt:1"),
        (&[&tp, &far], "no frames in common"),
        (&[&tp, &empty], "empty.csv"),
    ];
    for (args, want) in cases {
        let (code, out, err) = pftrack(args);
        assert_ne!(code, 0, "{args:?}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.starts_with("pftrack: error:"), "{err}");
        assert!(err.contains(want), "{args:?}: want '{want}' in {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(out.is_empty(), "{out}");
    }
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn the_lost_flag_is_counted_where_the_target_is_absent() {
    // Frames 2-4 without the target; the estimate has no row for frame 4, flags frame 1
    // (the target there) and frame 3 (not there) lost.
    let boxes = "10,10,20,30\n12,10,20,30\n0,0,0,0\n0,0,0,0\n0,0,0,0\n14,10,20,30\n";
    let truth = Truth::Boxes(parse_otb_boxes(boxes, Path::new("t.txt")).unwrap());
    let est: Vec<PoseRecord> = [0usize, 1, 2, 3, 5]
        .iter()
        .map(|&k| {
            let mut r = truth_records()[0].clone();
            r.frame = k;
            (r.state.cx, r.state.cy, r.state.a, r.state.b) = (20.0 + k as f64, 23.5, 10.0, 15.0);
            r.lost = Some(k == 1 || k == 3);
            r
        })
        .collect();
    let r = evaluate(&truth, &est).unwrap();
    assert_eq!(
        (r.absent, r.absent_estimated, r.absent_lost, r.lost),
        (3, 2, Some(1), Some(1))
    );
    let table = r.to_table();
    assert!(
        table.contains("3 truth frames without the target (not scored); flagged lost on 1 of the 2 with an estimate"),
        "{table}"
    );
    // The flag's frames where the target is absent change no score.
    let unflagged: Vec<PoseRecord> = est
        .iter()
        .map(|r| PoseRecord {
            lost: Some(false),
            ..r.clone()
        })
        .collect();
    let u = evaluate(&truth, &unflagged).unwrap();
    assert_eq!((u.absent_lost, u.lost), (Some(0), Some(0)));
    close(u.success_auc, r.success_auc, "auc");
    close(
        u.mean_centre_error_px,
        r.mean_centre_error_px,
        "centre error",
    );
    // Without a lost column there is nothing to count.
    let plain: Vec<PoseRecord> = est
        .iter()
        .map(|r| PoseRecord {
            lost: None,
            ..r.clone()
        })
        .collect();
    let p = evaluate(&truth, &plain).unwrap();
    assert_eq!((p.absent_estimated, p.absent_lost, p.lost), (2, None, None));
    assert!(!p.to_table().contains("flagged lost"), "{}", p.to_table());
    // Scored from frame 3 (a segment): the absent frame before it does not count.
    let seg = evaluate_from(&truth, &est, 3).unwrap();
    assert_eq!(
        (seg.absent, seg.absent_estimated, seg.absent_lost, seg.lost),
        (2, 1, Some(1), Some(0))
    );
    // The JSON report names both counts.
    let json = serde_json::to_string(&r).unwrap();
    assert!(
        json.contains("\"absent_estimated\":2") && json.contains("\"absent_lost\":1"),
        "{json}"
    );
    // No estimate where the target is absent: said so, not "0 of the 0".
    let kept: Vec<PoseRecord> = est
        .iter()
        .filter(|r| r.frame < 2 || r.frame > 4)
        .cloned()
        .collect();
    let k = evaluate(&truth, &kept).unwrap();
    assert_eq!((k.absent_estimated, k.absent_lost), (0, Some(0)));
    assert!(
        k.to_table().contains("; none with an estimate"),
        "{}",
        k.to_table()
    );
}

//! Edge statistics along the normal lines of ground-truth ellipses, per edge threshold.
//!
//! `cargo run --release --example edge_stats -- SEQ_DIR [STEP]` with `SEQ_DIR` holding `img/`
//! and an OTB `groundtruth_rect.txt`. Every `STEP`-th frame (default 5), along the 24 normal
//! lines (half length 8) of the truth box's inscribed ellipse, for a range of edge thresholds:
//!
//! - `detect`: share of lines with an edge within 4 px of the contour (1 − p0);
//! - `rms_d`: RMS distance of that nearest edge (σz);
//! - `clutter`: edges per line sample besides the contour's (γ);
//! - `win`: share of (frame, wrong ellipse) pairs in which the gradient term, with the
//!   p0, γ and σz just measured, scores the truth above the wrong ellipse (the truth moved by
//!   a quarter or a half of its semi-axes along x or y, or scaled by 0.6, 0.8, 1.25, 1.5);
//! - `margin`: the mean of ln p(truth) − ln p(wrong) over those pairs (nats).

use std::path::{Path, PathBuf};

use pftrack::geometry::Ellipse;
use pftrack::io::pose_csv::read_pose_csv;
use pftrack::io::read_otb_boxes;
use pftrack::likelihood::LikelihoodParams;
use pftrack::likelihood::cpu::EllipseF32;
use pftrack::likelihood::cpu::gradient::{
    GradientImage, LineTables, contour_point, half_samples, line_angles, line_edges,
    log_likelihood_ellipse,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = PathBuf::from(args.next().ok_or("usage: edge_stats SEQ_DIR [STEP]")?);
    let step: usize = args.next().map_or(Ok(5), |s| s.parse())?;
    let mut frames = Vec::new();
    if dir.join("truth.csv").exists() {
        // A sequence written by `pftrack synth`: the truth ellipse turns with rz.
        let truth = read_pose_csv(&dir.join("truth.csv"))?;
        for r in truth.iter().step_by(step) {
            let path = dir.join("frames").join(format!("{:05}.png", r.frame));
            let img = image::open(&path)?.to_rgb8();
            let e = EllipseF32::from_ellipse(&r.state.ellipse(0.0));
            frames.push((GradientImage::new(&img), e));
        }
    } else {
        let boxes = read_otb_boxes(&dir.join("groundtruth_rect.txt"))?;
        for (i, b) in boxes.iter().enumerate().step_by(step) {
            let path: PathBuf = dir.join("img").join(format!("{:04}.jpg", i + 1));
            if !Path::new(&path).exists() {
                break;
            }
            let img = image::open(&path)?.to_rgb8();
            let e = EllipseF32::from_ellipse(&Ellipse::from_box(b));
            frames.push((GradientImage::new(&img), e));
        }
    }
    let base = LikelihoodParams::default();
    let h = half_samples(&base);
    let angles = line_angles(base.num_lines);
    println!("frames {} (every {step})", frames.len());
    println!("thr    detect  rms_d  clutter   win   margin");
    for thr in [0.03f32, 0.05, 0.08, 0.1, 0.12, 0.15, 0.2, 0.25] {
        let (mut lines, mut near, mut d2, mut clutter) = (0usize, 0usize, 0.0f64, 0usize);
        for (g, e) in &frames {
            for &(cp, sp) in &angles {
                let (s, c) = e.theta.sin_cos();
                let (x, y, nx, ny) = contour_point(e, s, c, cp, sp);
                let ts: Vec<i32> = line_edges(g, x, y, nx, ny, h, thr).collect();
                let d = ts.iter().map(|t| t.unsigned_abs()).min();
                lines += 1;
                let hit = d.is_some_and(|d| d <= 4);
                if let Some(d) = d.filter(|_| hit) {
                    near += 1;
                    d2 += f64::from(d * d);
                }
                clutter += ts.len() - usize::from(hit);
            }
        }
        let detect = near as f64 / lines as f64;
        let p = LikelihoodParams {
            edge_threshold: thr,
            p_no_contour: (1.0 - detect).max(0.01) as f32,
            clutter_density: ((clutter as f64 / (lines as f64 * f64::from(2 * h + 1))).max(1e-3))
                as f32,
            sigma_z: ((d2 / near.max(1) as f64).sqrt().max(0.5)) as f32,
            ..base
        };
        let tables = LineTables::new(&p);
        let (mut wins, mut pairs, mut margin) = (0usize, 0usize, 0.0f64);
        for (g, e) in &frames {
            let truth = log_likelihood_ellipse(g, e, &tables, &p);
            let mut wrong = Vec::new();
            for f in [-0.5f32, -0.25, 0.25, 0.5] {
                wrong.push(EllipseF32 {
                    cx: e.cx + f * e.a,
                    ..*e
                });
                wrong.push(EllipseF32 {
                    cy: e.cy + f * e.b,
                    ..*e
                });
            }
            for s in [0.6f32, 0.8, 1.25, 1.5] {
                wrong.push(EllipseF32 {
                    a: e.a * s,
                    b: e.b * s,
                    ..*e
                });
            }
            for w in &wrong {
                let l = log_likelihood_ellipse(g, w, &tables, &p);
                pairs += 1;
                wins += usize::from(truth > l);
                margin += f64::from(truth - l);
            }
        }
        println!(
            "{thr:<5}  {detect:.3}   {:.2}   {:.4}   {:.3}  {:+.2}",
            p.sigma_z,
            p.clutter_density,
            wins as f64 / pairs as f64,
            margin / pairs as f64
        );
    }
    Ok(())
}

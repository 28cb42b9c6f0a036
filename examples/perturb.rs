//! Perturbed copies of an OTB sequence (`img/` and `groundtruth_rect.txt`), for the stress
//! tests of `docs/measurements.md`: the same footage with the target taken out, frames
//! dropped, or the light changed, written as a new OTB folder that `track` and
//! `scripts/eval_seeds.sh real --data` read like the originals.
//!
//! `cargo run --release --example perturb -- SRC DST vanish FROM`
//! : from frame `FROM` on (1-based, as OTB counts), the truth box enlarged 1.3 times about its
//!   centre is filled with the pixels 1.5 box widths to its side (to the right where they lie
//!   in the frame, else to the left), so the target is gone and what was beside it is where it
//!   was; those frames' truth is a box of no size (`0,0,0,0`: absent, not scored).
//!
//! `cargo run --release --example perturb -- SRC DST every K`
//! : only every `K`-th frame (the first, then `1 + K`, ...), so everything moves `K` times as
//!   far between frames.
//!
//! `cargo run --release --example perturb -- SRC DST light FROM GAIN [RAMP]`
//! : from frame `FROM` on, every pixel times `GAIN` (clamped), reached over `RAMP` frames
//!   (default 1: at once).
//!
//! The frames are written as PNG (`img/0001.png`, ...), so nothing is lost to a second JPEG
//! compression; the truth keeps OTB's 1-based boxes and comma form.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use pftrack::geometry::BoxRect;
use pftrack::image::{self, RgbImage};
use pftrack::io::boxes::pixel_to_otb;
use pftrack::io::read_otb_boxes;

/// One perturbation, from the command line.
enum Perturbation {
    /// The target's box filled from its side from this 0-based frame on.
    Vanish { from: usize },
    /// Every `k`-th frame kept.
    Every { k: usize },
    /// Every pixel times a gain from this 0-based frame on, reached over `ramp` frames.
    Light { from: usize, gain: f32, ramp: usize },
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("perturb: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: perturb SRC DST vanish FROM | every K | light FROM GAIN [RAMP]";
    if args.len() < 4 {
        return Err(usage.into());
    }
    let (src, dst) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]));
    let number = |i: usize, what: &str| -> Result<usize, String> {
        let s = args
            .get(i)
            .ok_or_else(|| format!("{what} missing; {usage}"))?;
        s.parse()
            .map_err(|_| format!("{what} must be a whole number, not '{s}'"))
    };
    let p = match args[2].as_str() {
        "vanish" => Perturbation::Vanish {
            from: number(3, "FROM")?.max(1) - 1,
        },
        "every" => Perturbation::Every {
            k: number(3, "K")?.max(1),
        },
        "light" => {
            let g = args.get(4).ok_or(usage)?;
            let gain: f32 = g
                .parse()
                .ok()
                .filter(|g: &f32| g.is_finite() && *g >= 0.0)
                .ok_or_else(|| format!("GAIN must be a number of 0 or more, not '{g}'"))?;
            let ramp = if args.len() > 5 {
                number(5, "RAMP")?
            } else {
                1
            };
            Perturbation::Light {
                from: number(3, "FROM")?.max(1) - 1,
                gain,
                ramp: ramp.max(1),
            }
        }
        other => return Err(format!("unknown perturbation '{other}'; {usage}")),
    };
    let truth_path = src.join("groundtruth_rect.txt");
    let truth = read_otb_boxes(&truth_path).map_err(|e| e.to_string())?;
    let frames = images(&src.join("img"))?;
    if frames.len() != truth.len() {
        return Err(format!(
            "{} frames in {} but {} boxes in {}",
            frames.len(),
            src.join("img").display(),
            truth.len(),
            truth_path.display()
        ));
    }
    if dst.exists() {
        return Err(format!("{} exists; give a new folder", dst.display()));
    }
    let img_dir = dst.join("img");
    std::fs::create_dir_all(&img_dir).map_err(|e| format!("{}: {e}", img_dir.display()))?;
    let mut rows = String::new();
    let mut written = 0;
    for (i, (path, b)) in frames.iter().zip(&truth).enumerate() {
        if let Perturbation::Every { k } = p
            && i % k != 0
        {
            continue;
        }
        let mut img = image::open(path)
            .map_err(|e| format!("{}: {e}", path.display()))?
            .to_rgb8();
        let mut b = *b;
        match p {
            Perturbation::Vanish { from } if i >= from && b.w > 0.0 && b.h > 0.0 => {
                fill_from_side(&mut img, &b);
                b = BoxRect::new(0.0, 0.0, 0.0, 0.0);
            }
            Perturbation::Light { from, gain, ramp } if i >= from => {
                let t = ((i - from + 1) as f32 / ramp as f32).min(1.0);
                scale_light(&mut img, 1.0 + t * (gain - 1.0));
            }
            _ => {}
        }
        written += 1;
        let out = img_dir.join(format!("{written:04}.png"));
        img.save(&out)
            .map_err(|e| format!("{}: {e}", out.display()))?;
        let v = if b.w > 0.0 && b.h > 0.0 {
            pixel_to_otb(&b)
        } else {
            [0.0; 4]
        };
        rows.push_str(&format!("{},{},{},{}\n", v[0], v[1], v[2], v[3]));
    }
    let truth_out = dst.join("groundtruth_rect.txt");
    std::fs::write(&truth_out, rows).map_err(|e| format!("{}: {e}", truth_out.display()))?;
    println!("{written} frames written to {}", dst.display());
    Ok(())
}

/// The frames of an OTB `img/` folder, in order of their names.
fn images(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|x| x.to_str())
                .is_some_and(|x| matches!(x.to_ascii_lowercase().as_str(), "jpg" | "png"))
        })
        .collect();
    v.sort();
    if v.is_empty() {
        return Err(format!("no jpg or png frames in {}", dir.display()));
    }
    Ok(v)
}

/// Fills the box `b` (pixel convention), enlarged 1.3 times about its centre, with the pixels
/// 1.5 box widths to its right, or to its left where the right runs out of the frame.
fn fill_from_side(img: &mut RgbImage, b: &BoxRect) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let (cx, cy) = (b.x + 0.5 * b.w, b.y + 0.5 * b.h);
    let (hw, hh) = (0.65 * b.w, 0.65 * b.h);
    let x0 = (cx - hw).round().max(0.0) as i64;
    let x1 = ((cx + hw).round() as i64).min(w - 1);
    let y0 = (cy - hh).round().max(0.0) as i64;
    let y1 = ((cy + hh).round() as i64).min(h - 1);
    let shift = (1.5 * b.w).round() as i64;
    let dx = if x1 + shift < w { shift } else { -shift };
    let src = img.clone();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let sx = (x + dx).clamp(0, w - 1);
            img.put_pixel(x as u32, y as u32, *src.get_pixel(sx as u32, y as u32));
        }
    }
}

/// Every channel of every pixel times `gain`, rounded and clamped to 0-255.
fn scale_light(img: &mut RgbImage, gain: f32) {
    for v in img.iter_mut() {
        *v = (*v as f32 * gain).round().clamp(0.0, 255.0) as u8;
    }
}

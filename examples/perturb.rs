//! Perturbed copies of an OTB sequence (`img/` and `groundtruth_rect.txt`), for the stress
//! tests of `docs/measurements.md`: the same footage with the target taken out, frames
//! dropped, or the light changed, written as a new OTB folder that `track` and
//! `scripts/eval_seeds.sh real --data` read like the originals.
//!
//! `cargo run --release --example perturb -- SRC DST vanish FROM`
//! : from frame `FROM` on (1-based, as OTB counts; 2 or later, since a track starts on the
//!   first), the truth box enlarged 1.3 times about its centre is filled with the pixels 1.5
//!   box widths to its side (to the right where they lie in the frame, else to the left), so
//!   the target is gone and what was beside it is where it was; those frames' truth is a box
//!   of no size (`0,0,0,0`: absent, not scored). A box too wide for the frame to hold that
//!   fill beside it is refused.
//!
//! `cargo run --release --example perturb -- SRC DST every K`
//! : only every `K`-th frame (`K` 2 or more: the first, then `1 + K`, ...), so everything
//!   moves `K` times as far between frames.
//!
//! `cargo run --release --example perturb -- SRC DST light FROM GAIN [RAMP]`
//! : from frame `FROM` on, every pixel times `GAIN` (clamped), reached over `RAMP` frames
//!   (default 1: at once).
//!
//! The frames are read as `track` reads the folder (natural order, hidden files left out) and
//! written as PNG (`img/0001.png`, ...), so nothing is lost to a second JPEG compression; the
//! truth keeps OTB's 1-based boxes and comma form. `DST` must not exist; a copy that fails
//! part way is removed.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use pftrack::frames::dir::list_images;
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
    if args.len() < 3 {
        return Err(usage.into());
    }
    let (src, dst) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]));
    // A count of at least `min`, from argument `i`.
    let number = |i: usize, what: &str, min: usize| -> Result<usize, String> {
        let s = args
            .get(i)
            .ok_or_else(|| format!("{what} missing; {usage}"))?;
        s.parse()
            .ok()
            .filter(|&v| v >= min)
            .ok_or_else(|| format!("{what} must be a whole number of at least {min}, not '{s}'"))
    };
    let (p, wanted) = match args[2].as_str() {
        // From the second frame at the earliest: a track starts on the first.
        "vanish" => (
            Perturbation::Vanish {
                from: number(3, "FROM", 2)? - 1,
            },
            4..=4,
        ),
        "every" => (
            Perturbation::Every {
                k: number(3, "K", 2)?,
            },
            4..=4,
        ),
        "light" => {
            let from = number(3, "FROM", 1)? - 1;
            let g = args
                .get(4)
                .ok_or_else(|| format!("GAIN missing; {usage}"))?;
            let gain: f32 = g
                .parse()
                .ok()
                .filter(|g: &f32| g.is_finite() && *g >= 0.0)
                .ok_or_else(|| format!("GAIN must be a number of 0 or more, not '{g}'"))?;
            let ramp = if args.len() > 5 {
                number(5, "RAMP", 1)?
            } else {
                1
            };
            (Perturbation::Light { from, gain, ramp }, 5..=6)
        }
        other => return Err(format!("unknown perturbation '{other}'; {usage}")),
    };
    if !wanted.contains(&args.len()) {
        return Err(format!(
            "'{}' takes {} argument(s) after its name, not {}; {usage}",
            args[2],
            if wanted.start() == wanted.end() {
                format!("{}", wanted.start() - 3)
            } else {
                format!("{} or {}", wanted.start() - 3, wanted.end() - 3)
            },
            args.len() - 3
        ));
    }
    let truth_path = src.join("groundtruth_rect.txt");
    let truth = read_otb_boxes(&truth_path).map_err(|e| e.to_string())?;
    // The frames as `track` reads the folder: natural order, hidden files left out.
    let img_src = src.join("img");
    let frames = list_images(&img_src).map_err(|e| e.to_string())?;
    if frames.len() != truth.len() {
        return Err(format!(
            "{} frames in {} but {} boxes in {}",
            frames.len(),
            img_src.display(),
            truth.len(),
            truth_path.display()
        ));
    }
    let from = match p {
        Perturbation::Vanish { from } | Perturbation::Light { from, .. } => from,
        Perturbation::Every { .. } => 0,
    };
    if from >= frames.len() {
        return Err(format!(
            "FROM {} is past the last of the {} frames: the copy would be unchanged",
            from + 1,
            frames.len()
        ));
    }
    if dst.exists() {
        return Err(format!("{} exists; give a new folder", dst.display()));
    }
    // A copy that fails part way is removed: what is left is whole or nothing.
    write_copy(&p, &frames, &truth, &dst).inspect_err(|_| {
        let _ = std::fs::remove_dir_all(&dst);
    })
}

/// Writes the perturbed frames and their truth into `dst`.
fn write_copy(
    p: &Perturbation,
    frames: &[PathBuf],
    truth: &[BoxRect],
    dst: &Path,
) -> Result<(), String> {
    let img_dir = dst.join("img");
    std::fs::create_dir_all(&img_dir).map_err(|e| format!("{}: {e}", img_dir.display()))?;
    let mut rows = String::new();
    let mut written = 0;
    for (i, (path, b)) in frames.iter().zip(truth).enumerate() {
        if let Perturbation::Every { k } = *p
            && i % k != 0
        {
            continue;
        }
        let mut img = image::open(path)
            .map_err(|e| format!("{}: {e}", path.display()))?
            .to_rgb8();
        let mut b = *b;
        match *p {
            Perturbation::Vanish { from } if i >= from && b.w > 0.0 && b.h > 0.0 => {
                fill_from_side(&mut img, &b).map_err(|e| format!("frame {}: {e}", i + 1))?;
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
        // Six decimals at most: the conversion's rounding (57.300000000000004) left out.
        let v = v.map(|x| {
            let s = format!("{x:.6}");
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        });
        rows.push_str(&format!("{},{},{},{}\n", v[0], v[1], v[2], v[3]));
    }
    let truth_out = dst.join("groundtruth_rect.txt");
    std::fs::write(&truth_out, rows).map_err(|e| format!("{}: {e}", truth_out.display()))?;
    println!("{written} frames written to {}", dst.display());
    Ok(())
}

/// Fills the box `b` (pixel convention: the pixels whose centres lie within its edges),
/// enlarged 1.3 times about its centre, with the pixels 1.5 box widths to its right, or to
/// its left where the right runs out of the frame. A box too wide for either side to hold
/// it (more than about 40 % of the frame's width) is refused: the fill would copy the target
/// back in.
fn fill_from_side(img: &mut RgbImage, b: &BoxRect) -> Result<(), String> {
    let (w, h) = (i64::from(img.width()), i64::from(img.height()));
    let (cx, cy) = (b.x + 0.5 * b.w, b.y + 0.5 * b.h);
    let (hw, hh) = (0.65 * b.w, 0.65 * b.h);
    // Whole pixels, a box of absurd size held to the frame first.
    let px = |v: f64, hi: i64| v.clamp(-1.0, hi as f64) as i64;
    let x0 = px((cx - hw).ceil(), w).max(0);
    let x1 = px((cx + hw).floor(), w).min(w - 1);
    let y0 = px((cy - hh).ceil(), h).max(0);
    let y1 = px((cy + hh).floor(), h).min(h - 1);
    let shift = px((1.5 * b.w).round(), w);
    let dx = if x1 + shift < w {
        shift
    } else if x0 - shift >= 0 {
        -shift
    } else {
        return Err(format!(
            "the box, {:.0} px wide, leaves no room beside it in a frame {w} px wide",
            b.w
        ));
    };
    let src = img.clone();
    for y in y0..=y1 {
        for x in x0..=x1 {
            // Within the frame by the choice of side above.
            let sx = (x + dx).clamp(0, w - 1);
            img.put_pixel(x as u32, y as u32, *src.get_pixel(sx as u32, y as u32));
        }
    }
    Ok(())
}

/// Every channel of every pixel times `gain`, rounded and clamped to 0-255.
fn scale_light(img: &mut RgbImage, gain: f32) {
    for v in img.iter_mut() {
        *v = (*v as f32 * gain).round().clamp(0.0, 255.0) as u8;
    }
}

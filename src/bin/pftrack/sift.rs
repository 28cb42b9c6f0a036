//! `pftrack sift`: exports SIFT keypoints and descriptors of an image.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use pftrack::features::{Sift, SiftParams, UpsampleGrid};
use pftrack::frames::GrayF32;
use pftrack::geometry::BoxRect;

/// Arguments of `pftrack sift`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct SiftArgs {
    /// The image (PNG, JPEG, BMP, PNM, TIFF, WebP).
    pub image: PathBuf,
    /// Detect only in this box `x,y,w,h` (pixels, origin at the top-left pixel's centre).
    #[arg(long, value_parser = parse_region, allow_hyphen_values = true)]
    pub region: Option<BoxRect>,
    /// Write keypoints and descriptors as CSV: `x,y,scale,angle_deg,response,octave,d0..d127`
    /// (`scale` is σ in pixels; OpenCV's `size` is 2σ; `d0..d127` Lowe's normalised
    /// descriptor, clipped at 0.2 and normalised again, as integers 0-255: the unit vector
    /// times 512, as OpenCV stores it), `-` for standard output. Without it, print a summary.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Do not double the image for the first octave.
    #[arg(long)]
    pub no_upsample: bool,
    /// Double the image as OpenCV's default SIFT does (a bilinear resize whose keypoints come
    /// out a quarter pixel off), to reproduce OpenCV's keypoints; exact by default.
    #[arg(long, conflicts_with = "no_upsample")]
    pub opencv_upscale: bool,
    /// Run detection this many times and report the median and fastest time of the runs (for
    /// timing; each run times the detection alone, not decoding or output).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub repeat: u32,
}

/// Parses `x,y,w,h`.
fn parse_region(s: &str) -> Result<BoxRect, String> {
    let v = crate::values::numbers(s, &[4])?;
    match v[..] {
        [x, y, w, h] if w > 0.0 && h > 0.0 => Ok(BoxRect::new(x, y, w, h)),
        _ => Err(format!("the width and height of '{s}' must be positive")),
    }
}

/// Runs the command.
pub fn run(args: SiftArgs) -> anyhow::Result<()> {
    let img = pftrack::frames::dir::decode_rgb(&args.image)?;
    if let Some(r) = &args.region
        && (r.x >= img.width() as f64
            || r.y >= img.height() as f64
            || r.x + r.w <= 0.0
            || r.y + r.h <= 0.0)
    {
        bail!(
            "--region {},{},{},{} lies outside the {}x{} image",
            r.x,
            r.y,
            r.w,
            r.h,
            img.width(),
            img.height()
        );
    }
    let gray = GrayF32::from_rgb(&img);
    let sift = Sift::new(SiftParams {
        upsample: !args.no_upsample,
        upsample_grid: if args.opencv_upscale {
            UpsampleGrid::OpenCv
        } else {
            UpsampleGrid::Exact
        },
        ..SiftParams::default()
    });
    // The library's advice on a window too large, in this command's flags.
    let mut feats = sift.detect(&gray, args.region).map_err(|e| {
        let msg = e.to_string();
        anyhow::anyhow!(
            "{}",
            msg.replace(
                "detect without the upsampled first octave or within a region",
                "use --no-upsample or --region"
            )
            .replace("detect within a region", "use --region")
        )
    })?;
    // Grown as the runs go: `--repeat 4000000000` reserved 32 GB up front and aborted.
    let mut times = Vec::new();
    for _ in 0..args.repeat {
        let t0 = Instant::now();
        feats = sift.detect(&gray, args.region)?;
        times.push(t0.elapsed());
    }
    // `repeat >= 1` (clap's range), so both exist; in milliseconds.
    let fastest = times
        .iter()
        .min()
        .copied()
        .unwrap_or_default()
        .as_secs_f64()
        * 1e3;
    let median = crate::bench::median(times).as_secs_f64() * 1e3;
    match &args.out {
        None => {
            outln!(
                "{}: {}x{}, {} keypoints in {median:.3} ms (median of {}, fastest {fastest:.3} ms)",
                args.image.display(),
                gray.width,
                gray.height,
                feats.len(),
                args.repeat,
            )?;
        }
        Some(path) => {
            let to_stdout = path.as_os_str() == pftrack::frames::STDIN;
            if !to_stdout {
                crate::paths::not_an_input("--out", path, &[&args.image])?;
            }
            let mut text = String::from("x,y,scale,angle_deg,response,octave");
            for i in 0..pftrack::features::DESCRIPTOR_LEN {
                text.push_str(&format!(",d{i}"));
            }
            text.push('\n');
            for (k, d) in feats.keypoints.iter().zip(&feats.descriptors) {
                text.push_str(&format!(
                    "{},{},{},{},{},{}",
                    k.x,
                    k.y,
                    k.scale,
                    k.angle.to_degrees(),
                    k.response,
                    k.octave
                ));
                for v in d {
                    text.push_str(&format!(",{v}"));
                }
                text.push('\n');
            }
            if to_stdout {
                out!("{text}")?;
            } else {
                let mut w = pftrack::io::AtomicFile::create(path)?;
                w.write_all(text.as_bytes())
                    .with_context(|| format!("writing {}", path.display()))?;
                w.commit()?;
            }
            errln!(
                "{} keypoints in {median:.3} ms (median of {}, fastest {fastest:.3} ms) → {}",
                feats.len(),
                args.repeat,
                if to_stdout {
                    "standard output".to_string()
                } else {
                    path.display().to_string()
                }
            );
        }
    }
    Ok(())
}

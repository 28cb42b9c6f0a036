//! `pftrack pose-noise`: reproduces the paper's Fig. 3 (rotation error against noise).
//!
//! The experiment itself lives in `pftrack::pose::noise` (its docs define the SNR, the noise
//! model and the error measure); this file parses arguments, prints the tables and writes the
//! CSV files and the plot.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, ValueEnum};
use pftrack::io::AtomicFile;
use pftrack::pose::noise::{
    LambdaRow, MAX_POINTS, MAX_TRIALS, NoiseConfig, NoiseOn, SnrRow, fig3a, fig3b,
};

/// Which frames receive the noise.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum NoiseFrames {
    /// Frame t+1 only: the regression model of the least-squares objective.
    Next,
    /// Both frames (errors in variables; every least-squares fit is then biased).
    Both,
}

/// Arguments of `pftrack pose-noise`.
///
/// SNR (dB) = 10 log10(P_s / σ²), P_s the mean square of the centred frame-t point
/// coordinates, σ the noise standard deviation per coordinate. Error = angle of
/// R_est · R_trueᵀ in degrees, scoring for every solver the Necker branch nearer the truth.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct PoseNoiseArgs {
    /// Points per trial.
    #[arg(long, default_value_t = 20)]
    pub points: usize,
    /// Trials per SNR value.
    #[arg(long, default_value_t = 5000)]
    pub trials: usize,
    /// Input SNRs in dB (Fig. 3b), comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0,5,10,15,20,25,30,35,40",
        allow_hyphen_values = true
    )]
    pub snr: Vec<f64>,
    /// SNRs in dB of the perturbation of SEA's multiplier Λ (Fig. 3a), comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0,5,10,15,20,25,30,35,40",
        allow_hyphen_values = true
    )]
    pub lambda_snr: Vec<f64>,
    /// Input SNR (dB) of the Λ experiment (Fig. 3a).
    #[arg(long, default_value_t = 10.0)]
    pub lambda_input_snr: f64,
    /// Largest random rotation angle (degrees).
    #[arg(long, default_value_t = 30.0)]
    pub max_angle: f64,
    /// Depth spread of the points relative to their lateral extent (0: one depth, the model
    /// under which q = R2 p + l is exact).
    #[arg(long, default_value_t = 0.0)]
    pub depth_spread: f64,
    /// Which frames receive the noise.
    #[arg(long, value_enum, default_value_t = NoiseFrames::Next)]
    pub noise_on: NoiseFrames,
    /// Master seed (each trial has its own generator seeded from it, the trial's number and
    /// its SNR's place in the list: `--snr 20` alone draws other trials than the 20 of
    /// `--snr 10,20`, so give the whole list to reproduce a figure).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write Fig. 3b as CSV `snr_db,sea,optimal,lsm,rls` (mean error, degrees) to this file,
    /// and Fig. 3a as `lambda_snr_db,sea` to the same name with `_lambda` before the extension
    /// (e.g. fig3.csv and fig3_lambda.csv). Fig. 3a's `sea` is the mean angle between the
    /// rotations from the perturbed and the unperturbed Λ, the error the perturbation adds
    /// (as the paper plots it); the table printed also gives the error against the truth.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Write a PNG with both panels (a: error vs Λ SNR, b: error vs input SNR).
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// `F.csv` → `F_lambda.csv` (a name without extension gets `_lambda` appended).
pub fn lambda_path(p: &Path) -> PathBuf {
    let stem = p
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = match p.extension() {
        Some(ext) => format!("{stem}_lambda.{}", ext.to_string_lossy()),
        None => format!("{stem}_lambda"),
    };
    p.with_file_name(name)
}

/// The SNRs (dB) accepted: beyond them the noise or the signal vanishes in rounding.
const SNR_RANGE: std::ops::RangeInclusive<f64> = -50.0..=150.0;

fn check_list(name: &str, v: &[f64]) -> anyhow::Result<()> {
    if v.is_empty() {
        anyhow::bail!("--{name} is empty");
    }
    if let Some(x) = v.iter().find(|x| !SNR_RANGE.contains(x)) {
        anyhow::bail!(
            "--{name}: {x} dB is outside {} to {} dB",
            SNR_RANGE.start(),
            SNR_RANGE.end()
        );
    }
    Ok(())
}

/// Checks the numeric arguments, each against its range.
fn check_args(args: &PoseNoiseArgs) -> anyhow::Result<()> {
    if !(3..=MAX_POINTS).contains(&args.points) {
        anyhow::bail!(
            "--points must be between 3 and {MAX_POINTS} (got {})",
            args.points
        );
    }
    if !(1..=MAX_TRIALS).contains(&args.trials) {
        anyhow::bail!(
            "--trials must be between 1 and {MAX_TRIALS} (got {})",
            args.trials
        );
    }
    check_list("snr", &args.snr)?;
    check_list("lambda-snr", &args.lambda_snr)?;
    check_list("lambda-input-snr", &[args.lambda_input_snr])?;
    if !(0.0..=180.0).contains(&args.max_angle) {
        anyhow::bail!(
            "--max-angle must be between 0 and 180 degrees (got {})",
            args.max_angle
        );
    }
    if !(0.0..=100.0).contains(&args.depth_spread) {
        anyhow::bail!(
            "--depth-spread must be between 0 and 100 (got {})",
            args.depth_spread
        );
    }
    Ok(())
}

/// The files the command will write, opened before the experiment runs so that a bad path
/// fails at once; each appears only once complete ([`AtomicFile`]).
struct Outputs {
    csv: Option<(AtomicFile, AtomicFile)>,
    plot: Option<AtomicFile>,
}

impl Outputs {
    fn open(args: &PoseNoiseArgs) -> anyhow::Result<Self> {
        let mut names: Vec<PathBuf> = Vec::new();
        if let Some(p) = &args.csv {
            // Two files are written, the second named after the first: a stream or device
            // has no such sibling (`--csv /dev/null` made a file `/dev/null_lambda`, and
            // `/dev/stdout` redirected to a file made `/dev/stdout_lambda`).
            let system = [Path::new("/dev"), Path::new("/proc")];
            let absolute = std::path::absolute(p).unwrap_or_else(|_| p.clone());
            let stream = p.as_os_str() == pftrack::frames::STDIN
                || system.iter().any(|d| absolute.starts_with(d))
                || std::fs::metadata(p).is_ok_and(|m| !m.is_file() && !m.is_dir());
            if stream {
                anyhow::bail!(
                    "--csv {}: writes two files, NAME and NAME with _lambda; give a file name",
                    p.display()
                );
            }
            names.push(p.clone());
            names.push(lambda_path(p));
        }
        if let Some(p) = &args.plot {
            crate::paths::png_name("--plot", p)?;
            names.push(p.clone());
        }
        // However spelled or linked (`x.png` and `./x.png`): two outputs of one file share
        // its partial file, and the second commit failed after the first had put a mix of
        // both in place.
        for (i, a) in names.iter().enumerate() {
            if names[..i]
                .iter()
                .any(|b| b == a || crate::paths::same(a, b))
            {
                anyhow::bail!(
                    "{} is named for two outputs (--csv writes its name and the name with \
                     _lambda, --plot its own)",
                    a.display()
                );
            }
        }
        let csv = match &args.csv {
            Some(p) => Some((AtomicFile::create(p)?, AtomicFile::create(&lambda_path(p))?)),
            None => None,
        };
        let plot = args.plot.as_deref().map(AtomicFile::create).transpose()?;
        Ok(Self { csv, plot })
    }
}

/// Runs the command.
pub fn run(args: PoseNoiseArgs) -> anyhow::Result<()> {
    check_args(&args)?;
    let outputs = Outputs::open(&args)?;
    let cfg = NoiseConfig {
        noise_on: match args.noise_on {
            NoiseFrames::Next => NoiseOn::Next,
            NoiseFrames::Both => NoiseOn::Both,
        },
        depth_spread: args.depth_spread,
        points: args.points,
        trials: args.trials,
        snr_db: args.snr.clone(),
        lambda_snr_db: args.lambda_snr.clone(),
        lambda_input_snr_db: args.lambda_input_snr,
        max_angle: args.max_angle.to_radians(),
        seed: args.seed,
        ..NoiseConfig::default()
    };
    let b = fig3b(&cfg)?;
    let a = fig3a(&cfg)?;
    outln!(
        "Fig. 3b: mean rotation error (deg), {} points, {} trials per SNR",
        cfg.points,
        cfg.trials
    )?;
    outln!(
        "{:>7} {:>9} {:>9} {:>9} {:>9}   {:>22} {:>9}",
        "snr_db",
        "sea",
        "optimal",
        "lsm",
        "rls",
        "optimal-sea (paired)",
        "differing"
    )?;
    for r in &b {
        let d = &r.optimal_minus_sea;
        outln!(
            "{:>7.1} {:>9.4} {:>9.4} {:>9.4} {:>9.4}   {:>+10.5} ± {:<9.5} {:>9}",
            r.snr_db,
            r.mean_deg[0],
            r.mean_deg[1],
            r.mean_deg[2],
            r.mean_deg[3],
            d.mean,
            d.std_error,
            format!("{}/{}", d.differing, d.trials)
        )?;
        if r.failures.iter().any(|f| *f > 0) {
            errln!(
                "  failures at {} dB (sea, optimal, lsm, rls): {:?}",
                r.snr_db,
                r.failures
            );
        }
    }
    outln!(
        "Fig. 3a: SEA error (deg) with perturbed Λ, input SNR {} dB: against SEA's unperturbed \
         answer (sea, the paper's figure) and against the truth",
        cfg.lambda_input_snr_db
    )?;
    outln!("{:>14} {:>9} {:>9}", "lambda_snr_db", "sea", "vs_truth")?;
    for r in &a {
        outln!(
            "{:>14.1} {:>9.4} {:>9.4}",
            r.lambda_snr_db,
            r.vs_unperturbed_deg,
            r.vs_truth_deg
        )?;
        if r.failures > 0 {
            errln!("  failures at Λ-SNR {} dB: {}", r.lambda_snr_db, r.failures);
        }
    }
    // Everything is written before anything is committed: a failure leaves no output.
    let Outputs {
        csv,
        plot: plot_file,
    } = outputs;
    let mut files: Vec<AtomicFile> = Vec::new();
    if let Some((mut fb, mut fa)) = csv {
        write_csv(&mut fb, &mut fa, &b, &a)?;
        files.extend([fb, fa]);
    }
    if let Some(mut f) = plot_file {
        let img = plot(&b, &a, &cfg).with_context(|| format!("drawing {}", f.path().display()))?;
        pftrack::output::encode_png(&mut f, &img)?;
        files.push(f);
    }
    // Every buffer flushed first, so that a stream or device target (a link to /dev/full)
    // fails before any file is renamed into place.
    for f in &mut files {
        let path = f.path().to_path_buf();
        f.flush()
            .with_context(|| format!("writing {}", path.display()))?;
    }
    for f in files {
        f.commit()?;
    }
    Ok(())
}

/// Fig. 3b's rows into `fb`, Fig. 3a's into `fa`.
fn write_csv(
    fb: &mut AtomicFile,
    fa: &mut AtomicFile,
    b: &[SnrRow],
    a: &[LambdaRow],
) -> anyhow::Result<()> {
    let err = |p: &Path| format!("writing {}", p.display());
    let pb = fb.path().to_path_buf();
    let pa = fa.path().to_path_buf();
    writeln!(fb, "snr_db,sea,optimal,lsm,rls").with_context(|| err(&pb))?;
    for r in b {
        writeln!(
            fb,
            "{},{},{},{},{}",
            r.snr_db, r.mean_deg[0], r.mean_deg[1], r.mean_deg[2], r.mean_deg[3]
        )
        .with_context(|| err(&pb))?;
    }
    writeln!(fa, "lambda_snr_db,sea").with_context(|| err(&pa))?;
    for r in a {
        writeln!(fa, "{},{}", r.lambda_snr_db, r.vs_unperturbed_deg).with_context(|| err(&pa))?;
    }
    Ok(())
}

/// Registers DejaVu Sans from the system fonts if present; returns whether text can be drawn.
fn register_font() -> bool {
    use plotters::style::{FontStyle, register_font};
    for p in [
        "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
        "/usr/share/fonts/TTF/DejaVuSans.ttf",
        "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    ] {
        if let Ok(bytes) = std::fs::read(p) {
            let leaked: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            if register_font("sans-serif", FontStyle::Normal, leaked).is_ok() {
                return true;
            }
        }
    }
    false
}

/// Plot size in pixels.
const PLOT_SIZE: (u32, u32) = (1400, 560);

/// Both panels drawn into an image.
fn plot(b: &[SnrRow], a: &[LambdaRow], cfg: &NoiseConfig) -> anyhow::Result<image::RgbImage> {
    let mut buf = vec![0u8; (PLOT_SIZE.0 * PLOT_SIZE.1 * 3) as usize];
    draw(&mut buf, b, a, cfg)?;
    image::RgbImage::from_raw(PLOT_SIZE.0, PLOT_SIZE.1, buf)
        .ok_or_else(|| anyhow::anyhow!("the plot's buffer has the wrong size"))
}

fn draw(buf: &mut [u8], b: &[SnrRow], a: &[LambdaRow], cfg: &NoiseConfig) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let text = register_font();
    let root = BitMapBackend::with_buffer(buf, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (left, right) = root.split_horizontally(700);

    // panel (a)
    type LambdaCurve = (RGBColor, &'static str, fn(&LambdaRow) -> f64);
    let lambda_curves: [LambdaCurve; 2] = [
        (RED, "against unperturbed SEA", |r| r.vs_unperturbed_deg),
        (BLACK, "against the truth", |r| r.vs_truth_deg),
    ];
    let curves: Vec<Curve> = lambda_curves
        .iter()
        .map(|&(colour, name, value)| Curve {
            colour,
            name,
            points: a.iter().map(|r| (r.lambda_snr_db, value(r))).collect(),
        })
        .collect();
    panel(
        &left,
        &format!(
            "(a) SEA, perturbed Λ (input SNR {} dB)",
            cfg.lambda_input_snr_db
        ),
        "SNR of Λ (dB)",
        &a.iter().map(|r| r.lambda_snr_db).collect::<Vec<_>>(),
        &curves,
        4,
        text,
    )?;

    // panel (b)
    let solvers = [
        (RED, "SEA"),
        (BLUE, "Optimal"),
        (GREEN, "LSM"),
        (MAGENTA, "RLS"),
    ];
    let curves: Vec<Curve> = solvers
        .iter()
        .enumerate()
        .map(|(i, &(colour, name))| Curve {
            colour,
            name,
            points: b.iter().map(|r| (r.snr_db, r.mean_deg[i])).collect(),
        })
        .collect();
    panel(
        &right,
        &format!("(b) error vs input SNR ({} points)", cfg.points),
        "input SNR (dB)",
        &b.iter().map(|r| r.snr_db).collect::<Vec<_>>(),
        &curves,
        3,
        text,
    )?;
    root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(())
}

/// One named curve of a panel: `(x, mean error)` per row, drawn where the error is finite.
struct Curve {
    colour: plotters::style::RGBColor,
    name: &'static str,
    points: Vec<(f64, f64)>,
}

/// One panel of the plot: the rows' x range, the curves' errors from 0 up, a line and a dot
/// of `radius` per point of each curve and, with `text`, the caption, axis names and legend.
fn panel(
    area: &plotters::drawing::DrawingArea<
        plotters::backend::BitMapBackend<'_>,
        plotters::coord::Shift,
    >,
    caption: &str,
    x_desc: &str,
    xs: &[f64],
    curves: &[Curve],
    radius: i32,
    text: bool,
) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let finite = |c: &Curve| -> Vec<(f64, f64)> {
        c.points
            .iter()
            .copied()
            .filter(|p| p.1.is_finite())
            .collect()
    };
    let ys: Vec<f64> = curves
        .iter()
        .flat_map(|c| finite(c).into_iter().map(|p| p.1))
        .collect();
    let (x0, x1) = range(xs);
    let (_, y1) = range(&ys);
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(20)
        .x_label_area_size(45)
        .y_label_area_size(60);
    if text {
        builder.caption(caption, ("sans-serif", 22));
    }
    let mut chart = builder
        .build_cartesian_2d(x0..x1, 0.0..y1 * 1.1)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut mesh = chart.configure_mesh();
    if text {
        mesh.x_desc(x_desc).y_desc("mean rotation error (deg)");
    } else {
        mesh.disable_x_mesh()
            .disable_y_mesh()
            .x_labels(0)
            .y_labels(0);
    }
    mesh.draw().map_err(|e| anyhow::anyhow!("{e}"))?;
    for c in curves {
        let pts = finite(c);
        let colour = c.colour;
        let series = chart
            .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if text {
            series
                .label(c.name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
        }
        chart
            .draw_series(pts.iter().map(|p| Circle::new(*p, radius, colour.filled())))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    if text {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(())
}

fn range(v: &[f64]) -> (f64, f64) {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !lo.is_finite() || !hi.is_finite() {
        (0.0, 1.0)
    } else if hi - lo < 1e-9 {
        (lo - 0.5, hi + 0.5)
    } else {
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lambda_path_inserts_suffix() {
        assert_eq!(
            lambda_path(Path::new("out/fig3.csv")),
            PathBuf::from("out/fig3_lambda.csv")
        );
        assert_eq!(lambda_path(Path::new("fig3")), PathBuf::from("fig3_lambda"));
    }
}

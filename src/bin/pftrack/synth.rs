//! `pftrack synth`: renders a synthetic sequence with exact ground truth.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use pftrack::synth::{Scenario, SynthConfig, parse_size, write_sequence};

/// Arguments of `pftrack synth`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct SynthArgs {
    /// Output directory: receives frames/00000.png..., truth.csv and init.txt.
    pub dir: PathBuf,
    /// Scenario: nod, pan, roll, combo, depth, car, long.
    #[arg(long, default_value = "combo", value_parser = crate::values::scenario)]
    pub scenario: Scenario,
    /// Number of frames (default: the scenario's own, e.g. 180 for nod, 2400 for long). The
    /// scenario's whole motion plays over them: fewer frames, faster motion per frame (and
    /// very few sample it coarsely: nod, pan, roll and depth swing out and back, so over 2 or
    /// 3 frames they do not move at all).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Image size WIDTHxHEIGHT, 24 to 8192 pixels a side, 2^25 pixels (8192x4096) at most in all, as `track` reads frames.
    #[arg(
        long,
        default_value = "160x120",
        value_parser = crate::values::synth_size,
        allow_hyphen_values = true
    )]
    pub size: String,
    /// Seed of the textures, the noise and the random motion of `long`.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Runs the command.
pub fn run(args: SynthArgs) -> anyhow::Result<()> {
    let scenario = args.scenario;
    let (width, height) = parse_size(&args.size)?;
    let mut cfg = SynthConfig::new(scenario);
    cfg.width = width;
    cfg.height = height;
    cfg.seed = args.seed;
    if let Some(n) = args.frames {
        cfg.frames = n;
    }
    cfg.validate()?;
    let summary = write_sequence(&cfg, &args.dir, std::io::stderr().is_terminal())
        .with_context(|| format!("rendering {} into {}", scenario, args.dir.display()))?;
    let e = summary.init;
    // The object's size follows the width (the field of view is horizontal): in a frame much
    // wider than tall it reaches past the top and bottom. The truth stays the whole outline's.
    let (w, h) = (f64::from(width), f64::from(height));
    if e.cx - e.a < -0.5 || e.cx + e.a > w - 0.5 || e.cy - e.b < -0.5 || e.cy + e.b > h - 0.5 {
        errln!(
            "pftrack: warning: the {scenario} at frame 0 ({:.0}x{:.0} px) reaches past the \
             {width}x{height} frame's edges: its size follows the width, so the start and the \
             truth hold pixels the frames do not (a taller frame keeps it whole)",
            2.0 * e.a,
            2.0 * e.b
        );
    }
    outln!(
        "wrote {} frame{} of '{}' ({}x{}, seed {}) to {}; truth {}; init {:.2},{:.2},{:.2},{:.2}",
        cfg.frames,
        if cfg.frames == 1 { "" } else { "s" },
        scenario,
        width,
        height,
        cfg.seed,
        summary.frames_dir.display(),
        summary.truth.display(),
        e.cx,
        e.cy,
        e.a,
        e.b
    )?;
    Ok(())
}

//! `pftrack eval`: scores an estimate against ground truth.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use pftrack::eval::{evaluate_from, load_truth};
use pftrack::io::read_pose_csv;

/// Arguments of `pftrack eval`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct EvalArgs {
    /// Ground truth: a pose CSV (`frame,cx,cy,a,b,rx,ry,rz`) or an OTB box file (`x,y,w,h`
    /// per frame, 1-based, commas or tabs).
    pub truth: PathBuf,
    /// The estimate: a pose CSV (e.g. from `pftrack track`).
    pub est: PathBuf,
    /// Score only the truth frames from the estimate's first frame on, as OTB's temporal
    /// robustness evaluation (TRE) scores a track started later (`track --start-frame N`):
    /// the frames before it are then not missing, nor failures in precision and success.
    #[arg(long)]
    pub segment: bool,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Runs the command.
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let truth = load_truth(&args.truth).context("reading the truth")?;
    let est = read_pose_csv(&args.est).context("reading the estimate")?;
    let from = match args.segment {
        true => est.iter().map(|r| r.frame).min().unwrap_or(0),
        false => 0,
    };
    let report = evaluate_from(&truth, &est, from)?;
    if args.json {
        outln!("{}", serde_json::to_string(&report)?)?;
    } else {
        outln!("truth             {}", args.truth.display())?;
        outln!(
            "estimate          {} ({} rows)",
            args.est.display(),
            est.len()
        )?;
        out!("{}", report.to_table())?;
    }
    Ok(())
}

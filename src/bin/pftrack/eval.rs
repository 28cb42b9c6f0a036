//! `pftrack eval`: scores an estimate against ground truth.

use clap::Args;

/// Arguments of `pftrack eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {}

/// Runs the command.
pub fn run(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack eval` is not implemented yet")
}

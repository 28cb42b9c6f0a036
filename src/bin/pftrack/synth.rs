//! `pftrack synth`: renders a synthetic sequence with exact ground truth.

use clap::Args;

/// Arguments of `pftrack synth`.
#[derive(Debug, Args)]
pub struct SynthArgs {}

/// Runs the command.
pub fn run(_args: SynthArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack synth` is not implemented yet")
}

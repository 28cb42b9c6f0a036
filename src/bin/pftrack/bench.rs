//! `pftrack bench`: times the likelihood pass stage by stage, CPU and GPU.

use clap::Args;

/// Arguments of `pftrack bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {}

/// Runs the command.
pub fn run(_args: BenchArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack bench` is not implemented yet")
}

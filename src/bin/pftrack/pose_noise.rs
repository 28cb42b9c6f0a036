//! `pftrack pose-noise`: reproduces the paper's Fig. 3 (rotation error against noise).

use clap::Args;

/// Arguments of `pftrack pose-noise`.
#[derive(Debug, Args)]
pub struct PoseNoiseArgs {}

/// Runs the command.
pub fn run(_args: PoseNoiseArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack pose-noise` is not implemented yet")
}

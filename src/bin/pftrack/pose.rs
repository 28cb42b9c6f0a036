//! `pftrack pose`: the rotation between two images.

use clap::Args;

/// Arguments of `pftrack pose`.
#[derive(Debug, Args)]
pub struct PoseArgs {}

/// Runs the command.
pub fn run(_args: PoseArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack pose` is not implemented yet")
}

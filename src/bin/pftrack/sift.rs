//! `pftrack sift`: exports SIFT keypoints and descriptors of an image.

use clap::Args;

/// Arguments of `pftrack sift`.
#[derive(Debug, Args)]
pub struct SiftArgs {}

/// Runs the command.
pub fn run(_args: SiftArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack sift` is not implemented yet")
}

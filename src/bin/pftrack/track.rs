//! `pftrack track`: tracks an object and estimates its pose through a video.

use clap::Args;

/// Arguments of `pftrack track`.
#[derive(Debug, Args)]
pub struct TrackArgs {}

/// Runs the command.
pub fn run(_args: TrackArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack track` is not implemented yet")
}

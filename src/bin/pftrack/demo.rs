//! `pftrack demo`: renders the default synthetic scenario, tracks it and scores it.

use clap::Args;

/// Arguments of `pftrack demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {}

/// Runs the command.
pub fn run(_args: DemoArgs) -> anyhow::Result<()> {
    anyhow::bail!("`pftrack demo` is not implemented yet")
}

//! `pftrack settings`: prints the tracker's default settings as JSON, the starting point of a
//! `track --config` file.

use clap::Args;
use pftrack::tracker::TrackerConfig;

/// Arguments of `pftrack settings`.
#[derive(Debug, Args)]
pub struct SettingsArgs {}

/// Runs the command.
pub fn run(_: SettingsArgs) -> anyhow::Result<()> {
    outln!(
        "{}",
        serde_json::to_string_pretty(&TrackerConfig::default())?
    )?;
    Ok(())
}

//! `pftrack demo`: renders the default synthetic scenario, tracks it and scores it against its
//! exact truth: the README's main command.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use pftrack::eval::{Truth, evaluate};
use pftrack::frames::{self, SourceOptions};
use pftrack::io::{PoseRecord, format_pose_csv, read_pose_csv};
use pftrack::likelihood::{Backend, create_engine};
use pftrack::synth::{Scenario, SynthConfig, stage_sequence};
use pftrack::tracker::{Init, Mode, Tracker};

use crate::track::{config, progress};

/// Arguments of `pftrack demo`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct DemoArgs {
    /// Scenario to render (nod, pan, roll, combo, depth, car, long).
    #[arg(long, default_value = "nod", value_parser = crate::values::scenario)]
    pub scenario: Scenario,
    /// Number of frames (the scenario's default if absent); the scenario's whole motion plays
    /// over them.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Where the rendered sequence (DIR/sequence) and the poses (DIR/poses.csv) go; the
    /// score is printed.
    #[arg(long, default_value = "pftrack-demo")]
    pub out: PathBuf,
    /// Likelihood engine: auto (the GPU if a hardware Vulkan adapter exists), cpu or gpu.
    #[arg(
        long,
        default_value = "auto",
        hide_possible_values = true,
        ignore_case = true
    )]
    pub backend: Backend,
    /// Number of particles.
    #[arg(long, default_value_t = 200)]
    pub particles: usize,
    /// Seed of the scene and of the filter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Runs the command.
pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    let scenario = a.scenario;
    let mut cfg = SynthConfig::new(scenario);
    cfg.seed = a.seed;
    if let Some(n) = a.frames {
        cfg.frames = n;
    }
    // Every argument checked before anything is rendered or written.
    cfg.validate()?;
    if a.out.exists() && !a.out.is_dir() {
        anyhow::bail!("--out {}: not a folder", a.out.display());
    }
    let poses = a.out.join("poses.csv");
    if poses.is_dir() {
        anyhow::bail!(
            "{} is a folder: the demo's poses cannot replace it",
            poses.display()
        );
    }
    let backend = a.backend;
    let mut tcfg = config(Mode::Sea, a.particles, a.seed)?;
    // The engine too: one that cannot open fails the demo before anything is written.
    let (engine, notice) = create_engine(backend)?;
    if let Some(n) = notice {
        errln!("pftrack: {}", crate::in_cli_terms(&n));
    }
    // The sequence is rendered into a staging folder (registered for an interrupt to remove)
    // and tracked from there; it moves into place together with the poses, so that an
    // interrupted or failed demo leaves DIR as it was, never a new sequence beside an earlier
    // run's poses.
    let seq_dir = a.out.join("sequence");
    let t0 = std::time::Instant::now();
    let staged = stage_sequence(&cfg, &seq_dir, std::io::stderr().is_terminal())?;
    let render_s = t0.elapsed().as_secs_f64();

    let init = Init::frontal(staged.init()?);
    let mut source = frames::open(staged.frames_dir(), &SourceOptions::default())?;
    let first = source
        .next()
        .context("the rendered sequence has no frames")??;
    // The synthetic camera is known: the init file gives it.
    tcfg.camera_hfov_deg = Some(staged.hfov_deg());
    let mut tracker = Tracker::with_engine(tcfg, engine, &first, init)?;
    let pb = progress(Some(cfg.frames));
    let mut records: Vec<PoseRecord> = vec![tracker.initial_estimate().to_record()];
    let t1 = std::time::Instant::now();
    for (k, frame) in source.enumerate() {
        let frame = frame.with_context(|| format!("reading frame {}", k + 1))?;
        records.push(tracker.step(&frame)?.to_record());
        pb.inc(1);
    }
    pb.finish_and_clear();
    let track_s = t1.elapsed().as_secs_f64();

    let summary = staged.commit(&[(&poses, &format_pose_csv(&records, true))])?;
    // Scored from the files written, as `pftrack eval` scores them.
    let truth = Truth::Poses(read_pose_csv(&summary.truth)?);
    let report = evaluate(&truth, &read_pose_csv(&poses)?)?;
    outln!("{}", report.to_table())?;
    // The clock ran over the steps alone: the first frame is the start, not a step.
    let steps = cfg.frames.saturating_sub(1);
    let rate = if steps == 0 {
        "no step".to_string()
    } else {
        format!("{:.0} frames/s", steps as f64 / track_s.max(1e-9))
    };
    outln!(
        "scenario {} ({} frame{} {}x{}): rendered in {render_s:.1} s, tracked in {track_s:.1} s ({rate}) with {}",
        scenario.name(),
        cfg.frames,
        if cfg.frames == 1 { "" } else { "s" },
        cfg.width,
        cfg.height,
        tracker.engine_name()
    )?;
    outln!(
        "frames {}\ntruth  {}\nposes  {}",
        summary.frames_dir.display(),
        summary.truth.display(),
        poses.display()
    )?;
    // The same track again (the same seed, particles, engine and camera: on the CPU engine the
    // same poses byte for byte), drawn for a person to watch.
    let seq = summary.frames_dir.parent().unwrap_or(&summary.frames_dir);
    let particles = if a.particles == 200 {
        String::new()
    } else {
        format!(" --particles {}", a.particles)
    };
    let engine = match a.backend {
        Backend::Auto => "",
        Backend::Cpu => " --backend cpu",
        Backend::Gpu => " --backend gpu",
    };
    outln!(
        "to watch it: pftrack track {} --seed {}{particles}{engine} -o {} --render-video {}",
        shell_word(seq),
        a.seed,
        shell_word(&poses),
        shell_word(&a.out.join("track.mp4"))
    )?;
    Ok(())
}

/// `path` as one word of a POSIX shell command line, to copy and paste: as it is where every
/// character is plain, else in single quotes (a quote in it written `'\''`); a relative path
/// that starts with `-` gets `./` first, so that it is not read as an option.
fn shell_word(path: &std::path::Path) -> String {
    let text = path.to_string_lossy();
    let text = if text.starts_with('-') {
        format!("./{text}")
    } else {
        text.into_owned()
    };
    let plain = |c: char| c.is_ascii_alphanumeric() || "_./,:=+@%-".contains(c);
    if !text.is_empty() && text.chars().all(plain) {
        text
    } else {
        format!("'{}'", text.replace('\'', "'\\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::shell_word;
    use std::path::Path;

    #[test]
    fn paths_are_written_as_one_shell_word() {
        assert_eq!(
            shell_word(Path::new("pftrack-demo/poses.csv")),
            "pftrack-demo/poses.csv"
        );
        assert_eq!(shell_word(Path::new("my dir/x")), "'my dir/x'");
        assert_eq!(shell_word(Path::new("it's $x")), "'it'\\''s $x'");
        assert_eq!(shell_word(Path::new("-x/seq")), "./-x/seq");
        assert_eq!(shell_word(Path::new("")), "''");
    }
}

//! `pftrack synth`: renders a synthetic sequence with exact ground truth.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use pftrack::output::png_len;
use pftrack::synth::{Renderer, Scenario, SynthConfig, parse_size, write_sequence};

use crate::paths::Room;

/// Arguments of `pftrack synth`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct SynthArgs {
    /// Output directory: receives frames/00000.png..., truth.csv and init.txt.
    pub dir: PathBuf,
    /// Scenario: nod, pan, roll, combo, depth, car, long.
    #[arg(long, default_value = "combo", value_parser = crate::values::scenario)]
    pub scenario: Scenario,
    /// Number of frames (default: the scenario's own, e.g. 180 for nod, 2400 for long). The
    /// scenario's whole motion plays over them: fewer frames, faster motion per frame (and
    /// very few sample it coarsely: nod, pan, roll and depth swing out and back, so over 2 or
    /// 3 frames they do not move at all).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Image size WIDTHxHEIGHT, 24 to 8192 pixels a side, 2^25 pixels (8192x4096) at most in all, as `track` reads frames.
    #[arg(
        long,
        default_value = "160x120",
        value_parser = crate::values::synth_size,
        allow_hyphen_values = true
    )]
    pub size: String,
    /// Seed of the textures, the noise and the random motion of `long`.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Refuses a sequence whose frames would not fit in the `room` left where they go (`DIR/frames`,
/// named `dir` in the message), before rendering any of it, instead of failing when the disk
/// is full, hours in. Each frame takes whole blocks, and 2 % more is asked for the truth, the
/// staging and whatever else is written meanwhile. Where even the frames' raw pixels would
/// fit it passes at once; otherwise the first, middle and last frames are rendered and
/// encoded, and the largest PNG is taken for every frame. Also refused: more frames than
/// files the file system can still make.
fn check_room(cfg: &SynthConfig, dir: &Path, room: Option<Room>) -> anyhow::Result<()> {
    let Some(room) = room else {
        return Ok(());
    };
    let frames = cfg.frames as u64;
    // The frames, the truth, the init file and the staging folder.
    if let Some(files) = room.files.filter(|&f| f < frames + 3) {
        bail!(
            "{} frames would need {} files, more than the {files} the file system where {} is \
             can still make: ask for fewer --frames",
            cfg.frames,
            frames + 3,
            dir.display()
        );
    }
    let on_disk = |len: u64| len.div_ceil(room.block).saturating_mul(room.block);
    let need = |len: u64| {
        let all = on_disk(len).saturating_mul(frames);
        all.saturating_add(all / 50)
    };
    // A PNG of noisy pixels is the raw pixels, a filter byte a row and a little framing.
    let raw = (u64::from(cfg.width) * 3 + 1) * u64::from(cfg.height) + 4096;
    if need(raw) <= room.bytes {
        return Ok(());
    }
    let renderer = Renderer::new(cfg)?;
    let mut packed = 0;
    for k in [0, cfg.frames / 2, cfg.frames - 1] {
        packed = packed.max(png_len(&renderer.render_image(k)).context("sizing the frames")?);
    }
    if need(packed) > room.bytes {
        bail!(
            "{} frames of {}x{} would take about {} ({} a frame as PNG), more than the {} \
             free where {} is: ask for fewer --frames or a smaller --size",
            cfg.frames,
            cfg.width,
            cfg.height,
            bytes(need(packed)),
            bytes(packed),
            bytes(room.bytes),
            dir.display()
        );
    }
    Ok(())
}

/// A number of bytes for a person: in GB from 1 GB, in MB from 1 MB, else in kB.
fn bytes(b: u64) -> String {
    match b {
        1_000_000_000.. => format!("{:.1} GB", b as f64 / 1e9),
        1_000_000.. => format!("{:.1} MB", b as f64 / 1e6),
        _ => format!("{:.1} kB", b as f64 / 1e3),
    }
}

/// Runs the command.
pub fn run(args: SynthArgs) -> anyhow::Result<()> {
    let scenario = args.scenario;
    let (width, height) = parse_size(&args.size)?;
    let mut cfg = SynthConfig::new(scenario);
    cfg.width = width;
    cfg.height = height;
    cfg.seed = args.seed;
    if let Some(n) = args.frames {
        cfg.frames = n;
    }
    cfg.validate()?;
    // The frames go into DIR/frames, wherever a link there leads.
    let frames_dir = args.dir.join("frames");
    check_room(&cfg, &args.dir, crate::paths::room(&frames_dir))?;
    let summary = write_sequence(&cfg, &args.dir, std::io::stderr().is_terminal())
        .with_context(|| format!("rendering {} into {}", scenario, args.dir.display()))?;
    let e = summary.init;
    // The object's size follows the width (the field of view is horizontal): in a frame much
    // wider than tall it reaches past the top and bottom. The truth stays the whole outline's.
    let (w, h) = (f64::from(width), f64::from(height));
    if e.cx - e.a < -0.5 || e.cx + e.a > w - 0.5 || e.cy - e.b < -0.5 || e.cy + e.b > h - 0.5 {
        errln!(
            "pftrack: warning: the {scenario} at frame 0 ({:.0}x{:.0} px) reaches past the \
             {width}x{height} frame's edges: its size follows the width, so the start and the \
             truth hold pixels the frames do not (a taller frame keeps it whole)",
            2.0 * e.a,
            2.0 * e.b
        );
    }
    outln!(
        "wrote {} frame{} of '{}' ({}x{}, seed {}) to {}; truth {}; init {:.2},{:.2},{:.2},{:.2}",
        cfg.frames,
        if cfg.frames == 1 { "" } else { "s" },
        scenario,
        width,
        height,
        cfg.seed,
        summary.frames_dir.display(),
        summary.truth.display(),
        e.cx,
        e.cy,
        e.a,
        e.b
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sequence_larger_than_the_free_space_is_refused_before_rendering() {
        let mut cfg = SynthConfig::new(Scenario::Nod);
        (cfg.width, cfg.height, cfg.frames) = (80, 60, 10);
        let dir = Path::new("/somewhere/seq");
        let renderer = Renderer::new(&cfg).unwrap();
        let png = (0..10)
            .map(|k| png_len(&renderer.render_image(k)).unwrap())
            .max()
            .unwrap();
        let raw = (80 * 3 + 1) * 60 + 4096;
        assert!(png < raw && png > 4096, "{png} {raw}");
        let room = |bytes: u64, block: u64| {
            Some(Room {
                bytes,
                block,
                files: Some(1000),
            })
        };
        // Unknown room, or room for the raw pixels: passes.
        assert!(check_room(&cfg, dir, None).is_ok());
        assert!(check_room(&cfg, dir, room(11 * raw, 1)).is_ok());
        // Room for the frames as PNG but not as raw pixels: passes after sizing them, with
        // the margin; not without it.
        assert!(check_room(&cfg, dir, room(10 * png * 51 / 50 + 10, 1)).is_ok());
        let e = check_room(&cfg, dir, room(10 * png, 1))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("10 frames of 80x60 would take about ")
                && e.contains(" kB a frame as PNG), more than the ")
                && e.contains(" kB free where /somewhere/seq is: ask for fewer --frames")
                && !e.contains('\n'),
            "{e}"
        );
        // Each frame takes whole blocks: with 1 MiB blocks ten frames need 10 MiB and more.
        assert!(check_room(&cfg, dir, room(10 * png * 2, 1 << 20)).is_err());
        assert!(check_room(&cfg, dir, room(11 << 20, 1 << 20)).is_ok());
        // Files: the frames and three more.
        let files = |n| {
            Some(Room {
                bytes: u64::MAX,
                block: 4096,
                files: Some(n),
            })
        };
        assert!(check_room(&cfg, dir, files(13)).is_ok());
        let e = check_room(&cfg, dir, files(12)).unwrap_err().to_string();
        assert_eq!(
            e,
            "10 frames would need 13 files, more than the 12 the file system where \
             /somewhere/seq is can still make: ask for fewer --frames"
        );
        // A single frame is sized by itself.
        cfg.frames = 1;
        assert!(check_room(&cfg, dir, room(png / 2, 1)).is_err());
        assert_eq!(bytes(999_999_999), "1000.0 MB");
        assert_eq!(bytes(48_900_000_000), "48.9 GB");
        assert_eq!(bytes(4_200), "4.2 kB");
    }
}

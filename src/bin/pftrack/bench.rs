//! `pftrack bench`: times the likelihood pass stage by stage, CPU and GPU, on a synthetic
//! frame made in code (no data needed); with `--step`, the whole tracker step on a rendered
//! synthetic sequence.

use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use pftrack::likelihood::cpu::CpuEngine;
use pftrack::likelihood::gpu::workload::{particles, workload};
use pftrack::likelihood::gpu::{GpuEngine, StageTimes, TimingSource};
use pftrack::likelihood::{Backend, FrameInput, LikelihoodEngine, LikelihoodError, create_engine};
use pftrack::synth::{Renderer, Scenario, SynthConfig};
use pftrack::tracker::{Init, Tracker, TrackerConfig};

/// Arguments of `pftrack bench`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct BenchArgs {
    /// Particle counts, comma separated [default: 200,1000,10000,100000; with `--step`,
    /// 200,1000,10000, as a whole step with 100000 particles on one thread takes seconds and
    /// the sequence has 59 of them per pass].
    #[arg(long, value_delimiter = ',')]
    pub particles: Vec<usize>,
    /// Frame size `WxH`, 8 to 8192 pixels a side (with `--step`, as `synth` renders: 24 or more,
    /// and 2^25 pixels, 8192x4096, at most in all).
    #[arg(long, default_value = "160x120", value_parser = parse_size, allow_hyphen_values = true)]
    pub size: (u32, u32),
    /// Which engines to time: `cpu`, `gpu` (an error without a Vulkan adapter), or `auto`:
    /// the CPU, and the GPU on the best adapter that opens, a software one such as lavapipe
    /// too (unlike `track --backend auto`, which leaves a software adapter alone: here
    /// timing it is the point).
    #[arg(
        long,
        default_value = "auto",
        hide_possible_values = true,
        ignore_case = true
    )]
    pub backend: Backend,
    /// Timed runs per measurement (the median is printed), after one warm-up run; with
    /// `--step`, passes over the sequence.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..))]
    pub repeats: u32,
    /// Time the whole tracker step instead (SIFT, matching, the keyframe fits, block
    /// matching, the filter with all its terms) on the synthetic `nod` scenario rendered at
    /// `--size`: the median per step and frames per second, on one thread and on all.
    #[arg(long)]
    pub step: bool,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = pftrack::frames::parse_wxh(s).map_err(|e| e.to_string())?;
    // The synthetic frames the step is timed on are bounded so; a larger frame would only
    // time the allocator (40000x40000 ran for minutes, 100000x100000 aborted).
    let max = pftrack::synth::MAX_SIDE;
    if w < 8 || h < 8 || w > max || h > max {
        return Err(format!("size {s:?}: each side from 8 to {max} pixels"));
    }
    Ok((w, h))
}

/// The median of `v`: the middle value, or the mean of the two middle ones of an even count
/// (the upper one alone made `--repeats 2` print the slower run); zero for none. `sift
/// --repeat` reports it too.
pub(crate) fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    let n = v.len();
    match n {
        0 => Duration::ZERO,
        _ if n % 2 == 1 => v[n / 2],
        _ => (v[n / 2 - 1] + v[n / 2]) / 2,
    }
}

fn ms(d: Duration) -> String {
    format!("{:.3}", d.as_secs_f64() * 1e3)
}

/// Median wall time of `evaluate` on an engine.
fn time_engine(
    engine: &mut dyn LikelihoodEngine,
    frame: &FrameInput<'_>,
    w: &pftrack::likelihood::gpu::workload::Workload,
    ps: &[pftrack::likelihood::Particle],
    repeats: usize,
) -> Result<Duration, LikelihoodError> {
    let mut out = Vec::new();
    engine.evaluate(frame, &w.params, ps, &mut out)?;
    let mut times = Vec::new();
    for _ in 0..repeats {
        let t = Instant::now();
        engine.evaluate(frame, &w.params, ps, &mut out)?;
        times.push(t.elapsed());
    }
    Ok(median(times))
}

/// Median of each stage over the runs.
fn median_stages(runs: &[StageTimes]) -> StageTimes {
    let pick = |f: &dyn Fn(&StageTimes) -> Duration| median(runs.iter().map(f).collect());
    let kernels = runs
        .first()
        .map(|r| {
            r.kernels
                .iter()
                .enumerate()
                .map(|(k, (name, _))| (*name, pick(&|s: &StageTimes| s.kernels[k].1)))
                .collect()
        })
        .unwrap_or_default();
    StageTimes {
        upload: pick(&|s| s.upload),
        kernels,
        readback: pick(&|s| s.readback),
        total: pick(&|s| s.total),
        source: runs.first().and_then(|r| r.source),
    }
}

/// Runs the command.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    let max = pftrack::filter::MAX_PARTICLES;
    if let Some(n) = args.particles.iter().find(|&&n| n == 0 || n > max) {
        anyhow::bail!("--particles: {n} is not a count from 1 to {max}");
    }
    if args.step {
        return run_step(&args);
    }
    let repeats = args.repeats as usize;
    let (width, height) = args.size;
    let w = workload(width, height, 1).context("building the benchmark frame")?;
    let frame = FrameInput {
        image: &w.image,
        features: &w.features,
        depths: None,
        prev: w.target,
        theta0: 0.0,
    };

    let want_cpu = args.backend != Backend::Gpu;
    let mut gpu = match args.backend {
        Backend::Cpu => None,
        Backend::Gpu => Some(GpuEngine::new().context("opening the GPU")?),
        Backend::Auto => match GpuEngine::new() {
            Ok(g) => Some(g),
            Err(e) => {
                errln!(
                    "pftrack: note: no GPU timings ({})",
                    crate::in_cli_terms(&e.to_string())
                );
                None
            }
        },
    };
    let mut cpu1 = CpuEngine::with_threads(1)?;
    let mut cpu_all = CpuEngine::new();
    if want_cpu {
        cpu1.set_colour_model(&w.model)?;
        cpu_all.set_colour_model(&w.model)?;
    }
    if let Some(g) = gpu.as_mut() {
        g.set_colour_model(&w.model)?;
    }

    outln!(
        "likelihood pass: {width}x{height} frame, {} normal lines, {} features, median of {repeats} run{} (ms)",
        w.params.num_lines,
        w.features.len(),
        if repeats == 1 { "" } else { "s" }
    )?;
    if want_cpu {
        outln!("cpu: {} thread(s) available", cpu_all.threads())?;
    }
    if let Some(g) = &gpu {
        let how = if g.has_timestamps() {
            "kernels timed by GPU timestamp queries"
        } else {
            "no timestamp queries: kernels timed by the wall clock, one submission each"
        };
        outln!("gpu: {} ({how})", g.name())?;
    }

    let mut header = vec!["N".to_string()];
    if want_cpu {
        header.push("cpu 1t".into());
        header.push(format!("cpu {}t", cpu_all.threads()));
    }
    let mut stage_names: Vec<&str> = Vec::new();
    let mut rows = Vec::new();
    for &n in &counts(&args.particles, false) {
        let ps = particles(&w.target, n, 7);
        let mut row = vec![n.to_string()];
        let mut best_cpu = None;
        if want_cpu {
            let t1 = time_engine(&mut cpu1, &frame, &w, &ps, repeats)?;
            let ta = time_engine(&mut cpu_all, &frame, &w, &ps, repeats)?;
            best_cpu = Some(t1.min(ta));
            row.push(ms(t1));
            row.push(ms(ta));
        }
        if let Some(g) = gpu.as_mut() {
            let mut out = Vec::new();
            g.evaluate(&frame, &w.params, &ps, &mut out)?; // warm-up (shader compile, buffers)
            let mut runs = Vec::new();
            for _ in 0..repeats {
                runs.push(g.evaluate_timed(&frame, &w.params, &ps, &mut out)?);
            }
            // Plain evaluate (no timestamps, one submission): what a tracker pays.
            let plain = time_engine(g, &frame, &w, &ps, repeats)?;
            let st = median_stages(&runs);
            if stage_names.is_empty() {
                stage_names = st.kernels.iter().map(|(k, _)| *k).collect();
            }
            row.push(ms(plain));
            if let Some(c) = best_cpu {
                row.push(format!("{:.2}", plain.as_secs_f64() / c.as_secs_f64()));
            }
            row.push(ms(st.upload));
            for (_, d) in &st.kernels {
                row.push(ms(*d));
            }
            row.push(ms(st.readback));
            if st.source == Some(TimingSource::WallClock) {
                row.push("(wall)".into());
            }
        }
        rows.push(row);
    }
    if gpu.is_some() {
        header.push("gpu".into());
        if want_cpu {
            header.push("gpu/cpu".into());
        }
        header.push("upload".into());
        header.extend(stage_names.iter().map(|s| s.to_string()));
        header.push("readback".into());
    }
    let table: Vec<Vec<String>> = std::iter::once(header).chain(rows).collect();
    print_table(&table)?;
    if gpu.is_some() {
        let ratio = if want_cpu {
            " gpu/cpu = gpu over the faster CPU column;"
        } else {
            ""
        };
        outln!(
            "gpu = one plain evaluate (upload, all kernels, readback);{ratio} \
             upload and readback are host wall-clock, kernels from timestamps, all from \
             separate runs with a submission per kernel, whose stages can add up to more than \
             the plain evaluate"
        )?;
    }
    Ok(())
}

/// Frames of the whole-step benchmark's sequence (the first starts each pass).
const STEP_FRAMES: usize = 60;

/// `--step`: the whole tracker step, per particle count, on one thread, on all, and on the
/// GPU engine when one is asked for or (with `auto`) found.
fn run_step(args: &BenchArgs) -> anyhow::Result<()> {
    let passes = args.repeats as usize;
    let (width, height) = args.size;
    let cfg = SynthConfig {
        width,
        height,
        frames: STEP_FRAMES,
        ..SynthConfig::new(Scenario::Nod)
    };
    let renderer = Renderer::new(&cfg).context("rendering the benchmark sequence")?;
    let frames: Vec<image::RgbImage> = (0..cfg.frames).map(|k| renderer.render(k).0).collect();
    let init = Init::frontal(renderer.init_ellipse());
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    // The GPU engine is opened once here, before anything is printed, so a missing adapter
    // is the run's only line and the table can name the adapter it timed.
    let gpu_name = match args.backend {
        Backend::Cpu => None,
        Backend::Gpu => Some(create_engine(Backend::Gpu)?.0.name()),
        Backend::Auto => match create_engine(Backend::Gpu) {
            Ok((engine, _)) => Some(engine.name()),
            Err(e) => {
                errln!(
                    "pftrack: note: no GPU row ({})",
                    crate::in_cli_terms(&e.to_string())
                );
                None
            }
        },
    };
    let want_gpu = gpu_name.is_some();
    // (label, threads, on the GPU)
    let mut columns: Vec<(String, usize, bool)> = Vec::new();
    if args.backend != Backend::Gpu {
        columns.push(("cpu 1t".into(), 1, false));
        if all > 1 {
            columns.push((format!("cpu {all}t"), all, false));
        }
    }
    if want_gpu {
        columns.push((format!("gpu {all}t"), all, true));
    }
    outln!(
        "whole tracker step: `nod` at {width}x{height}, {} steps x {passes} passes, median ms per \
         step (frames/s)",
        cfg.frames - 1
    )?;
    if let Some(name) = &gpu_name {
        outln!("gpu: {name}")?;
    }
    let mut rows = vec![
        std::iter::once("N".to_string())
            .chain(columns.iter().map(|c| c.0.clone()))
            .collect::<Vec<_>>(),
    ];
    let progress = std::io::IsTerminal::is_terminal(&std::io::stderr());
    for &n in &counts(&args.particles, true) {
        let mut row = vec![n.to_string()];
        for (label, threads, on_gpu) in &columns {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(*threads)
                .build()
                .with_context(|| format!("starting {threads} threads"))?;
            let mut tc = TrackerConfig::default();
            tc.filter.particles = n;
            let per_step = pool.install(|| -> anyhow::Result<Duration> {
                let engine = if *on_gpu {
                    create_engine(Backend::Gpu)?.0
                } else {
                    Box::new(CpuEngine::new())
                };
                let mut tracker = Tracker::with_engine(tc, engine, &frames[0], init)?;
                time_steps(&mut tracker, &frames, init, passes)
            })?;
            let secs = per_step.as_secs_f64();
            row.push(format!("{:.3} ({:.0}/s)", secs * 1e3, 1.0 / secs));
            if progress {
                errln!("bench: {n} particles, {label}: {:.3} ms a step", secs * 1e3);
            }
        }
        rows.push(row);
    }
    print_table(&rows)?;
    Ok(())
}

/// The particle counts asked for, or the defaults of the likelihood pass (`step` false) or
/// of the whole step.
fn counts(asked: &[usize], step: bool) -> Vec<usize> {
    match (asked.is_empty(), step) {
        (false, _) => asked.to_vec(),
        (true, false) => vec![200, 1000, 10_000, 100_000],
        (true, true) => vec![200, 1000, 10_000],
    }
}

/// The median wall time of one step over `passes` passes through `frames` after a warm-up
/// pass, the tracker started afresh on the first frame before each (not timed).
fn time_steps(
    tracker: &mut Tracker,
    frames: &[image::RgbImage],
    init: Init,
    passes: usize,
) -> anyhow::Result<Duration> {
    // Grown as the passes run: reserved up front, `--repeats 4000000000` asked for 3.8 TB
    // at once and aborted.
    let mut times = Vec::new();
    for pass in 0..=passes {
        tracker.reinit(&frames[0], init)?;
        for (k, f) in frames.iter().enumerate().skip(1) {
            let t0 = Instant::now();
            tracker
                .step(f)
                .with_context(|| format!("benchmark frame {k}"))?;
            if pass > 0 {
                times.push(t0.elapsed());
            }
        }
    }
    Ok(median(times))
}

/// Prints rows right-aligned in columns, the first row the header.
fn print_table(rows: &[Vec<String>]) -> anyhow::Result<()> {
    let cols = rows.iter().map(|r| r.len()).max().unwrap_or(0);
    let widths: Vec<usize> = (0..cols)
        .map(|i| {
            rows.iter()
                .filter_map(|r| r.get(i))
                .map(|s| s.len())
                .max()
                .unwrap_or(0)
        })
        .collect();
    for r in rows {
        let line: Vec<String> = r
            .iter()
            .zip(&widths)
            .map(|(s, w)| format!("{s:>w$}"))
            .collect();
        outln!("{}", line.join("  "))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_bad_ones_are_errors() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert_eq!(parse_size("160X120"), Ok((160, 120)));
        assert!(parse_size("640").is_err());
        assert!(parse_size("0x10").is_err());
        assert!(parse_size("ax10").is_err());
        assert_eq!(parse_size("8192x8"), Ok((8192, 8)));
        for big in ["8193x100", "100x8193", "100000x100000"] {
            assert!(parse_size(big).unwrap_err().contains("8192"), "{big}");
        }
    }

    #[test]
    fn the_whole_step_defaults_to_fewer_particles() {
        assert_eq!(counts(&[], false), vec![200, 1000, 10_000, 100_000]);
        assert_eq!(counts(&[], true), vec![200, 1000, 10_000]);
        assert_eq!(counts(&[50, 7], true), vec![50, 7]);
        assert_eq!(counts(&[50], false), vec![50]);
    }

    #[test]
    fn median_of_durations() {
        let d = |m| Duration::from_millis(m);
        assert_eq!(median(vec![d(3), d(1), d(2)]), d(2));
        assert_eq!(median(Vec::new()), Duration::ZERO);
        assert_eq!(median(vec![d(3), d(1)]), d(2));
        assert_eq!(
            median(vec![d(4), d(1), d(2), d(3)]),
            Duration::from_micros(2500)
        );
    }
}

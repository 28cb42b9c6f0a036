//! `pftrack bench`: times the likelihood pass stage by stage, CPU and GPU, on a synthetic
//! frame made in code (no data needed).

use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use pftrack::likelihood::cpu::CpuEngine;
use pftrack::likelihood::gpu::workload::{particles, workload};
use pftrack::likelihood::gpu::{GpuEngine, StageTimes, TimingSource};
use pftrack::likelihood::{Backend, FrameInput, LikelihoodEngine, LikelihoodError};

/// Arguments of `pftrack bench`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct BenchArgs {
    /// Particle counts, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "200,1000,10000,100000")]
    pub particles: Vec<usize>,
    /// Frame size `WxH`.
    #[arg(long, default_value = "160x120", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Which engines to time: `auto` = CPU and, when an adapter exists, GPU.
    #[arg(long, default_value = "auto")]
    pub backend: Backend,
    /// Timed runs per measurement (the median is printed), after one warm-up run.
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size {s:?} is not WxH"))?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("bad width in {s:?}"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("bad height in {s:?}"))?;
    if w < 8 || h < 8 {
        return Err(format!("size {s:?}: at least 8x8"));
    }
    Ok((w, h))
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v.get(v.len() / 2).copied().unwrap_or_default()
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
    if args.particles.is_empty() || args.particles.contains(&0) {
        anyhow::bail!("--particles needs positive counts");
    }
    let repeats = args.repeats.max(1);
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
                println!("note: no GPU timings ({e})");
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

    println!(
        "likelihood pass: {width}x{height} frame, {} normal lines, {} features, median of {repeats} runs (ms)",
        w.params.num_lines,
        w.features.len()
    );
    if want_cpu {
        println!("cpu: {} thread(s) available", cpu_all.threads());
    }
    if let Some(g) = &gpu {
        let how = if g.has_timestamps() {
            "kernels timed by GPU timestamp queries"
        } else {
            "no timestamp queries: kernels timed by the wall clock, one submission each"
        };
        println!("gpu: {} ({how})", g.name());
    }

    let mut header = vec!["N".to_string()];
    if want_cpu {
        header.push("cpu 1t".into());
        header.push(format!("cpu {}t", cpu_all.threads()));
    }
    let mut stage_names: Vec<&str> = Vec::new();
    let mut rows = Vec::new();
    for &n in &args.particles {
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
    let widths: Vec<usize> = (0..header.len())
        .map(|i| {
            rows.iter()
                .filter_map(|r| r.get(i))
                .chain([&header[i]])
                .map(|s| s.len())
                .max()
                .unwrap_or(0)
        })
        .collect();
    let line = |r: &[String]| {
        r.iter()
            .enumerate()
            .map(|(i, s)| format!("{:>w$}", s, w = widths.get(i).copied().unwrap_or(0)))
            .collect::<Vec<_>>()
            .join("  ")
    };
    println!("{}", line(&header));
    for r in &rows {
        println!("{}", line(r));
    }
    if gpu.is_some() {
        println!(
            "gpu = one plain evaluate (upload, all kernels, readback); gpu/cpu = gpu over the faster CPU column; \
             upload and readback are host wall-clock, kernels from timestamps"
        );
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
    }

    #[test]
    fn median_of_durations() {
        let d = |m| Duration::from_millis(m);
        assert_eq!(median(vec![d(3), d(1), d(2)]), d(2));
        assert_eq!(median(Vec::new()), Duration::ZERO);
    }
}

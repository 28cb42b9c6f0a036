//! The `pftrack` command line. Each subcommand lives in its own module; errors are printed as
//! one line (with their context chain) and exit with status 1.

mod bench;
mod demo;
mod eval;
mod pose;
mod pose_noise;
mod sift;
mod synth;
mod track;

use clap::{Parser, Subcommand};

/// Joint video tracking and 3D pose estimation of a rigid object.
#[derive(Debug, Parser)]
#[command(name = "pftrack", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Render the default synthetic scenario, track it and print the error table.
    Demo(demo::DemoArgs),
    /// Track an object through a video and write its pose per frame.
    Track(Box<track::TrackArgs>),
    /// Render a synthetic sequence with exact ground truth.
    Synth(synth::SynthArgs),
    /// Score an estimate against ground truth.
    Eval(eval::EvalArgs),
    /// Export SIFT keypoints and descriptors of an image.
    Sift(sift::SiftArgs),
    /// Estimate the rotation between two images.
    Pose(pose::PoseArgs),
    /// Reproduce the paper's Fig. 3: rotation error against noise, per solver.
    PoseNoise(pose_noise::PoseNoiseArgs),
    /// Time the likelihood pass stage by stage on the CPU and the GPU.
    Bench(bench::BenchArgs),
}

fn main() {
    // Mesa's device-select layer prints "error: XDG_RUNTIME_DIR is invalid or not set" for each
    // Vulkan instance on a headless machine, which reads as pftrack's own error. pftrack
    // chooses its adapter itself (PFTRACK_ADAPTER), so the layer is off unless the user set
    // NODEVICE_SELECT.
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: the first statement of `main`, before any thread exists.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Track(a) => track::run(*a),
        Command::Synth(a) => synth::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Sift(a) => sift::run(a),
        Command::Pose(a) => pose::run(a),
        Command::PoseNoise(a) => pose_noise::run(a),
        Command::Bench(a) => bench::run(a),
    };
    if let Err(e) = result {
        // One line: the error and its causes joined.
        let msg = e
            .chain()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(": ");
        eprintln!("pftrack: error: {msg}");
        std::process::exit(1);
    }
}

//! The `pftrack` command line. Each subcommand lives in its own module; errors are printed as
//! one line (with their context chain) and exit with status 1, or 2 for a command line that is
//! malformed or lacks what the command needs.
//!
//! Output goes through [`outln!`] and [`out!`], which return an error where `println!` would
//! panic (standard output on a full disk, `> /dev/full`); a reader that closed the pipe
//! (`pftrack eval ... | head -1`) ends the command quietly, as it does `cat`. Notes on
//! standard error go through [`errln!`], which cannot fail the command.

/// `println!` that returns `anyhow::Result<()>`: an error writing standard output is returned.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` that returns `anyhow::Result<()>` (see [`outln!`]).
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::write_stdout(format_args!($($arg)*))
    };
}

/// `eprintln!` that ignores a failure to write standard error instead of panicking, and
/// keeps its message to one line: control characters in it (a file name holding a newline)
/// are escaped, as in an error ([`escape_controls`]).
macro_rules! errln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let line = crate::escape_controls(&format!($($arg)*));
        let _ = writeln!(std::io::stderr(), "{line}");
    }};
}

mod bench;
mod demo;
mod eval;
mod paths;
mod pose;
mod pose_noise;
mod settings;
mod sift;
mod synth;
mod track;
mod values;

use std::io::{IsTerminal as _, Write as _};

use clap::error::ErrorKind;
use clap::{Parser, Subcommand};

/// Writing standard output failed.
#[derive(Debug, thiserror::Error)]
#[error("writing to standard output: {0}")]
struct StdoutError(std::io::Error);

/// A command line that parses but lacks what the command needs, which clap cannot say (a
/// start is required unless the input is a synth folder): a usage error, exit status 2.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
struct UsageError(String);

/// Writes to standard output (for [`outln!`] and [`out!`]).
fn write_stdout(args: std::fmt::Arguments<'_>) -> anyhow::Result<()> {
    std::io::stdout()
        .lock()
        .write_fmt(args)
        .map_err(|e| StdoutError(e).into())
}

/// Writes out what standard output holds, its error reported as [`write_stdout`]'s are.
fn flush_stdout() -> anyhow::Result<()> {
    std::io::stdout().flush().map_err(|e| StdoutError(e).into())
}

/// Joint video tracking and 3D pose estimation of a rigid object.
#[derive(Debug, Parser)]
#[command(name = "pftrack", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Render a synthetic scenario (nod by default), track it and print the error table.
    Demo(demo::DemoArgs),
    /// Track an object through a video and write its pose per frame.
    Track(Box<track::TrackArgs>),
    /// Render a synthetic sequence with exact ground truth.
    Synth(synth::SynthArgs),
    /// Score an estimate against ground truth.
    Eval(eval::EvalArgs),
    /// Export SIFT keypoints and descriptors of an image.
    Sift(sift::SiftArgs),
    /// Estimate the rotation between two images, and its Necker mirror (tilt and pan of the
    /// other sign); the first printed is the branch the features' parallax shows.
    Pose(pose::PoseArgs),
    /// Reproduce the paper's Fig. 3: rotation error against noise, per solver.
    PoseNoise(pose_noise::PoseNoiseArgs),
    /// Time the likelihood pass stage by stage on the CPU and the GPU.
    Bench(bench::BenchArgs),
    /// Print the tracker's default settings as JSON, to edit for `track --config` (angles in
    /// degrees, under names ending in `_deg`; the rest as the rustdoc of `TrackerConfig`
    /// gives them).
    Settings(settings::SettingsArgs),
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
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => usage_error(e),
    };
    on_interrupt_remove_partial_outputs();
    let result = match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Track(a) => track::run(*a),
        Command::Synth(a) => synth::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Sift(a) => sift::run(a),
        Command::Pose(a) => pose::run(a),
        Command::PoseNoise(a) => pose_noise::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Settings(a) => settings::run(a),
    };
    // What is still buffered is written now, where its error can be reported.
    let result = result.and_then(|()| flush_stdout());
    if let Err(e) = result {
        let closed = e.chain().any(closed_pipe);
        if closed {
            // The reader stopped reading: it has what it wanted.
            exit(0);
        }
        // One line: the error and its causes joined.
        let msg = compact_numbers(&one_line_chain(
            e.chain().map(|c| in_cli_terms(&c.to_string())),
        ));
        errln!("pftrack: error: {msg}");
        let usage = e.chain().any(|c| c.is::<UsageError>());
        exit(if usage { 2 } else { 1 });
    }
    exit(0);
}

/// Set in the signal handler itself, at the moment an interrupt arrives.
#[cfg(unix)]
static INTERRUPTED: std::sync::OnceLock<std::sync::Arc<std::sync::atomic::AtomicBool>> =
    std::sync::OnceLock::new();

/// Ends the process with `code`, unless an interrupt has arrived: then the interrupt's
/// handler ends it (by the signal, after its clean-up), however far the run had got. A
/// signal during the last moves of a run (its outputs' commit, which holds the clean-up
/// back) used to be lost when the run ended first, with status 0.
fn exit(code: i32) -> ! {
    #[cfg(unix)]
    if INTERRUPTED
        .get()
        .is_some_and(|f| f.load(std::sync::atomic::Ordering::SeqCst))
    {
        loop {
            std::thread::park();
        }
    }
    std::process::exit(code)
}

/// On Ctrl-C, `kill` (SIGTERM) or a closed terminal (SIGHUP): removes the outputs still in
/// progress (partial files, the render's staging folder), says so, and ends the process by
/// that signal's default action, so an interrupted run leaves the places it writes to as it
/// found them, as a failed one does, and a shell sees it killed by the signal (status 130 for
/// Ctrl-C; a loop over files stops). Where no handler can be installed the signals keep their
/// default action.
#[cfg(unix)]
fn on_interrupt_remove_partial_outputs() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    // A signal ignored from the start (`nohup`, a background job of a script) stays ignored:
    // catching it would end a run its caller asked to survive it.
    let caught: Vec<i32> = [SIGINT, SIGTERM, SIGHUP]
        .into_iter()
        .filter(|&s| !ignored(s))
        .collect();
    let Ok(mut signals) = signal_hook::iterator::Signals::new(&caught) else {
        return;
    };
    let flag = INTERRUPTED.get_or_init(Default::default);
    for &s in &caught {
        // Where this fails the run still ends by the iterator's thread below, only not
        // waited for at the very end.
        let _ = signal_hook::flag::register(s, std::sync::Arc::clone(flag));
    }
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            // A second signal ends the process at once, should the clean-up or the message
            // below block (on a stalled standard error, say).
            for &s in &caught {
                // SAFETY: restoring a signal's default action; no handler runs Rust code.
                unsafe { libc::signal(s, libc::SIG_DFL) };
            }
            pftrack::io::remove_partial_outputs();
            // On a terminal a progress bar may hold the line: start a fresh one.
            let fresh = if std::io::stderr().is_terminal() {
                "\n"
            } else {
                ""
            };
            errln!("{fresh}pftrack: interrupted");
            let _ = signal_hook::low_level::emulate_default_handler(signal);
            std::process::exit(128 + signal);
        }
    });
}

/// Whether `signal` is ignored (`SIG_IGN`), as a process started by `nohup` finds SIGHUP.
#[cfg(unix)]
fn ignored(signal: i32) -> bool {
    // SAFETY: `sigaction` with a null new action only reads the current one into `old`, a
    // zeroed `sigaction` owned here.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(signal, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_IGN
    }
}

/// Elsewhere the signals keep their default action.
#[cfg(not(unix))]
fn on_interrupt_remove_partial_outputs() {}

/// Whether `e` is a write to a pipe whose reader has gone, on standard output or on an
/// output file that is a pipe (`-o /dev/stdout | head -1`).
fn closed_pipe(e: &(dyn std::error::Error + 'static)) -> bool {
    let pipe = |io: &std::io::Error| io.kind() == std::io::ErrorKind::BrokenPipe;
    e.downcast_ref::<StdoutError>().is_some_and(|s| pipe(&s.0))
        || e.downcast_ref::<std::io::Error>().is_some_and(pipe)
        || matches!(
            e.downcast_ref::<pftrack::io::FormatError>(),
            Some(pftrack::io::FormatError::Io { cause, .. }) if pipe(cause)
        )
}

/// An error and its causes joined with `: `, leaving out a cause whose text the message
/// already ends with (some errors, the image crate's among them, repeat their source's text
/// in their own), and with control characters escaped: a file name holding a newline split
/// the message over two lines.
fn one_line_chain(chain: impl Iterator<Item = String>) -> String {
    let mut msg = String::new();
    for c in chain {
        if msg.is_empty() {
            msg = c;
        } else if !msg.ends_with(c.as_str()) {
            msg.push_str(": ");
            msg.push_str(&c);
        }
    }
    escape_controls(&msg)
}

/// `text` with its control characters escaped (`\n`, `\u{1b}`), so that it prints as one
/// line and cannot move a terminal's cursor.
fn escape_controls(text: &str) -> String {
    text.chars()
        .map(|c| {
            if c.is_control() {
                c.escape_default().to_string()
            } else {
                c.to_string()
            }
        })
        .collect()
}

/// The library's messages name its API where a user of the command line wants the flag:
/// `Backend::Cpu` is `--backend cpu` here, `Backend::Gpu` is `--backend gpu`.
fn in_cli_terms(msg: &str) -> String {
    msg.replace("Backend::Cpu", "`--backend cpu`")
        .replace("Backend::Gpu", "`--backend gpu`")
        .replace(" (SiftParams::max_scale_space_bytes)", "")
        .replace("(SourceOptions::resize)", "(--resize)")
}

/// The message with every number written in more than 24 characters put in exponent form:
/// Rust writes an `f64` in full, so a 1e308 given for a size came back as 309 digits, and
/// 1e-300 as 300 zeros. Only a number standing alone is touched (after a space, a bracket, a
/// comma, `=`, `:` or a quote, and before one, a full stop or the end), and nothing before
/// the first `": "`, where a message names its file: digits inside a name
/// (`run_20240101120000000000000001/video.mp4`, or a name all digits) are left as written,
/// and neither is a number a colon follows, which names a file after a context.
fn compact_numbers(msg: &str) -> String {
    // What comes before the first ": " is a path or a flag, as given: left alone.
    let (lead, msg) = msg.split_at(msg.find(": ").unwrap_or(0));
    let apart = |c: Option<char>| c.is_none_or(|c| c.is_whitespace() || "()[],;:='\"".contains(c));
    let mut out = String::from(lead);
    let mut rest = msg;
    while let Some(start) = rest.find(|c: char| c.is_ascii_digit()) {
        out.push_str(&rest[..start]);
        let mut back = out.chars().rev();
        let before = back.next();
        // A minus sign belongs to the number when it stands alone itself.
        let alone_before = apart(before) || (before == Some('-') && apart(back.next()));
        let run = &rest[start..];
        let len = run
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(run.len());
        let (num, after) = run.split_at(len);
        // A sentence's full stop after a number is not part of it.
        let (num, dot) = match num.strip_suffix('.') {
            Some(n) => (n, "."),
            None => (num, ""),
        };
        // Followed by a colon it is what a message names (a file named in digits after a
        // context: `reading the truth: 1000...0001: no such file`), never a value.
        let alone_after =
            (apart(after.chars().next()) && !after.starts_with(':')) || after.starts_with('°');
        match num.parse::<f64>() {
            Ok(v) if num.len() > 24 && alone_before && alone_after => {
                out.push_str(&format!("{v:e}"));
            }
            _ => out.push_str(num),
        }
        out.push_str(dot);
        rest = after;
    }
    out.push_str(rest);
    out
}

/// Prints a command-line usage error as one line, `pftrack: error: ...` with clap's tip and a
/// pointer to the help, and exits with status 2 (clap's own for usage errors); help and
/// version requests print as clap prints them, with a failure to write them reported.
fn usage_error(e: clap::Error) -> ! {
    match e.kind() {
        // Help and version go to standard output: a write error is reported (clap's own
        // `exit` would end with 0 and nothing said), a closed pipe ends quietly.
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => {
            match e.print().and_then(|()| std::io::stdout().flush()) {
                Err(err) if err.kind() != std::io::ErrorKind::BrokenPipe => {
                    errln!("pftrack: error: writing to standard output: {err}");
                    std::process::exit(1);
                }
                _ => std::process::exit(0),
            }
        }
        ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => e.exit(),
        _ => {
            errln!("pftrack: error: {}", one_line(&e.render().to_string()));
            std::process::exit(2);
        }
    }
}

/// clap's rendered message on one line: the lines before its usage block, trimmed and joined,
/// without the leading `error: `, and the usage's command pointed to for help.
fn one_line(rendered: &str) -> String {
    let mut parts = Vec::new();
    let mut help = None;
    for line in rendered.lines() {
        let line = line.trim();
        if let Some(usage) = line.strip_prefix("Usage: ") {
            // "pftrack track [OPTIONS] <INPUT>": the command is the words before the first
            // placeholder.
            let cmd: Vec<&str> = usage
                .split_whitespace()
                .take_while(|w| !w.starts_with(['[', '<', '-']))
                .collect();
            help = Some(format!("see '{} --help'", cmd.join(" ")));
            break;
        }
        if !line.is_empty() && !line.starts_with("For more information") {
            parts.push(line.strip_prefix("error: ").unwrap_or(line).to_string());
        }
    }
    parts.extend(help);
    // A list after a colon (the missing arguments) continues its sentence.
    let mut out = String::new();
    for p in parts {
        if !out.is_empty() {
            out.push_str(if out.ends_with(':') { " " } else { "; " });
        }
        out.push_str(&p);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn library_names_become_flags() {
        let e = pftrack::likelihood::LikelihoodError::DeviceLost("Destroyed".into());
        assert_eq!(
            in_cli_terms(&e.to_string()),
            "GPU device lost (Destroyed); rerun on the CPU engine (`--backend cpu`)"
        );
        assert_eq!(in_cli_terms("no Backend here"), "no Backend here");
    }

    #[test]
    fn long_numbers_are_written_in_exponent_form() {
        let big = format!("contrast weight {} is not in [0, 1e6]", 1e300);
        assert_eq!(
            compact_numbers(&big),
            "contrast weight 1e300 is not in [0, 1e6]"
        );
        let small = format!("camera hfov {}.", 1e-300);
        assert_eq!(compact_numbers(&small), "camera hfov 1e-300.");
        let tiny = format!("a {} b", 1.5e-30);
        assert_eq!(compact_numbers(&tiny), "a 1.5e-30 b");
        let neg = format!("weight {} is not in [0, 1e6]", -1e300);
        assert_eq!(compact_numbers(&neg), "weight -1e300 is not in [0, 1e6]");
        let angle = format!("hfov {}°), poses", 1e300);
        assert_eq!(compact_numbers(&angle), "hfov 1e300°), poses");
        for kept in [
            "frames/00012.png: 160x120, 3.25 px, 1.0. 12345678901234567890 ok",
            "",
            "no digits",
            "v1.2.3",
            "run_20240101120000000000000001/video.mp4: no such file or directory",
            "/data/20240101120000000000000001.mp4: no such file",
            "x-20240101120000000000000001 and 20240101120000000000000001a",
            "192.168.100.200",
            "1000000000000000000000000000001: no such file or directory",
            "my 1000000000000000000000000000001: no such file or directory",
            "reading the truth: 1000000000000000000000000000001: no such file or directory",
        ] {
            assert_eq!(compact_numbers(kept), kept);
        }
    }

    #[test]
    fn a_repeated_cause_is_said_once() {
        let chain = [
            "cannot read x.png",
            "Format error: bad signature",
            "bad signature",
        ];
        assert_eq!(
            one_line_chain(chain.iter().map(|s| s.to_string())),
            "cannot read x.png: Format error: bad signature"
        );
        let chain = ["reading the truth", "t.csv: no such file"];
        assert_eq!(
            one_line_chain(chain.iter().map(|s| s.to_string())),
            "reading the truth: t.csv: no such file"
        );
        // A name with a newline or a tab stays on the line, escaped; other text as it is.
        let chain = ["cannot read a\nb.png\t", "naïve: no such file"];
        assert_eq!(
            one_line_chain(chain.iter().map(|s| s.to_string())),
            "cannot read a\\nb.png\\t: naïve: no such file"
        );
    }

    #[test]
    fn clap_messages_become_one_line() {
        let rendered = "error: unexpected argument '--bogus' found\n\n  tip: to pass '--bogus' as a \
                        value, use '-- --bogus'\n\nUsage: pftrack track [OPTIONS] <INPUT>\n\nFor \
                        more information, try '--help'.\n";
        assert_eq!(
            one_line(rendered),
            "unexpected argument '--bogus' found; tip: to pass '--bogus' as a value, use \
             '-- --bogus'; see 'pftrack track --help'"
        );
        let missing = "error: the following required arguments were not provided:\n  <INPUT>\n\n\
                       Usage: pftrack track <INPUT>\n\nFor more information, try '--help'.\n";
        assert_eq!(
            one_line(missing),
            "the following required arguments were not provided: <INPUT>; see 'pftrack track --help'"
        );
    }
}

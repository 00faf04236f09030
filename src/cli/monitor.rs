//! `chaoscope monitor [RUN]`: attach to a running producer from a separate process and follow
//! the run live (curves, progress, current values), with the same analysis code as `analyze`.
//!
//! The monitor reads the producer's lossy monitor stream, so it can never slow the producer; it
//! may attach late and detach at any time (q, Ctrl+C), and exits when the run ends. Frames it
//! missed are counted and make its results "incomplete" (Lyapunov exponents then average the
//! intervals it saw; GALI and SALI are instantaneous and exact whenever the latest sample
//! arrived).
//!
//! `--foxglove [ADDR]` also serves the run over the Foxglove WebSocket protocol
//! ([`super::monitor_foxglove`]).

use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::ops::ControlFlow;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use chaoscope_analyzer::analysis::{Analysis, AnalysisOptions};
use chaoscope_analyzer::assemble::SampleAssembler;
use chaoscope_analyzer::progress::Progress;
use chaoscope_analyzer::run_info::RunInfo;
use chaoscope_bus::monitor::{LiveEnded, LiveEvent, LiveRun};
use chaoscope_bus::{self as bus, Liveness};
use chaoscope_schemas::names;
use chaoscope_schemas::proto::EndOfRun;

use super::monitor_foxglove::{self, FoxgloveServer};
use super::monitor_view::TerminalView;

#[derive(clap::Args)]
pub struct Args {
    /// Run to follow; default: the only live run (waits for one to appear).
    pub run: Option<String>,
    /// Stream one JSON object per update on stdout (the last one has "final": true if the run
    /// ended; a monitor stopped by a signal or detached says "interrupted" or "detached" instead).
    #[arg(long)]
    pub json_lines: bool,
    /// Seconds between updates.
    #[arg(long, default_value = "1", value_parser = super::parse_seconds)]
    pub interval: Duration,
    /// Give up if no run (or no run header) appears within this many seconds.
    #[arg(long, default_value = "30", value_parser = super::parse_seconds)]
    pub wait_timeout: Duration,
    /// Plain text lines even on a terminal (no full-screen view).
    #[arg(long)]
    pub plain: bool,
    /// Also serve the run over the Foxglove WebSocket protocol on ADDR (default
    /// 127.0.0.1:8765; port 0 picks a free one): open it in Foxglove or Lichtblick.
    #[arg(long, value_name = "ADDR", num_args = 0..=1,
          default_missing_value = monitor_foxglove::DEFAULT_ADDR)]
    pub foxglove: Option<SocketAddr>,
}

fn find_run(timeout: Duration) -> anyhow::Result<String> {
    let start = Instant::now();
    loop {
        let live: Vec<String> = bus::list_runs()
            .into_iter()
            .filter(|r| bus::node_liveness(&names::producer_node_name(r)) == Liveness::Alive)
            .collect();
        match live.len() {
            1 => return Ok(live[0].clone()),
            0 if start.elapsed() < timeout => std::thread::sleep(bus::POLL_INTERVAL),
            0 => bail!("no live run appeared within {timeout:?}"),
            _ => bail!("several runs are live ({}); name one", live.join(", ")),
        }
    }
}

enum View {
    JsonLines,
    Plain,
    Terminal(Box<TerminalView>),
}

/// One update as a JSON object: the same `run` and `schemes` as `analyze --json`, plus
/// progress fields.
fn json_line(
    analysis: &Analysis,
    progress: &Progress,
    live: &LiveRun,
    last: Option<Last>,
    end: Option<&EndOfRun>,
) -> serde_json::Value {
    // As `analyze` reports a finished recording: how the producer ended the run.
    let mut v = serde_json::to_value(analysis.report_ended(end)).expect("reports serialize");
    let step = analysis.step();
    let obj = v.as_object_mut().expect("a report is an object");
    // "final" only when the run is over: a monitor that stops following a run still going
    // says why it stopped instead.
    obj.insert("final".into(), (last == Some(Last::RunOver)).into());
    if last.is_some() {
        obj.insert(
            "interrupted".into(),
            (last == Some(Last::Interrupted)).into(),
        );
        obj.insert("detached".into(), (last == Some(Last::Detached)).into());
    }
    obj.insert(
        "progress".into(),
        serde_json::json!({
            "t": analysis.t(),
            "step": step,
            "fraction": progress.fraction(step),
            "steps_per_s": progress.steps_per_second(),
            "eta_s": progress.eta_seconds(step),
            "frames_received": live.frames_received(),
            "frames_lost": live.frames_lost(),
            "frames_before_attach": live.frames_before_attach(),
            "status": end.map(|e| e.status().word()),
        }),
    );
    v
}

/// Why the monitor's last line is its last.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Last {
    /// The run ended (its end record arrived, or its producer is gone).
    RunOver,
    /// SIGINT or SIGTERM stopped the monitor while the run went on.
    Interrupted,
    /// The user detached from the terminal view (`q`).
    Detached,
}

fn plain_line(analysis: &Analysis, progress: &Progress, live: &LiveRun) -> String {
    let step = analysis.step();
    let report = analysis.report();
    let mut s = format!(
        "t = {:.2} ({:.1} %), {:.0} steps/s, ETA {}, lost frames {}",
        analysis.t(),
        100.0 * progress.fraction(step),
        progress.steps_per_second().unwrap_or(0.0),
        progress
            .eta_seconds(step)
            .map_or("?".into(), |e| format!("{e:.0} s")),
        live.frames_lost()
    );
    for sc in report.schemes.iter().take(6) {
        let g: Vec<String> = sc
            .gali
            .0
            .iter()
            .map(|(j, g)| format!("G{j} {:.2}", g.log10_mean))
            .collect();
        s += &format!(" | {}: {} MLE {:.4}", sc.name, g.join(" "), sc.mle);
    }
    s
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    // Serving before the run appears, so a client can connect and wait for its channels.
    let foxglove = args.foxglove.map(FoxgloveServer::start).transpose()?;
    let run = match args.run {
        Some(r) => r,
        None => find_run(args.wait_timeout)?,
    };
    let Some((live, header)) = LiveRun::connect(&run, args.wait_timeout)? else {
        return Ok(super::exit_interrupted());
    };
    let mut channels = match &foxglove {
        Some(server) => Some(server.channels(&header)?),
        None => None,
    };
    let info = RunInfo::from_header(header).context("run header")?;
    let total_steps = info.header.total_steps;
    chaoscope_os::errln!("chaoscope monitor: attached to run {run}");
    let mut analysis = Analysis::new(
        info,
        &AnalysisOptions {
            series_capacity: 1000,
            per_decade: 20,
            ..chaoscope_app::flow::analysis_options()
        },
    );
    let mut view = if args.json_lines {
        View::JsonLines
    } else if args.plain || !std::io::stdout().is_terminal() {
        View::Plain
    } else {
        View::Terminal(Box::new(TerminalView::start()?))
    };
    let mut assembler = SampleAssembler::new();
    let mut progress = Progress::new(total_steps);
    let start = Instant::now();
    let mut last_update: Option<Instant> = None;
    let mut end: Option<EndOfRun> = None;
    let mut detached = false;
    let mut out_error: Option<std::io::Error> = None;
    let tick = args.interval.min(Duration::from_millis(100));
    let ended = live.receive(tick, |event| {
        if let LiveEvent::Message(m) = event {
            if let Some(c) = &mut channels {
                c.on_message(&m);
            }
            let (sample, e) = assembler.push(m);
            if let Some(s) = sample {
                analysis.feed(&s);
            }
            if e.is_some() {
                end = e;
                return ControlFlow::Break(());
            }
        }
        if let View::Terminal(t) = &mut view
            && t.quit_requested()
        {
            detached = true;
            return ControlFlow::Break(());
        }
        if last_update.is_none_or(|l| l.elapsed() >= args.interval) {
            last_update = Some(Instant::now());
            progress.observe(analysis.step(), start.elapsed());
            if live.missed_any() {
                analysis.mark_gap();
            }
            let result = match &mut view {
                View::JsonLines => writeln!(
                    std::io::stdout().lock(),
                    "{}",
                    json_line(&analysis, &progress, &live, None, None)
                ),
                View::Plain => writeln!(
                    std::io::stdout().lock(),
                    "{}",
                    plain_line(&analysis, &progress, &live)
                ),
                View::Terminal(t) => t.draw(&analysis, &progress, live.frames_lost()),
            };
            if let Err(e) = result {
                out_error = Some(e);
                return ControlFlow::Break(());
            }
        }
        ControlFlow::Continue(())
    })?;
    if let Some(s) = assembler.finish() {
        analysis.feed(&s);
    }
    if live.missed_any() {
        analysis.mark_gap();
    }
    if let View::Terminal(t) = view {
        t.stop()?;
    }
    if let Some(c) = &mut channels {
        c.finish();
    }
    if let Some(server) = foxglove {
        server.stop();
    }
    if let Some(e) = out_error {
        // A closed pipe ends the monitor quietly, a failed write with one line (`main`).
        return Err(chaoscope_os::stdout::StdoutError::from(e).into());
    }
    let how = match (ended, &end, detached) {
        (_, _, true) | (LiveEnded::Signal, _, _) => "detached",
        (_, Some(e), _) => e.status().word(),
        (LiveEnded::ProducerGone, None, _) => "producer gone",
        _ => "stopped",
    };
    let last = match (ended, &end, detached) {
        // An end record that arrived wins over a signal that came after it.
        (_, Some(_), _) => Last::RunOver,
        (_, _, true) => Last::Detached,
        (LiveEnded::Signal, _, _) => Last::Interrupted,
        _ => Last::RunOver,
    };
    if args.json_lines {
        chaoscope_os::outln!(
            "{}",
            json_line(&analysis, &progress, &live, Some(last), end.as_ref())
        )?;
    } else {
        super::analyze::print_table(&analysis.report())?;
    }
    let before = match live.frames_before_attach() {
        0 => String::new(),
        n => format!(" ({n} published before it attached)"),
    };
    chaoscope_os::errln!(
        "chaoscope monitor: run {run} {how}; {} frames received{before}, {} missed",
        live.frames_received(),
        live.frames_lost()
    );
    Ok(if ended == LiveEnded::Signal {
        super::exit_interrupted()
    } else {
        ExitCode::SUCCESS
    })
}

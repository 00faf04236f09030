//! `chaoscope run [CONFIG] [--out FILE.mcap]`: the producer and the recorder as two OS
//! processes (this executable's `produce` and `record`), connected only over iceoryx2; waits
//! for both, then prints the analysis summary of the recording.

use std::io::Write;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::Duration;

use anyhow::{Context, bail};
use chaoscope_producer::resolve_run_name;
use chaoscope_schemas::config::RunConfig;

/// The paper's chaotic Henon-Heiles orbit, run when no CONFIG is given.
pub const DEFAULT_CONFIG: &str = include_str!("hh_chaotic.toml");

#[derive(clap::Args)]
pub struct Args {
    /// Run configuration (TOML); default: the paper's chaotic Henon-Heiles orbit.
    pub config: Option<PathBuf>,
    /// Output MCAP file; default: `runs/<run name>.mcap`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run name; default: `[run] name` of the config, or generated.
    #[arg(long)]
    pub run: Option<String>,
    /// Replace the output file if it exists, and start even a run estimated to take more than a
    /// day or more memory than the machine has.
    #[arg(long)]
    pub force: bool,
}

/// A child process that is signalled and reaped if we bail out early.
struct Role {
    name: &'static str,
    child: Child,
    status: Option<std::process::ExitStatus>,
}

/// What wakes the supervision loop of `run` before its poll interval is over.
enum Wake {
    /// The producer said it opened the run's services: the recorder can start.
    Opened,
    /// A child exited (or could not be waited for): it is reaped at once.
    Exited,
}

impl Role {
    /// Starts `command`; `wake` hears of its exit.
    fn spawn(
        name: &'static str,
        mut command: Command,
        wake: &std::sync::mpsc::Sender<Wake>,
    ) -> anyhow::Result<Self> {
        let child = command
            .spawn()
            .with_context(|| format!("starting the {name} process"))?;
        let (pid, wake) = (child.id(), wake.clone());
        // Waits for the exit without reaping the child (WNOWAIT): the loop's `try_wait` reaps
        // it, so its pid stays this process's child until then and names no other process. The
        // thread ends with the child (or at once, if the loop reaped it first: ECHILD). A thread
        // that cannot be made costs only the wake-up: the loop still polls every interval.
        let _ = std::thread::Builder::new().spawn(move || {
            // SAFETY: waitid(2) with a zeroed siginfo_t, which it only writes.
            let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
            while unsafe {
                libc::waitid(
                    libc::P_PID,
                    pid as libc::id_t,
                    &mut info,
                    libc::WEXITED | libc::WNOWAIT,
                )
            } != 0
                && std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted
            {
            }
            let _ = wake.send(Wake::Exited);
        });
        Ok(Self {
            name,
            child,
            status: None,
        })
    }

    fn signal(&self, signal: i32) {
        if self.status.is_none() {
            // SAFETY: kill(2) on the pid of our own, not yet reaped, child.
            unsafe { libc::kill(self.child.id() as i32, signal) };
        }
    }

    fn poll(&mut self) -> anyhow::Result<bool> {
        if self.status.is_none() {
            self.status = self
                .child
                .try_wait()
                .with_context(|| format!("waiting for the {}", self.name))?;
        }
        Ok(self.status.is_some())
    }
}

impl Drop for Role {
    fn drop(&mut self) {
        if self.status.is_none() {
            self.signal(libc::SIGTERM);
            let _ = self.child.wait();
        }
    }
}

fn child_command(subcommand: &str) -> anyhow::Result<Command> {
    let exe = std::env::current_exe().context("locating the chaoscope executable")?;
    let mut command = Command::new(exe);
    command.arg(subcommand).stdout(Stdio::piped());
    let pause = spawn_pause(subcommand)?;
    // If this process is killed (SIGKILL cannot be forwarded), the children get SIGTERM from
    // the kernel and finalize their files as on Ctrl-C, instead of running on as orphans.
    let parent = std::process::id();
    // A SIGINT this process ignores (it was started so) the children ignore too: a Ctrl-C meant
    // for someone else reaches the whole process group.
    let sigint = if chaoscope_os::signals::sigint_ignored_at_start() {
        libc::SIG_IGN
    } else {
        libc::SIG_DFL
    };
    // SAFETY: only async-signal-safe calls (signal, prctl, getppid, raise, nanosleep) between
    // fork and exec.
    unsafe {
        command.pre_exec(move || {
            // Until exec the child runs this process's handlers, which would latch SIGINT or
            // SIGTERM in memory exec then discards: the parent-death signal, caught so, never
            // reached the child's own latch, and a recorder whose producer was gone waited
            // for it for ever. With the default action such a signal ends the child before
            // it starts anything; after exec chaoscope's handlers are its own.
            libc::signal(libc::SIGINT, sigint);
            libc::signal(libc::SIGTERM, libc::SIG_DFL);
            pause_at(pause, PausePoint::BeforeDeathSignal);
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent died before prctl took effect: act as if the signal came.
            if libc::getppid() as u32 != parent {
                libc::raise(libc::SIGTERM);
            }
            pause_at(pause, PausePoint::BeforeExec);
            Ok(())
        });
    }
    Ok(command)
}

/// Test seam: `CHAOSCOPE_SPAWN_PAUSE=SUBCOMMAND:POINT:MILLIS` holds the child `run` starts for
/// SUBCOMMAND (`produce`, `record`) for MILLIS between fork and exec, at POINT:
/// `before-pdeathsig` (its parent-death signal not yet set) or `before-exec` (set). A test
/// kills `run` there, where a kill otherwise lands only by chance.
const SPAWN_PAUSE_ENV: &str = "CHAOSCOPE_SPAWN_PAUSE";

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PausePoint {
    BeforeDeathSignal,
    BeforeExec,
}

/// The pause [`SPAWN_PAUSE_ENV`] asks of the child for `subcommand`, read before the fork.
fn spawn_pause(subcommand: &str) -> anyhow::Result<Option<(PausePoint, libc::timespec)>> {
    let Some(value) = std::env::var_os(SPAWN_PAUSE_ENV) else {
        return Ok(None);
    };
    let value = value.to_string_lossy();
    let bad = || {
        anyhow::anyhow!(
            "{SPAWN_PAUSE_ENV}={value:?}: expected SUBCOMMAND:POINT:MILLIS, POINT \
             before-pdeathsig or before-exec"
        )
    };
    let mut parts = value.split(':');
    let (Some(which), Some(point), Some(millis), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(bad());
    };
    let point = match point {
        "before-pdeathsig" => PausePoint::BeforeDeathSignal,
        "before-exec" => PausePoint::BeforeExec,
        _ => return Err(bad()),
    };
    let millis: u32 = millis.parse().map_err(|_| bad())?;
    if which != subcommand {
        return Ok(None);
    }
    let pause = libc::timespec {
        tv_sec: (millis / 1000) as libc::time_t,
        tv_nsec: (millis % 1000) as libc::c_long * 1_000_000,
    };
    Ok(Some((point, pause)))
}

/// Sleeps the whole pause when `at` is its point, through signals that interrupt the sleep
/// (async-signal-safe: only nanosleep).
fn pause_at(pause: Option<(PausePoint, libc::timespec)>, at: PausePoint) {
    let Some((point, mut left)) = pause else {
        return;
    };
    if point != at {
        return;
    }
    // SAFETY: nanosleep with valid pointers; `left` receives what an interruption left.
    while unsafe { libc::nanosleep(&left, &mut left) } != 0
        && std::io::Error::last_os_error().raw_os_error() == Some(libc::EINTR)
    {}
}

pub fn main(args: Args) -> anyhow::Result<ExitCode> {
    let (config, text, source) = match &args.config {
        Some(path) => {
            let (config, text, source) = super::load_config(path)?;
            (config, text, Some(source))
        }
        None => (
            RunConfig::from_toml(DEFAULT_CONFIG)?,
            DEFAULT_CONFIG.to_string(),
            None,
        ),
    };
    // Fail on a bad config or one beyond the machine here, before any process starts (the
    // producer process validates its own copy once more: a process trusts no other).
    let spec =
        chaoscope_dynamics::spec::RunSpec::from_config(&config).map_err(|e| match &source {
            Some(source) => super::invalid_config(source, "run", e),
            None => anyhow::Error::new(e).context("invalid run configuration"),
        })?;
    let machine = super::machine();
    let estimate = chaoscope_producer::estimate::run(&spec, &machine);
    super::check_estimate(&estimate, &machine, args.force, "run")?;
    super::warn_unused_params("run", &config);
    let run = resolve_run_name(&config, args.run.as_deref())?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| Path::new("runs").join(format!("{run}.mcap")));
    // A job Slurm requeued (preempted, or `scontrol requeue`) runs this command again: it
    // continues the recording its first run left instead of refusing or starting over.
    let mut force = args.force;
    if requeued_by_slurm()
        && (std::fs::symlink_metadata(&out).is_ok()
            || std::fs::symlink_metadata(chaoscope_os::output::partial_path(&out)).is_ok())
    {
        match resume_requeued(&config, &out)? {
            Some(code) => return Ok(code),
            // Nothing on disk to continue from: the leftover goes and the run starts afresh.
            None => force = true,
        }
    }
    // What the recorder will refuse, said before anything starts.
    chaoscope_os::output::check_target(
        &out,
        &chaoscope_os::OutputOptions {
            replace: force,
            inputs: args.config.iter().cloned().collect(),
            ..Default::default()
        },
    )?;

    // Ctrl+C reaches the whole process group; SIGTERM (or a SIGINT sent to us alone, unless
    // SIGINT was ignored when we started: then we and the children ignore it) is forwarded to
    // both children, which finalize cleanly.
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);

    // The producer first: the recorder starts once the producer has opened the run's services
    // (it says `open`), so it can only ever record this producer's run, never that of a live
    // producer of the same name, which refuses this one.
    let mut produce = child_command("produce")?;
    produce
        .args(["-", "--run", &run, "--recorders", "1", "--under-run"])
        .stdin(Stdio::piped());
    if force {
        produce.arg("--force");
    }
    let started = std::time::Instant::now();
    // The loop below sleeps until a child exits or the producer opens its services, at most a
    // poll interval (a signal is seen at the latest then): a fixed sleep instead added up to a
    // poll interval to the recorder's start and another to the run's end.
    let (wake, woken) = std::sync::mpsc::channel();
    let mut producer = Role::spawn("producer", produce, &wake)?;
    {
        let mut stdin = producer.child.stdin.take().context("producer stdin")?;
        stdin
            .write_all(text.as_bytes())
            .context("sending the configuration to the producer")?;
    }
    {
        let stdout = producer.child.stdout.take().context("producer stdout")?;
        let wake = wake.clone();
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if line == super::produce::OPEN_LINE {
                    let _ = wake.send(Wake::Opened);
                }
            }
        });
    }
    let mut opened = false;

    let mut recorder: Option<Role> = None;
    let mut forwarded = false;
    let mut recorder_failed = false;
    // This process stopped the recorder because the producer had failed.
    let mut stopped_recorder = false;
    loop {
        let producer_done = producer.poll()?;
        let recorder_done = match &mut recorder {
            Some(r) => r.poll()?,
            None => true,
        };
        if producer_done && recorder_done {
            break;
        }
        let signal = chaoscope_os::signals::received();
        if recorder.is_none() && !producer_done && signal.is_none() && opened {
            let mut record = child_command("record")?;
            record.args(["--run", &run, "--out"]).arg(&out);
            if force {
                record.arg("--force");
            }
            recorder = Some(Role::spawn("recorder", record, &wake)?);
        }
        if let Some(signal) = signal
            && !forwarded
        {
            producer.signal(signal);
            if let Some(r) = &recorder {
                r.signal(signal);
            }
            forwarded = true;
        }
        // A recorder that failed (it said why) leaves nobody to compute for.
        if let Some(r) = &recorder
            && r.status.is_some_and(|s| !s.success())
            && !recorder_failed
        {
            producer.signal(libc::SIGTERM);
            recorder_failed = true;
        }
        // Recorder alone after the producer failed before streaming: do not wait forever.
        if producer.status.is_some_and(|s| !s.success())
            && recorder.as_ref().is_some_and(|r| r.status.is_none())
            && !forwarded
        {
            std::thread::sleep(Duration::from_secs(2));
            if let Some(r) = &recorder {
                // SIGTERM: a SIGINT may be ignored (see `child_command`).
                r.signal(libc::SIGTERM);
                stopped_recorder = true;
            }
            forwarded = true;
        }
        let first = woken.recv_timeout(chaoscope_bus::POLL_INTERVAL).into_iter();
        for event in first.chain(woken.try_iter()) {
            opened |= matches!(event, Wake::Opened);
        }
    }

    let producer_status = producer.status.expect("reaped");
    // A producer killed by a signal (not one of ours: those it exits from with a status) said
    // nothing itself: the line is said here.
    let child_code = |status: std::process::ExitStatus| match status.code() {
        Some(code) => ExitCode::from(code as u8),
        None => {
            if let Some(signal) = std::os::unix::process::ExitStatusExt::signal(&status)
                && chaoscope_os::signals::received().is_none()
            {
                chaoscope_os::errln!(
                    "chaoscope: error: the producer was killed by signal {signal}{}",
                    // The recorder finalized what it got into place (a producer killed
                    // before it streamed leaves no file).
                    if std::fs::symlink_metadata(&out).is_ok() {
                        format!(
                            "; the recording holds the run up to there (`chaoscope resume {}` \
                             continues it)",
                            out.display()
                        )
                    } else {
                        String::new()
                    }
                );
            }
            ExitCode::FAILURE
        }
    };
    let Some(mut recorder) = recorder else {
        // The producer ended before it opened the run (it said why), or a signal came first:
        // nothing was recorded, no file was written.
        return Ok(match chaoscope_os::signals::received() {
            Some(_) => super::exit_interrupted(),
            None if producer_status.success() => ExitCode::FAILURE,
            None => child_code(producer_status),
        });
    };
    let recorder_status = recorder.status.expect("reaped");
    let seconds = started.elapsed().as_secs_f64();
    if !recorder_status.success() {
        if let Some(signal) = std::os::unix::process::ExitStatusExt::signal(&recorder_status) {
            bail!(
                "the recorder was killed by signal {signal}; what it wrote is in {} \
                 (`chaoscope resume {}` continues the run from its complete chunks)",
                chaoscope_os::output::partial_path(&out).display(),
                out.display()
            );
        }
        // It said why on stderr, in one line; the producer was stopped. Or the producer
        // failed (it said why) and the recorder was stopped here: the producer's status.
        return Ok(child_code(if stopped_recorder {
            producer_status
        } else {
            recorder_status
        }));
    }
    // The file at `out` must be the one this run's recorder put there: another writer's
    // `--force` may have replaced it since, and its report would not be this run's.
    let written = written_file(&mut recorder.child)?;
    let still_ours = || -> anyhow::Result<()> {
        let here = std::fs::symlink_metadata(&out).map(|m| {
            use std::os::unix::fs::MetadataExt;
            (m.dev(), m.ino())
        });
        if here.ok() != Some(written) {
            bail!(
                "{} was replaced or removed by another process after this run's recorder \
                 completed it: this run's recording is lost (another writer of that name with \
                 --force?)",
                out.display()
            );
        }
        Ok(())
    };
    still_ours()?;
    // How the recording ended, then the same analysis table as `chaoscope analyze` (one
    // renderer for both commands).
    let summary = chaoscope_analyzer::summary::summarize(&out)?;
    still_ours()?;
    chaoscope_os::outln!(
        "recording: {} (status {}, finalized by {}, {} frames missing) in {} (estimated {})",
        out.display(),
        summary.run_status,
        summary.finalized_by,
        summary.frames_missing,
        super::seconds(seconds),
        super::seconds(estimate.seconds + chaoscope_dynamics::estimate::RUN_START_SECONDS)
    )?;
    // Stopped by a signal: end now (reading a long recording takes time); `chaoscope analyze`
    // gives the table later.
    if chaoscope_os::signals::requested() {
        chaoscope_os::outln!("analysis: chaoscope analyze {}", out.display())?;
        return Ok(child_code(producer_status));
    }
    let (analysis, info) = chaoscope_analyzer::recording::analyze_file(
        &out,
        &chaoscope_analyzer::AnalysisOptions {
            ..chaoscope_app::flow::analysis_options()
        },
    )?;
    still_ours()?;
    // With the run's end, so an escaped or failed orbit is said so in the verdicts.
    super::analyze::print_table(&analysis.report_ended(info.end.as_ref()))?;
    Ok(child_code(producer_status))
}

/// Device and inode of the file a recorder that succeeded put at its output, from the summary
/// line it printed on its standard output.
fn written_file(recorder: &mut std::process::Child) -> anyhow::Result<(u64, u64)> {
    let mut text = String::new();
    if let Some(mut stdout) = recorder.stdout.take() {
        std::io::Read::read_to_string(&mut stdout, &mut text)
            .context("reading the recorder's summary")?;
    }
    text.lines()
        .rev()
        .find_map(|line| {
            let v: serde_json::Value = serde_json::from_str(line).ok()?;
            Some((v["file"]["device"].as_u64()?, v["file"]["inode"].as_u64()?))
        })
        .context("the recorder did not say which file it wrote")
}

/// Whether Slurm started this job again after a requeue (`SLURM_RESTART_COUNT` > 0).
fn requeued_by_slurm() -> bool {
    std::env::var("SLURM_RESTART_COUNT")
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok())
        .is_some_and(|n| n > 0)
}

/// Continues the recording `out` of this run (its configuration `config`) in place, as
/// `chaoscope resume` does: `Some(exit status)` when done (also when it was already complete),
/// `None` when nothing was on disk to continue from.
fn resume_requeued(config: &RunConfig, out: &Path) -> anyhow::Result<Option<ExitCode>> {
    use chaoscope_app::resume::{ResumeFailure, ResumeOptions, resume};
    chaoscope_bus::signals::install(chaoscope_os::signals::Mode::Finish);
    let options = ResumeOptions {
        config: Some(config.clone()),
        // `run` estimated this configuration before it came here.
        estimated: true,
        ..Default::default()
    };
    chaoscope_os::errln!(
        "chaoscope run: requeued by Slurm: continuing {} from its last complete sample",
        out.display()
    );
    match resume(out, &options) {
        Ok(outcome) => super::resume::report(&outcome, false).map(Some),
        Err(ResumeFailure::Complete { .. }) => {
            chaoscope_os::outln!("recording: {} (complete)", out.display())?;
            Ok(Some(ExitCode::SUCCESS))
        }
        Err(ResumeFailure::NoSample { path }) => {
            chaoscope_os::errln!(
                "chaoscope run: {path} holds no complete sample: starting the run afresh"
            );
            Ok(None)
        }
        Err(e) => Err(e.into()),
    }
}

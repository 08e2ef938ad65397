//! Running steps as subprocesses of the `trand` binary, with caching, logs and a progress bar.
//!
//! A step `(sequence, method, state)` is **cached** when its run folder has `metrics.json` (written last,
//! by `trand eval`). Otherwise any leftover folder is removed and the step runs
//! `trand reconstruct` (t=0) or `trand update` (t=1) into it, then `trand eval`. Everything the commands
//! print goes to `runs/<sequence>/<method>/<state>.log`; a failed step leaves its log and the bench
//! goes on (the t=1 steps of a failed t=0 fail at once, naming the missing run).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use trand_io::State;
use trand_report::layout::{self, RunSettings};
use trand_report::method::Update;

use super::jobs::{Job, Step};

/// How a step ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Cached,
    Done { seconds: f64 },
    Failed { reason: String, log: PathBuf },
}

/// What every step needs.
pub struct Runner<'a> {
    /// The `trand` executable the commands run.
    pub bin: &'a Path,
    pub report: &'a Path,
    pub settings: &'a RunSettings,
    /// The bench's sequences (name → data folder).
    pub sequences: &'a [trand_report::SequenceEntry],
}

/// A `trand` subcommand line, for running and for the log.
struct Cmd {
    args: Vec<String>,
}

impl Cmd {
    fn new(sub: &str) -> Self {
        Self {
            args: vec![sub.into()],
        }
    }
    fn arg(mut self, k: &str, v: impl std::fmt::Display) -> Self {
        self.args.push(k.into());
        self.args.push(v.to_string());
        self
    }
    fn path(self, k: &str, p: &Path) -> Self {
        self.arg(k, p.display())
    }
}

/// Runs `trand <args>` with stdout and stderr appended to `log`; `Err` names the command and status.
fn run_logged(bin: &Path, cmd: &Cmd, log: &Path) -> anyhow::Result<()> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(log)
        .with_context(|| format!("opening log {}", log.display()))?;
    let line = format!("$ trand {}", cmd.args.join(" "));
    writeln!(f, "{line}").with_context(|| format!("writing log {}", log.display()))?;
    let out = f
        .try_clone()
        .with_context(|| format!("log {}", log.display()))?;
    let status = Command::new(bin)
        .args(&cmd.args)
        .stdin(Stdio::null())
        .stdout(out)
        .stderr(f)
        .status()
        .with_context(|| format!("starting {}", bin.display()))?;
    if !status.success() {
        anyhow::bail!("`{line}` exited with {status}");
    }
    Ok(())
}

/// Last `n` lines of a log, for the failure message.
fn tail(log: &Path, n: usize) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

impl Runner<'_> {
    fn data(&self, sequence: &str) -> PathBuf {
        let e = self
            .sequences
            .iter()
            .find(|e| e.name == sequence)
            .expect("job sequence is in the manifest");
        trand_report::Manifest::data_path(self.report, e)
    }

    fn commands(&self, step: &Step, out: &Path) -> Vec<Cmd> {
        let data = self.data(&step.sequence);
        let m = step.method;
        let main = match step.state {
            State::T0 => {
                let mut c = Cmd::new("reconstruct")
                    .path("--data", &data)
                    .path("--out", out)
                    .arg("--views", m.views())
                    .arg("--method", m.reconstruct_method());
                if let Some(i) = self.settings.iterations {
                    c = c.arg("--iterations", i);
                }
                if let Some(s) = self.settings.seed {
                    c = c.arg("--seed", s);
                }
                if let Some(d) = self.settings.downsample {
                    c = c.arg("--downsample", d);
                }
                c
            }
            State::T1 => {
                let t0 = layout::result_dir(self.report, &step.sequence, m, State::T0);
                // "physics only" uses the new image for detection alone: no relocalisation either.
                let (physics, refine, relocalise) = match m.update() {
                    Update::Full => ("on", "on", "on"),
                    Update::NoPhysics => ("off", "on", "on"),
                    Update::NoRefine => ("on", "off", "off"),
                };
                Cmd::new("update")
                    .path("--run", &t0)
                    .path("--data", &data)
                    .path("--out", out)
                    .arg("--physics", physics)
                    .arg("--refine", refine)
                    .arg("--relocalise", relocalise)
            }
        };
        let eval = Cmd::new("eval")
            .path("--run", out)
            .path("--data", &data)
            .arg("--state", step.state.as_str());
        vec![main, eval]
    }

    /// Runs one step (or finds it cached).
    pub fn step(&self, step: &Step) -> Outcome {
        let dir = layout::run_dir(self.report, &step.sequence, step.method, step.state);
        let log = layout::log_path(self.report, &step.sequence, step.method, step.state);
        if dir.join(trand_io::run_layout::METRICS_JSON).is_file() {
            return Outcome::Cached;
        }
        let fail = |reason: String| Outcome::Failed {
            reason,
            log: log.clone(),
        };
        if step.state == State::T1 {
            let t0 = layout::result_dir(self.report, &step.sequence, step.method, State::T0);
            if !t0.join(trand_io::run_layout::METRICS_JSON).is_file() {
                let reason = format!("its t=0 run {} is missing or failed", t0.display());
                // Still leave a log, so every failed step has one.
                let _ = std::fs::create_dir_all(log.parent().expect("log has a parent"))
                    .and_then(|()| std::fs::write(&log, format!("not run: {reason}\n")));
                return fail(reason);
            }
        }
        let t = Instant::now();
        let prepared = (|| -> anyhow::Result<()> {
            // `trand reconstruct` keeps `<run>.checkpoint/` after an interruption; a bench step always
            // starts afresh (same numbers as an uninterrupted run), so both leftovers go.
            let mut ckpt = dir.clone().into_os_string();
            ckpt.push(".checkpoint");
            for leftover in [dir.clone(), PathBuf::from(ckpt)] {
                if leftover.exists() {
                    std::fs::remove_dir_all(&leftover).with_context(|| {
                        format!("removing incomplete run {}", leftover.display())
                    })?;
                }
            }
            let parent = dir.parent().expect("run dir has a parent");
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
            std::fs::write(&log, "").with_context(|| format!("creating log {}", log.display()))?;
            Ok(())
        })();
        if let Err(e) = prepared {
            return fail(format!("{e:#}"));
        }
        for cmd in self.commands(step, &dir) {
            if let Err(e) = run_logged(self.bin, &cmd, &log) {
                return fail(format!("{e:#}\n{}", tail(&log, 5)));
            }
        }
        if !dir.join(trand_io::run_layout::METRICS_JSON).is_file() {
            return fail(format!(
                "eval wrote no {}",
                dir.join("metrics.json").display()
            ));
        }
        Outcome::Done {
            seconds: t.elapsed().as_secs_f64(),
        }
    }
}

/// Name of a step in messages: `sequence/method/state`.
pub fn step_name(s: &Step) -> String {
    format!("{}/{}/{}", s.sequence, s.method, s.state.as_str())
}

/// Runs `jobs` on `threads` workers (steps of a job in order), with a progress bar over steps.
/// Returns every step's outcome, in job-list order.
pub fn run_jobs(runner: &Runner, jobs: &[Job], threads: usize) -> Vec<(Step, Outcome)> {
    let total: usize = jobs.iter().map(|j| j.steps.len()).sum();
    let pb = ProgressBar::new(total as u64);
    pb.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} steps  {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let next = AtomicUsize::new(0);
    // (job index, its steps' outcomes), in completion order.
    type JobResult = (usize, Vec<(Step, Outcome)>);
    let results: Mutex<Vec<JobResult>> = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some(job) = jobs.get(i) else { break };
                    let mut out = Vec::new();
                    for s in &job.steps {
                        pb.set_message(step_name(s));
                        let o = runner.step(s);
                        let line = match &o {
                            Outcome::Cached => format!("cached  {}", step_name(s)),
                            Outcome::Done { seconds } => {
                                format!("done    {} ({seconds:.1} s)", step_name(s))
                            }
                            Outcome::Failed { reason, log } => {
                                format!(
                                    "FAILED  {}: {reason}\n        log: {}",
                                    step_name(s),
                                    log.display()
                                )
                            }
                        };
                        pb.suspend(|| println!("{line}"));
                        pb.inc(1);
                        out.push((s.clone(), o));
                    }
                    results.lock().expect("no worker panicked").push((i, out));
                }
            });
        }
    });
    pb.finish_and_clear();
    let mut r = results.into_inner().expect("no worker panicked");
    r.sort_by_key(|(i, _)| *i);
    r.into_iter().flat_map(|(_, v)| v).collect()
}

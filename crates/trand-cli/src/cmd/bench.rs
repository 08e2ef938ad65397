//! `trand bench`: every sequence through t=0 and t=1 for the benchmarked methods, then the tables and
//! the HTML report; `trand bench merge` joins shard folders. Layout of the report folder: see
//! `trand_report`.
//!
//! * [`jobs`]: the deterministic job list and `--shard i/n`.
//! * [`runner`]: steps as subprocesses of `trand` (`reconstruct`, `update`, `eval`), cache and logs.
//! * [`data`]: the sequences of a bench (`--data` folders or `--synth N` generated ones).
//! * [`merge`]: `trand bench merge`.
//!
//! The commands run are those of the `trand` executable itself, or of `TRAND_BIN` / `--trand-bin` when
//! set (tests use a stand-in script).

pub mod data;
pub mod jobs;
pub mod merge;
pub mod runner;

use std::path::{Path, PathBuf};

use anyhow::Context;
use trand_report::layout::{Manifest, RunSettings, SequenceEntry};
use trand_report::{Method, Tables};

use jobs::Shard;
use runner::Outcome;

/// Preset of the generated sequences (`trand synth --preset`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SynthPreset {
    /// 640x480, the paper-like scene.
    Default,
    /// 160x120, few views: seconds per sequence.
    Tiny,
    /// 640x480, upright open containers, lying tumblers, a lean or a stack removed at t=1.
    Containers,
}

impl SynthPreset {
    pub fn name(self) -> &'static str {
        match self {
            SynthPreset::Default => "default",
            SynthPreset::Tiny => "tiny",
            SynthPreset::Containers => "containers",
        }
    }
}

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    #[command(subcommand)]
    pub sub: Option<Sub>,
    /// Sequence folders to benchmark (with --synth: besides the generated ones).
    #[arg(long, num_args = 1.., required_unless_present = "synth")]
    pub data: Vec<PathBuf>,
    /// Benchmark N generated sequences (`trand synth --seed 1000+i`), kept under OUT/data/.
    #[arg(long, value_name = "N")]
    pub synth: Option<u32>,
    /// `trand synth --preset` of the generated sequences.
    #[arg(long, value_enum, default_value = "default")]
    pub synth_preset: SynthPreset,
    /// Report folder (created; an existing one is resumed).
    #[arg(long, required = true)]
    pub out: Option<PathBuf>,
    /// Methods to run, comma-separated (default: all).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<Method>,
    /// Run only jobs i, i+n, ... of the job list (then `trand bench merge` the shard folders).
    #[arg(long, value_name = "i/n")]
    pub shard: Option<Shard>,
    /// Jobs run at once.
    #[arg(long, default_value_t = 1)]
    pub jobs: usize,
    /// `trand reconstruct --iterations` for every t=0 run.
    #[arg(long)]
    pub iterations: Option<u32>,
    /// `trand reconstruct --downsample` (integer image reduction for training) for every t=0 run.
    #[arg(long)]
    pub downsample: Option<u32>,
    /// `trand reconstruct --seed` for every t=0 run.
    #[arg(long)]
    pub seed: Option<u64>,
    /// The `trand` executable whose subcommands run the steps (default: this one; env TRAND_BIN).
    #[arg(long, hide = true)]
    pub trand_bin: Option<PathBuf>,
}

#[derive(clap::Subcommand)]
pub enum Sub {
    /// Join shard report folders into one and rebuild the tables and the report.
    Merge(merge::Args),
}

/// Everything a bench run needs, from `trand bench` or `trand demo`.
pub struct Plan {
    pub report: PathBuf,
    pub sequences: Vec<SequenceEntry>,
    pub methods: Vec<Method>,
    pub settings: RunSettings,
    pub shard: Shard,
    pub jobs: usize,
    pub bin: PathBuf,
}

/// What a bench run did.
pub struct Summary {
    pub tables: Tables,
    pub steps: Vec<(jobs::Step, Outcome)>,
}

impl Summary {
    pub fn failed(&self) -> Vec<&(jobs::Step, Outcome)> {
        self.steps
            .iter()
            .filter(|(_, o)| matches!(o, Outcome::Failed { .. }))
            .collect()
    }
}

/// The executable that runs the steps: `explicit`, else `$TRAND_BIN`, else this one.
pub fn trand_bin(explicit: Option<PathBuf>) -> anyhow::Result<PathBuf> {
    match explicit.or_else(|| std::env::var_os("TRAND_BIN").map(PathBuf::from)) {
        Some(p) => Ok(p),
        None => std::env::current_exe().context("finding the trand executable"),
    }
}

/// Creates the report folder and checks it is writable.
pub fn prepare_out(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create report folder {}", out.display()))?;
    let probe = out.join(".trand-write-test");
    std::fs::write(&probe, b"")
        .with_context(|| format!("report folder {} is not writable", out.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Runs a plan: data, steps, tables, report.
pub fn execute(plan: &Plan) -> anyhow::Result<Summary> {
    prepare_out(&plan.report)?;
    let mut manifest = Manifest {
        sequences: plan.sequences.clone(),
        methods: plan.methods.clone(),
        settings: plan.settings.clone(),
    };
    manifest.normalise();
    if plan.report.join(trand_report::layout::MANIFEST).is_file() {
        let mut old = Manifest::read(&plan.report)?;
        old.union(&manifest, &plan.report)
            .with_context(|| format!("resuming {}", plan.report.display()))?;
        manifest = old;
    }
    manifest.write(&plan.report)?;
    let names: Vec<String> = plan.sequences.iter().map(|s| s.name.clone()).collect();
    let mut sorted = names.clone();
    sorted.sort();
    let my_jobs = plan.shard.take(jobs::job_list(&sorted, &plan.methods));
    // Generate only the sequences this shard's jobs use.
    let needed: Vec<&SequenceEntry> = plan
        .sequences
        .iter()
        .filter(|s| my_jobs.iter().any(|j| j.steps[0].sequence == s.name))
        .collect();
    let mut data_failures = Vec::new();
    for s in needed {
        if let Err(e) = data::ensure(&plan.bin, &plan.report, s) {
            println!("FAILED  data {}: {e:#}", s.name);
            data_failures.push(s.name.clone());
        }
    }
    let runner = runner::Runner {
        bin: &plan.bin,
        report: &plan.report,
        settings: &plan.settings,
        sequences: &manifest.sequences,
    };
    println!(
        "{} jobs ({} steps) of shard {} in {}",
        my_jobs.len(),
        my_jobs.iter().map(|j| j.steps.len()).sum::<usize>(),
        plan.shard,
        plan.report.display()
    );
    let steps = runner::run_jobs(&runner, &my_jobs, plan.jobs);
    let tables = trand_report::write_tables(&plan.report, &manifest)?;
    trand_report::write_report(&plan.report, &manifest, &tables)
        .with_context(|| format!("writing the HTML report in {}", plan.report.display()))?;
    Ok(Summary { tables, steps })
}

/// Prints the accuracy tables, the per-kind tables and where the report is.
pub fn print_tables(report: &Path, tables: &Tables) {
    let n = tables.sequences.len();
    println!(
        "\nDepth accuracy at t=0\n{}",
        trand_report::tables::accuracy_markdown(&tables.accuracy_t0, n)
    );
    println!(
        "Depth accuracy at t=1\n{}",
        trand_report::tables::accuracy_markdown(&tables.accuracy_t1, n)
    );
    let kinds = trand_report::kinds::kinds_markdown(&tables.per_kind);
    if !kinds.is_empty() {
        println!("Depth accuracy per object kind (objects of every sequence pooled)\n\n{kinds}");
    }
    println!(
        "tables: {}\nreport: {}",
        report.join(trand_report::layout::TABLES_MD).display(),
        report.join(trand_report::layout::INDEX_HTML).display()
    );
}

/// Prints the tables and the failures; `Err` when any step failed.
pub fn finish(plan_report: &Path, s: &Summary) -> anyhow::Result<()> {
    print_tables(plan_report, &s.tables);
    let failed = s.failed();
    if !failed.is_empty() {
        let list: Vec<String> = failed
            .iter()
            .map(|(st, o)| match o {
                Outcome::Failed { log, .. } => {
                    format!("  {} (log: {})", runner::step_name(st), log.display())
                }
                _ => unreachable!(),
            })
            .collect();
        anyhow::bail!(
            "{} of {} steps failed:\n{}",
            failed.len(),
            s.steps.len(),
            list.join("\n")
        );
    }
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(Sub::Merge(m)) = a.sub {
        return merge::run(m);
    }
    let out = a.out.context("--out is required")?;
    let bin = trand_bin(a.trand_bin)?;
    let mut sequences = match a.synth {
        Some(0) => anyhow::bail!("--synth 0: benchmark at least one sequence"),
        Some(n) => data::synth_entries(n, a.synth_preset),
        None => Vec::new(),
    };
    sequences.extend(data::folder_entries(&a.data)?);
    data::ensure_unique_names(&sequences)?;
    let methods = if a.methods.is_empty() {
        Method::ALL.to_vec()
    } else {
        a.methods
    };
    let plan = Plan {
        report: out,
        sequences,
        methods,
        settings: RunSettings {
            iterations: a.iterations,
            downsample: a.downsample,
            seed: a.seed,
        },
        shard: a.shard.unwrap_or(Shard::WHOLE),
        jobs: a.jobs.max(1),
        bin,
    };
    let s = execute(&plan)?;
    finish(&plan.report, &s)
}

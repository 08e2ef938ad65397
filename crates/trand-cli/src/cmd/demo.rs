//! `trand demo`: one command from a fresh checkout to a report.
//!
//! Generates the demo scene (cached under `DIR/data/`), reconstructs it at t=0, updates it to t=1 after
//! the object removal, evaluates both and writes the tables and the HTML report: the same job runner
//! and subprocesses as `trand bench`, with the fixed choices below. A second `trand demo` reuses
//! everything already done.

use std::path::PathBuf;

use trand_report::Method;
use trand_report::layout::RunSettings;

use super::bench::{self, Plan, SynthPreset, data, jobs::Shard};

/// Scene: the tiny synthetic preset (160x120, 3 objects, 3 test views per state) so that the whole demo
/// takes a few minutes on 2 cores; seed 1000 is the first scene of `trand bench --synth`.
pub const DEMO_PRESET: SynthPreset = SynthPreset::Tiny;
/// Methods: full TRAN-D only (t=0 and t=1); the ablations are `trand bench`'s job.
pub const DEMO_METHODS: [Method; 1] = [Method::Trand];
/// Reconstruction settings: the defaults of `trand reconstruct` (no shortened schedule; the tiny
/// images are what keeps the demo fast), seed fixed for a repeatable result.
pub const DEMO_SETTINGS: RunSettings = RunSettings {
    iterations: None,
    downsample: None,
    seed: Some(0),
};

#[derive(clap::Args)]
pub struct Args {
    /// Output folder (the demo data, runs and report).
    #[arg(long, default_value = "trand-demo")]
    pub out: PathBuf,
    /// The `trand` executable whose subcommands run the steps (default: this one; env TRAND_BIN).
    #[arg(long, hide = true)]
    pub trand_bin: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let plan = Plan {
        report: a.out,
        sequences: data::synth_entries(1, DEMO_PRESET),
        methods: DEMO_METHODS.to_vec(),
        settings: DEMO_SETTINGS,
        shard: Shard::WHOLE,
        jobs: 1,
        bin: bench::trand_bin(a.trand_bin)?,
    };
    let t = std::time::Instant::now();
    let summary = bench::execute(&plan)?;
    println!("demo finished in {:.1} s", t.elapsed().as_secs_f64());
    bench::finish(&plan.report, &summary)
}

//! `trand eval`: depth metrics of a run folder against a sequence's test views (the paper's protocol,
//! see `trand_eval::metrics`), pooled over every object pixel and per GT object with its kind from
//! the sequence's `sequence.json` (see `trand_eval::objects`). Writes `RUN/metrics.json` and prints
//! both Markdown tables.

use std::path::PathBuf;

use anyhow::Context;
use trand_io::State;

#[derive(clap::Args)]
pub struct Args {
    /// Run folder with `depth/{frame:06}.npy` predictions (float32 metres) and optionally `run.json`.
    #[arg(long)]
    pub run: PathBuf,
    /// Sequence folder (BOP, authors' transforms or nerfstudio layout).
    #[arg(long)]
    pub data: PathBuf,
    /// Scene state to evaluate: t0 (test_0 views) or t1 (test_1); default from run.json, else t0.
    #[arg(long)]
    pub state: Option<State>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let ev = trand_eval::evaluate_run_detailed(&a.run, &a.data, a.state).with_context(|| {
        format!(
            "evaluating {} against {}",
            a.run.display(),
            a.data.display()
        )
    })?;
    let name = a
        .data
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "sequence".into());
    let (state, m) = (ev.state, &ev.metrics);
    let row = format!("{name} {}", state.as_str());
    print!("{}", trand_eval::table(&[(row.as_str(), m)]));
    println!("\nPer object ({row}):\n");
    print!("{}", trand_eval::object_table(&ev.objects));
    println!(
        "{} pixels ({} uncovered) over {} views; wrote {}",
        m.pixels,
        m.uncovered,
        m.per_view.len(),
        a.run.join("metrics.json").display()
    );
    Ok(())
}

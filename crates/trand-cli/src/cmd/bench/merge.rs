//! `trand bench merge --out REPORT SHARD...`: joins shard report folders.
//!
//! The manifests are united (settings must agree), generated sequences and every *finished* run folder
//! (one with `metrics.json`) are hard-linked (or copied, across file systems) into `REPORT` with their
//! logs, then the tables and the report are rebuilt from `REPORT/runs/` alone. A run already finished
//! in `REPORT` is kept.

use std::path::{Path, PathBuf};

use anyhow::Context;
use trand_report::Manifest;
use trand_report::layout::{self, DATA_DIR, RUNS_DIR, SequenceSource};

#[derive(clap::Args)]
pub struct Args {
    /// The merged report folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Shard report folders (each made by `trand bench --shard i/n`).
    #[arg(required = true)]
    pub shards: Vec<PathBuf>,
}

/// Hard-links (or copies) the tree `src` to `dst`, which must not exist.
pub fn link_tree(src: &Path, dst: &Path) -> anyhow::Result<()> {
    if src.is_dir() {
        std::fs::create_dir_all(dst).with_context(|| format!("creating {}", dst.display()))?;
        let entries =
            std::fs::read_dir(src).with_context(|| format!("reading {}", src.display()))?;
        for e in entries {
            let e = e.with_context(|| format!("reading {}", src.display()))?;
            link_tree(&e.path(), &dst.join(e.file_name()))?;
        }
    } else if std::fs::hard_link(src, dst).is_err() {
        std::fs::copy(src, dst)
            .with_context(|| format!("copying {} to {}", src.display(), dst.display()))?;
    }
    Ok(())
}

fn sub_dirs(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let p = e
            .with_context(|| format!("reading {}", dir.display()))?
            .path();
        if p.is_dir() {
            v.push(p);
        }
    }
    v.sort();
    Ok(v)
}

/// Copies finished runs of `shard` into `out`; returns how many were taken.
fn merge_runs(shard: &Path, out: &Path) -> anyhow::Result<usize> {
    let mut n = 0;
    for seq in sub_dirs(&shard.join(RUNS_DIR))? {
        for method in sub_dirs(&seq)? {
            for run in sub_dirs(&method)? {
                if !run.join(trand_io::run_layout::METRICS_JSON).is_file() {
                    continue;
                }
                let rel = run.strip_prefix(shard).expect("run is inside the shard");
                let dst = out.join(rel);
                if dst.join(trand_io::run_layout::METRICS_JSON).is_file() {
                    continue;
                }
                if dst.exists() {
                    std::fs::remove_dir_all(&dst)
                        .with_context(|| format!("removing incomplete {}", dst.display()))?;
                }
                link_tree(&run, &dst)?;
                let log = run.with_extension("log");
                let dst_log = dst.with_extension("log");
                if log.is_file() {
                    let _ = std::fs::remove_file(&dst_log);
                    link_tree(&log, &dst_log)?;
                }
                n += 1;
            }
        }
    }
    Ok(n)
}

/// Merges the shards into `out` and rebuilds the tables; returns the manifest. Every shard is checked
/// (a bench folder, not `out`, settings and sequences agreeing) before anything is written.
pub fn merge(out: &Path, shards: &[PathBuf]) -> anyhow::Result<(Manifest, trand_report::Tables)> {
    let out_abs = std::path::absolute(out).with_context(|| format!("--out {}", out.display()))?;
    let mut manifest: Option<Manifest> = if out.join(layout::MANIFEST).is_file() {
        Some(Manifest::read(out)?)
    } else {
        None
    };
    let mut shard_manifests = Vec::with_capacity(shards.len());
    for shard in shards {
        let abs =
            std::path::absolute(shard).with_context(|| format!("shard {}", shard.display()))?;
        anyhow::ensure!(
            abs != out_abs,
            "shard {} is the --out folder itself",
            shard.display()
        );
        anyhow::ensure!(
            shard.join(layout::MANIFEST).is_file(),
            "shard {} has no {} (not a bench folder)",
            shard.display(),
            layout::MANIFEST
        );
        let m = Manifest::read(shard)?;
        match &mut manifest {
            None => manifest = Some(m.clone()),
            Some(acc) => acc.union(&m, shard)?,
        }
        shard_manifests.push(m);
    }
    super::prepare_out(out)?;
    for (shard, m) in shards.iter().zip(&shard_manifests) {
        for e in &m.sequences {
            if matches!(e.source, SequenceSource::Synth { .. }) && e.data.is_relative() {
                let (src, dst) = (shard.join(&e.data), out.join(&e.data));
                if src.join("sequence.json").is_file() && !dst.join("sequence.json").is_file() {
                    if dst.exists() {
                        std::fs::remove_dir_all(&dst)
                            .with_context(|| format!("removing {}", dst.display()))?;
                    }
                    std::fs::create_dir_all(out.join(DATA_DIR))
                        .with_context(|| format!("creating {}", out.join(DATA_DIR).display()))?;
                    link_tree(&src, &dst)?;
                }
            }
        }
        let n = merge_runs(shard, out)?;
        println!("merged  {} finished runs from {}", n, shard.display());
    }
    let mut manifest = manifest.expect("at least one shard");
    manifest.normalise();
    manifest.write(out)?;
    let tables = trand_report::write_tables(out, &manifest)?;
    trand_report::write_report(out, &manifest, &tables)
        .with_context(|| format!("writing the HTML report in {}", out.display()))?;
    Ok((manifest, tables))
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let (_, tables) = merge(&a.out, &a.shards)?;
    super::print_tables(&a.out, &tables);
    Ok(())
}

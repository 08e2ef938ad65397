//! The sequences of a bench: `--data` folders (named by their folder name) and `--synth N` sequences
//! `synth_<1000+i>` (`containers_<1000+i>` for the containers preset), generated once by `trand synth`
//! into `REPORT/data/<name>` (a finished sequence has `sequence.json`; generation goes to
//! `<name>.partial` and is renamed when done).

use std::path::{Path, PathBuf};

use anyhow::Context;
use trand_report::layout::{DATA_DIR, SequenceEntry, SequenceSource};

use super::SynthPreset;

/// First seed of generated sequences.
pub const SYNTH_SEED0: u64 = 1000;

/// Entries for `--synth n`.
pub fn synth_entries(n: u32, preset: SynthPreset) -> Vec<SequenceEntry> {
    (0..n as u64)
        .map(|i| {
            let seed = SYNTH_SEED0 + i;
            let name = match preset {
                SynthPreset::Default | SynthPreset::Tiny => format!("synth_{seed}"),
                SynthPreset::Containers => format!("containers_{seed}"),
            };
            SequenceEntry {
                data: Path::new(DATA_DIR).join(&name),
                name,
                source: SequenceSource::Synth {
                    seed,
                    preset: preset.name().into(),
                },
            }
        })
        .collect()
}

/// Entries for `--data` folders: each must be a readable sequence; names must be unique.
pub fn folder_entries(paths: &[PathBuf]) -> anyhow::Result<Vec<SequenceEntry>> {
    let mut out: Vec<SequenceEntry> = Vec::new();
    for p in paths {
        if !p.is_dir() {
            anyhow::bail!("--data {}: no such folder", p.display());
        }
        trand_io::detect_format(p).with_context(|| format!("--data {}", p.display()))?;
        // Canonical, so that `../shared/x` and `/work/shared/x` name the same sequence on a resume.
        let abs = p
            .canonicalize()
            .with_context(|| format!("--data {}", p.display()))?;
        let name = abs
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .with_context(|| format!("--data {}: folder has no name", p.display()))?;
        if let Some(e) = out.iter().find(|e| e.name == name) {
            anyhow::bail!(
                "--data {} and {} have the same folder name `{name}`; sequence names must be unique",
                e.data.display(),
                p.display()
            );
        }
        out.push(SequenceEntry {
            name,
            data: abs,
            source: SequenceSource::Folder,
        });
    }
    Ok(out)
}

/// Fails when two sequences share a name (a `--data` folder named like a generated sequence).
pub fn ensure_unique_names(entries: &[SequenceEntry]) -> anyhow::Result<()> {
    for (i, e) in entries.iter().enumerate() {
        if entries[..i].iter().any(|o| o.name == e.name) {
            anyhow::bail!(
                "two sequences are named `{}` ({}); sequence names must be unique",
                e.name,
                e.data.display()
            );
        }
    }
    Ok(())
}

/// Makes sure a sequence exists on disk, generating it if it is a synthetic one not yet made.
pub fn ensure(bin: &Path, report: &Path, e: &SequenceEntry) -> anyhow::Result<()> {
    let dir = trand_report::Manifest::data_path(report, e);
    let SequenceSource::Synth { seed, preset } = &e.source else {
        anyhow::ensure!(dir.is_dir(), "sequence folder {} is gone", dir.display());
        return Ok(());
    };
    if dir.join("sequence.json").is_file() {
        println!("cached  data {}", e.name);
        return Ok(());
    }
    let partial = dir.with_file_name(format!("{}.partial", e.name));
    let log = dir.with_file_name(format!("{}.log", e.name));
    std::fs::create_dir_all(report.join(DATA_DIR))
        .with_context(|| format!("creating {}", report.join(DATA_DIR).display()))?;
    let logf =
        std::fs::File::create(&log).with_context(|| format!("creating log {}", log.display()))?;
    let errf = logf
        .try_clone()
        .with_context(|| format!("log {}", log.display()))?;
    println!("synth   data {} (seed {seed}, preset {preset})", e.name);
    let status = std::process::Command::new(bin)
        .arg("synth")
        .arg("--seed")
        .arg(seed.to_string())
        .arg("--out")
        .arg(&partial)
        .arg("--preset")
        .arg(preset)
        .arg("--force")
        .stdin(std::process::Stdio::null())
        .stdout(logf)
        .stderr(errf)
        .status()
        .with_context(|| format!("starting {}", bin.display()))?;
    anyhow::ensure!(
        status.success(),
        "`trand synth --seed {seed}` exited with {status}; log: {}",
        log.display()
    );
    if dir.exists() {
        std::fs::remove_dir_all(&dir)
            .with_context(|| format!("removing incomplete {}", dir.display()))?;
    }
    std::fs::rename(&partial, &dir)
        .with_context(|| format!("renaming {} to {}", partial.display(), dir.display()))?;
    anyhow::ensure!(
        dir.join("sequence.json").is_file(),
        "`trand synth` wrote no {}",
        dir.join("sequence.json").display()
    );
    Ok(())
}

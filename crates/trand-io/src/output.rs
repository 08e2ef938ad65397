//! Where trand may write, and what it may replace.
//!
//! Every folder trand writes (a run folder, a `trand synth` sequence) is built under a temporary
//! sibling name and renamed into place when complete. The temporary folder holds a marker file,
//! [`MARKER`], from its creation, so the finished folder carries it too. The marker is the one thing
//! that lets trand delete a folder:
//! * `--force` replaces an existing folder only if it holds the marker, i.e. trand wrote it; never
//!   the current folder or one of its ancestors (that would delete the process's own working
//!   folder, and with it files trand never wrote);
//! * temporary folders left by a killed process (`NAME.tmp-PID`, `.NAME.synth-tmp-PID`) are removed
//!   on the next run for the same target when their process is gone and they hold the marker, and
//!   reported when that cannot be decided.
//!
//! Targets are first made absolute and lexically normalised ([`resolve_target`]), so `.` or `a/..`
//! name their real folder and the temporary sibling is never created inside the target.

use std::path::{Component, Path, PathBuf};

use crate::error::IoError;
use crate::write::write_atomic;

/// The marker file in every folder trand writes.
pub const MARKER: &str = ".trand-output";

/// What wrote a marked folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A run folder (`trand reconstruct`, `trand update`).
    Run,
    /// A generated sequence (`trand synth`).
    Sequence,
}

impl OutputKind {
    fn name(self) -> &'static str {
        match self {
            OutputKind::Run => "run",
            OutputKind::Sequence => "sequence",
        }
    }
}

fn refuse(path: &Path, reason: impl Into<String>) -> IoError {
    IoError::Output {
        path: path.into(),
        reason: reason.into(),
    }
}

/// Removes `.` and folds `..` into its parent, without touching the file system.
fn normalise(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push(c);
                }
            }
            c => out.push(c),
        }
    }
    out
}

/// `target` as an absolute path with no `.` or `..`, its parent resolved through symlinks when it
/// exists; refused when it is the root, the current folder or one of its ancestors.
pub fn resolve_target(target: &Path) -> Result<PathBuf, IoError> {
    let cwd = std::env::current_dir().map_err(|e| IoError::io(".", e))?;
    resolve_target_from(target, &cwd)
}

/// [`resolve_target`] relative to `cwd` instead of the process's current folder.
pub fn resolve_target_from(target: &Path, cwd: &Path) -> Result<PathBuf, IoError> {
    if target.as_os_str().is_empty() {
        return Err(refuse(target, "the output path is empty"));
    }
    let abs = normalise(&cwd.join(target));
    let (Some(parent), Some(name)) = (abs.parent(), abs.file_name()) else {
        return Err(refuse(target, "the output cannot be the file-system root"));
    };
    let parent = parent.canonicalize().unwrap_or_else(|_| parent.into());
    let resolved = parent.join(name);
    let cwd = cwd.canonicalize().unwrap_or_else(|_| normalise(cwd));
    let resolved_real = resolved.canonicalize().unwrap_or_else(|_| resolved.clone());
    if cwd.starts_with(&resolved_real) || cwd.starts_with(&resolved) {
        return Err(refuse(
            target,
            "the output is the current folder or one of its ancestors; choose a new folder",
        ));
    }
    Ok(resolved)
}

/// Whether anything (a file, a folder, a dangling symlink) is at `p`.
pub fn occupied(p: &Path) -> bool {
    p.symlink_metadata().is_ok()
}

/// Checks, before any work, that a new output folder can be created at `target`: nothing is there
/// (not even a dangling symlink), its parent is a folder and is writable (probed by creating and
/// removing a temporary sibling). Returns the resolved target ([`resolve_target`]).
pub fn check_new_output(target: &Path) -> Result<PathBuf, IoError> {
    let resolved = resolve_target(target)?;
    if occupied(&resolved) {
        let what = match resolved.symlink_metadata() {
            Ok(m) if m.file_type().is_symlink() => "a symlink is already there",
            Ok(m) if m.is_dir() => "the folder already exists",
            _ => "a file is already there",
        };
        return Err(refuse(target, what));
    }
    let parent = resolved.parent().expect("resolved targets have a parent");
    if !parent.is_dir() {
        return Err(refuse(
            target,
            format!("its parent folder {} does not exist", parent.display()),
        ));
    }
    let probe = temp_sibling(&resolved, "probe");
    std::fs::create_dir(&probe).map_err(|e| {
        refuse(
            target,
            format!("cannot create folders in {}: {e}", parent.display()),
        )
    })?;
    let _ = std::fs::remove_dir(&probe);
    Ok(resolved)
}

/// `PARENT/.NAME.TAG-PID`: a temporary sibling of a resolved target.
pub fn temp_sibling(resolved: &Path, tag: &str) -> PathBuf {
    let name = resolved
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    resolved.with_file_name(format!(".{name}.{tag}-{}", std::process::id()))
}

/// Writes the marker into `dir` (a folder being built).
pub fn write_marker(dir: &Path, kind: OutputKind) -> Result<(), IoError> {
    let text = format!(
        "{{\"written_by\": \"trand\", \"kind\": \"{}\", \"version\": \"{}\"}}\n",
        kind.name(),
        env!("CARGO_PKG_VERSION")
    );
    write_atomic(&dir.join(MARKER), text.as_bytes())
}

/// Whether `dir` is a real folder (not a symlink) holding the marker.
pub fn is_marked(dir: &Path) -> bool {
    dir.symlink_metadata().is_ok_and(|m| m.is_dir()) && dir.join(MARKER).is_file()
}

/// Checks that the existing `resolved` folder may be replaced: a real folder that trand wrote.
pub fn check_replaceable(resolved: &Path) -> Result<(), IoError> {
    let meta = resolved
        .symlink_metadata()
        .map_err(|e| IoError::io(resolved, e))?;
    if meta.file_type().is_symlink() {
        return Err(refuse(
            resolved,
            "is a symlink; trand replaces only folders it wrote",
        ));
    }
    if !meta.is_dir() {
        return Err(refuse(resolved, "exists and is not a folder"));
    }
    if !is_marked(resolved) {
        return Err(refuse(
            resolved,
            format!(
                "holds no {MARKER} marker, so trand did not write it; it is never replaced (remove it yourself or choose another folder)"
            ),
        ));
    }
    Ok(())
}

/// Whether process `pid` is alive: `Some` where the platform says (Linux `/proc`), else `None`.
fn process_alive(pid: u32) -> Option<bool> {
    let proc = Path::new("/proc");
    if !proc.join("self").exists() {
        return None;
    }
    Some(proc.join(pid.to_string()).exists())
}

/// What [`clean_stale_temps`] found.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct StaleTemps {
    /// Removed: marked, and their process is gone.
    pub removed: Vec<PathBuf>,
    /// Left alone: unmarked, or their process may still run.
    pub kept: Vec<PathBuf>,
}

/// Removes the temporary siblings `prefix{PID}` of a target left by killed processes.
///
/// `prefix` is the file name up to the process id, e.g. `.run0.synth-tmp-` or `run0.tmp-`.
/// A sibling is removed only when it holds the marker and its process is known to be gone.
pub fn clean_stale_temps(parent: &Path, prefix: &str) -> StaleTemps {
    let mut found = StaleTemps::default();
    let Ok(entries) = std::fs::read_dir(parent) else {
        return found;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name
            .to_str()
            .and_then(|n| n.strip_prefix(prefix))
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        let path = e.path();
        if pid == std::process::id() {
            continue;
        }
        let dead = process_alive(pid) == Some(false);
        if dead && is_marked(&path) && std::fs::remove_dir_all(&path).is_ok() {
            found.removed.push(path);
        } else {
            found.kept.push(path);
        }
    }
    found.removed.sort();
    found.kept.sort();
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalise_folds_dots() {
        assert_eq!(normalise(Path::new("/a/./b/../c")), PathBuf::from("/a/c"));
        assert_eq!(normalise(Path::new("/a/..")), PathBuf::from("/"));
    }

    #[test]
    fn current_folder_and_ancestors_are_refused() {
        let cwd = std::env::temp_dir();
        for t in [".", "./", "..", "../..", "x/..", "/"] {
            assert!(
                resolve_target_from(Path::new(t), &cwd).is_err(),
                "{t} was accepted"
            );
        }
        let r = resolve_target_from(Path::new("new_out"), &cwd).unwrap();
        assert_eq!(r, cwd.canonicalize().unwrap().join("new_out"));
    }
}

//! Resolving image paths written into JSON files by another machine.

use std::path::{Path, PathBuf};

/// Resolves `p` from a JSON file in `base`: a relative path is joined to `base`; an absolute path that
/// does not exist here (written on another machine) is re-rooted by trying its ever-shorter suffixes
/// under `base` and its parent, e.g. `/data/seq/train_0/data/rgb/000001.png` → `base/train_0/data/rgb/000001.png`.
/// Returns the best guess (the plain join or the original path) when nothing exists, so the caller's
/// "missing file" error names it.
pub(crate) fn resolve(base: &Path, p: &str) -> PathBuf {
    let path = Path::new(p);
    if path.is_relative() {
        return base.join(path);
    }
    if path.exists() {
        return path.into();
    }
    let comps: Vec<_> = path.components().skip(1).collect();
    for root in [Some(base), base.parent()].into_iter().flatten() {
        for start in 0..comps.len() {
            let cand: PathBuf = comps[start..]
                .iter()
                .fold(root.to_path_buf(), |acc, c| acc.join(c));
            if cand.exists() {
                return cand;
            }
        }
    }
    path.into()
}

/// The trailing integer of a file stem (`000012.png` → 12, `frame_00012.jpg` → 12).
pub(crate) fn frame_number(p: &str) -> Option<u32> {
    let stem = Path::new(p).file_stem()?.to_str()?;
    let digits: String = stem
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit())
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    digits.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_number_takes_trailing_digits() {
        assert_eq!(frame_number("/a/b/000012.png"), Some(12));
        assert_eq!(frame_number("images/frame_00007.jpg"), Some(7));
        assert_eq!(frame_number("images/left.jpg"), None);
    }
}

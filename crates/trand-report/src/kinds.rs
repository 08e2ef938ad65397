//! Per-object and per-kind tables: from the `per_object` list that `trand eval` writes into each
//! run's `metrics.json` (see `trand_eval::objects`). Per kind, the objects of every sequence of the
//! report are pooled pixel-weighted (an upright bowl is one label, `bowl (upright)`, whatever the
//! sequence), unlike the sequence tables, which average sequences.

use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;
use trand_eval::{LabelRow, PerObject, label_table, object_table, pool_by_label};
use trand_io::State;

use crate::layout::{self, ReportError};
use crate::method::Method;

/// One method at one state, pooled per kind over the report's sequences.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KindTable {
    pub method: Method,
    pub state: State,
    /// Sequences whose metrics.json lists objects.
    pub sequences: usize,
    pub rows: Vec<LabelRow>,
}

/// One method at one state on one sequence, per object.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ObjectTable {
    pub sequence: String,
    pub method: Method,
    pub state: State,
    pub objects: Vec<PerObject>,
}

/// The `per_object` list of a run folder's `metrics.json` (empty when the file or the list is absent:
/// runs evaluated before per-object figures existed).
pub fn read_objects(run: &Path) -> Result<Vec<PerObject>, ReportError> {
    let path = run.join(trand_io::run_layout::METRICS_JSON);
    if !path.is_file() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(&path).map_err(|e| ReportError::io(&path, e))?;
    #[derive(serde::Deserialize)]
    struct Only {
        #[serde(default)]
        per_object: Vec<PerObject>,
    }
    let only: Only =
        serde_json::from_str(&text).map_err(|source| ReportError::Json { path, source })?;
    Ok(only.per_object)
}

/// Per-object tables of every `(method, state)` in `runs` on every sequence, and the per-kind
/// pooling of each over the sequences.
pub fn build(
    report: &Path,
    seqs: &[String],
    runs: &[(Method, State)],
) -> Result<(Vec<KindTable>, Vec<ObjectTable>), ReportError> {
    let (mut kinds, mut objects) = (Vec::new(), Vec::new());
    for &(method, state) in runs {
        let mut found = Vec::new();
        for s in seqs {
            let list = read_objects(&layout::result_dir(report, s, method, state))?;
            if !list.is_empty() {
                found.push(ObjectTable {
                    sequence: s.clone(),
                    method,
                    state,
                    objects: list,
                });
            }
        }
        kinds.push(KindTable {
            method,
            state,
            sequences: found.len(),
            rows: pool_by_label(found.iter().flat_map(|t| &t.objects)),
        });
        objects.extend(found);
    }
    Ok((kinds, objects))
}

/// The per-kind section of `tables.md`.
pub fn kinds_markdown(tables: &[KindTable]) -> String {
    let mut s = String::new();
    for t in tables.iter().filter(|t| !t.rows.is_empty()) {
        let _ = writeln!(
            s,
            "**{} {}** ({} sequences)\n\n{}",
            t.method,
            t.state.as_str(),
            t.sequences,
            label_table(&t.rows)
        );
    }
    s
}

/// The per-object tables of one sequence.
pub fn objects_markdown(tables: &[ObjectTable], sequence: &str) -> String {
    let mut s = String::new();
    for t in tables.iter().filter(|t| t.sequence == sequence) {
        let _ = writeln!(
            s,
            "{} {}, per object:\n\n{}",
            t.method,
            t.state.as_str(),
            object_table(&t.objects)
        );
    }
    s
}

//! Per-object and per-kind tables: from the `per_object` list that `trand eval` writes into each
//! run's `metrics.json` (see `trand_eval::objects`). Per kind, the objects of every sequence of the
//! report are pooled pixel-weighted (an upright bowl is one label, `bowl (upright)`, whatever the
//! sequence; [`trand_eval::pool_by_kind`]), unlike the sequence tables, which average sequences.
//! Each kind row says how many objects and sequences it pools.

use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;
use trand_eval::{KindRow, PerObject, kind_table, object_table, pool_by_kind};
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
    pub rows: Vec<KindRow>,
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
            rows: pool_tables(&found),
        });
        objects.extend(found);
    }
    Ok((kinds, objects))
}

/// The objects of `tables` (each a sequence) pooled per kind.
pub fn pool_tables(tables: &[ObjectTable]) -> Vec<KindRow> {
    pool_by_kind(
        tables
            .iter()
            .flat_map(|t| t.objects.iter().map(|o| (t.sequence.as_str(), o))),
    )
}

/// The heading of a per-kind table: `trand t0 (1 sequence)`, `trand t1 (3 sequences)`.
pub fn kind_table_title(t: &KindTable) -> String {
    let plural = if t.sequences == 1 { "" } else { "s" };
    format!(
        "{} {} ({} sequence{plural})",
        t.method,
        t.state.as_str(),
        t.sequences
    )
}

/// The per-kind section of `tables.md`.
pub fn kinds_markdown(tables: &[KindTable]) -> String {
    let mut s = String::new();
    for t in tables.iter().filter(|t| !t.rows.is_empty()) {
        let _ = writeln!(s, "**{}**\n\n{}", kind_table_title(t), kind_table(&t.rows));
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{Manifest, RunSettings, SequenceEntry, SequenceSource};
    use trand_eval::{Counts, Metrics, UNKNOWN_KIND};

    /// An object with `pixels` pixels of |e| = `err` each (all within 2.5 cm when `err` is).
    fn object(id: u16, kind: Option<&str>, orientation: &str, pixels: u64, err: f64) -> PerObject {
        let within = trand_eval::THRESHOLDS_M.map(|t| if err < t { pixels } else { 0 });
        let counts = Counts {
            pixels,
            uncovered: 0,
            abs_sum: pixels as f64 * err,
            sq_sum: pixels as f64 * err * err,
            within,
        };
        PerObject {
            id,
            kind: kind.map(String::from),
            orientation: kind.map(|_| orientation.to_string()),
            label: format!("object {id}"),
            metrics: Metrics::from_counts(&counts, Vec::new()),
            counts,
        }
    }

    /// `metrics.json` as `trand eval` writes it: pooled figures at the top level, then `per_object`
    /// (without it, as written before per-object figures existed, pooled over 10 pixels).
    fn put(report: &Path, seq: &str, state: State, objects: Option<&[PerObject]>) {
        let dir = layout::run_dir(report, seq, Method::Trand, state);
        std::fs::create_dir_all(&dir).unwrap();
        let mut total = Counts::default();
        let legacy = [object(1, None, "", 10, 0.0)];
        for o in objects.unwrap_or(&legacy) {
            total.add(&o.counts);
        }
        let mut j = serde_json::to_value(Metrics::from_counts(&total, Vec::new())).unwrap();
        if let Some(list) = objects {
            j["per_object"] = serde_json::to_value(list).unwrap();
        }
        std::fs::write(dir.join("metrics.json"), j.to_string()).unwrap();
    }

    fn manifest(seqs: &[&str]) -> Manifest {
        Manifest {
            sequences: seqs
                .iter()
                .map(|n| SequenceEntry {
                    name: n.to_string(),
                    data: n.into(),
                    source: SequenceSource::Folder,
                })
                .collect(),
            methods: vec![Method::Trand],
            settings: RunSettings::default(),
        }
    }

    #[test]
    fn per_kind_tables_pool_pixels_over_sequences_and_count_objects_and_sequences() {
        let dir = trand_io::ScratchDir::new("kinds").unwrap();
        let r = dir.path();
        // a: an upright bowl (100 px, 1 cm off) and an unnamed object; b: an upright bowl (300 px,
        // 4 cm off), an inverted bowl and an unnamed object with the same id as a's; c: evaluated
        // before per-object figures existed.
        put(
            r,
            "a",
            State::T0,
            Some(&[
                object(1, Some("bowl"), "upright", 100, 0.01),
                object(3, None, "", 50, 0.0),
            ]),
        );
        put(
            r,
            "b",
            State::T0,
            Some(&[
                object(2, Some("bowl"), "upright", 300, 0.04),
                object(3, None, "", 10, 0.0),
                object(5, Some("bowl"), "inverted", 40, 0.0),
            ]),
        );
        put(r, "c", State::T0, None);
        put(
            r,
            "a",
            State::T1,
            Some(&[object(1, Some("bowl"), "upright", 80, 0.1)]),
        );
        let t = crate::build_tables(r, &manifest(&["a", "b", "c"])).unwrap();

        assert_eq!(t.per_kind.len(), 2, "trand at t0 and at t1");
        let t0 = &t.per_kind[0];
        assert_eq!(
            (t0.method, t0.state, t0.sequences),
            (Method::Trand, State::T0, 2)
        );
        let rows: Vec<(&str, usize, usize, u64)> = t0
            .rows
            .iter()
            .map(|k| (k.label.as_str(), k.objects, k.sequences, k.metrics.pixels))
            .collect();
        assert_eq!(
            rows,
            [
                ("bowl (inverted)", 1, 1, 40),
                ("bowl (upright)", 2, 2, 400),
                (UNKNOWN_KIND, 2, 2, 60),
            ]
        );
        // Pixel-weighted: (100 · 0.01 + 300 · 0.04) / 400 = 0.0325, not the mean 0.025 of the two
        // bowls; within 2.5 cm: a's 100 pixels of 400.
        let upright = &t0.rows[1].metrics;
        assert!((upright.mae_m - 0.0325).abs() < 1e-12, "{}", upright.mae_m);
        assert_eq!(upright.acc[2], 0.25);
        let t1 = &t.per_kind[1];
        assert_eq!((t1.state, t1.sequences, t1.rows.len()), (State::T1, 1, 1));
        assert!((t1.rows[0].metrics.mae_m - 0.1).abs() < 1e-12);
        assert_eq!(kind_table_title(t0), "trand t0 (2 sequences)");
        assert_eq!(kind_table_title(t1), "trand t1 (1 sequence)");

        // Per object: one table per sequence and state that lists objects.
        let listed: Vec<(&str, State, usize)> = t
            .per_object
            .iter()
            .map(|o| (o.sequence.as_str(), o.state, o.objects.len()))
            .collect();
        assert_eq!(
            listed,
            [
                ("a", State::T0, 2),
                ("b", State::T0, 3),
                ("a", State::T1, 1)
            ]
        );

        // tables.md and tables.json carry both.
        let md = t.markdown();
        assert!(
            md.contains("| bowl (upright) | 2 | 2 | 400 | 0.0325 | 25.00% | 100.00% |"),
            "{md}"
        );
        assert!(md.contains("| 2 | bowl (upright) | 300 | 0.0400 |"), "{md}");
        let j = serde_json::to_value(&t).unwrap();
        assert_eq!(j["per_kind"][0]["rows"][1]["sequences"], 2);
        assert_eq!(j["per_object"][1]["objects"][2]["kind"], "bowl");
    }

    #[test]
    fn a_run_without_per_object_figures_reads_as_no_objects() {
        let dir = trand_io::ScratchDir::new("kinds-legacy").unwrap();
        put(dir.path(), "a", State::T0, None);
        let run = layout::run_dir(dir.path(), "a", Method::Trand, State::T0);
        assert!(run.join("metrics.json").is_file());
        assert!(read_objects(&run).unwrap().is_empty());
        assert!(read_objects(&dir.path().join("absent")).unwrap().is_empty());
        std::fs::write(run.join("metrics.json"), "{\"per_object\": [{\"id\": 1}]}").unwrap();
        let e = read_objects(&run).unwrap_err().to_string();
        assert!(e.contains("metrics.json"), "{e}");
    }
}

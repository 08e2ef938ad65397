//! The benchmark tables, built from the run folders alone (so one bench and merged shards agree).
//!
//! Depth figures are the paper's: per sequence, the metrics pooled over every test view
//! (`metrics.json`, from `trand eval`); per method, the unweighted mean over the sequences that have a
//! result ([`trand_eval::mean_over_sequences`]). Efficiency figures are means over sequences of the
//! `timings`, `num_surfels` and `peak_rss_mb` fields of `run.json`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;
use trand_eval::Metrics;
use trand_io::State;

use crate::kinds::{self, KindTable, ObjectTable};
use crate::layout::{self, Manifest, ReportError};
use crate::method::Method;

/// Stages of `run.json`'s `timings` shown per state, in column order.
pub const T0_STAGES: [&str; 3] = ["preprocess_s", "optimise_s", "total_s"];
pub const T1_STAGES: [&str; 6] = [
    "detection_s",
    "meshing_s",
    "simulation_s",
    "relocalisation_s",
    "refinement_s",
    "total_s",
];

/// Stage names of a state.
pub fn stages(state: State) -> &'static [&'static str] {
    match state {
        State::T0 => &T0_STAGES,
        State::T1 => &T1_STAGES,
    }
}

/// One method at one state: the mean metrics over the sequences that have a result.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AccuracyRow {
    pub method: Method,
    pub state: State,
    /// Sequences with a result.
    pub sequences: usize,
    /// `None` when no sequence has a result.
    pub metrics: Option<Metrics>,
}

/// Mean timings and model size of the runs a method owns at a state.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EfficiencyRow {
    pub method: Method,
    pub state: State,
    pub sequences: usize,
    /// Mean seconds per stage (`run.json` `timings`), over the sequences that report the stage.
    pub timings_s: BTreeMap<String, f64>,
    /// Mean surfel (Gaussian) count.
    pub num_surfels: Option<f64>,
    pub peak_rss_mb: Option<f64>,
}

/// Every method and state of one sequence.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SequenceRows {
    pub sequence: String,
    pub rows: Vec<AccuracyRow>,
}

/// All tables of a report (`tables.json`; [`Tables::markdown`] gives `tables.md`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Tables {
    pub sequences: Vec<String>,
    /// Methods with their own t=0 run (the others reuse one of these).
    pub accuracy_t0: Vec<AccuracyRow>,
    /// Methods with their own t=1 run (all but views-6, which is trand).
    pub accuracy_t1: Vec<AccuracyRow>,
    pub efficiency_t0: Vec<EfficiencyRow>,
    pub efficiency_t1: Vec<EfficiencyRow>,
    /// trand vs no-object-loss, t0 then t1.
    pub loss_ablation: Vec<AccuracyRow>,
    /// trand, no-simulation, physics-only at t1.
    pub simulation_ablation: Vec<AccuracyRow>,
    /// views-3, views-6, views-12, t0 then t1.
    pub view_study: Vec<AccuracyRow>,
    pub per_sequence: Vec<SequenceRows>,
    /// Per object kind, pooled over the sequences, for every method with its own run.
    pub per_kind: Vec<KindTable>,
    /// Per object, per sequence, for every method with its own run.
    pub per_object: Vec<ObjectTable>,
}

/// `metrics.json` of a run folder, `None` if absent.
pub fn read_metrics(run: &Path) -> Result<Option<Metrics>, ReportError> {
    let path = run.join(trand_io::run_layout::METRICS_JSON);
    if !path.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(|e| ReportError::io(&path, e))?;
    let mut m: Metrics =
        serde_json::from_str(&text).map_err(|source| ReportError::Json { path, source })?;
    m.per_view.clear();
    Ok(Some(m))
}

/// `run.json` of a run folder, `None` if absent.
pub fn read_run_json(run: &Path) -> Result<Option<trand_io::RunManifest>, ReportError> {
    Ok(trand_io::RunManifest::read(run)?)
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

struct Collected {
    /// (sequence, method, state) → metrics, for every manifest method.
    metrics: BTreeMap<(String, Method, &'static str), Metrics>,
}

impl Collected {
    fn row(&self, seqs: &[String], method: Method, state: State) -> AccuracyRow {
        let found: Vec<Metrics> = seqs
            .iter()
            .filter_map(|s| {
                self.metrics
                    .get(&(s.clone(), method, state.as_str()))
                    .cloned()
            })
            .collect();
        AccuracyRow {
            method,
            state,
            sequences: found.len(),
            metrics: (!found.is_empty()).then(|| trand_eval::mean_over_sequences(&found)),
        }
    }
}

/// Owners of the runs of `methods` at `state`, each once, in table order.
fn owners(methods: &[Method], state: State) -> Vec<Method> {
    let mut v: Vec<Method> = methods.iter().map(|m| m.source(state)).collect();
    v.sort();
    v.dedup();
    v
}

fn efficiency(
    report: &Path,
    seqs: &[String],
    method: Method,
    state: State,
) -> Result<EfficiencyRow, ReportError> {
    let mut stage_vals: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let (mut surfels, mut rss, mut n) = (Vec::new(), Vec::new(), 0);
    for s in seqs {
        let dir = layout::run_dir(report, s, method, state);
        if read_metrics(&dir)?.is_none() {
            continue;
        }
        let Some(run) = read_run_json(&dir)? else {
            continue;
        };
        n += 1;
        for (k, x) in run.timings.iter().flatten() {
            stage_vals.entry(k.clone()).or_default().push(*x);
        }
        surfels.extend(run.num_surfels.map(|n| n as f64));
        rss.extend(run.peak_rss_mb);
    }
    Ok(EfficiencyRow {
        method,
        state,
        sequences: n,
        timings_s: stage_vals
            .into_iter()
            .filter_map(|(k, v)| mean(&v).map(|m| (k, m)))
            .collect(),
        num_surfels: mean(&surfels),
        peak_rss_mb: mean(&rss),
    })
}

/// Builds every table from `REPORT/runs/`. Missing results leave gaps; unreadable files are errors.
pub fn build_tables(report: &Path, manifest: &Manifest) -> Result<Tables, ReportError> {
    let seqs: Vec<String> = manifest.sequences.iter().map(|s| s.name.clone()).collect();
    let mut methods = manifest.methods.clone();
    methods.sort();
    methods.dedup();
    let mut c = Collected {
        metrics: BTreeMap::new(),
    };
    let mut read = methods.clone();
    read.extend(owners(&methods, State::T0));
    read.extend(owners(&methods, State::T1));
    for s in &seqs {
        for &m in &read {
            for state in [State::T0, State::T1] {
                if let Some(x) = read_metrics(&layout::result_dir(report, s, m, state))? {
                    c.metrics.insert((s.clone(), m, state.as_str()), x);
                }
            }
        }
    }
    let rows = |list: &[Method], states: &[State]| -> Vec<AccuracyRow> {
        states
            .iter()
            .flat_map(|&st| list.iter().map(move |&m| (m, st)))
            .map(|(m, st)| c.row(&seqs, m, st))
            .collect()
    };
    // The selected methods among `list`.
    let sel = |list: &[Method]| -> Vec<Method> {
        list.iter()
            .copied()
            .filter(|m| methods.contains(m))
            .collect()
    };
    let (own0, own1) = (owners(&methods, State::T0), owners(&methods, State::T1));
    let both = [State::T0, State::T1];
    let eff = |state| -> Result<Vec<EfficiencyRow>, ReportError> {
        owners(&methods, state)
            .into_iter()
            .map(|m| efficiency(report, &seqs, m, state))
            .collect()
    };
    let efficiency_t0 = eff(State::T0)?;
    let efficiency_t1 = eff(State::T1)?;
    let own_runs: Vec<(Method, State)> = own0
        .iter()
        .map(|&m| (m, State::T0))
        .chain(own1.iter().map(|&m| (m, State::T1)))
        .collect();
    let (per_kind, per_object) = kinds::build(report, &seqs, &own_runs)?;
    Ok(Tables {
        per_kind,
        per_object,
        accuracy_t0: rows(&own0, &[State::T0]),
        accuracy_t1: rows(&own1, &[State::T1]),
        efficiency_t0,
        efficiency_t1,
        loss_ablation: rows(&sel(&[Method::Trand, Method::NoObjectLoss]), &both),
        simulation_ablation: rows(
            &sel(&[Method::Trand, Method::NoSimulation, Method::PhysicsOnly]),
            &[State::T1],
        ),
        view_study: rows(
            &sel(&[Method::Views3, Method::Views6, Method::Views12]),
            &both,
        ),
        per_sequence: seqs
            .iter()
            .map(|s| SequenceRows {
                sequence: s.clone(),
                rows: own0
                    .iter()
                    .map(|&m| (m, State::T0))
                    .chain(own1.iter().map(|&m| (m, State::T1)))
                    .map(|(m, st)| c.row(std::slice::from_ref(s), m, st))
                    .collect(),
            })
            .collect(),
        sequences: seqs,
    })
}

/// Row label: `method t0`, with `[k/n seq]` when only some sequences have a result.
pub fn row_label(r: &AccuracyRow, total: usize) -> String {
    let mut s = format!("{} {}", r.method, r.state.as_str());
    if r.sequences != total {
        let _ = write!(s, " [{}/{} seq]", r.sequences, total);
    }
    s
}

/// An accuracy table in the paper's columns; rows without results show dashes.
pub fn accuracy_markdown(rows: &[AccuracyRow], total: usize) -> String {
    let labels: Vec<String> = rows.iter().map(|r| row_label(r, total)).collect();
    let present: Vec<(&str, &Metrics)> = rows
        .iter()
        .zip(&labels)
        .filter_map(|(r, l)| r.metrics.as_ref().map(|m| (l.as_str(), m)))
        .collect();
    let mut s = trand_eval::table(&present);
    for (r, l) in rows.iter().zip(&labels) {
        if r.metrics.is_none() {
            let _ = writeln!(s, "| {l} |{}", " – |".repeat(8));
        }
    }
    s
}

fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map(|x| format!("{x:.decimals$}"))
        .unwrap_or_else(|| "–".into())
}

/// An efficiency table: seconds per stage, Gaussians, peak memory.
pub fn efficiency_markdown(rows: &[EfficiencyRow], state: State) -> String {
    let st = stages(state);
    let mut s = String::from("| | sequences |");
    for k in st {
        let _ = write!(s, " {} (s) |", k.trim_end_matches("_s"));
    }
    s += " Gaussians | peak RSS (MB) |\n|---|---|";
    s += &"---|".repeat(st.len() + 2);
    s.push('\n');
    for r in rows {
        let _ = write!(s, "| {} {} | {} |", r.method, state.as_str(), r.sequences);
        for k in st {
            let _ = write!(s, " {} |", opt(r.timings_s.get(*k).copied(), 2));
        }
        let _ = writeln!(
            s,
            " {} | {} |",
            opt(r.num_surfels, 0),
            opt(r.peak_rss_mb, 0)
        );
    }
    s
}

impl Tables {
    /// `tables.md`.
    pub fn markdown(&self) -> String {
        let n = self.sequences.len();
        let mut s = String::from("# trand benchmark\n\n");
        let _ = writeln!(s, "Sequences ({n}): {}\n", self.sequences.join(", "));
        let _ = writeln!(
            s,
            "Depth metrics: MAE and RMSE in metres, accuracies in % of pixels; per sequence pooled over all \
             test views, then the unweighted mean over sequences. Pixels: {}.\n",
            trand_eval::PIXEL_SET_NOTE
        );
        let sections: [(&str, String); 9] = [
            (
                "Depth accuracy at t=0",
                accuracy_markdown(&self.accuracy_t0, n),
            ),
            (
                "Depth accuracy at t=1",
                accuracy_markdown(&self.accuracy_t1, n),
            ),
            (
                "Depth accuracy per object kind (objects of every sequence pooled)",
                kinds::kinds_markdown(&self.per_kind),
            ),
            (
                "Efficiency at t=0",
                efficiency_markdown(&self.efficiency_t0, State::T0),
            ),
            (
                "Efficiency at t=1",
                efficiency_markdown(&self.efficiency_t1, State::T1),
            ),
            (
                "Loss ablation (object-aware 3D loss)",
                accuracy_markdown(&self.loss_ablation, n),
            ),
            (
                "Simulation ablation (t=1)",
                accuracy_markdown(&self.simulation_ablation, n),
            ),
            (
                "Number of training views",
                accuracy_markdown(&self.view_study, n),
            ),
            ("Per sequence", String::new()),
        ];
        for (title, body) in sections {
            let _ = writeln!(s, "## {title}\n");
            if !body.is_empty() {
                let _ = writeln!(s, "{body}");
            }
        }
        for q in &self.per_sequence {
            let _ = writeln!(
                s,
                "### {}\n\n{}\n{}",
                q.sequence,
                accuracy_markdown(&q.rows, 1),
                kinds::objects_markdown(&self.per_object, &q.sequence)
            );
        }
        s
    }
}

/// Builds the tables and writes `tables.md` and `tables.json`.
pub fn write_tables(report: &Path, manifest: &Manifest) -> Result<Tables, ReportError> {
    let t = build_tables(report, manifest)?;
    trand_io::write_atomic(&report.join(layout::TABLES_MD), t.markdown().as_bytes())?;
    let json = serde_json::to_vec_pretty(&t).expect("tables serialise");
    trand_io::write_atomic(&report.join(layout::TABLES_JSON), &json)?;
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{RunSettings, SequenceEntry, SequenceSource};

    fn metrics(mae: f64, acc0: f64) -> Metrics {
        Metrics {
            mae_m: mae,
            rmse_m: 2.0 * mae,
            thresholds_m: trand_eval::THRESHOLDS_M,
            acc: [acc0, 0.5, 0.6, 0.7, 0.8, 1.0],
            pixels: 100,
            uncovered: 0,
            sequences: 1,
            pixel_set: "test".into(),
            per_view: Vec::new(),
        }
    }

    fn put(report: &Path, seq: &str, m: Method, st: State, x: &Metrics, run: serde_json::Value) {
        let dir = layout::run_dir(report, seq, m, st);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("metrics.json"), serde_json::to_string(x).unwrap()).unwrap();
        std::fs::write(dir.join("run.json"), run.to_string()).unwrap();
    }

    fn manifest(methods: &[Method]) -> Manifest {
        let e = |n: &str| SequenceEntry {
            name: n.into(),
            data: n.into(),
            source: SequenceSource::Folder,
        };
        Manifest {
            sequences: vec![e("a"), e("b")],
            methods: methods.to_vec(),
            settings: RunSettings::default(),
        }
    }

    #[test]
    fn means_are_unweighted_over_sequences_and_reused_runs_are_read_from_their_owner() {
        let dir = trand_io::ScratchDir::new("tables").unwrap();
        let r = dir.path();
        let t0 = serde_json::json!({"timings": {"preprocess_s": 1.0, "optimise_s": 3.0, "total_s": 4.0}, "num_surfels": 10});
        put(
            r,
            "a",
            Method::Trand,
            State::T0,
            &metrics(0.01, 0.2),
            t0.clone(),
        );
        put(
            r,
            "b",
            Method::Trand,
            State::T0,
            &metrics(0.03, 0.4),
            serde_json::json!({"num_surfels": 30}),
        );
        put(
            r,
            "a",
            Method::NoSimulation,
            State::T1,
            &metrics(0.05, 0.1),
            serde_json::json!({}),
        );
        let t = build_tables(
            r,
            &manifest(&[Method::Trand, Method::NoSimulation, Method::Views6]),
        )
        .unwrap();
        // t0: only the owner (trand); no-simulation and views-6 reuse it.
        assert_eq!(t.accuracy_t0.len(), 1);
        let m = t.accuracy_t0[0].metrics.as_ref().unwrap();
        assert!((m.mae_m - 0.02).abs() < 1e-12 && (m.acc[0] - 0.3).abs() < 1e-12);
        assert_eq!((m.sequences, t.accuracy_t0[0].sequences), (2, 2));
        let v6 = t
            .view_study
            .iter()
            .find(|r| r.method == Method::Views6 && r.state == State::T0)
            .unwrap();
        assert_eq!(v6.metrics.as_ref().unwrap().mae_m, m.mae_m);
        // t1: trand has no result, no-simulation one of two sequences.
        let rows: Vec<(Method, usize)> = t
            .accuracy_t1
            .iter()
            .map(|r| (r.method, r.sequences))
            .collect();
        assert_eq!(rows, vec![(Method::Trand, 0), (Method::NoSimulation, 1)]);
        // Efficiency: timings from the one sequence that has them, surfels from both.
        let e = &t.efficiency_t0[0];
        assert_eq!(
            (e.sequences, e.timings_s["optimise_s"], e.num_surfels),
            (2, 3.0, Some(20.0))
        );
        assert_eq!(
            t.per_sequence[1].rows[0].metrics.as_ref().unwrap().mae_m,
            0.03
        );
    }

    #[test]
    fn markdown_tables_show_gaps_and_partial_coverage() {
        let row = |m, n, x: Option<Metrics>| AccuracyRow {
            method: m,
            state: State::T1,
            sequences: n,
            metrics: x,
        };
        let md = accuracy_markdown(
            &[
                row(Method::Trand, 2, Some(metrics(0.0123, 0.25))),
                row(Method::PhysicsOnly, 1, Some(metrics(0.5, 0.0))),
                row(Method::NoSimulation, 0, None),
            ],
            2,
        );
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(
            lines[0],
            "| | MAE ↓ | RMSE ↓ | <0.5cm ↑ | <1cm ↑ | <2.5cm ↑ | <5cm ↑ | <10cm ↑ | <20cm ↑ |"
        );
        assert_eq!(
            lines[2],
            "| trand t1 | 0.0123 | 0.0246 | 25.00% | 50.00% | 60.00% | 70.00% | 80.00% | 100.00% |"
        );
        assert!(
            lines[3].starts_with("| physics-only t1 [1/2 seq] | 0.5000 |"),
            "{md}"
        );
        assert_eq!(
            lines[4],
            "| no-simulation t1 [0/2 seq] | – | – | – | – | – | – | – | – |"
        );
        let e = EfficiencyRow {
            method: Method::Trand,
            state: State::T1,
            sequences: 1,
            timings_s: [
                ("simulation_s".to_string(), 2.5),
                ("total_s".to_string(), 4.0),
            ]
            .into(),
            num_surfels: None,
            peak_rss_mb: Some(812.4),
        };
        let md = efficiency_markdown(&[e], State::T1);
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(
            lines[0],
            "| | sequences | detection (s) | meshing (s) | simulation (s) | relocalisation (s) | refinement (s) | total (s) | Gaussians | peak RSS (MB) |"
        );
        assert_eq!(lines[1].matches("---").count(), 10);
        assert_eq!(
            lines[2],
            "| trand t1 | 1 | – | – | 2.50 | – | – | 4.00 | – | 812 |"
        );
    }
}

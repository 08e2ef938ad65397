//! The paper's metrics per ground-truth object and per object kind.
//!
//! * **Per object**: the pixel set of [`crate::metrics`] restricted to one object's visible mask (its
//!   instance id; BOP `mask_visib/{frame}_{obj}.png` files give object ids), pooled over the test
//!   views of the state. The per-object pixel sets partition the pooled one, so the pooled sums are
//!   the sums of the per-object sums.
//! * **Kind**: where the sequence says what an object is (`sequence.json`, written by Blender's
//!   exporter and by `trand synth`: `objects[].kind`, and the orientation as `initial_mode` or
//!   `params_m.initial_mode`), an object is labelled `kind (orientation)`, e.g. `bowl (upright)`: an
//!   upright bowl and an upturned one are different problems (an opening against a dome).
//!   [`kind_label`] is the one rule for that label. The orientation is the one the sequence gives
//!   for t=0, also at t=1.
//! * **Per kind**: the sums of every object with the same label, pooled (pixel-weighted), over any
//!   number of sequences ([`pool_by_kind`]). Objects whose kind the sequence does not name pool under
//!   [`UNKNOWN_KIND`], never by id (id 3 of one sequence is not id 3 of another).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use trand_io::{DepthMap, View};

use crate::metrics::{
    Counts, EvalError, Metrics, PAPER_COLUMNS, add_pixel, check_view, paper_cells,
};

/// The label of an object whose kind the sequence does not name.
pub const UNKNOWN_KIND: &str = "unknown";

/// What the sequence says about one object.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectInfo {
    pub id: u16,
    pub kind: Option<String>,
    pub orientation: Option<String>,
}

impl ObjectInfo {
    /// [`kind_label`] of this object.
    pub fn label(&self) -> String {
        kind_label(self.kind.as_deref(), self.orientation.as_deref())
    }
}

/// The label of an object kind, used for every per-object and per-kind row: `kind (orientation)`
/// (`bowl (upright)`), `kind` when the orientation is not given, [`UNKNOWN_KIND`] when the kind is
/// not (an orientation alone says too little to pool objects by).
pub fn kind_label(kind: Option<&str>, orientation: Option<&str>) -> String {
    match (kind, orientation) {
        (Some(k), Some(o)) => format!("{k} ({o})"),
        (Some(k), None) => k.to_string(),
        (None, _) => UNKNOWN_KIND.to_string(),
    }
}

/// Why `sequence.json` could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ObjectInfoError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: invalid JSON: {source}")]
    Json {
        path: String,
        source: serde_json::Error,
    },
    #[error("{path}: field `{field}`: {reason}")]
    Field {
        path: String,
        field: String,
        reason: &'static str,
    },
}

/// The objects listed in `DATA/sequence.json`; none when the file does not exist (layouts other than
/// BOP have no such file).
pub fn read_object_info(data: &Path) -> Result<Vec<ObjectInfo>, ObjectInfoError> {
    let path = data.join("sequence.json");
    if !path.is_file() {
        return Ok(Vec::new());
    }
    let p = path.display().to_string();
    let text = std::fs::read_to_string(&path).map_err(|source| ObjectInfoError::Io {
        path: p.clone(),
        source,
    })?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|source| ObjectInfoError::Json {
            path: p.clone(),
            source,
        })?;
    let Some(objects) = v.get("objects") else {
        return Ok(Vec::new());
    };
    let field = |i: usize, f: &str, reason| ObjectInfoError::Field {
        path: p.clone(),
        field: format!("objects[{i}].{f}"),
        reason,
    };
    let list = objects
        .as_array()
        .ok_or_else(|| field(0, "", "`objects` is not a list"))?;
    list.iter()
        .enumerate()
        .map(|(i, o)| {
            let id = o
                .get("id")
                .and_then(|x| x.as_u64())
                .filter(|&x| (1..=u16::MAX as u64).contains(&x))
                .ok_or_else(|| field(i, "id", "missing or not an integer in 1..65535"))?;
            let text = |x: Option<&serde_json::Value>| x.and_then(|s| s.as_str()).map(String::from);
            Ok(ObjectInfo {
                id: id as u16,
                kind: text(o.get("kind")),
                orientation: text(o.get("initial_mode"))
                    .or_else(|| text(o.get("params_m").and_then(|p| p.get("initial_mode")))),
            })
        })
        .collect()
}

/// One object's figures at one state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PerObject {
    pub id: u16,
    pub kind: Option<String>,
    pub orientation: Option<String>,
    /// [`kind_label`] of `kind` and `orientation`, for readers of `metrics.json`.
    pub label: String,
    /// The sums, so that objects can be pooled later (per kind, over sequences).
    pub counts: Counts,
    pub metrics: Metrics,
}

impl PerObject {
    /// [`kind_label`] of this object (recomputed, so pooling never depends on a stored label).
    pub fn kind_label(&self) -> String {
        kind_label(self.kind.as_deref(), self.orientation.as_deref())
    }
}

/// Metrics of every GT object seen in the test views (ascending id): for object `i`, the pixels `p`
/// of every view with instance id `i` and GT depth `g > 0`, `e = g − pred` (`pred = 0` where
/// uncovered), MAE = Σ|e| / N, RMSE = √(Σe² / N), δ<τ = #{|e| < τ} / N. Views are checked and paired
/// as by [`crate::evaluate`]; `info` gives kinds and orientations (objects it does not list get
/// none).
pub fn per_object(
    pred: &[(String, DepthMap)],
    gt: &[View],
    info: &[ObjectInfo],
) -> Result<Vec<PerObject>, EvalError> {
    let mut sums: BTreeMap<u16, Counts> = BTreeMap::new();
    for v in gt {
        let (p, d, m) = check_view(pred, v)?;
        for ((&pv, &g), &id) in p.data.iter().zip(&d.data).zip(&m.data) {
            if id != 0 && g > 0.0 && g.is_finite() {
                add_pixel(sums.entry(id).or_default(), pv, g);
            }
        }
    }
    Ok(sums
        .into_iter()
        .map(|(id, counts)| object_row(id, counts, info))
        .collect())
}

fn object_row(id: u16, counts: Counts, info: &[ObjectInfo]) -> PerObject {
    let known = info.iter().find(|o| o.id == id);
    let text = |f: fn(&ObjectInfo) -> &Option<String>| known.and_then(|o| f(o).clone());
    let (kind, orientation) = (text(|o| &o.kind), text(|o| &o.orientation));
    PerObject {
        id,
        label: kind_label(kind.as_deref(), orientation.as_deref()),
        kind,
        orientation,
        metrics: Metrics::from_counts(&counts, Vec::new()),
        counts,
    }
}

/// The objects of one kind label pooled: Σ over the objects of their sums, then the metrics of
/// [`per_object`] on the pooled sums (pixel-weighted, not a mean of the objects' figures).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KindRow {
    /// [`kind_label`].
    pub label: String,
    pub kind: Option<String>,
    pub orientation: Option<String>,
    /// Objects pooled.
    pub objects: usize,
    /// Distinct sequences those objects come from.
    pub sequences: usize,
    pub metrics: Metrics,
}

/// Pools `(sequence, object)` pairs from any number of sequences by [`kind_label`]: named kinds in
/// ascending label order, then [`UNKNOWN_KIND`].
pub fn pool_by_kind<'a>(
    objects: impl IntoIterator<Item = (&'a str, &'a PerObject)>,
) -> Vec<KindRow> {
    struct Pool<'a> {
        first: &'a PerObject,
        objects: usize,
        sequences: std::collections::BTreeSet<&'a str>,
        counts: Counts,
    }
    let mut by: BTreeMap<(bool, String), Pool<'a>> = BTreeMap::new();
    for (seq, o) in objects {
        let e = by
            .entry((o.kind.is_none(), o.kind_label()))
            .or_insert(Pool {
                first: o,
                objects: 0,
                sequences: Default::default(),
                counts: Counts::default(),
            });
        e.objects += 1;
        e.sequences.insert(seq);
        e.counts.add(&o.counts);
    }
    by.into_iter()
        .map(|((_, label), p)| KindRow {
            label,
            kind: p.first.kind.clone(),
            orientation: p.first.orientation.clone(),
            objects: p.objects,
            sequences: p.sequences.len(),
            metrics: Metrics::from_counts(&p.counts, Vec::new()),
        })
        .collect()
}

/// A Markdown table of objects: id, kind label, pixels and the paper's columns.
pub fn object_table(rows: &[PerObject]) -> String {
    let mut s = format!(
        "| object | kind | pixels | {PAPER_COLUMNS}\n|---|---|---|{}\n",
        "---|".repeat(8)
    );
    for r in rows {
        s += &format!(
            "| {} | {} | {} |{}\n",
            r.id,
            r.kind_label(),
            r.metrics.pixels,
            paper_cells(&r.metrics)
        );
    }
    s
}

/// A Markdown table of kinds: label, objects, sequences, pixels, MAE, and the shares within 2.5 and
/// 5 cm.
pub fn kind_table(rows: &[KindRow]) -> String {
    let mut s = String::from(
        "| kind | objects | sequences | pixels | MAE ↓ | <2.5cm ↑ | <5cm ↑ |\n|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let m = &r.metrics;
        s += &format!(
            "| {} | {} | {} | {} | {:.4} | {:.2}% | {:.2}% |\n",
            r.label,
            r.objects,
            r.sequences,
            m.pixels,
            m.mae_m,
            100.0 * m.acc[2],
            100.0 * m.acc[3]
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::{Camera, Intrinsics};
    use trand_io::Image;

    fn view(name: &str, depth: Vec<f32>, inst: Vec<u16>) -> View {
        let cam = Camera::look_at(
            Intrinsics::centered(10.0, 3, 2),
            glam::DVec3::Z,
            glam::DVec3::ZERO,
            glam::DVec3::Y,
        );
        View {
            name: name.into(),
            frame: 0,
            camera: cam,
            rgb: None,
            instance: Some(Image::from_vec(3, 2, 1, inst).unwrap()),
            depth: Some(Image::from_vec(3, 2, 1, depth).unwrap()),
        }
    }

    fn pred(name: &str, d: Vec<f32>) -> (String, DepthMap) {
        (name.into(), Image::from_vec(3, 2, 1, d).unwrap())
    }

    /// Two 3×2 views of objects 3 and 7, with a background pixel and an object pixel without GT
    /// depth in each. Every error is a power of two, so every figure below is exact.
    /// Object 3: |e| = 1/256, 1/32 (view a), 0, 1/128 (view b).
    /// Object 7: |e| = 1/8 (a, uncovered: pred 0), 0 (a), 1/16, 1 (b, uncovered: pred NaN).
    fn case() -> (Vec<(String, DepthMap)>, Vec<View>) {
        let gt = vec![
            view(
                "a",
                vec![1.0, 1.0, 0.125, 2.0, 1.0, 0.0],
                vec![3, 3, 7, 0, 7, 3],
            ),
            view(
                "b",
                vec![1.5, 0.0, 1.0, 1.0, 1.0, 1.0],
                vec![3, 7, 7, 7, 3, 0],
            ),
        ];
        let pr = vec![
            pred(
                "a",
                vec![1.0 + 1.0 / 256.0, 1.0 - 1.0 / 32.0, 0.0, 5.0, 1.0, 1.0],
            ),
            pred(
                "b",
                vec![1.5, 9.0, 1.0 + 1.0 / 16.0, f32::NAN, 1.0 + 1.0 / 128.0, 1.0],
            ),
        ];
        (pr, gt)
    }

    fn bowl_upright(id: u16) -> ObjectInfo {
        ObjectInfo {
            id,
            kind: Some("bowl".into()),
            orientation: Some("upright".into()),
        }
    }

    #[test]
    fn per_object_metrics_match_a_hand_computed_case() {
        let (pr, gt) = case();
        let info = vec![bowl_upright(3), bowl_upright(11)];
        let rows = per_object(&pr, &gt, &info).unwrap();
        assert_eq!(
            rows.iter().map(|r| r.id).collect::<Vec<_>>(),
            vec![3, 7],
            "objects seen in the views only, ascending"
        );
        let (o3, o7) = (&rows[0], &rows[1]);
        assert_eq!(
            (
                o3.label.as_str(),
                o3.kind.as_deref(),
                o3.orientation.as_deref()
            ),
            ("bowl (upright)", Some("bowl"), Some("upright"))
        );
        assert_eq!(
            (o7.label.as_str(), o7.kind.as_deref()),
            (UNKNOWN_KIND, None)
        );
        // Object 3: Σ|e| = 11/256, Σe² = 69/65536.
        let c3 = Counts {
            pixels: 4,
            uncovered: 0,
            abs_sum: 11.0 / 256.0,
            sq_sum: 69.0 / 65536.0,
            within: [2, 3, 3, 4, 4, 4],
        };
        assert_eq!(o3.counts, c3);
        let m3 = &o3.metrics;
        assert_eq!((m3.pixels, m3.uncovered), (4, 0));
        assert_eq!(m3.mae_m, 11.0 / 1024.0);
        assert_eq!(m3.rmse_m, 69f64.sqrt() / 512.0);
        assert_eq!(m3.acc, [0.5, 0.75, 0.75, 1.0, 1.0, 1.0]);
        // Object 7: Σ|e| = 19/16, Σe² = 261/256; the uncovered pixels cost their GT depth.
        let c7 = Counts {
            pixels: 4,
            uncovered: 2,
            abs_sum: 19.0 / 16.0,
            sq_sum: 261.0 / 256.0,
            within: [1, 1, 1, 1, 2, 3],
        };
        assert_eq!(o7.counts, c7);
        let m7 = &o7.metrics;
        assert_eq!((m7.pixels, m7.uncovered), (4, 2));
        assert_eq!(m7.mae_m, 19.0 / 64.0);
        assert_eq!(m7.rmse_m, 261f64.sqrt() / 32.0);
        assert_eq!(m7.acc, [0.25, 0.25, 0.25, 0.25, 0.5, 0.75]);
    }

    #[test]
    fn the_objects_partition_the_pooled_pixels() {
        let (pr, gt) = case();
        let pooled = crate::evaluate(&pr, &gt).unwrap();
        let rows = per_object(&pr, &gt, &[]).unwrap();
        let mut sum = Counts::default();
        for r in &rows {
            sum.add(&r.counts);
        }
        let m = Metrics::from_counts(&sum, Vec::new());
        assert_eq!((m.pixels, m.uncovered), (pooled.pixels, pooled.uncovered));
        assert_eq!(
            (m.mae_m, m.rmse_m, m.acc),
            (pooled.mae_m, pooled.rmse_m, pooled.acc)
        );
    }

    #[test]
    fn objects_of_one_kind_pool_their_pixels_across_sequences() {
        let (pr, gt) = case();
        let mug = |id| ObjectInfo {
            id,
            kind: Some("mug".into()),
            orientation: Some("upright".into()),
        };
        // Sequence s: 3 is a mug, 7 unnamed; sequence t: 3 an upright bowl, 7 a mug.
        let s = per_object(&pr, &gt, &[mug(3)]).unwrap();
        let t = per_object(&pr, &gt, &[bowl_upright(3), mug(7)]).unwrap();
        let rows = pool_by_kind(s.iter().map(|o| ("s", o)).chain(t.iter().map(|o| ("t", o))));
        let labels: Vec<&str> = rows.iter().map(|r| r.label.as_str()).collect();
        assert_eq!(labels, ["bowl (upright)", "mug (upright)", UNKNOWN_KIND]);
        let mugs = &rows[1];
        assert_eq!((mugs.objects, mugs.sequences), (2, 2));
        // Object 3 (Σ|e| = 11/256) and object 7 (19/16) over 8 pixels, not the mean of their MAEs.
        assert_eq!(mugs.metrics.pixels, 8);
        assert_eq!(mugs.metrics.uncovered, 2);
        assert_eq!(mugs.metrics.mae_m, (11.0 / 256.0 + 19.0 / 16.0) / 8.0);
        assert_eq!(mugs.metrics.acc[2], 4.0 / 8.0);
        assert_eq!((rows[0].objects, rows[0].sequences), (1, 1));
        assert_eq!(rows[0].metrics.mae_m, 11.0 / 1024.0);
        assert_eq!(
            (rows[2].objects, rows[2].sequences, rows[2].kind.as_deref()),
            (1, 1, None)
        );
        // The same object twice from one sequence counts one sequence.
        let twice = pool_by_kind([("s", &s[0]), ("s", &s[0])]);
        assert_eq!(
            (
                twice[0].objects,
                twice[0].sequences,
                twice[0].metrics.pixels
            ),
            (2, 1, 8)
        );
    }

    #[test]
    fn kind_label_names_kind_and_orientation_and_never_an_id() {
        assert_eq!(
            kind_label(Some("bowl"), Some("inverted")),
            "bowl (inverted)"
        );
        assert_eq!(kind_label(Some("bowl"), Some("upright")), "bowl (upright)");
        assert_eq!(kind_label(Some("bowl"), None), "bowl");
        assert_eq!(kind_label(None, Some("upright")), UNKNOWN_KIND);
        assert_eq!(kind_label(None, None), UNKNOWN_KIND);
        assert_eq!(bowl_upright(4).label(), "bowl (upright)");
    }

    #[test]
    fn pooling_uses_the_label_rule_not_a_stored_label() {
        let (pr, gt) = case();
        let mut rows = per_object(&pr, &gt, &[bowl_upright(3)]).unwrap();
        rows[0].label = "object 3".into();
        rows[1].label = "object 7".into();
        let pooled = pool_by_kind(rows.iter().map(|o| ("s", o)));
        let labels: Vec<&str> = pooled.iter().map(|r| r.label.as_str()).collect();
        assert_eq!(labels, ["bowl (upright)", UNKNOWN_KIND]);
    }

    #[test]
    fn tables_show_every_object_and_kind_row() {
        let (pr, gt) = case();
        let rows = per_object(&pr, &gt, &[bowl_upright(3)]).unwrap();
        let t = object_table(&rows);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(
            lines[0],
            "| object | kind | pixels | MAE ↓ | RMSE ↓ | <0.5cm ↑ | <1cm ↑ | <2.5cm ↑ | <5cm ↑ | <10cm ↑ | <20cm ↑ |"
        );
        assert_eq!(lines[1].matches("---").count(), 11);
        assert_eq!(
            lines[2],
            "| 3 | bowl (upright) | 4 | 0.0107 | 0.0162 | 50.00% | 75.00% | 75.00% | 100.00% | 100.00% | 100.00% |"
        );
        assert!(
            lines[3].starts_with("| 7 | unknown | 4 | 0.2969 | 0.5049 | 25.00% |"),
            "{t}"
        );
        let k = kind_table(&pool_by_kind(rows.iter().map(|o| ("s", o))));
        let lines: Vec<&str> = k.lines().collect();
        assert_eq!(lines.len(), 4, "{k}");
        assert_eq!(
            lines[2],
            "| bowl (upright) | 1 | 1 | 4 | 0.0107 | 75.00% | 100.00% |"
        );
    }

    #[test]
    fn sequence_json_gives_kinds_and_a_bad_one_names_the_field() {
        let dir = trand_io::ScratchDir::new("objinfo").unwrap();
        assert!(
            read_object_info(dir.path()).unwrap().is_empty(),
            "no file: no kinds"
        );
        let write = |s: &str| std::fs::write(dir.path().join("sequence.json"), s).unwrap();
        write(
            r#"{"objects": [{"id": 1, "kind": "bowl", "params_m": {"initial_mode": "upright"}},
                               {"id": 2, "kind": "sphere", "initial_mode": "upright"}, {"id": 3}]}"#,
        );
        let info = read_object_info(dir.path()).unwrap();
        assert_eq!(info[0].label(), "bowl (upright)");
        assert_eq!(info[1].label(), "sphere (upright)");
        assert_eq!(info[2].label(), UNKNOWN_KIND);
        write(r#"{"objects": [{"id": 1}, {"kind": "mug"}]}"#);
        let e = read_object_info(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("objects[1].id") && e.contains("sequence.json"),
            "{e}"
        );
        write("{not json");
        let e = read_object_info(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("sequence.json") && e.contains("invalid JSON"),
            "{e}"
        );
    }
}

//! The paper's metrics per ground-truth object and per object kind.
//!
//! * **Per object**: the pixel set of [`crate::metrics`] restricted to one object's visible mask (its
//!   instance id), pooled over the test views of the state. The per-object pixel sets partition the
//!   pooled one, so the pooled sums are the sums of the per-object sums.
//! * **Kind**: where the sequence says what an object is (`sequence.json`, written by Blender's
//!   exporter and by `trand synth`: `objects[].kind`, and the orientation as `initial_mode` or
//!   `params_m.initial_mode`), an object is labelled `kind (orientation)`, e.g. `bowl (upright)`: an
//!   upright bowl and an upturned one are different problems (an opening against a dome).
//! * **Per kind**: the sums of every object with the same label, pooled (pixel-weighted), over any
//!   number of sequences ([`pool_by_label`]).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use trand_io::{DepthMap, View};

use crate::metrics::{Counts, EvalError, Metrics, add_pixel, check_view};

/// What the sequence says about one object.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectInfo {
    pub id: u16,
    pub kind: Option<String>,
    pub orientation: Option<String>,
}

impl ObjectInfo {
    /// `kind (orientation)`, `kind`, or `object ID` when the sequence does not say.
    pub fn label(&self) -> String {
        kind_label(self.id, self.kind.as_deref(), self.orientation.as_deref())
    }
}

/// The label rule of [`ObjectInfo::label`].
pub fn kind_label(id: u16, kind: Option<&str>, orientation: Option<&str>) -> String {
    match (kind, orientation) {
        (Some(k), Some(o)) => format!("{k} ({o})"),
        (Some(k), None) => k.to_string(),
        _ => format!("object {id}"),
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
    /// [`ObjectInfo::label`].
    pub label: String,
    /// The sums, so that objects can be pooled later (per kind, over sequences).
    pub counts: Counts,
    pub metrics: Metrics,
}

/// Metrics of every GT object seen in the test views (ascending id). Views are checked and paired as
/// by [`crate::evaluate`].
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
        .map(|(id, counts)| {
            let known = info
                .iter()
                .find(|o| o.id == id)
                .cloned()
                .unwrap_or(ObjectInfo {
                    id,
                    ..Default::default()
                });
            PerObject {
                id,
                label: known.label(),
                kind: known.kind,
                orientation: known.orientation,
                metrics: Metrics::from_counts(&counts, Vec::new()),
                counts,
            }
        })
        .collect())
}

/// Objects of one label pooled: pixel-weighted metrics over every object with that label.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LabelRow {
    pub label: String,
    /// Objects pooled.
    pub objects: usize,
    pub metrics: Metrics,
}

/// Pools `objects` (from any number of sequences) by label, labels in ascending order.
pub fn pool_by_label<'a>(objects: impl IntoIterator<Item = &'a PerObject>) -> Vec<LabelRow> {
    let mut by: BTreeMap<&str, (usize, Counts)> = BTreeMap::new();
    for o in objects {
        let e = by.entry(o.label.as_str()).or_default();
        e.0 += 1;
        e.1.add(&o.counts);
    }
    by.into_iter()
        .map(|(label, (objects, c))| LabelRow {
            label: label.to_string(),
            objects,
            metrics: Metrics::from_counts(&c, Vec::new()),
        })
        .collect()
}

/// A Markdown table of objects: id, label, pixels, MAE, and the share within 2.5 cm and 5 cm.
pub fn object_table(rows: &[PerObject]) -> String {
    let mut s = String::from(
        "| object | kind | pixels | MAE ↓ | <2.5cm ↑ | <5cm ↑ |\n|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let m = &r.metrics;
        s += &format!(
            "| {} | {} | {} | {:.4} | {:.2}% | {:.2}% |\n",
            r.id,
            r.label,
            m.pixels,
            m.mae_m,
            100.0 * m.acc[2],
            100.0 * m.acc[3]
        );
    }
    s
}

/// A Markdown table of pooled labels: label, objects, pixels, MAE, and the shares within 2.5 and 5 cm.
pub fn label_table(rows: &[LabelRow]) -> String {
    let mut s = String::from(
        "| kind | objects | pixels | MAE ↓ | <2.5cm ↑ | <5cm ↑ |\n|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let m = &r.metrics;
        s += &format!(
            "| {} | {} | {} | {:.4} | {:.2}% | {:.2}% |\n",
            r.label,
            r.objects,
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
            Intrinsics::centered(10.0, 2, 2),
            glam::DVec3::Z,
            glam::DVec3::ZERO,
            glam::DVec3::Y,
        );
        View {
            name: name.into(),
            frame: 0,
            camera: cam,
            rgb: None,
            instance: Some(Image::from_vec(2, 2, 1, inst).unwrap()),
            depth: Some(Image::from_vec(2, 2, 1, depth).unwrap()),
        }
    }

    fn pred(name: &str, d: Vec<f32>) -> (String, DepthMap) {
        (name.into(), Image::from_vec(2, 2, 1, d).unwrap())
    }

    /// Two views of objects 3 and 7, a background pixel and an object pixel without GT depth.
    /// |e| of object 3: 0.01, 0.03 (view a), 0 (b); of object 7: 0.06 (a, uncovered), 0.15, 0.15 (b).
    fn case() -> (Vec<(String, DepthMap)>, Vec<View>) {
        let gt = vec![
            view("a", vec![1.0, 1.0, 0.06, 2.0], vec![3, 3, 7, 0]),
            view("b", vec![1.5, 0.0, 1.2, 1.2], vec![3, 7, 7, 7]),
        ];
        let pr = vec![
            pred("a", vec![1.01, 0.97, 0.0, 5.0]),
            pred("b", vec![1.5, 9.0, 1.05, 1.35]),
        ];
        (pr, gt)
    }

    #[test]
    fn per_object_metrics_match_a_hand_computed_case() {
        let (pr, gt) = case();
        let info = vec![ObjectInfo {
            id: 3,
            kind: Some("bowl".into()),
            orientation: Some("upright".into()),
        }];
        let rows = per_object(&pr, &gt, &info).unwrap();
        assert_eq!(rows.iter().map(|r| r.id).collect::<Vec<_>>(), vec![3, 7]);
        let (o3, o7) = (&rows[0].metrics, &rows[1].metrics);
        // Object 3: |e| = 0.01, 0.03, 0.0.
        assert_eq!(o3.pixels, 3);
        assert!((o3.mae_m - 0.04 / 3.0).abs() < 1e-6, "{}", o3.mae_m);
        assert!((o3.rmse_m - (0.001f64 / 3.0).sqrt()).abs() < 1e-6);
        assert!((o3.acc[2] - 2.0 / 3.0).abs() < 1e-12);
        assert!((o3.acc[3] - 1.0).abs() < 1e-12);
        assert_eq!(rows[0].label, "bowl (upright)");
        // Object 7: 0.06 uncovered (|e| = GT), 0.15, 0.15 (no GT depth at b[1]: not counted).
        assert_eq!(o7.pixels, 3);
        assert_eq!(o7.uncovered, 1);
        assert!((o7.mae_m - 0.12).abs() < 1e-6, "{}", o7.mae_m);
        assert!((o7.acc[3] - 0.0).abs() < 1e-12);
        assert!((o7.acc[4] - 1.0 / 3.0).abs() < 1e-12, "{}", o7.acc[4]);
        assert!((o7.acc[5] - 1.0).abs() < 1e-12);
        assert_eq!(rows[1].label, "object 7");
    }

    #[test]
    fn the_objects_partition_the_pooled_pixels() {
        let (pr, gt) = case();
        let pooled = crate::evaluate(&pr, &gt).unwrap();
        let rows = per_object(&pr, &gt, &[]).unwrap();
        let all = pool_by_label(&rows);
        let mut sum = Counts::default();
        for r in &rows {
            sum.add(&r.counts);
        }
        let m = Metrics::from_counts(&sum, Vec::new());
        assert_eq!(m.pixels, pooled.pixels);
        assert!((m.mae_m - pooled.mae_m).abs() < 1e-12);
        assert_eq!(all.len(), 2, "two labels: object 3, object 7");
    }

    #[test]
    fn pooling_by_label_weights_objects_by_pixels_across_sequences() {
        let (pr, gt) = case();
        let info = vec![
            ObjectInfo {
                id: 3,
                kind: Some("mug".into()),
                orientation: Some("upright".into()),
            },
            ObjectInfo {
                id: 7,
                kind: Some("mug".into()),
                orientation: Some("upright".into()),
            },
        ];
        let mut rows = per_object(&pr, &gt, &info).unwrap();
        rows.extend(per_object(&pr, &gt, &info).unwrap());
        let pooled = pool_by_label(&rows);
        assert_eq!(pooled.len(), 1);
        assert_eq!(pooled[0].label, "mug (upright)");
        assert_eq!(pooled[0].objects, 4);
        assert_eq!(pooled[0].metrics.pixels, 12);
        assert!((pooled[0].metrics.mae_m - 0.8 / 12.0).abs() < 1e-6);
    }

    #[test]
    fn labels_name_kind_and_orientation_where_known() {
        assert_eq!(
            kind_label(2, Some("bowl"), Some("inverted")),
            "bowl (inverted)"
        );
        assert_eq!(kind_label(2, Some("bowl"), None), "bowl");
        assert_eq!(kind_label(2, None, Some("upright")), "object 2");
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
        assert_eq!(info[2].label(), "object 3");
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

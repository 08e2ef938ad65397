//! The paper's depth metrics, as the authors' evaluation computes them (reference notes §6 and §10 row 16).
//!
//! * **Pixels**: in each GT test view, the pixels of any object (instance id ≠ 0, the union of *all* GT
//!   visible masks) whose GT depth is > 0.
//! * **Error** `e = gt − pred` in metres. A pixel the prediction leaves uncovered (`pred = 0`, or
//!   non-finite) counts with `|e| = gt`; it is never skipped.
//! * **Pooled** over every pixel of every test view of the sequence (not averaged per image):
//!   MAE = Σ|e| / N, RMSE = √(Σe² / N), and for τ = 0.5, 1, 2.5, 5, 10, 20 cm the share of pixels with
//!   `|e| < τ` (strict).
//! * Across sequences, [`mean_over_sequences`] takes the unweighted mean of the per-sequence figures.

use serde::{Deserialize, Serialize};
use trand_io::{DepthMap, View};

/// The accuracy thresholds in metres (0.5, 1, 2.5, 5, 10, 20 cm), the paper's table columns.
pub const THRESHOLDS_M: [f64; 6] = [0.005, 0.01, 0.025, 0.05, 0.1, 0.2];

/// What `metrics.json` says about the pixel set.
pub const PIXEL_SET_NOTE: &str = "pixels of the union of all GT objects' visible masks (instance id != 0) with GT depth > 0, \
pooled over all test views; uncovered pixels (prediction 0 or non-finite) count with error = GT depth; \
accuracy thresholds are strict (|error| < tau)";

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EvalError {
    #[error("no prediction for test view {view}")]
    MissingPrediction { view: String },
    #[error("prediction for {view} is {pred_w}x{pred_h}, GT is {gt_w}x{gt_h}")]
    SizeMismatch {
        view: String,
        pred_w: u32,
        pred_h: u32,
        gt_w: u32,
        gt_h: u32,
    },
    #[error("GT view {view} has no {what} loaded")]
    MissingGt { view: String, what: &'static str },
    #[error("GT view {view}: instance map and depth differ in size or are not single-channel")]
    GtInconsistent { view: String },
    #[error("no GT views to evaluate")]
    NoViews,
}

/// Raw sums of one view (or of a pool of views).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Counts {
    /// Evaluated pixels.
    pub pixels: u64,
    /// Evaluated pixels the prediction left at 0.
    pub uncovered: u64,
    /// Σ |e| (m).
    pub abs_sum: f64,
    /// Σ e² (m²).
    pub sq_sum: f64,
    /// Pixels with |e| < τ, per [`THRESHOLDS_M`].
    pub within: [u64; 6],
}

impl Counts {
    /// Adds another pool's sums.
    pub fn add(&mut self, o: &Counts) {
        self.pixels += o.pixels;
        self.uncovered += o.uncovered;
        self.abs_sum += o.abs_sum;
        self.sq_sum += o.sq_sum;
        for (a, b) in self.within.iter_mut().zip(o.within) {
            *a += b;
        }
    }
}

/// One view's counts, by name.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewCounts {
    pub view: String,
    #[serde(flatten)]
    pub counts: Counts,
}

/// Depth metrics of one sequence state (or a mean over sequences).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Mean absolute error, metres.
    pub mae_m: f64,
    /// Root mean squared error, metres.
    pub rmse_m: f64,
    /// The thresholds of `acc`, metres.
    pub thresholds_m: [f64; 6],
    /// Share of pixels with |error| < threshold, in [0, 1].
    pub acc: [f64; 6],
    /// Evaluated pixels (summed over sequences for a mean).
    pub pixels: u64,
    /// Evaluated pixels with no prediction.
    pub uncovered: u64,
    /// Sequences averaged (1 for a single sequence).
    pub sequences: usize,
    /// How the pixel set and the errors are defined.
    pub pixel_set: String,
    /// Per-view counts (empty for a mean over sequences).
    pub per_view: Vec<ViewCounts>,
}

impl Metrics {
    /// The figures of pooled sums (NaN where there are no pixels).
    pub fn from_counts(total: &Counts, per_view: Vec<ViewCounts>) -> Self {
        let n = total.pixels as f64;
        let div = |v: f64| if total.pixels == 0 { f64::NAN } else { v / n };
        Self {
            mae_m: div(total.abs_sum),
            rmse_m: div(total.sq_sum).sqrt(),
            thresholds_m: THRESHOLDS_M,
            acc: total.within.map(|w| div(w as f64)),
            pixels: total.pixels,
            uncovered: total.uncovered,
            sequences: 1,
            pixel_set: PIXEL_SET_NOTE.into(),
            per_view,
        }
    }
}

/// Adds one evaluated pixel of GT depth `g` (> 0) and prediction `p` (uncovered when 0 or not
/// finite) to `c`.
pub fn add_pixel(c: &mut Counts, p: f32, g: f32) {
    let p = if p.is_finite() { p as f64 } else { 0.0 };
    if p == 0.0 {
        c.uncovered += 1;
    }
    let e = (g as f64 - p).abs();
    c.pixels += 1;
    c.abs_sum += e;
    c.sq_sum += e * e;
    for (w, &t) in c.within.iter_mut().zip(&THRESHOLDS_M) {
        if e < t {
            *w += 1;
        }
    }
}

/// Counts of one view: `gt_depth`, `instance` and `pred` of the same size (checked by [`evaluate`]).
pub fn view_counts(
    pred: &DepthMap,
    gt_depth: &DepthMap,
    instance: &trand_io::InstanceMap,
) -> Counts {
    let mut c = Counts::default();
    for ((&p, &g), &id) in pred.data.iter().zip(&gt_depth.data).zip(&instance.data) {
        if id != 0 && g > 0.0 && g.is_finite() {
            add_pixel(&mut c, p, g);
        }
    }
    c
}

/// The prediction paired with GT view `v` by name, and `v`'s depth and instance map, all checked to
/// be single-channel and of one size.
pub(crate) fn check_view<'a>(
    pred: &'a [(String, DepthMap)],
    v: &'a View,
) -> Result<(&'a DepthMap, &'a DepthMap, &'a trand_io::InstanceMap), EvalError> {
    let (_, p) =
        pred.iter()
            .find(|(n, _)| *n == v.name)
            .ok_or_else(|| EvalError::MissingPrediction {
                view: v.name.clone(),
            })?;
    let d = v.depth.as_ref().ok_or_else(|| EvalError::MissingGt {
        view: v.name.clone(),
        what: "depth",
    })?;
    let m = v.instance.as_ref().ok_or_else(|| EvalError::MissingGt {
        view: v.name.clone(),
        what: "instance map",
    })?;
    if !p.same_size(d) || p.channels != 1 {
        return Err(EvalError::SizeMismatch {
            view: v.name.clone(),
            pred_w: p.width,
            pred_h: p.height,
            gt_w: d.width,
            gt_h: d.height,
        });
    }
    if !m.same_size(d) || m.channels != 1 || d.channels != 1 {
        return Err(EvalError::GtInconsistent {
            view: v.name.clone(),
        });
    }
    Ok((p, d, m))
}

/// Evaluates predicted depths against GT views (each with `depth` and `instance` loaded), pairing
/// them by view name. Every GT view needs a prediction; extra predictions are ignored.
pub fn evaluate(pred: &[(String, DepthMap)], gt: &[View]) -> Result<Metrics, EvalError> {
    if gt.is_empty() {
        return Err(EvalError::NoViews);
    }
    let mut total = Counts::default();
    let mut per_view = Vec::with_capacity(gt.len());
    for v in gt {
        let (p, d, m) = check_view(pred, v)?;
        let c = view_counts(p, d, m);
        total.add(&c);
        per_view.push(ViewCounts {
            view: v.name.clone(),
            counts: c,
        });
    }
    Ok(Metrics::from_counts(&total, per_view))
}

/// Unweighted mean of per-sequence figures (the paper's cross-sequence number).
pub fn mean_over_sequences(seqs: &[Metrics]) -> Metrics {
    let n = seqs.len() as f64;
    let mean = |f: &dyn Fn(&Metrics) -> f64| seqs.iter().map(f).sum::<f64>() / n;
    Metrics {
        mae_m: mean(&|m| m.mae_m),
        rmse_m: mean(&|m| m.rmse_m),
        thresholds_m: THRESHOLDS_M,
        acc: std::array::from_fn(|k| mean(&|m| m.acc[k])),
        pixels: seqs.iter().map(|m| m.pixels).sum(),
        uncovered: seqs.iter().map(|m| m.uncovered).sum(),
        sequences: seqs.iter().map(|m| m.sequences).sum(),
        pixel_set: format!(
            "unweighted mean over sequences of pooled per-sequence metrics; per sequence: {PIXEL_SET_NOTE}"
        ),
        per_view: Vec::new(),
    }
}

/// The paper's column headers in Markdown: MAE, RMSE and the accuracy at every threshold.
pub const PAPER_COLUMNS: &str =
    "MAE ↓ | RMSE ↓ | <0.5cm ↑ | <1cm ↑ | <2.5cm ↑ | <5cm ↑ | <10cm ↑ | <20cm ↑ |";

/// The Markdown cells under [`PAPER_COLUMNS`]: MAE and RMSE in metres (4 decimals), accuracies in %.
pub fn paper_cells(m: &Metrics) -> String {
    let mut s = format!(" {:.4} | {:.4} |", m.mae_m, m.rmse_m);
    for a in m.acc {
        s += &format!(" {:.2}% |", 100.0 * a);
    }
    s
}

/// A Markdown table with the paper's columns ([`PAPER_COLUMNS`], [`paper_cells`]).
pub fn table(rows: &[(&str, &Metrics)]) -> String {
    let mut s = format!("| | {PAPER_COLUMNS}\n|---|{}\n", "---|".repeat(8));
    for (name, m) in rows {
        s += &format!("| {name} |{}\n", paper_cells(m));
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

    #[test]
    fn only_object_pixels_with_gt_depth_count_and_uncovered_pixels_cost_their_depth() {
        // Pixel 0: background (ignored). Pixel 1: object, error 0.003. Pixel 2: object, GT depth 0
        // (ignored). Pixel 3: object of another id, uncovered: error = 0.5.
        let gt = [view("a", vec![1.0, 1.0, 0.0, 0.5], vec![0, 1, 1, 7])];
        let m = evaluate(&[pred("a", vec![9.0, 1.003, 9.0, 0.0])], &gt).unwrap();
        assert_eq!((m.pixels, m.uncovered), (2, 1));
        assert!((m.mae_m - (0.003 + 0.5) / 2.0).abs() < 1e-7);
        assert!((m.rmse_m - ((0.003f64.powi(2) + 0.25) / 2.0).sqrt()).abs() < 1e-7);
        assert_eq!(m.acc, [0.5, 0.5, 0.5, 0.5, 0.5, 0.5]);
    }

    #[test]
    fn each_threshold_counts_the_errors_below_it() {
        // Errors 0.25, 0.125, 0, 0.0078125 (all exact in binary).
        let gt = [view("a", vec![1.0, 1.0, 1.0, 1.0], vec![1, 1, 1, 1])];
        let m = evaluate(&[pred("a", vec![1.25, 1.125, 1.0, 0.9921875])], &gt).unwrap();
        assert_eq!(m.acc, [0.25, 0.5, 0.5, 0.5, 0.5, 0.75]);
    }

    #[test]
    fn pooling_weights_views_by_pixel_count() {
        let gt = [
            view("a", vec![1.0; 4], vec![1, 1, 1, 0]),
            view("b", vec![1.0; 4], vec![1, 0, 0, 0]),
        ];
        let m = evaluate(&[pred("b", vec![1.4; 4]), pred("a", vec![1.0; 4])], &gt).unwrap();
        assert_eq!(m.pixels, 4);
        assert!(
            (m.mae_m - 0.1).abs() < 1e-6,
            "pooled, not the per-view mean 0.2"
        );
        assert_eq!(
            m.per_view
                .iter()
                .map(|v| v.counts.pixels)
                .collect::<Vec<_>>(),
            vec![3, 1]
        );
    }

    #[test]
    fn missing_prediction_and_size_mismatch_are_errors() {
        let gt = [view("a", vec![1.0; 4], vec![1; 4])];
        assert_eq!(
            evaluate(&[pred("b", vec![1.0; 4])], &gt),
            Err(EvalError::MissingPrediction { view: "a".into() })
        );
        let small = ("a".to_string(), Image::filled(1, 2, 1, 1.0f32));
        assert!(matches!(
            evaluate(&[small], &gt),
            Err(EvalError::SizeMismatch {
                pred_w: 1,
                gt_w: 2,
                ..
            })
        ));
        let mut bad = view("a", vec![1.0; 4], vec![1; 4]);
        bad.instance = Some(Image::filled(1, 1, 1, 1u16));
        assert_eq!(
            evaluate(&[pred("a", vec![1.0; 4])], &[bad]),
            Err(EvalError::GtInconsistent { view: "a".into() })
        );
        assert_eq!(evaluate(&[], &[]), Err(EvalError::NoViews));
    }

    #[test]
    fn mean_over_sequences_is_unweighted_and_table_has_paper_columns() {
        let gt_a = [view("a", vec![1.0; 4], vec![1; 4])];
        let gt_b = [view("b", vec![1.0; 4], vec![1, 0, 0, 0])];
        let a = evaluate(&[pred("a", vec![1.0; 4])], &gt_a).unwrap();
        let b = evaluate(&[pred("b", vec![1.5; 4])], &gt_b).unwrap();
        let m = mean_over_sequences(&[a.clone(), b]);
        assert!((m.mae_m - 0.25).abs() < 1e-9);
        assert_eq!((m.sequences, m.pixels), (2, 5));
        assert_eq!(m.acc[5], 0.5);
        let t = table(&[("seq_a", &a), ("mean", &m)]);
        assert!(
            t.contains(
                "| MAE ↓ | RMSE ↓ | <0.5cm ↑ | <1cm ↑ | <2.5cm ↑ | <5cm ↑ | <10cm ↑ | <20cm ↑ |"
            ),
            "{t}"
        );
        assert!(t.contains("| seq_a | 0.0000 | 0.0000 | 100.00% |"), "{t}");
        assert!(t.contains("| mean | 0.2500 |"), "{t}");
        let j = serde_json::to_value(&a).unwrap();
        assert_eq!(j["pixels"], 4);
        assert!(
            j["pixel_set"]
                .as_str()
                .unwrap()
                .contains("union of all GT objects")
        );
        assert_eq!(j["per_view"][0]["view"], "a");
    }
}

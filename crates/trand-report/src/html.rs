//! The static HTML report: `index.html` (tables, links) and `seq/<sequence>.html` per sequence, with
//! PNGs under `assets/<sequence>/`. Pages are plain HTML with inline CSS and inline SVG plots; images
//! are relative files (the colour-mapped ones written here, predicted object maps linked from the run
//! folders), so the folder can be opened or copied as is.
//!
//! A sequence page: its metrics; the training views; per state, for the first [`SHOWN_VIEWS`] test
//! views of the primary method (the first of the bench's methods with a result, `trand` when run) the
//! GT and rendered depth on one colour scale, the absolute error, the signed error (rendered − GT on
//! a diverging scale: blue where the rendering is too near, as over a lid that closes an opening;
//! //! red where it is too far), the GT and predicted object maps; then the error histogram, accuracy vs
//! threshold for every method, the loss curves and the time per stage. Both error maps saturate at
//! [`ERROR_MAX_M`], which their colour bars state.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use trand_eval::{KindRow, Metrics, PerObject, THRESHOLDS_M};
use trand_io::{
    DepthMap, InstanceMap, Load, LoadOptions, Rgb8Image, Sequence, Split, State, View, ViewCount,
    read_npy_f32, read_sequence_with, run_layout,
};

use crate::kinds::{self, KindTable, ObjectTable};
use crate::layout::{self, ASSETS_DIR, Manifest, ReportError, SEQ_DIR, SequenceEntry};
use crate::method::Method;
use crate::raster;
use crate::svg::{self, Series, escape};
use crate::tables::{self, AccuracyRow, EfficiencyRow, Tables, read_metrics, read_run_json};

/// Test views shown as images per state (the first ones in frame order).
pub const SHOWN_VIEWS: usize = 4;
/// Width of training-view thumbnails (pixels, at most).
pub const THUMB_WIDTH: u32 = 160;
/// Width of depth / error / object images (pixels, at most).
pub const IMAGE_WIDTH: u32 = 320;
/// Top of the error colour scales (m): |error| and ±(rendered − GT) saturate beyond it.
pub const ERROR_MAX_M: f64 = 0.05;
/// Share of the object depth range added below and above it on the depth colour scale.
pub const DEPTH_MARGIN: f64 = 0.1;
/// Error histogram: bins over [0, HIST_MAX_M].
pub const HIST_BINS: usize = 40;
pub const HIST_MAX_M: f64 = 0.10;

const CSS: &str = "body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1400px}
h1{font-size:22px}h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ccc}h3{font-size:15px}
table{border-collapse:collapse;margin:8px 0 16px}th,td{border:1px solid #ccc;padding:3px 7px;font-size:13px;text-align:right}
th:first-child,td:first-child{text-align:left}tr:nth-child(even){background:#f6f6f6}
.views td,.views th{text-align:center;vertical-align:top}.views img{width:200px;image-rendering:pixelated;display:block}
.thumbs{display:flex;flex-wrap:wrap;gap:8px}.thumbs figure{margin:0;font-size:11px;text-align:center}
.thumbs img{width:160px;image-rendering:pixelated;display:block}.used{outline:3px solid #26828e}
.plots{display:flex;flex-wrap:wrap;gap:12px}.bars{display:flex;gap:24px;flex-wrap:wrap}
.note{color:#666;font-size:12px}svg text{font-family:system-ui,sans-serif;fill:#222}";

fn page(title: &str, body: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{CSS}</style></head>\n<body>\n{body}</body></html>\n",
        escape(title)
    )
}

fn fmt_opt(v: Option<f64>, d: usize) -> String {
    v.map(|x| format!("{x:.d$}")).unwrap_or_else(|| "–".into())
}

/// The header cells of the paper's columns: MAE, RMSE and the accuracy at every threshold.
fn paper_header() -> String {
    let mut s = String::from("<th>MAE ↓ (m)</th><th>RMSE ↓ (m)</th>");
    for t in THRESHOLDS_M {
        let _ = write!(s, "<th>&lt;{}cm ↑</th>", t * 100.0);
    }
    s
}

/// The cells under [`paper_header`].
fn paper_cells(m: &Metrics) -> String {
    let mut s = format!("<td>{:.4}</td><td>{:.4}</td>", m.mae_m, m.rmse_m);
    for a in m.acc {
        let _ = write!(s, "<td>{:.2}%</td>", 100.0 * a);
    }
    s
}

/// An accuracy table in the paper's columns.
pub fn accuracy_html(rows: &[AccuracyRow], total: usize) -> String {
    let mut s = format!("<table><tr><th></th>{}</tr>\n", paper_header());
    for r in rows {
        let _ = write!(s, "<tr><td>{}</td>", escape(&tables::row_label(r, total)));
        match &r.metrics {
            Some(m) => s += &paper_cells(m),
            None => s += &"<td>–</td>".repeat(8),
        }
        s += "</tr>\n";
    }
    s + "</table>\n"
}

/// Per-object figures of one run: id, kind label, pixels and the paper's columns.
pub fn objects_html(objects: &[PerObject]) -> String {
    let mut s = format!(
        "<table><tr><th>object</th><th>kind</th><th>pixels</th>{}</tr>\n",
        paper_header()
    );
    for o in objects {
        let _ = writeln!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{}</td>{}</tr>",
            o.id,
            escape(&o.kind_label()),
            o.metrics.pixels,
            paper_cells(&o.metrics)
        );
    }
    s + "</table>\n"
}

/// Kinds pooled: label, objects, sequences, pixels, MAE and the shares within 2.5 and 5 cm.
pub fn kind_rows_html(rows: &[KindRow]) -> String {
    let mut s = String::from(
        "<table><tr><th>kind</th><th>objects</th><th>sequences</th><th>pixels</th><th>MAE ↓ (m)</th><th>&lt;2.5cm ↑</th><th>&lt;5cm ↑</th></tr>\n",
    );
    for r in rows {
        let m = &r.metrics;
        let _ = writeln!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.2}%</td><td>{:.2}%</td></tr>",
            escape(&r.label),
            r.objects,
            r.sequences,
            m.pixels,
            m.mae_m,
            100.0 * m.acc[2],
            100.0 * m.acc[3]
        );
    }
    s + "</table>\n"
}

/// Per-kind tables, one per method and state.
pub fn kinds_html(tables: &[KindTable]) -> String {
    let mut s = String::new();
    for t in tables.iter().filter(|t| !t.rows.is_empty()) {
        let _ = write!(
            s,
            "<h3>{}</h3>\n{}",
            escape(&kinds::kind_table_title(t)),
            kind_rows_html(&t.rows)
        );
    }
    s
}

/// The per-object and per-kind tables of one sequence, per method and state.
fn sequence_objects_html(tables: &[ObjectTable], sequence: &str) -> String {
    let mut s = String::new();
    for t in tables.iter().filter(|t| t.sequence == sequence) {
        let _ = write!(
            s,
            "<h3>{} {}</h3>\n{}{}",
            t.method,
            t.state.as_str(),
            objects_html(&t.objects),
            kind_rows_html(&kinds::pool_tables(std::slice::from_ref(t)))
        );
    }
    s
}

/// An efficiency table: seconds per stage, Gaussians, peak memory.
pub fn efficiency_html(rows: &[EfficiencyRow], state: State) -> String {
    let st = tables::stages(state);
    let mut s = String::from("<table><tr><th></th><th>sequences</th>");
    for k in st {
        let _ = write!(s, "<th>{} (s)</th>", k.trim_end_matches("_s"));
    }
    s += "<th>Gaussians</th><th>peak RSS (MB)</th></tr>\n";
    for r in rows {
        let _ = write!(
            s,
            "<tr><td>{} {}</td><td>{}</td>",
            r.method,
            state.as_str(),
            r.sequences
        );
        for k in st {
            let _ = write!(s, "<td>{}</td>", fmt_opt(r.timings_s.get(*k).copied(), 2));
        }
        let _ = writeln!(
            s,
            "<td>{}</td><td>{}</td></tr>",
            fmt_opt(r.num_surfels, 0),
            fmt_opt(r.peak_rss_mb, 0)
        );
    }
    s + "</table>\n"
}

/// Mean of the evaluated (non-NaN) pixels of an error map; 0 when there are none.
fn mean_evaluated(e: &DepthMap) -> f64 {
    let (sum, n) = e
        .data
        .iter()
        .filter(|x| !x.is_nan())
        .fold((0.0f64, 0usize), |(s, n), &x| (s + x as f64, n + 1));
    sum / n.max(1) as f64
}

fn seq_file(name: &str) -> String {
    format!("{SEQ_DIR}/{name}.html")
}

/// Logs of steps that ran but left no `metrics.json` (failed or interrupted), as paths relative to
/// the report, sorted.
pub fn unfinished_logs(report: &Path, manifest: &Manifest) -> Vec<String> {
    let mut out = Vec::new();
    for e in &manifest.sequences {
        for m in Method::ALL {
            for st in [State::T0, State::T1] {
                let log = layout::log_path(report, &e.name, m, st);
                let run = layout::run_dir(report, &e.name, m, st);
                if log.is_file() && !run.join(run_layout::METRICS_JSON).is_file() {
                    out.push(format!(
                        "{}/{}/{}/{}.log",
                        layout::RUNS_DIR,
                        e.name,
                        m,
                        st.as_str()
                    ));
                }
            }
        }
    }
    out
}

fn index_page(manifest: &Manifest, t: &Tables, unfinished: &[String]) -> String {
    let n = t.sequences.len();
    let methods: Vec<&str> = manifest.methods.iter().map(|m| m.name()).collect();
    let mut b = String::from("<h1>trand benchmark</h1>\n");
    let _ = write!(
        b,
        "<p>{n} sequence{}; methods: {}. Depth metrics as in the paper: per sequence pooled over all test views, \
         then the unweighted mean over sequences. Also as <a href=\"{}\">Markdown</a> and <a href=\"{}\">JSON</a>.</p>\n\
         <p class=\"note\">Pixels: {}.</p>\n",
        if n == 1 { "" } else { "s" },
        escape(&methods.join(", ")),
        layout::TABLES_MD,
        layout::TABLES_JSON,
        escape(trand_eval::PIXEL_SET_NOTE)
    );
    b += "<h2>Sequences</h2>\n<ul>\n";
    for s in &manifest.sequences {
        let _ = writeln!(
            b,
            "<li><a href=\"{}\">{}</a></li>",
            escape(&seq_file(&s.name)),
            escape(&s.name)
        );
    }
    b += "</ul>\n";
    if !unfinished.is_empty() {
        b += "<h2>Steps without a result</h2>\n<p class=\"note\">Failed or interrupted; their output:</p>\n<ul>\n";
        for l in unfinished {
            let _ = writeln!(b, "<li><a href=\"{}\">{}</a></li>", escape(l), escape(l));
        }
        b += "</ul>\n";
    }
    let sections = [
        ("Depth accuracy at t=0", accuracy_html(&t.accuracy_t0, n)),
        ("Depth accuracy at t=1", accuracy_html(&t.accuracy_t1, n)),
        (
            "Depth accuracy per object kind (objects of every sequence pooled)",
            kinds_html(&t.per_kind),
        ),
        (
            "Efficiency at t=0",
            efficiency_html(&t.efficiency_t0, State::T0),
        ),
        (
            "Efficiency at t=1",
            efficiency_html(&t.efficiency_t1, State::T1),
        ),
        (
            "Loss ablation (object-aware 3D loss)",
            accuracy_html(&t.loss_ablation, n),
        ),
        (
            "Simulation ablation (t=1)",
            accuracy_html(&t.simulation_ablation, n),
        ),
        ("Number of training views", accuracy_html(&t.view_study, n)),
    ];
    for (title, table) in sections {
        let _ = write!(b, "<h2>{title}</h2>\n{table}");
    }
    page("trand benchmark", &b)
}

/// Images and figures of one state of one sequence.
struct StateView<'a> {
    report: &'a Path,
    entry: &'a SequenceEntry,
    seq: &'a Sequence,
    state: State,
}

impl StateView<'_> {
    fn asset(&self, file: &str) -> (PathBuf, String) {
        let rel = format!("{ASSETS_DIR}/{}/{file}", self.entry.name);
        (self.report.join(&rel), format!("../{rel}"))
    }

    /// The depth range shared by GT and prediction images: GT depth of the object pixels of the shown
    /// views, widened by [`DEPTH_MARGIN`] on each side (the background saturates; objects keep the
    /// contrast). Falls back to every pixel with depth when no object is visible.
    fn depth_range(&self) -> (f64, f64) {
        let views = || {
            self.seq
                .views(Split::Test, self.state)
                .iter()
                .take(SHOWN_VIEWS)
        };
        let range = |objects_only: bool| {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for v in views() {
                let (Some(d), Some(m)) = (&v.depth, &v.instance) else {
                    continue;
                };
                for (&z, &id) in d.data.iter().zip(&m.data) {
                    if z.is_finite() && z > 0.0 && (id != 0 || !objects_only) {
                        lo = lo.min(z as f64);
                        hi = hi.max(z as f64);
                    }
                }
            }
            (lo < hi).then_some((lo, hi))
        };
        match range(true).or_else(|| range(false)) {
            Some((lo, hi)) => {
                let pad = DEPTH_MARGIN * (hi - lo);
                (lo - pad, hi + pad)
            }
            None => (0.0, 1.0),
        }
    }

    /// The first of the bench's methods with a result at this state.
    fn primary_method(&self, manifest: &Manifest) -> Option<Method> {
        manifest.methods.iter().copied().find(|&m| {
            layout::result_dir(self.report, &self.entry.name, m, self.state)
                .join(run_layout::METRICS_JSON)
                .is_file()
        })
    }

    /// The state's section: images of the primary method's first test views, then the plots.
    fn html(&self, manifest: &Manifest) -> Result<String, ReportError> {
        let st = self.state.as_str();
        let mut b = format!("<h2>State {st} ({})</h2>\n", Split::Test.folder(self.state));
        let Some(method) = self.primary_method(manifest) else {
            b += "<p class=\"note\">No finished run at this state.</p>\n";
            return Ok(b);
        };
        let depth_range = self.depth_range();
        b += &self.intro(method, depth_range);
        let (rows, hist) = self.view_rows(method, depth_range)?;
        b += "<table class=\"views\"><tr><th>view</th><th>GT depth</th><th>rendered depth</th><th>|error|</th><th>rendered − GT</th><th>GT objects</th><th>predicted objects</th></tr>\n";
        b += &rows;
        b += "</table>\n<p class=\"note\">Object colours: GT by object id; predicted maps as the run wrote them (colour-coded argmax).</p>\n<div class=\"plots\">\n";
        b += &svg::histogram(
            &format!("|error| of {method} at {st}"),
            &hist.bins,
            0.0,
            HIST_MAX_M,
            hist.overflow,
            "absolute error (m)",
        );
        b += &self.accuracy_chart(manifest)?;
        if self.state == State::T0 {
            b += &self.loss_chart(manifest)?;
        }
        b += &self.time_bars(manifest)?;
        b += "</div>\n";
        Ok(b)
    }

    /// What the images show, and the colour bars of depth (`lo..hi`), error and signed error.
    fn intro(&self, method: Method, (lo, hi): (f64, f64)) -> String {
        let st = self.state.as_str();
        let views = self.seq.views(Split::Test, self.state);
        format!(
            "<p>Images of <b>{method}</b>, first {} of {} test views. GT and rendered depth share one colour scale; \
             the errors are shown on the evaluated pixels only (GT objects with GT depth). The signed error is \
             blue where the rendering is nearer than the truth (a lid over an open container, a floater) and red \
             where it is farther (a hole, the table seen through); an uncovered pixel counts as rendered at 0, so \
             it is saturated blue.</p>\n<div class=\"bars\">{}{}{}</div>\n",
            views.len().min(SHOWN_VIEWS),
            views.len(),
            svg::colour_bar(lo, hi, "depth (m)", &format!("gd{st}")),
            svg::colour_bar(
                0.0,
                ERROR_MAX_M,
                &format!("absolute error (m), saturating at {ERROR_MAX_M}"),
                &format!("ge{st}")
            ),
            svg::colour_bar_of(
                &crate::colormap::DIVERGING,
                -ERROR_MAX_M,
                ERROR_MAX_M,
                &format!(
                    "rendered − GT depth (m), saturating at ±{ERROR_MAX_M}: blue too near, red too far"
                ),
                &format!("gs{st}"),
            )
        )
    }

    /// The table rows of the first [`SHOWN_VIEWS`] test views with GT, and the error histogram of
    /// every test view.
    fn view_rows(
        &self,
        method: Method,
        depth_range: (f64, f64),
    ) -> Result<(String, ErrorHistogram), ReportError> {
        let run = layout::result_dir(self.report, &self.entry.name, method, self.state);
        let mut hist = ErrorHistogram::default();
        let mut rows = String::new();
        for (k, v) in self.seq.views(Split::Test, self.state).iter().enumerate() {
            let (Some(gt), Some(inst)) = (&v.depth, &v.instance) else {
                continue;
            };
            let pred_path = run_layout::depth_path(&run, v.frame);
            let pred: Option<DepthMap> = if pred_path.is_file() {
                Some(read_npy_f32(&pred_path)?)
            } else {
                None
            };
            let errors = ViewErrors::of(pred.as_ref(), gt, inst);
            if let Some(e) = &errors.absolute {
                hist.add(e);
            }
            if k < SHOWN_VIEWS {
                let maps = ViewMaps {
                    view: v,
                    gt,
                    inst,
                    pred: pred.as_ref(),
                    errors: &errors,
                };
                rows += &self.view_row(&maps, &run, method, depth_range)?;
            }
        }
        Ok((rows, hist))
    }

    /// One image cell: `img` written as the asset `file`, or a dash.
    fn image_cell(&self, file: String, img: Option<Rgb8Image>) -> Result<String, ReportError> {
        Ok(match img {
            Some(img) => {
                let (path, rel) = self.asset(&file);
                raster::write_png(&path, &raster::downscale(&img, IMAGE_WIDTH))?;
                format!(
                    "<td><img src=\"{}\" alt=\"{}\"></td>",
                    escape(&rel),
                    escape(&file)
                )
            }
            None => "<td class=\"note\">–</td>".into(),
        })
    }

    /// The row of one shown view: its name and errors, GT and rendered depth on `lo..hi`, both error
    /// maps, GT objects and the run's predicted objects (linked from the run folder `run`).
    fn view_row(
        &self,
        m: &ViewMaps,
        run: &Path,
        method: Method,
        (lo, hi): (f64, f64),
    ) -> Result<String, ReportError> {
        let (st, f) = (self.state.as_str(), m.view.frame);
        let (signed, err) = (&m.errors.signed, &m.errors.absolute);
        let mut row = format!(
            "<tr><td>{}<br><span class=\"note\">MAE {} m<br>mean rendered − GT {} m</span></td>",
            escape(&m.view.name),
            fmt_opt(err.as_ref().map(mean_evaluated), 4),
            fmt_opt(signed.as_ref().map(mean_evaluated), 4)
        );
        row += &self.image_cell(
            format!("{st}_{f:06}_gt_depth.png"),
            Some(raster::colour_depth(m.gt, lo, hi)),
        )?;
        row += &self.image_cell(
            format!("{st}_{f:06}_depth.png"),
            m.pred.map(|p| raster::colour_depth(p, lo, hi)),
        )?;
        row += &self.image_cell(
            format!("{st}_{f:06}_error.png"),
            err.as_ref().map(|e| raster::colour_error(e, ERROR_MAX_M)),
        )?;
        row += &self.image_cell(
            format!("{st}_{f:06}_signed_error.png"),
            signed
                .as_ref()
                .map(|e| raster::colour_signed_error(e, ERROR_MAX_M)),
        )?;
        row += &self.image_cell(
            format!("{st}_{f:06}_gt_objects.png"),
            Some(raster::colour_instances(m.inst)),
        )?;
        let objects = run.join("objects").join(format!("{f:06}.png"));
        if objects.is_file() {
            let rel = format!(
                "../{}/{}/{}/{st}/objects/{f:06}.png",
                layout::RUNS_DIR,
                self.entry.name,
                method.source(self.state)
            );
            let _ = write!(
                row,
                "<td><img src=\"{}\" alt=\"predicted objects\"></td>",
                escape(&rel)
            );
        } else {
            row += "<td class=\"note\">–</td>";
        }
        row += "</tr>\n";
        Ok(row)
    }

    /// Accuracy against the threshold, one line per method that ran this state.
    fn accuracy_chart(&self, manifest: &Manifest) -> Result<String, ReportError> {
        let mut acc = Vec::new();
        for m in owners(manifest, self.state) {
            if let Some(x) = read_metrics(&layout::run_dir(
                self.report,
                &self.entry.name,
                m,
                self.state,
            ))? {
                acc.push(Series {
                    name: m.name().into(),
                    points: std::iter::once((0.0, 0.0))
                        .chain(
                            THRESHOLDS_M
                                .iter()
                                .zip(x.acc)
                                .map(|(t, a)| (t * 100.0, a * 100.0)),
                        )
                        .collect(),
                });
            }
        }
        Ok(svg::line_chart(
            &format!("accuracy vs threshold at {}", self.state.as_str()),
            &acc,
            "threshold (cm)",
            "pixels within (%)",
            Some((0.0, 100.0)),
            svg::Legend::BottomRight,
        ))
    }

    /// The t = 0 training loss curves, one line per method that records one.
    fn loss_chart(&self, manifest: &Manifest) -> Result<String, ReportError> {
        let mut loss = Vec::new();
        for m in owners(manifest, State::T0) {
            let dir = layout::run_dir(self.report, &self.entry.name, m, State::T0);
            let Some(r) = read_run_json(&dir)? else {
                continue;
            };
            let pts: Vec<(f64, f64)> = r
                .loss_curve
                .iter()
                .flatten()
                .map(|&(i, l)| (i as f64, l as f64))
                .collect();
            if !pts.is_empty() {
                loss.push(Series {
                    name: m.name().into(),
                    points: pts,
                });
            }
        }
        Ok(svg::line_chart(
            "training loss at t0",
            &loss,
            "iteration",
            "loss",
            None,
            svg::Legend::TopRight,
        ))
    }

    /// Seconds per stage of each method that ran this state (its total when it records no stages).
    fn time_bars(&self, manifest: &Manifest) -> Result<String, ReportError> {
        let mut bars = Vec::new();
        for m in owners(manifest, self.state) {
            let dir = layout::run_dir(self.report, &self.entry.name, m, self.state);
            let Some(r) = read_run_json(&dir)? else {
                continue;
            };
            let Some(t) = &r.timings else {
                continue;
            };
            let segs: Vec<(String, f64)> = tables::stages(self.state)
                .iter()
                .filter(|k| **k != "total_s")
                .filter_map(|k| Some((k.to_string(), *t.get(*k)?)))
                .collect();
            let segs = if segs.is_empty() {
                t.get("total_s")
                    .map(|&v| vec![("total_s".to_string(), v)])
                    .unwrap_or_default()
            } else {
                segs
            };
            bars.push((m.name().to_string(), segs));
        }
        Ok(svg::stacked_bars(
            &format!("time per stage at {}", self.state.as_str()),
            &bars,
            "seconds",
        ))
    }
}

/// The errors of one view's prediction on the evaluated pixels: rendered − GT and its absolute
/// value (`None` without a prediction of the GT's size).
struct ViewErrors {
    signed: Option<DepthMap>,
    absolute: Option<DepthMap>,
}

impl ViewErrors {
    fn of(pred: Option<&DepthMap>, gt: &DepthMap, inst: &InstanceMap) -> Self {
        let signed = pred
            .filter(|p| p.same_size(gt))
            .map(|p| raster::signed_error(p, gt, inst));
        let absolute = signed.as_ref().map(raster::absolute);
        Self { signed, absolute }
    }
}

/// What one row of the views table shows.
struct ViewMaps<'a> {
    view: &'a View,
    gt: &'a DepthMap,
    inst: &'a InstanceMap,
    pred: Option<&'a DepthMap>,
    errors: &'a ViewErrors,
}

/// Counts of |error| in [`HIST_BINS`] bins over `[0, HIST_MAX_M]`, and of the errors beyond.
struct ErrorHistogram {
    bins: Vec<u64>,
    overflow: u64,
}

impl Default for ErrorHistogram {
    fn default() -> Self {
        Self {
            bins: vec![0; HIST_BINS],
            overflow: 0,
        }
    }
}

impl ErrorHistogram {
    /// Counts the evaluated pixels (not NaN) of an |error| map.
    fn add(&mut self, e: &DepthMap) {
        for &x in e.data.iter().filter(|x| !x.is_nan()) {
            let bin = (x as f64 / HIST_MAX_M * HIST_BINS as f64) as usize;
            match self.bins.get_mut(bin) {
                Some(c) => *c += 1,
                None => self.overflow += 1,
            }
        }
    }
}

fn owners(manifest: &Manifest, state: State) -> Vec<Method> {
    let mut v: Vec<Method> = manifest.methods.iter().map(|m| m.source(state)).collect();
    v.sort();
    v.dedup();
    v
}

fn sequence_page(
    report: &Path,
    manifest: &Manifest,
    entry: &SequenceEntry,
    t: &Tables,
) -> Result<String, ReportError> {
    let mut b = format!(
        "<p><a href=\"../{}\">← all sequences</a></p>\n<h1>{}</h1>\n",
        layout::INDEX_HTML,
        escape(&entry.name)
    );
    let data = Manifest::data_path(report, entry);
    let _ = writeln!(
        b,
        "<p class=\"note\">data: {}</p>",
        escape(&data.display().to_string())
    );
    if let Some(rows) = t.per_sequence.iter().find(|r| r.sequence == entry.name) {
        b += "<h2>Metrics</h2>\n";
        b += &accuracy_html(&rows.rows, 1);
    }
    if t.per_object.iter().any(|o| o.sequence == entry.name) {
        b += "<h2>Metrics per object and per kind</h2>\n";
        b += &sequence_objects_html(&t.per_object, &entry.name);
    }
    let opts = LoadOptions {
        rgb: Load::Yes,
        masks: Load::Yes,
        depth: Load::Yes,
        object_channels: None,
    };
    let seq = match read_sequence_with(&data, &opts) {
        Ok(s) => s,
        Err(e) => {
            let _ = writeln!(
                b,
                "<p class=\"note\">Sequence data unavailable, no images: {}</p>",
                escape(&e.to_string())
            );
            return Ok(page(&entry.name, &b));
        }
    };
    b += &training_thumbnails(report, entry, &seq)?;
    for state in [State::T0, State::T1] {
        b += &StateView {
            report,
            entry,
            seq: &seq,
            state,
        }
        .html(manifest)?;
    }
    Ok(page(&entry.name, &b))
}

/// The training photographs of both states as thumbnails (written under the sequence's assets), the
/// default t = 0 reconstruction's views outlined.
fn training_thumbnails(
    report: &Path,
    entry: &SequenceEntry,
    seq: &Sequence,
) -> Result<String, ReportError> {
    let mut b = String::from(
        "<h2>Training views</h2>\n<p class=\"note\">Outlined: the 6 views of the default t=0 reconstruction.</p>\n<div class=\"thumbs\">\n",
    );
    let used = ViewCount::Six.frames();
    for (state, views) in [(State::T0, &seq.train_t0), (State::T1, &seq.train_t1)] {
        for v in views {
            let Some(rgb) = &v.rgb else { continue };
            let file = format!("{}_{:06}.png", Split::Train.folder(state), v.frame);
            let rel = format!("{ASSETS_DIR}/{}/{file}", entry.name);
            raster::write_png(&report.join(&rel), &raster::downscale(rgb, THUMB_WIDTH))?;
            let class = if state == State::T0 && used.contains(&v.frame) {
                " class=\"used\""
            } else {
                ""
            };
            let _ = writeln!(
                b,
                "<figure><img{class} src=\"../{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
                escape(&rel),
                escape(&v.name),
                escape(&v.name)
            );
        }
    }
    b += "</div>\n";
    Ok(b)
}

/// Writes `index.html` and one page per sequence; returns the path of `index.html`.
pub fn write_report(
    report: &Path,
    manifest: &Manifest,
    t: &Tables,
) -> Result<PathBuf, ReportError> {
    for e in &manifest.sequences {
        let html = sequence_page(report, manifest, e, t)?;
        let path = report.join(seq_file(&e.name));
        std::fs::create_dir_all(report.join(SEQ_DIR))
            .map_err(|err| ReportError::io(&report.join(SEQ_DIR), err))?;
        trand_io::write_atomic(&path, html.as_bytes())?;
    }
    let index = report.join(layout::INDEX_HTML);
    let unfinished = unfinished_logs(report, manifest);
    trand_io::write_atomic(&index, index_page(manifest, t, &unfinished).as_bytes())?;
    Ok(index)
}

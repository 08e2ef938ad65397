//! Hand-written inline SVG plots: colour bars, histograms, line charts, stacked bar charts.
//!
//! Every plot is a self-contained `<svg>` element with a fixed view box ([`W`]×[`H`] for charts), plain
//! text labels and no scripts, so a page renders from the file alone.

use std::fmt::Write as _;

use crate::colormap::{VIRIDIS, hex, object_colour};

/// Chart size in SVG units.
pub const W: f64 = 460.0;
pub const H: f64 = 270.0;
const LEFT: f64 = 58.0;
const RIGHT: f64 = 14.0;
const TOP: f64 = 26.0;
const BOTTOM: f64 = 42.0;

/// Escapes text for HTML/SVG content and attributes.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// About `n` round tick values covering `[lo, hi]`.
pub fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if hi.is_nan() || lo.is_nan() || hi <= lo || !lo.is_finite() || !hi.is_finite() {
        return vec![lo];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// A tick label with just enough decimals for `step`.
fn label(v: f64, step: f64) -> String {
    let d = if step >= 1.0 {
        0
    } else {
        (-step.log10()).ceil() as usize
    };
    format!("{v:.d$}")
}

/// A horizontal colour bar for values `[lo, hi]` with ticks and a caption (e.g. "depth (m)").
pub fn colour_bar(lo: f64, hi: f64, caption: &str, id: &str) -> String {
    colour_bar_of(&VIRIDIS, lo, hi, caption, id)
}

/// [`colour_bar`] on the colour samples `stops` (evenly spaced from `lo` to `hi`).
pub fn colour_bar_of(stops: &[[u8; 3]], lo: f64, hi: f64, caption: &str, id: &str) -> String {
    let (w, h, x0) = (300.0, 14.0, 10.0);
    let mut s = format!(
        r#"<svg class="bar" viewBox="0 0 {} 48" width="{}" height="48" role="img"><defs><linearGradient id="{id}">"#,
        w + 2.0 * x0,
        w + 2.0 * x0
    );
    for (k, c) in stops.iter().enumerate() {
        let _ = write!(
            s,
            r#"<stop offset="{:.3}" stop-color="{}"/>"#,
            k as f64 / (stops.len() - 1).max(1) as f64,
            hex(*c)
        );
    }
    let _ = write!(
        s,
        r##"</linearGradient></defs><rect x="{x0}" y="4" width="{w}" height="{h}" fill="url(#{id})" stroke="#555"/>"##
    );
    let ticks = nice_ticks(lo, hi, 5);
    let step = if ticks.len() > 1 {
        ticks[1] - ticks[0]
    } else {
        hi - lo
    };
    for t in ticks {
        let x = x0 + (t - lo) / (hi - lo).max(1e-12) * w;
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" x2="{x:.1}" y1="18" y2="22" stroke="#333"/><text x="{x:.1}" y="32" font-size="10" text-anchor="middle">{}</text>"##,
            label(t, step)
        );
    }
    let _ = write!(
        s,
        r#"<text x="{:.1}" y="45" font-size="10" text-anchor="middle">{}</text></svg>"#,
        x0 + w / 2.0,
        escape(caption)
    );
    s
}

/// Whether an axis has ticks and grid lines.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Axis {
    Ticks,
    Hidden,
}

/// Where a chart's legend goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Legend {
    TopRight,
    BottomRight,
}

/// Axes with ticks; returns the SVG so far and the data → pixel maps.
struct Frame {
    x: (f64, f64),
    y: (f64, f64),
    /// Left edge of the plot area.
    left: f64,
}

impl Frame {
    fn px(&self, v: f64) -> f64 {
        self.left + (v - self.x.0) / (self.x.1 - self.x.0).max(1e-12) * (W - self.left - RIGHT)
    }
    fn py(&self, v: f64) -> f64 {
        H - BOTTOM - (v - self.y.0) / (self.y.1 - self.y.0).max(1e-12) * (H - TOP - BOTTOM)
    }
    fn open(&self, title: &str, xlabel: &str, ylabel: &str, y_axis: Axis) -> String {
        let mut s = format!(
            r#"<svg class="chart" viewBox="0 0 {W} {H}" width="{W}" height="{H}" role="img"><title>{t}</title><text x="{:.1}" y="16" font-size="12" font-weight="bold" text-anchor="middle">{t}</text>"#,
            W / 2.0,
            t = escape(title)
        );
        let y_ticks = match y_axis {
            Axis::Ticks => nice_ticks(self.y.0, self.y.1, 5),
            Axis::Hidden => Vec::new(),
        };
        for (ticks, vertical) in [(nice_ticks(self.x.0, self.x.1, 6), true), (y_ticks, false)] {
            let step = if ticks.len() > 1 {
                ticks[1] - ticks[0]
            } else {
                1.0
            };
            for t in ticks {
                if vertical {
                    let x = self.px(t);
                    let _ = write!(
                        s,
                        r##"<line x1="{x:.1}" x2="{x:.1}" y1="{TOP}" y2="{:.1}" stroke="#e4e4e4"/><text x="{x:.1}" y="{:.1}" font-size="10" text-anchor="middle">{}</text>"##,
                        H - BOTTOM,
                        H - BOTTOM + 13.0,
                        label(t, step)
                    );
                } else {
                    let y = self.py(t);
                    let _ = write!(
                        s,
                        r##"<line x1="{}" x2="{:.1}" y1="{y:.1}" y2="{y:.1}" stroke="#e4e4e4"/><text x="{:.1}" y="{:.1}" font-size="10" text-anchor="end">{}</text>"##,
                        self.left,
                        W - RIGHT,
                        self.left - 4.0,
                        y + 3.0,
                        label(t, step)
                    );
                }
            }
        }
        let _ = write!(
            s,
            r##"<rect x="{}" y="{TOP}" width="{:.1}" height="{:.1}" fill="none" stroke="#888"/><text x="{:.1}" y="{:.1}" font-size="11" text-anchor="middle">{}</text><text x="12" y="{:.1}" font-size="11" text-anchor="middle" transform="rotate(-90 12 {:.1})">{}</text>"##,
            self.left,
            W - self.left - RIGHT,
            H - TOP - BOTTOM,
            (self.left + W - RIGHT) / 2.0,
            H - 6.0,
            escape(xlabel),
            (TOP + H - BOTTOM) / 2.0,
            (TOP + H - BOTTOM) / 2.0,
            escape(ylabel)
        );
        s
    }
}

/// A histogram of `counts` over equal bins of `[x0, x1]`, as a share of `total` (in %). `overflow`
/// values beyond `x1` are reported in the title.
pub fn histogram(
    title: &str,
    counts: &[u64],
    x0: f64,
    x1: f64,
    overflow: u64,
    xlabel: &str,
) -> String {
    let total: u64 = counts.iter().sum::<u64>() + overflow;
    let share = |c: u64| {
        if total == 0 {
            0.0
        } else {
            100.0 * c as f64 / total as f64
        }
    };
    let ymax = counts
        .iter()
        .map(|&c| share(c))
        .fold(0.0, f64::max)
        .max(1e-9)
        * 1.05;
    let f = Frame {
        x: (x0, x1),
        y: (0.0, ymax),
        left: LEFT,
    };
    let title = format!("{title} ({:.1}% beyond {x1})", share(overflow));
    let mut s = f.open(&title, xlabel, "share of pixels (%)", Axis::Ticks);
    let bw = (x1 - x0) / counts.len().max(1) as f64;
    for (k, &c) in counts.iter().enumerate() {
        let (a, b) = (f.px(x0 + k as f64 * bw), f.px(x0 + (k + 1) as f64 * bw));
        let y = f.py(share(c));
        let _ = write!(
            s,
            r#"<rect x="{a:.1}" y="{y:.1}" width="{:.1}" height="{:.1}" fill="{}"/>"#,
            (b - a - 0.5).max(0.5),
            (H - BOTTOM - y).max(0.0),
            hex(VIRIDIS[3])
        );
    }
    s + "</svg>"
}

/// One line of a [`line_chart`].
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// Lines with markers and a legend; ranges fit the data (y from 0 unless a range is given).
pub fn line_chart(
    title: &str,
    series: &[Series],
    xlabel: &str,
    ylabel: &str,
    y_range: Option<(f64, f64)>,
    legend: Legend,
) -> String {
    let all = || {
        series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| p.0.is_finite() && p.1.is_finite())
    };
    let xmin = all().map(|p| p.0).fold(f64::INFINITY, f64::min);
    let xmax = all().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
    let ymax = all().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    let (xmin, xmax) = if xmin.is_finite() && xmax > xmin {
        (xmin, xmax)
    } else {
        (0.0, 1.0)
    };
    let y = y_range.unwrap_or((
        0.0,
        if ymax.is_finite() && ymax > 0.0 {
            ymax * 1.05
        } else {
            1.0
        },
    ));
    let f = Frame {
        x: (xmin, xmax),
        y,
        left: LEFT,
    };
    let mut s = f.open(title, xlabel, ylabel, Axis::Ticks);
    let legend_top = match legend {
        Legend::TopRight => TOP + 12.0,
        Legend::BottomRight => H - BOTTOM - 8.0 - 13.0 * (series.len().max(1) - 1) as f64,
    };
    for (i, ser) in series.iter().enumerate() {
        let c = hex(object_colour(i as u16 + 1));
        let pts: Vec<String> = ser
            .points
            .iter()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .map(|&(x, v)| format!("{:.1},{:.1}", f.px(x), f.py(v)))
            .collect();
        let _ = write!(
            s,
            r#"<polyline fill="none" stroke="{c}" stroke-width="1.8" points="{}"/>"#,
            pts.join(" ")
        );
        if ser.points.len() <= 20 {
            for p in &pts {
                let (x, yv) = p.split_once(',').expect("x,y");
                let _ = write!(s, r#"<circle cx="{x}" cy="{yv}" r="2.5" fill="{c}"/>"#);
            }
        }
        let ly = legend_top + 13.0 * i as f64;
        let _ = write!(
            s,
            r#"<rect x="{:.1}" y="{:.1}" width="10" height="3" fill="{c}"/><text x="{:.1}" y="{:.1}" font-size="10">{}</text>"#,
            W - RIGHT - 110.0,
            ly - 4.0,
            W - RIGHT - 96.0,
            ly,
            escape(&ser.name)
        );
    }
    s + "</svg>"
}

/// Horizontal stacked bars: one bar per row, one segment per stage (seconds), with a stage legend.
pub fn stacked_bars(title: &str, rows: &[(String, Vec<(String, f64)>)], xlabel: &str) -> String {
    let mut stages: Vec<&str> = Vec::new();
    for (_, segs) in rows {
        for (k, _) in segs {
            if !stages.contains(&k.as_str()) {
                stages.push(k);
            }
        }
    }
    let xmax = rows
        .iter()
        .map(|(_, v)| v.iter().map(|s| s.1.max(0.0)).sum::<f64>())
        .fold(0.0, f64::max)
        .max(1e-9)
        * 1.05;
    let left = 112.0;
    let f = Frame {
        x: (0.0, xmax),
        y: (0.0, 1.0),
        left,
    };
    let mut s = f.open(title, xlabel, "", Axis::Hidden);
    let span = W - RIGHT - left;
    let bar_h = ((H - TOP - BOTTOM - 24.0) / rows.len().max(1) as f64).min(22.0);
    for (r, (name, segs)) in rows.iter().enumerate() {
        let y = TOP + 4.0 + r as f64 * (bar_h + 2.0);
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}" font-size="10" text-anchor="end">{}</text>"#,
            left - 4.0,
            y + bar_h * 0.7,
            escape(name)
        );
        let mut x = 0.0;
        for (k, v) in segs {
            let c = hex(object_colour(
                stages.iter().position(|s| s == k).unwrap_or(0) as u16 + 1,
            ));
            let w = v.max(0.0) / xmax * span;
            let _ = write!(
                s,
                r#"<rect x="{:.1}" y="{y:.1}" width="{w:.1}" height="{bar_h:.1}" fill="{c}"><title>{}: {v:.2} s</title></rect>"#,
                left + x,
                escape(k)
            );
            x += w;
        }
    }
    for (i, k) in stages.iter().enumerate() {
        let c = hex(object_colour(i as u16 + 1));
        let x = left + (i as f64) * (span / stages.len().max(1) as f64);
        let _ = write!(
            s,
            r#"<rect x="{x:.1}" y="{:.1}" width="8" height="8" fill="{c}"/><text x="{:.1}" y="{:.1}" font-size="9">{}</text>"#,
            H - BOTTOM - 14.0,
            x + 10.0,
            H - BOTTOM - 6.5,
            escape(k.trim_end_matches("_s"))
        );
    }
    s + "</svg>"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_ticks_are_round_and_inside() {
        let t = nice_ticks(0.0, 1.0, 5);
        assert_eq!((t.len(), t[0], t[5]), (6, 0.0, 1.0));
        assert!((t[1] - 0.2).abs() < 1e-12);
        let t = nice_ticks(0.43, 0.91, 5);
        assert!(
            t.iter().all(|v| (0.43..=0.91).contains(v)) && t.len() >= 3,
            "{t:?}"
        );
        assert_eq!(label(0.1, 0.1), "0.1");
        assert_eq!(label(0.05, 0.05), "0.05");
    }

    #[test]
    fn plots_are_closed_svg_with_escaped_text() {
        let s = Series {
            name: "a<b".into(),
            points: vec![(0.0, 1.0), (1.0, 0.5)],
        };
        for svg in [
            line_chart("t", &[s], "x", "y", None, Legend::BottomRight),
            histogram("h", &[1, 2, 3], 0.0, 0.1, 1, "m"),
            stacked_bars("b", &[("trand".into(), vec![("total_s".into(), 2.0)])], "s"),
            colour_bar(0.4, 0.9, "depth (m)", "g"),
        ] {
            assert!(svg.starts_with("<svg") && svg.ends_with("</svg>"), "{svg}");
            assert!(!svg.contains("a<b") && !svg.contains("NaN"), "{svg}");
        }
    }
}

//! `uquad plot`: altitude, attitude and motor speeds of a run over time, as SVG.
//!
//! Works on our run folders and the original's (x_hat.log, w.log; kalman_in.log for the times
//! of the estimates). The SVG is written by hand and its text is drawn, not typeset: each
//! character is the 8 × 8 bitmap glyph of the embedded public-domain font8x8 font, drawn as
//! filled squares, so the image looks the same on every viewer and needs no system font.

use crate::logs::{self, Parsed};
use anyhow::{Context, bail};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One named series: (time s, value).
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// One panel of the figure.
pub struct Panel {
    pub title: String,
    pub series: Vec<Series>,
}

const COLORS: [&str; 4] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"];
const WIDTH: f64 = 960.0;
const PANEL_H: f64 = 240.0;
const MARGIN_L: f64 = 70.0;
const MARGIN_R: f64 = 130.0;
/// At most this many points per series are drawn (evenly picked).
const MAX_POINTS: usize = 2000;

fn read<T>(path: &Path, parse: impl Fn(&[&str]) -> Result<T, String>) -> anyhow::Result<Vec<T>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let Parsed { rows, .. } =
        logs::parse_log(&text, parse).with_context(|| path.display().to_string())?;
    Ok(rows)
}

/// The panels of a run folder.
pub fn panels(run_dir: &Path) -> anyhow::Result<Vec<Panel>> {
    let x_hat = read(&run_dir.join("x_hat.log"), logs::parse_x_hat)?;
    let w = read(&run_dir.join("w.log"), logs::parse_time_and_4)?;
    if x_hat.is_empty() {
        bail!(
            "{}: no estimates to plot",
            run_dir.join("x_hat.log").display()
        );
    }
    // Times of the estimates: kalman_in's, continued 10 ms apart past its last row.
    let times: Vec<i64> =
        read(&run_dir.join("kalman_in.log"), logs::parse_time_column).unwrap_or_default();
    let t_of = |k: usize| -> f64 {
        match (times.get(k), times.last()) {
            (Some(&t), _) => t as f64 / 1e6,
            (None, Some(&last)) => (last as f64 + (k + 1 - times.len()) as f64 * 1e4) / 1e6,
            (None, None) => k as f64 * 0.01,
        }
    };
    let series = |name: &str, col: usize| Series {
        name: name.to_string(),
        points: x_hat
            .iter()
            .enumerate()
            .map(|(k, x)| (t_of(k), x[col]))
            .collect(),
    };
    Ok(vec![
        Panel {
            title: "altitude (m)".into(),
            series: vec![series("z", 2)],
        },
        Panel {
            title: "attitude (rad)".into(),
            series: vec![
                series("roll psi", 3),
                series("pitch phi", 4),
                series("yaw theta", 5),
            ],
        },
        Panel {
            title: "motor speeds (rad/s)".into(),
            series: (0..4)
                .map(|m| Series {
                    name: format!("m{m}"),
                    points: w.iter().map(|(t, v)| (*t as f64 / 1e6, v[m])).collect(),
                })
                .collect(),
        },
    ])
}

/// Where a drawn text is anchored horizontally.
#[derive(Clone, Copy)]
enum Anchor {
    Start,
    End,
}

/// `s` drawn as a path of the font8x8 glyphs' pixels, `px` units per glyph pixel, with its
/// baseline at `y`; the text itself is kept as the path's title (for search and screen
/// readers). Characters without a glyph are drawn as '?'.
fn text(x: f64, y: f64, s: &str, px: f64, anchor: Anchor) -> String {
    use font8x8::UnicodeFonts as _;
    let width = 8.0 * px * s.chars().count() as f64;
    let left = match anchor {
        Anchor::Start => x,
        Anchor::End => x - width,
    };
    // The glyphs' baseline is below their 7th row.
    let top = y - 7.0 * px;
    let mut d = String::new();
    for (i, ch) in s.chars().enumerate() {
        let glyph = font8x8::BASIC_FONTS
            .get(ch)
            .or_else(|| font8x8::BASIC_FONTS.get('?'))
            .unwrap_or([0; 8]);
        let gx = left + 8.0 * px * i as f64;
        for (r, bits) in glyph.iter().enumerate() {
            // Runs of set pixels in the row (bit 0 is the leftmost), one rectangle each.
            let mut c = 0;
            while c < 8 {
                if bits & (1 << c) == 0 {
                    c += 1;
                    continue;
                }
                let start = c;
                while c < 8 && bits & (1 << c) != 0 {
                    c += 1;
                }
                let _ = write!(
                    d,
                    "M{:.2} {:.2}h{:.2}v{:.2}h-{:.2}z",
                    gx + start as f64 * px,
                    top + r as f64 * px,
                    (c - start) as f64 * px,
                    px,
                    (c - start) as f64 * px
                );
            }
        }
    }
    format!(
        r#"<path fill="black" d="{d}"><title>{}</title></path>"#,
        esc(s)
    )
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The figure as an SVG document.
pub fn svg(title: &str, panels: &[Panel]) -> String {
    let height = 40.0 + PANEL_H * panels.len() as f64;
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height}" viewBox="0 0 {WIDTH} {height}">"#
    );
    let _ = writeln!(out, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(out, "{}", text(MARGIN_L, 24.0, title, 1.75, Anchor::Start));
    for (p, panel) in panels.iter().enumerate() {
        let top = 40.0 + p as f64 * PANEL_H;
        let (x0, x1) = (MARGIN_L, WIDTH - MARGIN_R);
        let (y0, y1) = (top + 20.0, top + PANEL_H - 30.0);
        let all = panel
            .series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| p.0.is_finite() && p.1.is_finite());
        let (mut tmin, mut tmax, mut vmin, mut vmax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for &(t, v) in all {
            tmin = tmin.min(t);
            tmax = tmax.max(t);
            vmin = vmin.min(v);
            vmax = vmax.max(v);
        }
        if tmin > tmax {
            (tmin, tmax, vmin, vmax) = (0.0, 1.0, 0.0, 1.0);
        }
        if tmax - tmin < 1e-9 {
            tmax = tmin + 1.0;
        }
        if vmax - vmin < 1e-9 {
            vmax += 0.5;
            vmin -= 0.5;
        }
        let sx = |t: f64| x0 + (t - tmin) / (tmax - tmin) * (x1 - x0);
        let sy = |v: f64| y1 - (v - vmin) / (vmax - vmin) * (y1 - y0);
        let _ = writeln!(
            out,
            r##"<rect x="{x0}" y="{y0}" width="{}" height="{}" fill="none" stroke="#888"/>"##,
            x1 - x0,
            y1 - y0
        );
        let _ = writeln!(
            out,
            "{}",
            text(x0, top + 14.0, &panel.title, 1.5, Anchor::Start)
        );
        for (v, y) in [(vmax, y0 + 8.0), (vmin, y1)] {
            let _ = writeln!(
                out,
                "{}",
                text(x0 - 6.0, y, &format!("{v:.3}"), 1.25, Anchor::End)
            );
        }
        for (t, anchor) in [(tmin, Anchor::Start), (tmax, Anchor::End)] {
            let _ = writeln!(
                out,
                "{}",
                text(sx(t), y1 + 18.0, &format!("{t:.1} s"), 1.25, anchor)
            );
        }
        for (k, s) in panel.series.iter().enumerate() {
            let color = COLORS[k % COLORS.len()];
            let stride = s.points.len().div_ceil(MAX_POINTS).max(1);
            let pts: Vec<String> = s
                .points
                .iter()
                .step_by(stride)
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .map(|&(t, v)| format!("{:.1},{:.1}", sx(t), sy(v)))
                .collect();
            let _ = writeln!(
                out,
                r#"<polyline data-series="{}" fill="none" stroke="{color}" stroke-width="1.2" points="{}"/>"#,
                esc(&s.name),
                pts.join(" ")
            );
            // The legend, right of the panel.
            let ly = y0 + 14.0 + 18.0 * k as f64;
            let _ = writeln!(
                out,
                r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="{color}" stroke-width="2"/>{}"#,
                x1 + 12.0,
                ly - 4.0,
                x1 + 32.0,
                ly - 4.0,
                text(x1 + 38.0, ly, &s.name, 1.25, Anchor::Start)
            );
        }
    }
    out.push_str("</svg>\n");
    out
}

/// Plots `run_dir` into `out` (default `RUN_DIR/plot.svg`); returns the file written.
pub fn run(run_dir: &Path, out: Option<&Path>) -> anyhow::Result<PathBuf> {
    let out = out.map_or_else(|| run_dir.join("plot.svg"), Path::to_path_buf);
    if out
        .extension()
        .is_none_or(|e| !e.eq_ignore_ascii_case("svg"))
    {
        bail!(
            "{}: only SVG output is written (name the file .svg); any browser shows it",
            out.display()
        );
    }
    let panels = panels(run_dir)?;
    let title = format!("uquad run {}", run_dir.display());
    std::fs::write(&out, svg(&title, &panels))
        .with_context(|| format!("cannot write {}", out.display()))?;
    Ok(out)
}

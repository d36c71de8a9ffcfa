//! Draws a [`Figure`] with plotters on any of its backends (PNG and SVG): the four time
//! panels stacked on the left, the horizontal track on the right; ticks, gridlines, units and
//! a legend on each; set points dashed in their series' colour; mode changes (grey) and
//! failsafes (red) marked on every panel.

use super::data::{Figure, Mark, Series, TimePanel};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;

/// The figure's size in pixels, and the track's column.
pub const SIZE: (u32, u32) = (1600, 1200);
const TRACK_W: u32 = 560;
const FONT: &str = "sans-serif";
const PALETTE: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
];
const FAILSAFE: RGBColor = RGBColor(200, 0, 0);
const MODE: RGBColor = RGBColor(120, 120, 120);

type Result = anyhow::Result<()>;
type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Turns a drawing error into the command's error.
fn failed<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("drawing the plot: {e:?}")
}

/// Draws `fig` on `root`.
pub fn figure<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, fig: &Figure) -> Result {
    root.fill(&WHITE).map_err(failed)?;
    let body = root
        .titled(&fig.title, (FONT, 22).into_font())
        .map_err(failed)?;
    let (w, _) = body.dim_in_pixel();
    let (left, right) = body.split_horizontally(w.saturating_sub(TRACK_W));
    let rows = left.split_evenly((fig.panels.len().max(1), 1));
    for (area, panel) in rows.iter().zip(&fig.panels) {
        time_panel(area, panel, &fig.marks)?;
    }
    track(&right, &fig.track, &fig.marks)
}

/// The span of the values, widened so that a flat series still has an axis.
fn span(values: impl Iterator<Item = f64>) -> Range<f64> {
    let (lo, hi) = values.fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return 0.0..1.0;
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad)..(hi + pad)
}

/// The truth's colours: black, then dark grey.
const TRUTH: [RGBColor; 2] = [RGBColor(0, 0, 0), RGBColor(120, 120, 120)];

fn colour(k: usize) -> RGBColor {
    PALETTE[k % PALETTE.len()]
}

/// A set point's colour is its series' (the same name without " set point"); the truth is
/// black, a panel's second truth dark grey.
fn colours(series: &[Series]) -> Vec<RGBColor> {
    let mut out = Vec::with_capacity(series.len());
    let mut k = 0;
    let mut truths = 0;
    for s in series {
        if s.truth {
            out.push(TRUTH[truths % TRUTH.len()]);
            truths += 1;
            continue;
        }
        let own = series
            .iter()
            .position(|o| !o.setpoint && s.name.starts_with(&o.name) && s.setpoint);
        match own {
            Some(i) => out.push(out.get(i).copied().unwrap_or(colour(k))),
            None => {
                out.push(colour(k));
                k += 1;
            }
        }
    }
    out
}

fn time_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &TimePanel,
    marks: &[Mark],
) -> Result {
    let pts = || panel.series.iter().flat_map(|s| s.points.iter());
    let t = span(pts().map(|p| p.0));
    let y = span(pts().map(|p| p.1));
    let mut chart = ChartBuilder::on(area)
        .caption(panel.title, (FONT, 18))
        .margin(8)
        .margin_right(16)
        .x_label_area_size(40)
        .y_label_area_size(80)
        .build_cartesian_2d(t.clone(), y.clone())
        .map_err(failed)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc(panel.y_desc)
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 14))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(failed)?;
    for (s, c) in panel.series.iter().zip(colours(&panel.series)) {
        draw_series(&mut chart, s, c)?;
    }
    for m in marks.iter().filter(|m| t.contains(&m.t_s)) {
        let c = if m.failsafe { FAILSAFE } else { MODE };
        let line = PathElement::new(vec![(m.t_s, y.start), (m.t_s, y.end)], c.stroke_width(1));
        // Labels right of their line; near the panel's right edge, left of it (not cut).
        let right_edge = m.t_s > t.start + 0.9 * (t.end - t.start);
        let h = if right_edge { HPos::Right } else { HPos::Left };
        let style = (FONT, 11).into_font().color(&c).pos(Pos::new(h, VPos::Top));
        let label = Text::new(format!(" {} ", m.label), (m.t_s, y.end), style);
        chart.draw_series([line]).map_err(failed)?;
        chart.draw_series([label]).map_err(failed)?;
    }
    legend(&mut chart)
}

/// One series: a solid line, or dashed for a set point; named in the legend.
fn draw_series<'a, DB: DrawingBackend + 'a>(
    chart: &mut Chart<'a, DB>,
    s: &Series,
    c: RGBColor,
) -> Result {
    let style = c.stroke_width(if s.setpoint { 2 } else { 1 });
    let drawn = if s.setpoint {
        chart.draw_series(DashedLineSeries::new(s.points.iter().copied(), 6, 4, style))
    } else {
        chart.draw_series(LineSeries::new(s.points.iter().copied(), style))
    }
    .map_err(failed)?;
    drawn
        .label(s.name.clone())
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    Ok(())
}

fn legend<'a, DB: DrawingBackend + 'a>(chart: &mut Chart<'a, DB>) -> Result {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(180, 180, 180))
        .label_font((FONT, 12))
        .draw()
        .map_err(failed)
}

/// The horizontal track, east and north on the same scale, with the modes where they began.
fn track<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    track: &[Series],
    marks: &[Mark],
) -> Result {
    let pts = || track.iter().flat_map(|s| s.points.iter());
    let (e, n) = (span(pts().map(|p| p.0)), span(pts().map(|p| p.1)));
    // One metre is as long east as north: the larger span sets both.
    let half = (e.end - e.start).max(n.end - n.start) / 2.0;
    let (ec, nc) = ((e.start + e.end) / 2.0, (n.start + n.end) / 2.0);
    let (e, n) = ((ec - half)..(ec + half), (nc - half)..(nc + half));
    let (w, h) = area.dim_in_pixel();
    let side = w.min(h);
    let square = area.margin(0, h.saturating_sub(side), 0, 0);
    let mut chart = ChartBuilder::on(&square)
        .caption("horizontal track", (FONT, 18))
        .margin(8)
        .margin_right(20)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(e, n)
        .map_err(failed)?;
    chart
        .configure_mesh()
        .x_desc("east (m)")
        .y_desc("north (m)")
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 14))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(failed)?;
    for (s, c) in track.iter().zip(colours(track)) {
        draw_series(&mut chart, s, c)?;
    }
    for m in marks {
        let Some(at) = m.at_m else { continue };
        let c = if m.failsafe { FAILSAFE } else { MODE };
        let dot = Circle::new(at, 3, c.filled());
        let label = Text::new(m.label.clone(), at, (FONT, 11).into_font().color(&c));
        chart.draw_series([dot]).map_err(failed)?;
        chart.draw_series([label]).map_err(failed)?;
    }
    legend(&mut chart)
}

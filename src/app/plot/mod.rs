//! `uquad plot`: a run's altitude, roll and pitch, yaw and motor speeds over time with their
//! set points, and its horizontal track against the planned one, mode changes and failsafes
//! marked; PNG or SVG by the output file's extension.
//!
//! - `data`: what is drawn, read from the run folder;
//! - `draw`: the drawing, with plotters, on either backend.
//!
//! Text is set in DejaVu Sans, embedded (`DejaVuSans.ttf`, its licence beside it), so a PNG
//! looks the same on every machine; an SVG names the font family (`sans-serif`) and is drawn
//! with the viewer's.

mod data;
mod draw;

pub use data::{Figure, Mark, Series, TimePanel, figure};

use anyhow::bail;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// The embedded font (Bitstream Vera / DejaVu licence: `DejaVuSans-LICENSE.txt`).
static FONT: &[u8] = include_bytes!("DejaVuSans.ttf");

/// Makes the embedded font plotters' `sans-serif`, once.
fn register_font() -> anyhow::Result<()> {
    static DONE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_ok()
    });
    if ok {
        Ok(())
    } else {
        bail!("the embedded font could not be read")
    }
}

/// The output's format, from its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Png,
    Svg,
}

fn format_of(out: &Path) -> anyhow::Result<Format> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("png") => Ok(Format::Png),
        Some("svg") => Ok(Format::Svg),
        _ => bail!(
            "{}: name the file .png or .svg (the format follows the extension)",
            out.display()
        ),
    }
}

/// Draws `fig` on `root` and writes it to `out`.
fn render<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    fig: &Figure,
    out: &Path,
) -> anyhow::Result<()> {
    draw::figure(&root, fig)?;
    root.present()
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e:?}", out.display()))
}

/// Plots `run_dir` into `out` (default `RUN_DIR/plot.png`); returns the file written.
pub fn run(run_dir: &Path, out: Option<&Path>) -> anyhow::Result<PathBuf> {
    let out = out.map_or_else(|| run_dir.join("plot.png"), Path::to_path_buf);
    let format = format_of(&out)?;
    let fig = figure(run_dir)?;
    register_font()?;
    match format {
        Format::Png => render(
            BitMapBackend::new(&out, draw::SIZE).into_drawing_area(),
            &fig,
            &out,
        )?,
        Format::Svg => render(
            SVGBackend::new(&out, draw::SIZE).into_drawing_area(),
            &fig,
            &out,
        )?,
    }
    Ok(out)
}

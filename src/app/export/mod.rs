//! `uquad export RUN_DIR --format ulog|csv --out PATH`: a run folder (ours, or the
//! original's) for the tools people use — a ULog for Flight Review, PlotJuggler and pyulog
//! (`ulog`), or CSV files with units in their headers (`csv`).

mod csv;
mod ulog;

pub(crate) use csv::EstimateTimes;

use anyhow::Context;
use std::io::Write;
use std::path::{Path, PathBuf};

/// What to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One ULog file (PX4's format).
    Ulog,
    /// A folder of CSV files, one per stream.
    Csv,
}

/// The parameters of the run's own configuration (its `config.toml`), under the ids a
/// ground station sees; none for a folder without one (the original's).
fn params(run_dir: &Path) -> anyhow::Result<Vec<(String, f64)>> {
    let path = run_dir.join("config.toml");
    if !path.exists() {
        return Ok(Vec::new());
    }
    // A configuration an older uquad wrote may not load now: the export goes on without it.
    let profile = match crate::config::load(&path, &[]) {
        Ok(p) => p,
        Err(e) => {
            eprintln!(
                "warning: {}: {e}; exported without parameters",
                path.display()
            );
            return Ok(Vec::new());
        }
    };
    let p = crate::gcs::params::Params::of(&profile.config);
    Ok((0..p.len())
        .filter_map(|i| p.get(i))
        .map(|p| (p.id.to_string(), p.value))
        .collect())
}

/// Exports `run_dir` as `format` into `out`; returns the files written.
pub fn run(run_dir: &Path, format: Format, out: &Path) -> anyhow::Result<Vec<PathBuf>> {
    match format {
        Format::Ulog => {
            has_estimates(run_dir)?;
            let params = params(run_dir)?;
            let file = std::fs::File::create(out)
                .with_context(|| format!("cannot write {}", out.display()))?;
            let mut w = std::io::BufWriter::with_capacity(256 * 1024, file);
            let warnings = ulog::write(run_dir, &params, &mut w)
                .and_then(|warnings| Ok(w.flush().map(|()| warnings)?))
                .with_context(|| format!("cannot write {}", out.display()))?;
            warn(warnings);
            Ok(vec![out.to_path_buf()])
        }
        Format::Csv => {
            has_estimates(run_dir)?;
            let (files, warnings) = csv::write(run_dir, out)?;
            warn(warnings);
            Ok(files)
        }
    }
}

/// A run folder holds estimates (x_hat.log, not empty), or there is nothing to export.
fn has_estimates(run_dir: &Path) -> anyhow::Result<()> {
    let x_hat = run_dir.join("x_hat.log");
    if std::fs::metadata(&x_hat).map_or(true, |m| m.len() == 0) {
        anyhow::bail!(
            "{}: no estimates (x_hat.log missing or empty)",
            run_dir.display()
        );
    }
    Ok(())
}

/// The logs' skipped lines, told on stderr (the export goes on).
fn warn(warnings: Vec<String>) {
    for w in warnings {
        eprintln!("warning: {w}");
    }
}

//! `uquad export RUN_DIR --format ulog|csv --out PATH`: a run folder (ours, or the
//! original's) for the tools people use — a ULog for Flight Review, PlotJuggler and pyulog
//! (`ulog`), or CSV files with units in their headers (`csv`).

mod csv;
mod ulog;

use crate::app::run_logs::RunLogs;
use anyhow::Context;
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
    let run = RunLogs::read(run_dir)?;
    match format {
        Format::Ulog => {
            let bytes = ulog::build(&run, &params(run_dir)?).map_err(anyhow::Error::msg)?;
            std::fs::write(out, bytes)
                .with_context(|| format!("cannot write {}", out.display()))?;
            Ok(vec![out.to_path_buf()])
        }
        Format::Csv => csv::write(&run, out),
    }
}

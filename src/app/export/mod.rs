//! `uquad export RUN_DIR --format ulog|csv --out PATH`: a run folder (ours, or the
//! original's) for the tools people use — a ULog for Flight Review, PlotJuggler and pyulog
//! (`ulog`), or CSV files with units in their headers (`csv`).

mod csv;
mod ulog;

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
    // Only a file that is not there is absent: a link to nothing is said (below).
    if !crate::config::bounded::exists(&path) {
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

/// Exports `run_dir` as `format` into `out`; returns the files written. They are written as
/// `.partial` files and take their names only once the whole export has succeeded: a failed
/// export leaves an earlier one as it was.
pub fn run(run_dir: &Path, format: Format, out: &Path) -> anyhow::Result<Vec<PathBuf>> {
    has_estimates(run_dir)?;
    let written = match format {
        Format::Ulog => write_ulog(run_dir, out),
        Format::Csv => csv::write(run_dir, out).map(|w| (w.files, w.warnings, w.estimates)),
    };
    let (partials, warnings, estimates) = match written {
        Ok(w) => w,
        Err(e) => {
            remove_partials(out);
            return Err(e.context(format!("export to {}", out.display())));
        }
    };
    warn(warnings);
    if estimates == 0 {
        for p in &partials {
            let _ = std::fs::remove_file(p);
        }
        anyhow::bail!(
            "{}: no estimates (no line of x_hat.log could be read)",
            run_dir.display()
        );
    }
    let mut files = Vec::with_capacity(partials.len());
    for p in partials {
        let done = p.with_extension("");
        std::fs::rename(&p, &done)
            .with_context(|| format!("cannot rename {} to {}", p.display(), done.display()))?;
        files.push(done);
    }
    Ok(files)
}

/// The ULog into `OUT.partial`: its path, the warnings and the estimates written.
fn write_ulog(run_dir: &Path, out: &Path) -> anyhow::Result<(Vec<PathBuf>, Vec<String>, u64)> {
    let params = params(run_dir)?;
    let partial = partial(out);
    let file = std::fs::File::create(&partial)
        .with_context(|| format!("cannot write {}", partial.display()))?;
    let mut w = std::io::BufWriter::with_capacity(256 * 1024, file);
    let (warnings, estimates) = ulog::write(run_dir, &params, &mut w)?;
    w.flush()
        .with_context(|| format!("cannot write {}", partial.display()))?;
    Ok((vec![partial], warnings, estimates))
}

/// `path` with `.partial` appended.
fn partial(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(".partial");
    PathBuf::from(p)
}

/// A failed export's `.partial` files (the ULog's, or a CSV folder's).
fn remove_partials(out: &Path) {
    let _ = std::fs::remove_file(partial(out));
    if let Ok(entries) = std::fs::read_dir(out) {
        for e in entries.flatten() {
            if e.path().extension().is_some_and(|x| x == "partial") {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// A run folder holds estimates: x_hat.log is there and a regular file (what it is, named
/// otherwise), or there is nothing to export.
fn has_estimates(run_dir: &Path) -> anyhow::Result<()> {
    if crate::app::log_lines::LogLines::open(&run_dir.join("x_hat.log"))?.is_none() {
        anyhow::bail!("{}: no estimates (x_hat.log missing)", run_dir.display());
    }
    Ok(())
}

/// The logs' skipped lines, told on stderr (the export goes on).
fn warn(warnings: Vec<String>) {
    for w in warnings {
        eprintln!("warning: {w}");
    }
}

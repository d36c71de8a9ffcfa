//! Keeping a parameter a ground station sets: checked as `--set` is against the run's
//! configuration and against what the next start will apply (the profile with every kept
//! parameter), then kept in the parameters file and noted in the run's config.toml (as a
//! comment: the running flight keeps the values it started with, so its replay stays exact).

use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, Clone)]
pub struct ParamStore {
    /// The run's config.toml.
    pub run_config: PathBuf,
    /// The profile the run started from (the next start's base).
    pub profile: PathBuf,
    /// The parameters file (`config::kept_params_path`).
    pub kept_file: PathBuf,
}

/// A parameter kept: the line that tells it (for err.log), and why it could not be noted in
/// the run's config.toml, if it could not (kept all the same).
pub struct Kept {
    pub line: String,
    pub note_failed: Option<String>,
}

impl ParamStore {
    /// Checks and keeps `key = value` (parameter `id`, set at `t_s` on the run's clock); why
    /// not, when it cannot be.
    pub fn set(&self, id: &str, key: &str, value: toml::Value, t_s: f64) -> Result<Kept, String> {
        super::check_set(&self.run_config, key, value.clone())?;
        super::check_kept(&self.profile, &self.kept_file, key, value.clone())?;
        super::write_kept(&self.kept_file, key, value.clone())?;
        let line = format!(
            "parameter {id} ({key}) set to {value} by the ground station at {t_s:.1} s; kept in \
             {} for the next start",
            self.kept_file.display()
        );
        let noted = std::fs::OpenOptions::new()
            .append(true)
            .open(&self.run_config)
            .and_then(|mut f| writeln!(f, "# {line}"));
        let note_failed = noted.err().map(|e| {
            format!(
                "cannot note the parameter in {}: {e}",
                self.run_config.display()
            )
        });
        Ok(Kept { line, note_failed })
    }
}

//! Keeping a parameter a ground station sets: checked as `--set` is against the run's
//! configuration and against what the next start will apply (the profile with every kept
//! parameter), then noted in err.log and in the run's config.toml (as a comment: the running
//! flight keeps the values it started with, so its replay stays exact) and kept in the
//! parameters file.

use crate::gcs::params::Param;
use crate::tasks::logger::LogHub;
use std::io::Write;
use std::path::PathBuf;

pub struct ParamStore {
    /// The run's config.toml.
    pub run_config: PathBuf,
    /// The profile the run started from (the next start's base).
    pub profile: PathBuf,
    /// The parameters file (`config::kept_params_path`).
    pub kept_file: PathBuf,
    pub logs: LogHub,
}

impl ParamStore {
    /// Checks and keeps `p = value`; why not, when it cannot be.
    pub fn set(&self, p: &Param, value: toml::Value, t_s: f64) -> Result<(), String> {
        crate::config::check_set(&self.run_config, p.key, value.clone())?;
        crate::config::check_kept(&self.profile, &self.kept_file, p.key, value.clone())?;
        crate::config::write_kept(&self.kept_file, p.key, value.clone())?;
        let line = format!(
            "parameter {} ({}) set to {value} by the ground station at {t_s:.1} s; kept in {} \
             for the next start",
            p.id,
            p.key,
            self.kept_file.display()
        );
        let noted = std::fs::OpenOptions::new()
            .append(true)
            .open(&self.run_config)
            .and_then(|mut f| writeln!(f, "# {line}"));
        if let Err(e) = noted {
            self.logs.err(format!(
                "cannot note the parameter in {}: {e}",
                self.run_config.display()
            ));
        }
        tracing::info!("{line}");
        self.logs.err(line);
        Ok(())
    }
}

//! Loading a profile: read and parse the TOML, apply the `--set` overrides, deserialise
//! (reporting every type error and unknown key), validate, resolve relative paths and load the
//! data files. Also the report of what is wrong: `Problem` and `ConfigError`.

use super::bounded::{self, FileKind};
use super::overrides::{remove_dotted, set_dotted};
use super::parameters::PARAMETERS;
use super::profile::Profile;
use super::schema::Config;
use super::validate::validate;
use crate::core::imu::calib::{CALIB_NUMBERS, Calibration};
use crate::core::numfile;
use std::fmt;
use std::path::{Path, PathBuf};

/// Default configuration used when a command gets no `--config`.
pub const DEFAULT_CONFIG: &str = "config/uquad.toml";

/// One problem in a configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// The file the problem is in (the configuration or a data file it names).
    pub file: PathBuf,
    /// The configuration key concerned, when there is one.
    pub key: Option<String>,
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: ", self.file.display())?;
        if let Some(k) = &self.key {
            write!(f, "{k}: ")?;
        }
        f.write_str(&self.message)
    }
}

/// Every problem found while loading a configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    pub problems: Vec<Problem>,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, p) in self.problems.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{p}")?;
        }
        Ok(())
    }
}

/// Picks the configuration file: the given one, else `config/uquad.toml` under the working
/// directory when it exists.
pub fn resolve_path(given: Option<&Path>) -> Result<PathBuf, String> {
    match given {
        Some(p) => Ok(p.to_path_buf()),
        None if Path::new(DEFAULT_CONFIG).is_file() => Ok(PathBuf::from(DEFAULT_CONFIG)),
        None => Err(format!(
            "no --config given and {DEFAULT_CONFIG} does not exist under the working directory"
        )),
    }
}

/// Loads, overrides, validates and resolves a configuration file and its data files.
pub fn load(path: &Path, sets: &[(String, toml::Value)]) -> Result<Profile, ConfigError> {
    load_layers(path, None, sets)
}

/// [`load`], with the parameters a ground station set in earlier runs applied before the
/// `--set` overrides (which win): the file [`kept_params_path`] names, when it exists. Also
/// which file that was and how many it applied.
pub fn load_kept(
    path: &Path,
    sets: &[(String, toml::Value)],
    log_dir: Option<&Path>,
) -> Result<(Profile, Option<(PathBuf, usize)>), ConfigError> {
    let plain = load(path, sets)?;
    let file = kept_params_path(&plain.config, log_dir);
    let Some(kept) = read_kept(&file)? else {
        return Ok((plain, None));
    };
    let profile = load_layers(path, Some((&file, &kept)), sets)?;
    Ok((profile, Some((file, kept.len()))))
}

/// Where a ground station's parameters are kept: `gcs.params_file`, else `params.toml` in the
/// log folder (`log_dir` when the command line names one).
pub fn kept_params_path(c: &Config, log_dir: Option<&Path>) -> PathBuf {
    if !c.gcs.params_file.as_os_str().is_empty() {
        return c.gcs.params_file.clone();
    }
    log_dir.unwrap_or(&c.log.dir).join("params.toml")
}

/// The kept parameters as dotted keys and values; none when there is no such file.
fn read_kept(file: &Path) -> Result<Option<Vec<(String, toml::Value)>>, ConfigError> {
    // Only a file that is not there is "no parameters kept": a link to nothing, a path
    // through a file or a folder that cannot be read is refused, as a FIFO is.
    let text = match bounded::read_text(file, FileKind::Parameters) {
        Err(e) if e.missing => return Ok(None),
        read => read.map_err(|e| read_problem(file, FileKind::Parameters, &e))?,
    };
    let table = parse_table(file, &text)?;
    let mut out = Vec::new();
    flatten("", &table, &mut out);
    // Only parameters: anything else (`commander.start = "flying"`, a path) would change the
    // vehicle behind the operator's back, kept for every later start.
    let problems: Vec<Problem> = out
        .iter()
        .filter(|(key, _)| !PARAMETERS.iter().any(|(_, k)| k == key))
        .map(|(key, _)| Problem {
            file: file.to_path_buf(),
            key: Some(key.clone()),
            message: "not a parameter: this file keeps only the keys `uquad params` lists \
                      (edit the profile, or pass --set, for any other)"
                .to_string(),
        })
        .collect();
    if !problems.is_empty() {
        return Err(ConfigError { problems });
    }
    Ok(Some(out))
}

fn flatten(prefix: &str, t: &toml::Table, out: &mut Vec<(String, toml::Value)>) {
    for (k, v) in t {
        let key = format!("{prefix}{k}");
        match v {
            toml::Value::Table(sub) => flatten(&format!("{key}."), sub, out),
            v => out.push((key, v.clone())),
        }
    }
}

/// Whether the profile at `profile` with the kept parameters and `key = value` among them (what
/// the next start applies) is valid; the first problem otherwise, as "key: message".
pub fn check_kept(
    profile: &Path,
    file: &Path,
    key: &str,
    value: toml::Value,
) -> Result<(), String> {
    let mut kept = read_kept(file)
        .map_err(|e| e.to_string())?
        .unwrap_or_default();
    kept.retain(|(k, _)| k != key);
    kept.push((key.to_string(), value));
    load_layers(profile, Some((file, &kept)), &[])
        .map(|_| ())
        .map_err(|e| first_problem(&e, &format!(" (from {})", file.display())))
}

/// The first problem of a failed load, as "key: message", without the origin `origin` (the
/// caller says where the change came from).
fn first_problem(e: &ConfigError, origin: &str) -> String {
    e.problems.first().map_or_else(String::new, |p| {
        let message = p.message.replace(origin, "");
        match &p.key {
            Some(k) => format!("{k}: {message}"),
            None => message,
        }
    })
}

/// Sets `key` to `value` in the kept-parameters file (created when missing): written whole
/// under a temporary name, flushed to the disk and renamed into place, so a power cut leaves
/// the old file or the new one.
pub fn write_kept(file: &Path, key: &str, value: toml::Value) -> Result<(), String> {
    let mut table = match bounded::read_text(file, FileKind::Parameters) {
        Err(e) if e.missing => toml::Table::new(),
        read => {
            let text =
                read.map_err(|e| read_problem(file, FileKind::Parameters, &e).to_string())?;
            parse_table(file, &text).map_err(|e| e.to_string())?
        }
    };
    set_dotted(&mut table, key, value)?;
    let text = toml::to_string(&table).map_err(|e| e.to_string())?;
    let header = "# Parameters set by a ground station (uquad writes this file). `uquad fly` and \
                  `uquad sim` apply them at start, under --set.\n";
    let tmp = file.with_extension(format!("toml.{}.tmp", std::process::id()));
    let written = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        std::io::Write::write_all(&mut f, format!("{header}{text}").as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&tmp, file)?;
        if let Some(dir) = file.parent() {
            std::fs::File::open(dir)?.sync_all()?;
        }
        Ok::<(), std::io::Error>(())
    })();
    written.map_err(|e| format!("cannot write {}: {e}", file.display()))
}

/// Whether `key = value` is a valid change of the configuration at `path`, checked as `--set`
/// is; the first problem otherwise, as "key: message".
pub fn check_set(path: &Path, key: &str, value: toml::Value) -> Result<(), String> {
    let sets = [(key.to_string(), value)];
    load(path, &sets)
        .map(|_| ())
        .map_err(|e| first_problem(&e, " (from --set)"))
}

/// Loads with the kept parameters (when any) and then the `--set` overrides applied.
fn load_layers(
    path: &Path,
    kept: Option<(&Path, &[(String, toml::Value)])>,
    sets: &[(String, toml::Value)],
) -> Result<Profile, ConfigError> {
    let mut table = read_table(path, FileKind::Profile)?;
    let mut report = Report {
        path,
        kept,
        sets,
        problems: Vec::new(),
    };
    apply_sets(&mut table, &mut report);
    let Some(mut config) = deserialise(table, &mut report) else {
        return Err(report.into_error());
    };
    for check in validate(&config) {
        let origin = report.origin(&check.key);
        let message = format!(
            "{} is out of range{origin}: allowed {}",
            check.value, check.allowed
        );
        report.push(Some(&check.key), message);
    }
    resolve_paths(&mut config, path);
    match load_data(&config, &mut report) {
        Some(data) if report.problems.is_empty() => Ok(Profile {
            path: path.to_path_buf(),
            config,
            calib: data.calib,
            k_prop: data.k_prop,
            k_int: data.k_int,
            lqr_q: data.lqr_q,
            lqr_r: data.lqr_r,
            signing_key: data.signing_key,
            mission: None,
        }),
        _ => Err(report.into_error()),
    }
}

/// The problems found so far in one configuration file.
struct Report<'a> {
    /// The configuration file.
    path: &'a Path,
    /// The kept parameters' file and its keys, applied before the `--set` overrides.
    kept: Option<(&'a Path, &'a [(String, toml::Value)])>,
    /// The `--set` overrides applied to it.
    sets: &'a [(String, toml::Value)],
    problems: Vec<Problem>,
}

impl Report<'_> {
    /// " (from --set)" for a key given with `--set`: the user then knows the file is not at
    /// fault.
    fn origin(&self, key: &str) -> String {
        let has = |list: &[(String, toml::Value)]| list.iter().any(|(k, _)| k == key);
        match self.kept {
            _ if has(self.sets) => " (from --set)".into(),
            Some((file, kept)) if has(kept) => format!(" (from {})", file.display()),
            _ => String::new(),
        }
    }

    /// A problem in the configuration file, at `key` when there is one.
    fn push(&mut self, key: Option<&str>, message: String) {
        self.problems.push(Problem {
            file: self.path.to_path_buf(),
            key: key.map(str::to_string),
            message,
        });
    }

    fn into_error(self) -> ConfigError {
        ConfigError {
            problems: self.problems,
        }
    }
}

/// Reads (bounded, see `config::bounded`) and parses a configuration file of `kind`; either
/// failing ends the load with that one problem.
fn read_table(path: &Path, kind: FileKind) -> Result<toml::Table, ConfigError> {
    let text = bounded::read_text(path, kind).map_err(|e| read_problem(path, kind, &e))?;
    parse_table(path, &text)
}

/// A file of `kind` that could not be read, as the load's one problem.
fn read_problem(path: &Path, kind: FileKind, e: &bounded::ReadError) -> ConfigError {
    let what = match kind {
        FileKind::Parameters => "the kept parameters",
        _ => "the configuration",
    };
    one_problem(path, format!("cannot read {what}: {e}"))
}

fn parse_table(path: &Path, text: &str) -> Result<toml::Table, ConfigError> {
    toml::from_str(text)
        .map_err(|e| one_problem(path, format!("not valid TOML: {}", e.to_string().trim())))
}

fn one_problem(path: &Path, message: String) -> ConfigError {
    ConfigError {
        problems: vec![Problem {
            file: path.to_path_buf(),
            key: None,
            message,
        }],
    }
}

/// Applies the kept parameters, then the `--set` overrides, in order; one that cannot apply
/// is reported and skipped.
fn apply_sets(table: &mut toml::Table, report: &mut Report<'_>) {
    let kept = report.kept.map_or(&[][..], |(_, k)| k);
    for (key, value) in kept.iter().chain(report.sets) {
        if let Err(e) = set_dotted(table, key, value.clone()) {
            report.push(Some(key), format!("--set cannot apply: {e}"));
        }
    }
}

/// Deserialises the table, reporting every type error and unknown key. On a type error the
/// key is noted and dropped (its default applies) and deserialising starts again, so every
/// bad value is reported rather than only the first. None when a type error cannot be
/// dropped (it is not at a key).
fn deserialise(mut table: toml::Table, report: &mut Report<'_>) -> Option<Config> {
    loop {
        let mut unknown: Vec<String> = Vec::new();
        match deserialise_once(&table, &mut unknown) {
            Ok(config) => {
                for key in &unknown {
                    let message = format!("unknown key{}", report.origin(key));
                    report.push(Some(key), message);
                }
                return Some(config);
            }
            Err((key, message)) => {
                let message = format!("{message}{}", report.origin(&key));
                report.push(Some(&key), message);
                if key.is_empty() || key == "." || !remove_dotted(&mut table, &key) {
                    return None;
                }
            }
        }
    }
}

/// One pass of serde over the table, collecting the unknown keys: the configuration, or the
/// key of the first type error and its message.
fn deserialise_once(
    table: &toml::Table,
    unknown: &mut Vec<String>,
) -> Result<Config, (String, String)> {
    let mut track = serde_path_to_error::Track::new();
    let de = serde_path_to_error::Deserializer::new(toml::Value::Table(table.clone()), &mut track);
    let result: Result<Config, _> = serde_ignored::deserialize(de, |p| unknown.push(p.to_string()));
    result.map_err(|e| {
        // The first line is the problem; the rest repeats the key we already name.
        let full = e.to_string();
        let message = full.lines().next().unwrap_or("invalid value").trim();
        (track.path().to_string(), message.to_string())
    })
}

/// Makes every path of the configuration absolute, relative ones resolving against the
/// configuration file's folder. An empty console socket stays empty (no console).
fn resolve_paths(c: &mut Config, path: &Path) {
    let base = path
        .parent()
        .map(|p| {
            if p.as_os_str().is_empty() {
                Path::new(".")
            } else {
                p
            }
        })
        .unwrap_or(Path::new("."));
    let base = std::fs::canonicalize(base).unwrap_or_else(|_| base.to_path_buf());
    let resolve = |p: &Path| {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            base.join(p)
        }
    };
    c.imu.calib_file = resolve(&c.imu.calib_file);
    c.log.dir = resolve(&c.log.dir);
    if !c.console.socket.as_os_str().is_empty() {
        c.console.socket = resolve(&c.console.socket);
    }
    for p in [
        &mut c.gcs.serial,
        &mut c.gcs.params_file,
        &mut c.gcs.signing_key_file,
    ] {
        if !p.as_os_str().is_empty() {
            *p = resolve(p);
        }
    }
    c.control.k_prop_file = resolve(&c.control.k_prop_file);
    c.control.k_int_file = resolve(&c.control.k_int_file);
    c.control.lqr_q_file = resolve(&c.control.lqr_q_file);
    c.control.lqr_r_file = resolve(&c.control.lqr_r_file);
}

/// The data files a configuration names, loaded.
struct DataFiles {
    signing_key: Option<super::SigningKey>,
    calib: Calibration,
    k_prop: Vec<f64>,
    k_int: Vec<f64>,
    lqr_q: Vec<f64>,
    lqr_r: Vec<f64>,
}

/// Loads every data file, reporting each one that is missing or malformed.
fn load_data(c: &Config, report: &mut Report<'_>) -> Option<DataFiles> {
    let control = &c.control;
    let calib = load_numbers(report, "imu.calib_file", &c.imu.calib_file, CALIB_NUMBERS)
        .map(|n| Calibration::from_numbers(&n));
    // The original read exactly rows × cols numbers and ignored the rest (spec 4.3).
    let n_states = if control.states == 8 { 8 } else { 12 };
    let n_int = control.integrator_set().map_or(4, |s| s.states().len());
    let k_prop = load_numbers(
        report,
        "control.k_prop_file",
        &control.k_prop_file,
        4 * n_states,
    );
    let k_int = load_numbers(report, "control.k_int_file", &control.k_int_file, 4 * n_int);
    let lqr_q = load_numbers(report, "control.lqr_q_file", &control.lqr_q_file, 256);
    let lqr_r = load_numbers(report, "control.lqr_r_file", &control.lqr_r_file, 16);
    let signing_key = load_signing_key(report, &c.gcs.signing_key_file);
    Some(DataFiles {
        signing_key: signing_key?,
        calib: calib?,
        k_prop: k_prop?,
        k_int: k_int?,
        lqr_q: lqr_q?,
        lqr_r: lqr_r?,
    })
}

/// `gcs.signing_key_file`'s key (`None`: signing off), read bounded; a file that cannot be
/// read or holds no key is reported against the configuration.
fn load_signing_key(report: &mut Report<'_>, file: &Path) -> Option<Option<super::SigningKey>> {
    const KEY: &str = "gcs.signing_key_file";
    if file.as_os_str().is_empty() {
        return Some(None);
    }
    let key = bounded::read_text(file, FileKind::Calibration)
        .map_err(|e| format!("cannot read {}: {e}", file.display()))
        .and_then(|text| {
            super::gcs::signing_key(&text).map_err(|e| format!("{}: {e}", file.display()))
        });
    match key {
        Ok(k) => Some(Some(super::SigningKey(k))),
        Err(why) => {
            report.push(Some(KEY), why);
            None
        }
    }
}

/// Reads exactly `count` numbers from `file`, named by `key`. A file that cannot be read is
/// reported against the configuration; a malformed one against itself, with the position.
fn load_numbers(report: &mut Report<'_>, key: &str, file: &Path, count: usize) -> Option<Vec<f64>> {
    let kind = if key == "imu.calib_file" {
        FileKind::Calibration
    } else {
        FileKind::Numbers
    };
    let text = match bounded::read_text(file, kind) {
        Ok(t) => t,
        Err(e) => {
            report.push(Some(key), format!("cannot read {}: {e}", file.display()));
            return None;
        }
    };
    match numfile::parse_exact(&text, count) {
        Ok(n) => Some(n),
        Err(e) => {
            report.problems.push(Problem {
                file: file.to_path_buf(),
                key: Some(key.to_string()),
                message: e.to_string(),
            });
            None
        }
    }
}

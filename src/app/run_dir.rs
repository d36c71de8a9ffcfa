//! The run folder: a new, unique `<UTC time>` folder per run, made self-contained with the
//! resolved configuration and copies of the data files it names, and the run's id: its
//! folder's name and a random part, written in config.toml's header (and by the flight in
//! mode.log and gps.log), so that logs of another run are refused by a replay.

use crate::config::bounded::{self, FileKind};
use crate::config::{Config, Profile};
use anyhow::Context;
use std::path::{Path, PathBuf};

/// Seconds since the Unix epoch as a UTC `YYYYMMDD-HHMMSS` (no time-zone database needed).
fn utc_stamp(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Civil from days (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// Creates a new, unique run folder under `parent`: `<UTC time>`, or `<UTC time>-N` when runs
/// start in the same second (creation is atomic, so concurrent runs never share one).
pub fn create_run_dir(parent: &Path) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(parent)
        .with_context(|| format!("cannot create the log folder {}", parent.display()))?;
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let base = utc_stamp(secs);
    for n in 0..10_000u32 {
        let name = if n == 0 {
            base.clone()
        } else {
            format!("{base}-{n}")
        };
        let dir = parent.join(name);
        match std::fs::create_dir(&dir) {
            Ok(()) => return Ok(dir),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => {
                return Err(e).with_context(|| format!("cannot create {}", dir.display()));
            }
        }
    }
    anyhow::bail!("no free run folder name under {}", parent.display())
}

/// The id of a new run in `run_dir`: the folder's name and 32 random bits (two runs of one
/// name, on two vehicles or after a folder was renamed, differ).
pub fn new_run_id(run_dir: &Path) -> String {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    let name = run_dir
        .file_name()
        .map_or_else(|| "run".to_string(), |n| n.to_string_lossy().into_owned());
    format!("{name}-{:08x}", h.finish() as u32)
}

/// config.toml's line naming the run.
const RUN_LINE: &str = "# run ";

/// The id the run folder's config.toml names; `None` when it names none (a folder written
/// before runs had ids, or the 2012 flights, which have no config.toml).
pub fn run_id_of(run_dir: &Path) -> anyhow::Result<Option<String>> {
    let path = run_dir.join("config.toml");
    let text = match bounded::read_text(&path, FileKind::Profile) {
        Ok(t) => t,
        Err(e) if e.missing => return Ok(None),
        Err(e) => anyhow::bail!("cannot read {}: {e}", path.display()),
    };
    Ok(text
        .lines()
        .take_while(|l| l.starts_with('#'))
        .find_map(|l| l.strip_prefix(RUN_LINE))
        .map(|id| id.trim_end_matches('\r').to_string()))
}

/// The mission a run flew, kept in its folder for its replay.
pub const MISSION_FILE: &str = "mission.toml";

/// Makes the run folder self-contained: copies the data files the profile names (read
/// bounded, as the load read them) and writes the resolved configuration pointing at the
/// copies, so `uquad replay <run>` works anywhere, its header naming the run `run_id`. Two
/// files of one name (from two folders)
/// keep apart: the later is named after its key too.
pub fn write_run_config(profile: &Profile, run_dir: &Path, run_id: &str) -> anyhow::Result<()> {
    if let Some(m) = &profile.mission {
        let path = run_dir.join(MISSION_FILE);
        std::fs::write(&path, &m.text)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    let mut c: Config = profile.config.clone();
    let mut taken: Vec<PathBuf> = Vec::with_capacity(5);
    let mut copy = |key: &str, p: &mut PathBuf, kind: FileKind| -> anyhow::Result<()> {
        let mut name = p
            .file_name()
            .map(PathBuf::from)
            .with_context(|| format!("{key}: {} has no file name", p.display()))?;
        if taken.contains(&name) {
            name = PathBuf::from(format!("{key}-{}", name.display()));
        }
        let text = bounded::read_text(p, kind)
            .with_context(|| format!("{key}: cannot read {}", p.display()))?;
        std::fs::write(run_dir.join(&name), text)
            .with_context(|| format!("cannot copy {} into {}", p.display(), run_dir.display()))?;
        taken.push(name.clone());
        *p = name;
        Ok(())
    };
    copy(
        "imu.calib_file",
        &mut c.imu.calib_file,
        FileKind::Calibration,
    )?;
    copy(
        "control.k_prop_file",
        &mut c.control.k_prop_file,
        FileKind::Numbers,
    )?;
    copy(
        "control.k_int_file",
        &mut c.control.k_int_file,
        FileKind::Numbers,
    )?;
    copy(
        "control.lqr_q_file",
        &mut c.control.lqr_q_file,
        FileKind::Numbers,
    )?;
    copy(
        "control.lqr_r_file",
        &mut c.control.lqr_r_file,
        FileKind::Numbers,
    )?;
    c.log.dir = PathBuf::from("..");
    let text = toml::to_string(&c).context("cannot serialise the configuration")?;
    let header = format!(
        "# The resolved configuration of this run (uquad writes it; paths are relative to this \
         folder).\n{RUN_LINE}{run_id}\n"
    );
    std::fs::write(run_dir.join("config.toml"), format!("{header}{text}"))
        .with_context(|| format!("cannot write {}", run_dir.join("config.toml").display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_is_named_in_its_configuration() {
        let d = tempfile::tempdir().unwrap();
        let run = create_run_dir(d.path()).unwrap();
        let id = new_run_id(&run);
        assert!(
            id.starts_with(&*run.file_name().unwrap().to_string_lossy()),
            "{id}"
        );
        assert_ne!(id, new_run_id(&run), "a random part");
        assert_eq!(run_id_of(&run).unwrap(), None, "no config.toml yet");
        let profile = crate::config::load(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("config/uquad.toml"),
            &[],
        )
        .unwrap();
        write_run_config(&profile, &run, &id).unwrap();
        assert_eq!(run_id_of(&run).unwrap(), Some(id));
    }

    #[test]
    fn utc_stamps() {
        assert_eq!(utc_stamp(0), "19700101-000000");
        assert_eq!(utc_stamp(1_327_662_538), "20120127-110858");
        assert_eq!(utc_stamp(951_782_400), "20000229-000000");
    }

    #[test]
    fn run_dirs_are_unique_in_the_same_second() {
        let d = tempfile::tempdir().unwrap();
        let dirs: Vec<PathBuf> = (0..5).map(|_| create_run_dir(d.path()).unwrap()).collect();
        let mut names: Vec<_> = dirs
            .iter()
            .map(|p| p.file_name().unwrap().to_owned())
            .collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), 5);
    }
}

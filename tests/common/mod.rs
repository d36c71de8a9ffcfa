//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub fn flight_dir() -> PathBuf {
    root().join("tests/data/flight-2012-05-25")
}

pub fn profile_2012() -> PathBuf {
    root().join("config/flight-2012-05.toml")
}

/// Runs the `uquad` binary with `args` in `cwd`.
pub fn uquad(cwd: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_uquad"))
        .args(args)
        .current_dir(cwd)
        .env("RUST_LOG", "warn")
        .output()
        .expect("the uquad binary runs")
}

/// Reads a whitespace-separated numeric log, accepting every line-end style.
pub fn read_table(path: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.split(['\n', '\r'])
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split_whitespace().map(str::to_string).collect())
        .collect()
}

/// Copies the two 2012 profile files and the data files they name into `dir`.
pub fn copy_profile(dir: &Path) -> PathBuf {
    for f in [
        "flight-2012-05.toml",
        "imu_calib.txt",
        "K_prop_full_ppzt.txt",
        "K_int_full_ppzt.txt",
        "lqr-Q.txt",
        "lqr-R.txt",
    ] {
        std::fs::copy(root().join("config").join(f), dir.join(f)).expect("copy profile");
    }
    dir.join("flight-2012-05.toml")
}

/// Runs `uquad replay RUN --config <2012 profile> --out <fresh folder> EXTRA...`.
pub fn replay_2012(run: &Path, extra: &[&str]) -> (Output, tempfile::TempDir) {
    let out = tempfile::tempdir().expect("temp dir");
    let profile = profile_2012();
    let mut args = vec![
        "replay",
        run.to_str().expect("utf-8 path"),
        "--config",
        profile.to_str().expect("utf-8 path"),
        "--out",
        out.path().to_str().expect("utf-8 path"),
    ];
    args.extend_from_slice(extra);
    (uquad(&root(), &args), out)
}

/// [`replay_2012`], which must succeed; returns the output folder.
pub fn replay_ok(run: &Path, extra: &[&str]) -> tempfile::TempDir {
    let (o, out) = replay_2012(run, extra);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// A numeric log as rows of numbers.
pub fn numbers(path: &Path) -> Vec<Vec<f64>> {
    read_table(path)
        .into_iter()
        .map(|r| r.iter().map(|v| v.parse().expect("a number")).collect())
        .collect()
}

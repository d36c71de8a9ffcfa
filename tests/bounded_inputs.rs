//! Every file uquad reads is bounded: a device that never ends (/dev/zero), a FIFO that
//! would hold the start forever, a 1 GB file, as the profile, the calibration, a mission and
//! the kept parameters, refused at once with the reason (exit 2); `params.toml` holds
//! parameters only, and a link of it to nothing is refused, not ignored; a replay's mission
//! that is a link to nothing fails the replay.

mod common;
use common::*;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Runs `uquad ARGS` from the repository's root; its exit code and stderr. A run still going
/// after a minute (a read that never ends) is killed and fails the test, instead of hanging it.
fn run(args: &[&str]) -> (Option<i32>, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_uquad"))
        .args(args)
        .current_dir(root())
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let out = child.wait_with_output().unwrap();
            return (
                status.code(),
                String::from_utf8_lossy(&out.stderr).to_string(),
            );
        }
        if start.elapsed() > Duration::from_secs(60) {
            child.kill().unwrap();
            let out = child.wait_with_output().unwrap();
            panic!(
                "uquad {args:?} still running after 60 s: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A FIFO, /dev/zero and a sparse 1 GB file in `dir`, with what each must be called.
fn hostile(dir: &Path) -> Vec<(String, &'static str)> {
    let fifo = dir.join("fifo");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only creates the node.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let big = dir.join("big");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(1 << 30)
        .unwrap();
    vec![
        (fifo.display().to_string(), "a FIFO, not a regular file"),
        ("/dev/zero".to_string(), "a character device"),
        (big.display().to_string(), "1073741824 bytes; "),
    ]
}

#[test]
fn hostile_profiles_calibrations_and_missions_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    for (file, why) in hostile(dir.path()) {
        let (code, err) = run(&["check-config", &file]);
        assert_eq!(code, Some(2), "{err}");
        assert!(
            err.contains(&format!("{file}: cannot read the configuration: {why}")),
            "{err}"
        );
        let calib = format!("imu.calib_file=\"{file}\"");
        let (code, err) = run(&["check-config", "config/uquad.toml", "--set", &calib]);
        assert_eq!(code, Some(2), "{err}");
        assert!(
            err.contains(&format!("imu.calib_file: cannot read {file}: {why}")),
            "{err}"
        );
        let (code, err) = run(&["sim", "--fast", "--mission", &file]);
        assert_eq!(code, Some(2), "{err}");
        assert!(
            err.contains(&format!("cannot read the mission {file}: {why}")),
            "{err}"
        );
    }
}

#[test]
fn kept_parameters_are_parameters_in_a_regular_file() {
    let dir = tempfile::tempdir().unwrap();
    let logs = dir.path().join("logs");
    std::fs::create_dir(&logs).unwrap();
    let params = logs.join("params.toml");
    let start = |params_note: &str| {
        let (code, err) = run(&["sim", "--fast", "--log-dir", logs.to_str().unwrap()]);
        assert_eq!(code, Some(2), "{params_note}: {err}");
        err
    };
    // A key that is no parameter: the vehicle would start flying with no operator.
    std::fs::write(
        &params,
        "[commander]\nstart = \"flying\"\n[fence]\nradius_m = 40.0\n",
    )
    .unwrap();
    let err = start("a key outside the table");
    assert!(
        err.contains("params.toml: commander.start: not a parameter"),
        "{err}"
    );
    assert!(
        !err.contains("fence.radius_m"),
        "a parameter is fine: {err}"
    );
    // A link to nothing is not "no parameters kept".
    std::fs::remove_file(&params).unwrap();
    std::os::unix::fs::symlink(dir.path().join("gone"), &params).unwrap();
    let err = start("a dangling link");
    assert!(err.contains("which does not exist"), "{err}");
    // A path through a file is not "no parameters kept" either.
    let afile = dir.path().join("afile");
    std::fs::write(&afile, "").unwrap();
    let through = format!(
        "gcs.params_file=\"{}\"",
        afile.join("params.toml").display()
    );
    let (code, err) = run(&["sim", "--fast", "--set", &through]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("cannot read the kept parameters"), "{err}");
    // A FIFO, /dev/zero, a 1 GB file.
    for (file, why) in hostile(dir.path()) {
        std::fs::remove_file(&params).unwrap();
        std::os::unix::fs::symlink(&file, &params).unwrap();
        let err = start(&file);
        assert!(
            err.contains(&format!("cannot read the kept parameters: {why}")),
            "{err}"
        );
    }
}

#[test]
fn a_replay_whose_mission_is_a_link_to_nothing_fails() {
    // The replay read "no mission" and replayed another flight, exit 0.
    let logs = tempfile::tempdir().unwrap();
    let flown = sim_run(
        logs.path(),
        &["--fast", "--mission", "config/missions/square.toml"],
    );
    let mission = flown.join("mission.toml");
    std::fs::remove_file(&mission).unwrap();
    std::os::unix::fs::symlink(logs.path().join("gone"), &mission).unwrap();
    let out = tempfile::tempdir().unwrap();
    let (code, err) = run(&[
        "replay",
        flown.to_str().unwrap(),
        "--out",
        out.path().to_str().unwrap(),
    ]);
    assert_ne!(code, Some(0), "{err}");
    assert!(err.contains("which does not exist"), "{err}");
}

#[test]
fn data_files_of_one_name_keep_apart_in_the_run_folder() {
    // The LQR weights in a file named like the calibration, from another folder: the run
    // folder's copy of one overwrote the other, and the replay read the weights as the
    // calibration ("acceleration norm 16.00").
    let dir = tempfile::tempdir().unwrap();
    let q = dir.path().join("imu_calib.txt");
    std::fs::copy(root().join("config/lqr-Q-uquad.txt"), &q).unwrap();
    let logs = dir.path().join("logs");
    std::fs::create_dir(&logs).unwrap();
    let set = format!("control.lqr_q_file=\"{}\"", q.display());
    let flown = sim_run(&logs, &["--fast", "--set", &set, "--duration", "15"]);
    assert!(flown.join("imu_calib.txt").exists());
    assert!(flown.join("control.lqr_q_file-imu_calib.txt").exists());
    replay_run(&flown);
}

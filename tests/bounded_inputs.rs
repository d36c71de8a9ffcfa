//! Every file uquad reads is bounded: a device that never ends (/dev/zero), a FIFO that
//! would hold the start forever, a 1 GB file, as the profile, the calibration, a mission and
//! the kept parameters, refused at once with the reason (exit 2); `params.toml` holds
//! parameters only, and a link of it to nothing is refused, not ignored; a replay's mission
//! that is a link to nothing fails the replay; a replay refuses a tampered mode.log naming
//! the line (quoting a bounded prefix) and another run's; a full log disk still leaves the
//! report, err.log and mode.log.

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

/// Replays `run` (its mode.log rewritten by `edit`) into a fresh folder: its exit code and
/// stderr.
fn replay_edited(run: &Path, edit: impl FnOnce(&str) -> String) -> (Option<i32>, String) {
    let path = run.join("mode.log");
    let original = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, edit(&original)).unwrap();
    let out = tempfile::tempdir().unwrap();
    let result = run_replay(run, out.path());
    std::fs::write(&path, original).unwrap();
    result
}

fn run_replay(run: &Path, out: &Path) -> (Option<i32>, String) {
    self::run(&[
        "replay",
        run.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
}

#[test]
fn a_replay_refuses_a_tampered_mode_log_naming_the_line() {
    // Times reversed, negative or at i64::MAX, another run's mode.log, an inserted line: all
    // replayed with exit 0; a 50 MB bad line was echoed whole.
    let (logs, other_logs) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let args = ["--fast", "--duration", "15"];
    let run = sim_run(logs.path(), &args);
    let other = sim_run(other_logs.path(), &args);
    let text = std::fs::read_to_string(run.join("mode.log")).unwrap();
    let id = text.lines().next().unwrap();
    assert!(id.starts_with("0 run "), "{text}");
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(
        config.contains(&format!("\n# run {}\n", &id[6..])),
        "{config}"
    );
    // As recorded, it replays to the same bytes, its run line included.
    let out = tempfile::tempdir().unwrap();
    let (code, err) = run_replay(&run, out.path());
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(
        std::fs::read_to_string(out.path().join("mode.log")).unwrap(),
        text
    );
    // The arm is line 3 (after the run line and the start).
    let arm = text
        .lines()
        .position(|l| l.contains(" in gcs arm"))
        .unwrap()
        + 1;
    let retimed = |t: &str| {
        let t = t.to_string();
        move |s: &str| {
            s.lines()
                .map(|l| match l.split_once(" in gcs arm") {
                    Some((_, rest)) => format!("{t} in gcs arm{rest}\n"),
                    None => format!("{l}\n"),
                })
                .collect()
        }
    };
    type Edit = Box<dyn FnOnce(&str) -> String>;
    let cases: Vec<(Edit, String)> = vec![
        (Box::new(retimed("-5")), format!("line {arm}: time -5 µs")),
        (
            Box::new(retimed("1")),
            format!("line {arm}: time 1 µs is before the previous"),
        ),
        (
            Box::new(retimed("9223372036854775807")),
            format!("line {arm}: time 9223372036854775807 µs is more than a week after"),
        ),
        (
            Box::new(|s: &str| format!("{s}7000000 sing gcs\n")),
            "unknown record \"sing\"".to_string(),
        ),
        (
            Box::new(|s: &str| format!("{s}7000000 in gcs {}\n", "x".repeat(50_000_000))),
            "bytes)".to_string(),
        ),
    ];
    for (edit, expected) in cases {
        let (code, err) = replay_edited(&run, edit);
        assert_ne!(code, Some(0), "{expected}: {err}");
        assert!(err.contains(&expected), "{expected}: {err}");
        assert!(err.len() < 2000, "a bounded message: {} bytes", err.len());
    }
    // Another run's mode.log, another run's gps.log.
    let foreign = std::fs::read_to_string(other.join("mode.log")).unwrap();
    let (code, err) = replay_edited(&run, |_| foreign);
    assert_ne!(code, Some(0), "{err}");
    assert!(err.contains("the mode.log of another run"), "{err}");
    std::fs::copy(other.join("gps.log"), run.join("gps.log")).unwrap();
    let (code, err) = run_replay(&run, out.path());
    assert_ne!(code, Some(0), "{err}");
    assert!(err.contains("the gps.log of another run"), "{err}");
}

#[test]
fn a_full_log_disk_still_gives_the_report_and_the_mode_and_error_logs() {
    // A full disk, as a file-size limit of 64 KiB every log write meets (x_hat.log and the
    // other large streams fail; err.log, mode.log and the report fit): the run ended with
    // status 1, no report, and neither err.log nor mode.log.
    use std::os::unix::process::CommandExt;
    let logs = tempfile::tempdir().unwrap();
    let report_dir = tempfile::tempdir().unwrap();
    let report = report_dir.path().join("report.json");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_uquad"));
    cmd.args([
        "sim",
        "--fast",
        "--config",
        "config/uquad.toml",
        "--duration",
        "15",
    ])
    .arg("--log-dir")
    .arg(logs.path())
    .arg("--report")
    .arg(&report)
    .current_dir(root());
    // SAFETY: between fork and exec only async-signal-safe calls: setrlimit and signal.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: 64 * 1024,
                rlim_max: 64 * 1024,
            };
            // A write past the limit fails (EFBIG) instead of killing the process.
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let o = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let error = r["error"].as_str().unwrap_or_default();
    assert!(error.contains("File too large"), "{r}");
    assert!(
        r["log_io_errors_by_stream"]["x_hat"].as_u64() >= Some(1),
        "{r}"
    );
    assert_eq!(r["log_io_errors_by_stream"]["mode"], 0, "{r}");
    let run = run_dir(logs.path());
    let mode = std::fs::read_to_string(run.join("mode.log")).unwrap();
    assert!(mode.contains(" mode disarmed "), "{mode}");
    let err_log = std::fs::read_to_string(run.join("err.log")).unwrap();
    assert!(err_log.contains("simulation, seed"), "{err_log}");
}

//! `uquad export`: the 2012 flight and a simulated run as ULog, read back by pyulog (installed
//! by the test command, `tests/run.sh`; `UQUAD_PYTHON` names its python) and compared with
//! the text logs; and as CSV, read back by Python's csv module.

mod common;
use common::*;
use serde_json::Value;
use std::path::Path;

fn python() -> String {
    std::env::var("UQUAD_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// Exports `run` as `format` into `out`, which must succeed.
fn export(run: &Path, format: &str, out: &Path) {
    let o = try_export(run, format, out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `uquad export RUN --format FORMAT --out OUT`: its status and output.
fn try_export(run: &Path, format: &str, out: &Path) -> std::process::Output {
    let (run, out) = (run.to_str().unwrap(), out.to_str().unwrap());
    uquad(&root(), &["export", run, "--format", format, "--out", out])
}

/// `script` with `args` under the python that has pyulog; its JSON line.
fn python_json(script: &str, args: &[&Path]) -> Value {
    let o = std::process::Command::new(python())
        .arg(root().join("tests").join(script))
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python()));
    assert!(
        o.status.success(),
        "{script} failed (pyulog missing? run tests/run.sh, or set UQUAD_PYTHON): {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let out = String::from_utf8_lossy(&o.stdout);
    serde_json::from_str(out.lines().last().unwrap_or("{}")).unwrap()
}

/// The ULog of `run` read back by pyulog: every compared column equal to the text logs'.
fn ulog_of(run: &Path) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let ulg = dir.path().join("run.ulg");
    export(run, "ulog", &ulg);
    let v = python_json("ulog_check.py", &[&ulg, run]);
    eprintln!("pyulog read: {v}");
    for (column, d) in v["diff"].as_object().unwrap() {
        assert_eq!(
            d.as_f64(),
            Some(0.0),
            "{column} differs from the text log: {v}"
        );
    }
    assert_eq!(v["sys_name"], "uquad", "{v}");
    v
}

fn topics(v: &Value) -> Vec<&str> {
    v["topics"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap())
        .collect()
}

#[test]
fn the_2012_flight_exports_to_a_ulog_pyulog_reads() {
    let v = ulog_of(&flight_dir());
    for t in [
        "vehicle_attitude",
        "vehicle_local_position",
        "actuator_outputs",
        "sensor_combined",
        "vehicle_air_data",
        "uquad_imu_raw",
    ] {
        assert!(topics(&v).contains(&t), "{t}: {v}");
    }
    assert_eq!(v["rows"]["vehicle_local_position"], 1121, "{v}");
    // The original's err.log lines are logged messages; it had no configuration file.
    assert!(v["messages"].as_array().unwrap().len() > 2, "{v}");
    assert_eq!(v["params"], 0);
}

#[test]
fn a_sim_run_exports_to_ulog_and_csv() {
    let logs = tempfile::tempdir().unwrap();
    let run = sim_run(logs.path(), &[]);
    let v = ulog_of(&run);
    for t in [
        "vehicle_local_position_setpoint",
        "vehicle_attitude_setpoint",
        "vehicle_gps_position",
        "estimator_status",
        "vehicle_status",
    ] {
        assert!(topics(&v).contains(&t), "{t}: {v}");
    }
    // ulog2kml draws the fixes' track (latitude, longitude and altitude).
    assert!(v["kml_bytes"].as_u64().is_some_and(|b| b > 1000), "{v}");
    // Disarmed, armed, takeoff, hold, land, disarmed.
    assert_eq!(v["rows"]["vehicle_status"], 6, "{v}");
    assert_eq!(v["params"], uquad::gcs::params::TABLE.len(), "{v}");
    let messages: Vec<&str> = v["messages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap())
        .collect();
    assert!(messages.contains(&"mode armed command arm"), "{messages:?}");
    let out = tempfile::tempdir().unwrap();
    export(&run, "csv", out.path());
    let c = python_json("csv_check.py", &[out.path(), &run]);
    eprintln!("csv read: {c}");
    assert_eq!(
        c["files"],
        serde_json::json!([
            "gps",
            "imu_raw",
            "innov",
            "kalman_in",
            "mode",
            "setpoint",
            "w",
            "x_hat"
        ]),
        "{c}"
    );
    assert_eq!(c["x_hat_z_diff"], 0.0, "{c}");
    assert_eq!(c["headers_without_unit"], serde_json::json!([]), "{c}");
}

/// A log with an over-long line (a corrupted card) and one cut off at its end (a power cut):
/// export and plot go on, the lines skipped and named on stderr (a bad line made them fail,
/// and a line of a gigabyte was read whole).
#[test]
fn over_long_and_cut_off_lines_are_skipped_and_told() {
    let logs = tempfile::tempdir().unwrap();
    let run = sim_run(logs.path(), &["--fast", "--duration", "15"]);
    let out = tempfile::tempdir().unwrap();
    export(&run, "csv", &out.path().join("before"));
    let x_hat = run.join("x_hat.log");
    let text = std::fs::read_to_string(&x_hat).unwrap();
    let rows = text.lines().count();
    // Line 2 overwritten by a line of 200 000 bytes.
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[1] = "1".repeat(200_000);
    std::fs::write(&x_hat, lines.join("\n") + "\n").unwrap();
    let w = run.join("w.log");
    let mut w_text = std::fs::read_to_string(&w).unwrap();
    w_text.push_str("15.0 1 2");
    std::fs::write(&w, w_text).unwrap();
    for (format, path) in [
        ("csv", out.path().join("csv")),
        ("ulog", out.path().join("r.ulg")),
    ] {
        let o = try_export(&run, format, &path);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{format}: {err}");
        assert!(
            err.contains("x_hat.log: 1 line(s) skipped (1 over 65536 bytes"),
            "{err}"
        );
        assert!(
            err.contains("w.log: 1 line(s) skipped (0 over 65536 bytes, 1 cut off"),
            "{err}"
        );
    }
    let csv = std::fs::read_to_string(out.path().join("csv/x_hat.csv")).unwrap();
    assert_eq!(
        csv.lines().count(),
        rows,
        "every row but the lost one, and the header"
    );
    // The rows after the lost one keep their times (estimates pair with kalman_in by line).
    let before = std::fs::read_to_string(out.path().join("before/x_hat.csv")).unwrap();
    let time = |csv: &str, row: usize| {
        csv.lines()
            .nth(row)
            .unwrap()
            .split(',')
            .next()
            .unwrap()
            .to_string()
    };
    assert_eq!(time(&csv, 2), time(&before, 3), "{csv:.300}");
    let o = uquad(
        &root(),
        &[
            "plot",
            run.to_str().unwrap(),
            "--out",
            out.path().join("p.svg").to_str().unwrap(),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("x_hat.log: 1 line(s) skipped"), "{err}");
    // A failed export leaves no partial files and an earlier export as it was.
    std::fs::remove_file(run.join("w.log")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", run.join("w.log")).unwrap();
    let o = try_export(&run, "csv", &out.path().join("before"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("w.log: a character device, not a regular file"),
        "{err}"
    );
    let kept = std::fs::read_to_string(out.path().join("before/x_hat.csv")).unwrap();
    assert_eq!(kept, before);
    let left: Vec<_> = std::fs::read_dir(out.path().join("before"))
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "partial"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    // A config.toml that is a link to nothing is said, not read as absent.
    std::fs::remove_file(run.join("w.log")).unwrap();
    std::fs::remove_file(run.join("config.toml")).unwrap();
    std::os::unix::fs::symlink("/nowhere", run.join("config.toml")).unwrap();
    let ulg = out.path().join("dangling.ulg");
    let o = try_export(&run, "ulog", &ulg);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("which does not exist; exported without parameters"),
        "{err}"
    );
}

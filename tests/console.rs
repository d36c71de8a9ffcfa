//! The console: two consoles attached to a running `uquad sim --realtime` receive its events,
//! one changes the set point and the run's logs show it; a console that never reads costs the
//! control path nothing; the socket is closed to other users.

mod common;
use common::*;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Collects a console's lines in the background.
fn reader(stream: UnixStream) -> Arc<Mutex<Vec<String>>> {
    let lines = Arc::new(Mutex::new(Vec::new()));
    let out = lines.clone();
    std::thread::spawn(move || {
        for line in BufReader::new(stream).lines() {
            match line {
                Ok(l) => out.lock().unwrap().push(l),
                Err(_) => break,
            }
        }
    });
    lines
}

fn max_step(lines: &Mutex<Vec<String>>) -> u64 {
    lines
        .lock()
        .unwrap()
        .iter()
        .filter_map(|l| l.split(" step=").nth(1))
        .filter_map(|s| s.split_whitespace().next()?.parse().ok())
        .max()
        .unwrap_or(0)
}

#[test]
fn two_consoles_watch_and_steer_a_running_flight() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("console.sock");
    let report = dir.path().join("report.json");
    // The subject is the console, not this shared machine's scheduling.
    let socket = format!("console.socket=\"{}\"", sock.display());
    let mut child = Uquad::spawn(
        realtime_sim(&["--duration", "15", "--set", &socket], dir.path()).env("RUST_LOG", "info"),
    );
    let t0 = Instant::now();
    while !sock.exists() {
        assert!(t0.elapsed() < Duration::from_secs(10), "no console socket");
        std::thread::sleep(Duration::from_millis(20));
    }
    // Owner and group only.
    let mode = std::fs::metadata(&sock).unwrap().permissions().mode() & 0o777;
    assert_eq!(
        mode & 0o007,
        0,
        "others may not use the console: mode {mode:o}"
    );
    assert_eq!(mode, 0o660);

    let a = UnixStream::connect(&sock).unwrap();
    let b = UnixStream::connect(&sock).unwrap();
    // A third console that never reads anything.
    let _silent = UnixStream::connect(&sock).unwrap();
    let mut a_write = a.try_clone().unwrap();
    let (a_lines, b_lines) = (reader(a), reader(b));
    // Once the flight is under way (the stats show control steps), raise the set point.
    while max_step(&a_lines) < 150 {
        assert!(
            t0.elapsed() < Duration::from_secs(16),
            "the flight did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    a_write.write_all(b"e\n").unwrap();
    let status = child.child.wait().unwrap();
    assert!(status.success(), "{status}");
    std::thread::sleep(Duration::from_millis(200));

    for (name, lines) in [("A", &a_lines), ("B", &b_lines)] {
        let lines = lines.lock().unwrap();
        assert!(
            lines.iter().filter(|l| l.starts_with("stats ")).count() >= 8,
            "{name}: {lines:?}"
        );
        assert!(
            lines
                .iter()
                .any(|l| l.starts_with("INFO ") && l.contains("IMU calibration completed")),
            "{name} saw no event: {lines:?}"
        );
    }
    assert!(
        a_lines
            .lock()
            .unwrap()
            .iter()
            .any(|l| l == "console: sent Altitude(Up)")
    );
    // The new set point is in the run's logs and the stats.
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let run = std::path::Path::new(r["run_dir"].as_str().unwrap()).to_path_buf();
    let err = std::fs::read_to_string(run.join("err.log")).unwrap();
    assert!(
        err.contains("manual Altitude(Up): Applied; set point Some([0.0, 0.0, 1.2"),
        "{err}"
    );
    assert!(
        b_lines
            .lock()
            .unwrap()
            .iter()
            .any(|l| l.contains("setpoint_z=1.20"))
    );
    // The silent console slowed nothing.
    assert_eq!(r["deadline_misses"], 0);
    assert!(r["halt"].is_null(), "{r}");
}

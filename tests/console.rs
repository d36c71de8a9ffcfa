//! The console: two consoles attached to a running `uquad sim --realtime` receive its events,
//! one changes the set point and the run's logs show it; a console that never reads costs the
//! control path nothing; the socket is closed to other users.

mod common;
use common::*;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::sync::Mutex;
use std::time::{Duration, Instant};

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
        realtime_sim(&["--duration", "20", "--set", &socket], dir.path()).env("RUST_LOG", "info"),
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
    // Once the flight is under way (the stats show control steps) and holding (the key moves
    // a hold's height only; a takeoff ignores it), raise the set point.
    let holding = |lines: &Mutex<Vec<String>>| {
        let lines = lines.lock().unwrap();
        lines.iter().any(|l| l.contains("mode hold"))
    };
    while max_step(&a_lines) < 150 || !holding(&a_lines) {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the flight did not start and hold: {:?}",
            a_lines.lock().unwrap()
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
    // Where the latency went: each stage in the report (a command's total is its stages' sum,
    // each rounded down to the µs), and each stage's last-second figures on the stats line.
    let stages = &r["latency_stages_us"];
    let mut stage_max_sum = 0;
    for name in [
        "decode_to_estimate",
        "estimate_to_command",
        "command_to_write",
    ] {
        let p = |k: &str| {
            stages[name][k]
                .as_u64()
                .unwrap_or_else(|| panic!("{name} {k}: {r}"))
        };
        assert!(p("p50") <= p("p99") && p("p99") <= p("max"), "{name}: {r}");
        stage_max_sum += p("max");
    }
    let total = &r["latency_us"];
    assert!(total["p50"].as_u64().unwrap() > 0, "{r}");
    assert!(total["max"].as_u64().unwrap() <= stage_max_sum + 2, "{r}");
    assert!(
        a_lines
            .lock()
            .unwrap()
            .iter()
            .any(|l| l.starts_with("stats ")
                && l.contains("latency_stages_us[estimate,command,write](median/max)=[")
                && !l.contains("=[0/0, 0/0, 0/0]")),
        "no stage figures on the stats lines"
    );
    let run = std::path::Path::new(r["run_dir"].as_str().unwrap()).to_path_buf();
    let err = std::fs::read_to_string(run.join("err.log")).unwrap();
    assert!(
        err.contains("manual Altitude(Up): hold height 1.20 m"),
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

/// Resident memory of a process, kB.
fn rss_kb(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap()
}

/// The first line a console sends when it attaches.
fn banner(sock: &std::path::Path) -> String {
    let s = UnixStream::connect(sock).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line).unwrap();
    line
}

/// The console's bounds, not the real threads, are the subject: the paced simulator serves the
/// same console and a stall of this shared machine cannot halt its flight.
#[test]
fn an_endless_line_is_cut_off_and_a_second_run_leaves_the_live_console_alone() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("console.sock");
    let socket = format!("console.socket=\"{}\"", sock.display());
    let first_dir = dir.path().join("first");
    let mut first = Uquad::spawn(&mut paced_sim(
        "1",
        &[
            "--duration",
            "14",
            "--set",
            &socket,
            "--set",
            "gcs.enabled=never",
        ],
        &first_dir,
    ));
    let t0 = Instant::now();
    while !sock.exists() {
        assert!(t0.elapsed() < Duration::from_secs(10), "no console socket");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_secs(1));
    let rss_before = rss_kb(first.child.id());

    // 64 MiB without a newline: the console answers, then hangs up.
    let mut hostile = UnixStream::connect(&sock).unwrap();
    let replies = reader(hostile.try_clone().unwrap());
    let chunk = vec![b'x'; 1 << 20];
    let mut sent = 0usize;
    for _ in 0..64 {
        match hostile.write_all(&chunk) {
            Ok(()) => sent += chunk.len(),
            Err(_) => break,
        }
    }
    std::thread::sleep(Duration::from_millis(300));
    let rss_after = rss_kb(first.child.id());
    assert!(
        replies
            .lock()
            .unwrap()
            .iter()
            .any(|l| l == "console: line longer than 1024 bytes; disconnecting"),
        "{:?}",
        replies.lock().unwrap()
    );
    assert!(sent < 64 << 20, "the console kept reading all {sent} bytes");
    assert!(
        rss_after < rss_before + 10_000,
        "resident memory grew from {rss_before} kB to {rss_after} kB"
    );

    // A second run with the same socket path: it flies, but serves no console and says why.
    let second_dir = dir.path().join("second");
    let second = Uquad::spawn(&mut paced_sim(
        "1",
        &[
            "--duration",
            "4",
            "--set",
            &socket,
            "--set",
            "gcs.enabled=never",
        ],
        &second_dir,
    ));
    let t1 = Instant::now();
    while !second.stderr().contains("console of another running uquad") {
        assert!(
            t1.elapsed() < Duration::from_secs(10),
            "no refusal:\n{}",
            second.stderr()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(banner(&sock).starts_with("uquad console:"));
    drop(second);
    assert!(
        banner(&sock).starts_with("uquad console:"),
        "the first run's console still answers"
    );

    let status = first.child.wait().unwrap();
    assert!(status.success(), "{status}\n{}", first.stderr());
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(first_dir.join("report.json")).unwrap())
            .unwrap();
    assert_eq!(r["deadline_misses"], 0, "{r}");
    assert!(r["halt"].is_null(), "{r}");
}

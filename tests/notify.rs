//! systemd integration: with NOTIFY_SOCKET, the binary says READY=1, pings WATCHDOG=1 while its
//! own watchdog is healthy, and stops pinging after an injected fault.

mod common;
use common::*;
use std::os::unix::net::UnixDatagram;
use std::time::{Duration, Instant};

#[test]
fn ready_then_pings_which_stop_after_a_fault() {
    let dir = tempfile::tempdir().unwrap();
    let sock_path = dir.path().join("notify.sock");
    let sock = UnixDatagram::bind(&sock_path).unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let report = dir.path().join("report.json");
    let start = Instant::now();
    // Tolerant of this shared machine's scheduling, so only the injected stall trips.
    let mut child = Uquad::spawn(
        realtime_sim(
            &["--duration", "16", "--inject", "imu-stall@13"],
            dir.path(),
        )
        .env("NOTIFY_SOCKET", &sock_path)
        .env("WATCHDOG_USEC", "400000")
        .env("RUST_LOG", "warn"),
    );
    let mut msgs: Vec<(f64, String)> = Vec::new();
    let mut buf = [0u8; 4096];
    let status = loop {
        if let Ok(n) = sock.recv(&mut buf) {
            msgs.push((
                start.elapsed().as_secs_f64(),
                String::from_utf8_lossy(&buf[..n]).to_string(),
            ));
        }
        if let Some(s) = child.child.try_wait().unwrap() {
            break s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the run did not end"
        );
    };
    assert!(!status.success(), "a halt ends the run with a failure");
    assert!(msgs[0].1.starts_with("READY=1"), "{msgs:?}");
    let pings: Vec<f64> = msgs
        .iter()
        .filter(|m| m.1 == "WATCHDOG=1")
        .map(|m| m.0)
        .collect();
    // Every 200 ms (half of WATCHDOG_USEC) for about 13 s.
    assert!(pings.len() >= 50, "{} pings", pings.len());
    assert!(
        pings.windows(2).all(|w| w[1] - w[0] < 0.6),
        "a gap in the pings: {pings:?}"
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["halt"]["reason"], "imu-timeout", "{r}");
    // The pings stopped at the halt (run time and this test's clock differ by the start-up of
    // the process, well under the 200 ms between pings).
    let halt_s = r["halt"]["halt_s"].as_f64().unwrap();
    let last = *pings.last().unwrap();
    assert!(
        last < halt_s + 0.25,
        "ping at {last} s after the halt at {halt_s} s"
    );
    assert!(msgs.iter().any(|m| m.1 == "STOPPING=1"));
}

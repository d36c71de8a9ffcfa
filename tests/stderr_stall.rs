//! A stalled terminal (a paused ssh session, a pipe nobody reads) never stalls the flight:
//! `sim --realtime` (fly's own tasks) with its stderr a full pipe for the first 12 s flies as
//! usual — its log lines wait in a queue of their own — and finishes once the pipe drains.

mod common;
use common::*;
use std::io::Read;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::time::Duration;

/// A pipe whose write end is full (a blocking write to it waits until the read end drains).
fn full_pipe() -> (std::fs::File, OwnedFd) {
    let mut fds = [0; 2];
    // SAFETY: pipe fills two fds we then own.
    assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
    // SAFETY: both fds are fresh and owned from here on.
    let (read, write) = unsafe {
        (
            std::fs::File::from_raw_fd(fds[0]),
            OwnedFd::from_raw_fd(fds[1]),
        )
    };
    let fd = write.as_raw_fd();
    // Fill it without blocking, then make it blocking again, as a terminal's stderr is.
    // SAFETY: fcntl and write on an fd we own.
    unsafe {
        let flags = libc::fcntl(fd, libc::F_GETFL);
        libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK);
        let chunk = [b'#'; 4096];
        while libc::write(fd, chunk.as_ptr().cast(), chunk.len()) > 0 {}
        libc::fcntl(fd, libc::F_SETFL, flags);
    }
    (read, write)
}

#[test]
fn a_stalled_stderr_costs_the_flight_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (mut read, write) = full_pipe();
    let mut cmd = realtime_sim(&["--duration", "20"], dir.path());
    let mut child = cmd
        .env("RUST_LOG", "info")
        .stderr(std::process::Stdio::from(write))
        .spawn()
        .unwrap();
    // The command holds its copy of the write end: without closing it, no end of file.
    drop(cmd);
    // Nobody reads stderr for 12 s: the start-up (about 9 s) and some flight happen then.
    std::thread::sleep(Duration::from_secs(12));
    let drain = std::thread::spawn(move || {
        let mut all = Vec::new();
        let _ = read.read_to_end(&mut all);
        String::from_utf8_lossy(&all)
            .trim_start_matches('#')
            .to_string()
    });
    let status = child.wait().unwrap();
    let stderr = drain.join().unwrap();
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("report.json"))
            .unwrap_or_else(|e| panic!("no report ({e}):\n{stderr}")),
    )
    .unwrap();
    assert!(status.success(), "{status}: {report}\n{stderr}");
    assert!(report["halt"].is_null(), "{report}\n{stderr}");
    assert_eq!(report["deadline_misses"], 0, "{report}\n{stderr}");
    // About 11 s of flight after the 9 s start-up, most of it while stderr was stalled.
    let steps = report["steps"].as_u64().unwrap();
    assert!(steps >= 900, "{steps} steps: {report}\n{stderr}");
    // The lines logged during the stall were kept and written once it drained.
    assert!(stderr.contains("IMU calibration completed"), "{stderr}");
}

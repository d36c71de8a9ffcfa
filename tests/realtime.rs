//! Real-time priority: `fly` refuses to start, before opening any device, when SCHED_FIFO or
//! locked memory is refused, unless given `--allow-no-rt`; `sim` keeps working unprivileged.
//!
//! The child is made unprivileged the way an ordinary user is: no real-time priority and a
//! small locked-memory limit, and (when the tests run as root) without the capabilities that
//! bypass those limits.

mod common;
use common::*;
use std::os::unix::process::CommandExt;
use std::process::Command;

/// `CAP_IPC_LOCK` and `CAP_SYS_NICE` (linux/capability.h).
const CAP_IPC_LOCK: libc::c_ulong = 14;
const CAP_SYS_NICE: libc::c_ulong = 23;

/// `uquad ARGS` from the repository's root, as an unprivileged user; its output.
fn unprivileged(args: &[&str]) -> std::process::Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_uquad"));
    cmd.args(args).current_dir(root()).env("RUST_LOG", "warn");
    // SAFETY: only async-signal-safe calls (setrlimit, prctl) between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            let no_rt = libc::rlimit {
                rlim_cur: 0,
                rlim_max: 0,
            };
            let small = libc::rlimit {
                rlim_cur: 64 * 1024,
                rlim_max: 64 * 1024,
            };
            if libc::setrlimit(libc::RLIMIT_RTPRIO, &no_rt) != 0
                || libc::setrlimit(libc::RLIMIT_MEMLOCK, &small) != 0
            {
                return Err(std::io::Error::last_os_error());
            }
            // As root: drop the capabilities that bypass those limits (a no-op otherwise).
            for cap in [CAP_IPC_LOCK, CAP_SYS_NICE] {
                libc::prctl(libc::PR_CAPBSET_DROP, cap, 0, 0, 0);
            }
            Ok(())
        });
    }
    cmd.output().expect("the uquad binary runs")
}

#[test]
fn fly_refuses_to_start_without_real_time_unless_allowed() {
    let logs = tempfile::tempdir().unwrap();
    let dir = logs.path().to_str().unwrap();
    let base = [
        "fly",
        "--config",
        "config/uquad.toml",
        "--log-dir",
        dir,
        "--set",
        "imu.device=\"/nonexistent/ttyIMU\"",
    ];
    let o = unprivileged(&base);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("real-time scheduling refused"), "{err}");
    assert!(err.contains("--allow-no-rt"), "{err}");
    assert!(
        !err.contains("ttyIMU"),
        "refused before any device was opened: {err}"
    );
    assert_eq!(
        std::fs::read_dir(logs.path()).unwrap().count(),
        0,
        "no run folder"
    );

    // Allowed: it goes on, and stops at the (missing) IMU device instead.
    let mut allowed = base.to_vec();
    allowed.push("--allow-no-rt");
    let o = unprivileged(&allowed);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(!err.contains("real-time scheduling refused"), "{err}");
    assert!(err.contains("/nonexistent/ttyIMU"), "{err}");
}

#[test]
fn sim_flies_unprivileged() {
    let logs = tempfile::tempdir().unwrap();
    let dir = logs.path().to_str().unwrap();
    for mode in ["fast", "realtime"] {
        let mut args = vec![
            "sim",
            "--mode",
            mode,
            "--config",
            "config/uquad.toml",
            "--duration",
            "4",
            "--log-dir",
            dir,
        ];
        args.extend_from_slice(&REALTIME_TOLERANT);
        let o = unprivileged(&args);
        assert!(
            o.status.success(),
            "sim --mode {mode}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;
use uquad::core::imu::frame::RawFrame;
use uquad::hw::esc_bus::MockBus;
use uquad::logs::{ImuRawRecord, parse_log};

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

/// The 2012 flight's raw frames, to be sent again and again.
pub fn frames_2012() -> Vec<RawFrame> {
    let text = std::fs::read_to_string(flight_dir().join("imu_raw.log")).unwrap();
    parse_log(&text, ImuRawRecord::parse_fields)
        .unwrap()
        .rows
        .into_iter()
        .map(|r| r.frame)
        .collect()
}

/// Writes frames into the pty master every 10 ms, each in three chunks spaced as 115200 baud
/// sends them (about 0.9 ms per 10 bytes), starting after the IMU got its '!' command.
pub async fn imu_sim(mut master: tokio_serial::SerialStream, cancel: CancellationToken) -> u64 {
    let mut cmd = [0u8; 1];
    tokio::select! {
        _ = cancel.cancelled() => return 0,
        r = master.read_exact(&mut cmd) => { r.unwrap(); }
    }
    assert_eq!(cmd[0], b'!', "the host puts the IMU in binary mode first");
    let frames = frames_2012();
    let mut tick = tokio::time::interval(Duration::from_millis(10));
    let mut sent = 0u64;
    for (i, f) in frames.iter().cycle().enumerate() {
        tokio::select! {
            _ = cancel.cancelled() => return sent,
            _ = tick.tick() => {}
        }
        let bytes = f.encode(if i % 2 == 0 { b'C' } else { b'A' });
        for chunk in bytes.chunks(10) {
            if master.write_all(chunk).await.is_err() {
                return sent;
            }
            tokio::time::sleep(Duration::from_micros(870)).await;
        }
        sent += 1;
    }
    sent
}

/// A short start-up; and a command timeout above this machine's frame-pacing jitter (a test
/// process writing a pty on a loaded 2-core machine is not a 100 Hz IMU; the 12 ms default is
/// exercised by the watchdog's tests).
pub fn sets(extra: &[&str]) -> Vec<(String, toml::Value)> {
    [
        "imu.settle_frames=5",
        "imu.settle_max_frames=40",
        "imu.calib_frames=64",
        "esc.command_timeout_ms=200",
    ]
    .iter()
    .chain(extra)
    .map(|s| uquad::config::parse_set(s).unwrap())
    .collect()
}

/// Flies the 2012 profile (with a short start-up) while `during` runs, then cancels as a
/// signal would. Returns the summary, the frames sent, the bus and the log folder.
pub async fn fly_for(
    extra: &[&str],
    stall: Option<uquad::tasks::logger::LogStall>,
    during: impl std::future::Future<Output = ()>,
) -> (uquad::app::fly::FlySummary, u64, MockBus, tempfile::TempDir) {
    let profile = uquad::config::load(&profile_2012(), &sets(extra)).unwrap();
    let logs = tempfile::tempdir().unwrap();
    let (master, slave) = tokio_serial::SerialStream::pair().expect("a pty pair");
    let bus = MockBus::new();
    let cancel = CancellationToken::new();
    let sim = tokio::spawn(imu_sim(master, cancel.clone()));
    let fly = tokio::spawn({
        let bus = bus.clone();
        let cancel = cancel.clone();
        let log_dir = logs.path().to_path_buf();
        async move {
            uquad::app::fly::run(
                &profile,
                uquad::app::fly::Edges {
                    imu: Box::new(slave),
                    bus: Box::new(bus),
                },
                uquad::app::fly::FlyOptions {
                    log_dir: Some(log_dir),
                    log_stall: stall,
                    ..Default::default()
                },
                cancel,
            )
            .await
        }
    });
    during.await;
    cancel.cancel();
    let summary = fly.await.unwrap().unwrap();
    let sent = sim.await.unwrap();
    (summary, sent, bus, logs)
}

//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;
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

/// `--set`s that let a `sim --realtime` run ride out this shared machine's scheduling stalls
/// (tens of ms at times) where the subject of a test is not timing: a wide accepted IMU period
/// and frames to settle in, and deadline, IMU and command timeouts above the stalls. Also no
/// ground-station link: a ground station open on this machine (UDP 14550) would see, and
/// could command, the tests' vehicles (tests/gcs.rs turns it back on).
pub const REALTIME_TOLERANT: [&str; 14] = [
    "--set",
    "gcs.enabled=never",
    "--set",
    "imu.settle_max_frames=1000",
    "--set",
    "watchdog.deadline_ms=100",
    "--set",
    "imu.period_max_us=100000",
    "--set",
    "imu.period_min_us=1000",
    "--set",
    "watchdog.imu_timeout_ms=100",
    "--set",
    "esc.command_timeout_ms=150",
];

/// The operator's script of the tests about hovering (not the commander's): arm once the
/// estimator check passes (calibrated at rest by 5.7 s), take off once the ESCs' ramp is done,
/// never land, so the hover window runs from 31 s to the end.
pub const HOVER_SCRIPT: &str = "arm@7,takeoff@10";

/// `uquad sim --realtime --config config/uquad.toml ARGS` with [`REALTIME_TOLERANT`], its run
/// folder under `dir` and its report at `dir/report.json`, from the repository's root. The
/// vehicle starts flying (`commander.start = "flying"`, no operator script) unless ARGS say
/// otherwise: these tests are about the flight, not the commander.
pub fn realtime_sim(args: &[&str], dir: &Path) -> Command {
    let mut all = args.to_vec();
    all.extend_from_slice(&REALTIME_TOLERANT);
    sim_in(&["--realtime"], &all, dir)
}

/// [`realtime_sim`]'s run as `uquad sim --mode paced --speed SPEED`: the lock-step flight
/// paced to the wall clock, the link and the console served.
#[allow(dead_code)]
pub fn paced_sim(speed: &str, args: &[&str], dir: &Path) -> Command {
    sim_in(&["--mode", "paced", "--speed", speed], args, dir)
}

/// `uquad sim MODE --config config/uquad.toml` flying from the start, then ARGS, its run
/// folder under `dir` and its report at `dir/report.json`.
fn sim_in(mode: &[&str], args: &[&str], dir: &Path) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_uquad"));
    cmd.arg("sim")
        .args(mode)
        .args(["--config", "config/uquad.toml"])
        .args(["--set", "commander.start=flying"])
        .args(args)
        .arg("--log-dir")
        .arg(dir)
        .arg("--report")
        .arg(dir.join("report.json"))
        .current_dir(root());
    cmd
}

/// Every `.rs` file under `dir`.
pub fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// A running `uquad` process: its stderr goes to a file, printed when the test fails; the
/// process is killed if the test ends before it does.
pub struct Uquad {
    pub child: std::process::Child,
    stderr: tempfile::NamedTempFile,
}

impl Uquad {
    /// Spawns `cmd` (its stderr is taken over).
    pub fn spawn(cmd: &mut Command) -> Uquad {
        let stderr = tempfile::NamedTempFile::new().unwrap();
        let child = cmd
            .stderr(stderr.reopen().unwrap())
            .spawn()
            .expect("the uquad binary runs");
        Uquad { child, stderr }
    }

    /// What it wrote on stderr so far.
    pub fn stderr(&self) -> String {
        std::fs::read_to_string(self.stderr.path()).unwrap_or_default()
    }
}

impl Drop for Uquad {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if std::thread::panicking() {
            eprintln!("--- uquad's stderr ---\n{}", self.stderr());
        }
    }
}

/// Runs `uquad sim ARGS --report <tmp> --log-dir <tmp>` and returns its exit status, its report
/// (written also when a halt ends the run) and the folder holding the run.
#[allow(dead_code)]
pub fn sim_report(
    args: &[&str],
) -> (
    std::process::ExitStatus,
    serde_json::Value,
    tempfile::TempDir,
) {
    let logs = tempfile::tempdir().unwrap();
    let report = logs.path().join("report.json");
    let (r, l) = (
        report.to_str().unwrap().to_string(),
        logs.path().to_str().unwrap().to_string(),
    );
    let mut all = vec!["sim"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--report", &r, "--log-dir", &l]);
    let o = uquad(&root(), &all);
    let text = std::fs::read_to_string(&report)
        .unwrap_or_else(|_| panic!("no report: {}", String::from_utf8_lossy(&o.stderr)));
    (o.status, serde_json::from_str(&text).unwrap(), logs)
}

/// Reads a whitespace-separated numeric log, accepting every line-end style.
pub fn read_table(path: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.split(['\n', '\r'])
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split_whitespace().map(str::to_string).collect())
        .collect()
}

/// `--set` value giving the default profile the 2012 flights' EKF process noise (roll and pitch
/// 0.01 instead of the default profile's 0.001).
/// The simulated receiver without errors: exact fixes once a second (for checks of the
/// control against the set point, which a real receiver's wandering error would swamp).
pub const EXACT_GPS: [&str; 12] = [
    "--set",
    "sim.gps_delay_s=0",
    "--set",
    "sim.gps_noise_h_m=0",
    "--set",
    "sim.gps_noise_v_m=0",
    "--set",
    "sim.gps_bias_h_m=0",
    "--set",
    "sim.gps_bias_v_m=0",
    "--set",
    "sim.gps_noise_vel_m_s=0",
];

pub const EKF_Q_2012: &str = "ekf.q=[100.0, 100.0, 100.0, 0.01, 0.01, 1e-5, 100.0, 100.0, 100.0, 0.1, 0.1, 0.1, 1.0, 1.0, 1.0]";
/// The 2012 flights' measurement noise, with this profile's unused receiver altitude.
pub const EKF_R_IMU_2012: &str =
    "ekf.r_imu=[100.0, 100.0, 1e5, 1e4, 1e4, 1e4, 1e-3, 1e-3, 1e-3, 1e5]";
pub const EKF_R_GPS_2012: &str =
    "ekf.r_gps=[100.0, 100.0, 1e5, 1e4, 1e4, 1e4, 1e-3, 1e-3, 1e-3, 100.0, 100.0, 1e12]";
/// `--set` arguments giving the default profile the 2012 flights' filter: their noise (Q and
/// R), their fusion of the IMU's angles at every step (their noise is sized for it), no gyro
/// bias states, and with them the original's calibration order ([`AFTER_ARM`]).
pub const EKF_2012: [&str; 14] = [
    "--set",
    EKF_Q_2012,
    "--set",
    EKF_R_IMU_2012,
    "--set",
    EKF_R_GPS_2012,
    "--set",
    "ekf.angle_period_s=0",
    "--set",
    "ekf.q_gyro_bias=0",
    "--set",
    "ekf.p0_gyro_bias=0",
    "--set",
    AFTER_ARM,
];

/// The original's calibration order (after the arm and the ESC ramp, motors idling). The 2012
/// noise values need it: they leave the filter claiming a tilt known to about 1 rad, which the
/// `estimator` pre-arm check of a calibration at rest refuses.
pub const AFTER_ARM: &str = "imu.calibrate=\"after-arm\"";

/// [`HOVER_SCRIPT`] for a run calibrated after its arm: arm once settled, take off once
/// calibrated (about 8.5 s).
pub const HOVER_SCRIPT_AFTER_ARM: &str = "arm@1,takeoff@9";

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

/// `uquad replay RUN --out <fresh folder>` with the run's own configuration, which must
/// succeed; returns the output folder.
#[allow(dead_code)]
pub fn replay_run(run: &Path) -> tempfile::TempDir {
    let out = tempfile::tempdir().expect("temp dir");
    let args = [
        "replay",
        run.to_str().expect("utf-8 path"),
        "--out",
        out.path().to_str().expect("utf-8 path"),
    ];
    let o = uquad(&root(), &args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// [`replay_run`], whose `names` must be the run's own bytes.
pub fn assert_replays_same(run: &Path, names: &[&str]) -> tempfile::TempDir {
    let out = replay_run(run);
    for name in names {
        let a = std::fs::read(run.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let b = std::fs::read(out.path().join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(a == b, "{name}: the replay differs from the run");
    }
    out
}

/// `uquad sim --log-dir LOGS ARGS` (the main job), which must succeed; its run folder.
pub fn sim_run(logs: &Path, args: &[&str]) -> PathBuf {
    let mut all = vec!["sim", "--log-dir", logs.to_str().expect("utf-8 path")];
    all.extend_from_slice(args);
    let o = uquad(&root(), &all);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    run_dir(logs)
}

/// The modes a report lists, in order.
pub fn report_modes(r: &serde_json::Value) -> Vec<String> {
    let list = r["modes"]
        .as_array()
        .unwrap_or_else(|| panic!("no modes: {r}"));
    list.iter()
        .map(|m| m["mode"].as_str().unwrap_or("?").to_string())
        .collect()
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

/// A blocking byte stream the feeder writes frames into.
pub trait ReadWrite: std::io::Read + std::io::Write + Send {}
impl<T: std::io::Read + std::io::Write + Send> ReadWrite for T {}

/// What the simulated IMU sends as frame `k`: the frame, or `None` to fall silent from then on.
pub type FramePlan = Box<dyn Fn(usize, RawFrame) -> Option<RawFrame> + Send>;

/// The simulated IMU: a thread writing the 2012 frames into a pty master every 10 ms on an
/// absolute schedule, each frame in three chunks spaced as 115200 baud sends them, after the
/// host's '!' command. A thread (not a task) so the test's own load cannot delay frames.
pub struct ImuFeeder {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<u64>>,
}

/// How the simulated IMU reaches `fly`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Link {
    /// A pseudo-terminal, opened by `fly` with tokio-serial, as a serial IMU is.
    Pty,
    /// An in-memory pipe: no kernel tty layer in between, so the frame timing is the feeder's
    /// alone (for the tests that measure milliseconds).
    Pipe,
}

/// The feeder's end of a pipe: blocking reads and writes on the test's runtime.
struct PipeEnd {
    io: tokio::io::DuplexStream,
    rt: tokio::runtime::Handle,
}

impl std::io::Read for PipeEnd {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        use tokio::io::AsyncReadExt;
        self.rt.block_on(self.io.read(buf))
    }
}

impl std::io::Write for PipeEnd {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        use tokio::io::AsyncWriteExt;
        self.rt.block_on(self.io.write(buf))
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl ImuFeeder {
    /// Returns the feeder and the host's end of the link (boxed for `fly`'s edges). Must be
    /// called inside a Tokio runtime.
    pub fn start(plan: FramePlan, link: Link) -> (ImuFeeder, Box<dyn uquad::app::fly::ImuIo>) {
        use std::io::{Read, Write};
        use std::sync::atomic::Ordering;
        let (mut master, slave): (Box<dyn ReadWrite>, Box<dyn uquad::app::fly::ImuIo>) = match link
        {
            Link::Pty => {
                let (master, slave) = serialport::TTYPort::pair().expect("a pty pair");
                let slave =
                    tokio_serial::SerialStream::try_from(slave).expect("the slave end as async");
                (Box::new(master), Box::new(slave))
            }
            Link::Pipe => {
                let (a, b) = tokio::io::duplex(64 * 1024);
                (
                    Box::new(PipeEnd {
                        io: a,
                        rt: tokio::runtime::Handle::current(),
                    }),
                    Box::new(b),
                )
            }
        };
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            // Real time when permitted, like the IMU it stands for (its timing is not the
            // test's load).
            let param = libc::sched_param { sched_priority: 60 };
            // SAFETY: sets this thread's scheduling policy; no memory is touched.
            unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
            // The host puts the IMU in binary mode first.
            let mut cmd = [0u8; 1];
            loop {
                if flag.load(Ordering::SeqCst) {
                    return 0;
                }
                match master.read(&mut cmd) {
                    Ok(1) => break,
                    _ => continue,
                }
            }
            assert_eq!(cmd[0], b'!', "the host puts the IMU in binary mode first");
            let frames = frames_2012();
            let t0 = std::time::Instant::now();
            let mut sent = 0u64;
            let mut silent = false;
            for (k, f) in frames.iter().cycle().enumerate() {
                if flag.load(Ordering::SeqCst) {
                    break;
                }
                let due = t0 + Duration::from_millis(10 * k as u64);
                if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
                    std::thread::sleep(wait);
                }
                if silent {
                    continue;
                }
                let Some(f) = plan(k, *f) else {
                    silent = true;
                    continue;
                };
                let bytes = f.encode(if k % 2 == 0 { b'C' } else { b'A' });
                for (i, chunk) in bytes.chunks(10).enumerate() {
                    if i > 0 {
                        std::thread::sleep(Duration::from_micros(870));
                    }
                    if master.write_all(chunk).is_err() {
                        return sent;
                    }
                }
                sent += 1;
            }
            sent
        });
        (
            ImuFeeder {
                stop,
                thread: Some(thread),
            },
            slave,
        )
    }

    /// Stops the feeder; returns the frames it sent.
    pub fn stop(mut self) -> u64 {
        self.stop.store(true, std::sync::atomic::Ordering::SeqCst);
        self.thread.take().map_or(0, |t| t.join().unwrap_or(0))
    }
}

impl Drop for ImuFeeder {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::SeqCst);
    }
}

/// A short start-up (5 settling frames, 64 calibration frames), and an IMU timeout of 100 ms:
/// tests of other subjects must not fail on this shared machine's scheduling jitter (the 12 ms
/// default leaves 2 ms over the 10 ms frame period; the watchdog's tests use it).
pub fn sets(extra: &[&str]) -> Vec<(String, toml::Value)> {
    [
        "imu.settle_frames=5",
        // Settling gives up only after this many frames: a stall of this shared machine at
        // start-up costs a few frames, not the run.
        "imu.settle_max_frames=1000",
        "imu.calib_frames=64",
        "watchdog.imu_timeout_ms=100",
        "esc.command_timeout_ms=150",
    ]
    .iter()
    .chain(extra)
    .map(|s| uquad::config::parse_set(s).unwrap())
    .collect()
}

/// `--set`s that let a `fly` run in a test ride out this shared machine's scheduling stalls
/// where the subject is not timing (the watchdog's own tests keep the 10 ms deadline): a wide
/// accepted IMU period and a deadline above the stalls.
pub const FLY_TOLERANT: [&str; 3] = [
    "imu.period_min_us=1000",
    "imu.period_max_us=100000",
    "watchdog.deadline_ms=100",
];

/// What a `fly` run against the mock bus leaves: its summary, the frames fed, the bus, and
/// the temporary folder holding its logs.
pub type FlyRun = (
    uquad::app::report::FlySummary,
    u64,
    MockBus,
    tempfile::TempDir,
);

/// Flies the 2012 profile (with a short start-up and [`FLY_TOLERANT`]) while `during` runs,
/// then cancels as a signal would. Returns the summary, the frames sent, the bus and the log
/// folder.
pub async fn fly_for(
    extra: &[&str],
    stall: Option<uquad::tasks::logger::LogStall>,
    during: impl std::future::Future<Output = ()>,
) -> FlyRun {
    let sets: Vec<&str> = FLY_TOLERANT.iter().chain(extra).copied().collect();
    fly_with(
        &sets,
        uquad::app::fly::FlyOptions {
            log_stall: stall,
            ..Default::default()
        },
        Link::Pty,
        Box::new(|_, f| Some(f)),
        |_| during,
    )
    .await
}

/// [`fly_for`] with any options and frame plan; `during` gets the mock bus.
pub async fn fly_with<F: std::future::Future<Output = ()>>(
    extra: &[&str],
    opts: uquad::app::fly::FlyOptions,
    link: Link,
    plan: FramePlan,
    during: impl FnOnce(MockBus) -> F,
) -> FlyRun {
    fly_with_rc(extra, opts, link, plan, None, during).await
}

/// The RC receiver's port (`rc.device` opened), as `fly` takes it.
pub type RcPort = Box<dyn tokio::io::AsyncRead + Send + Unpin>;

/// [`fly_with`], with an RC receiver's port.
pub async fn fly_with_rc<F: std::future::Future<Output = ()>>(
    extra: &[&str],
    opts: uquad::app::fly::FlyOptions,
    link: Link,
    plan: FramePlan,
    rc: Option<RcPort>,
    during: impl FnOnce(MockBus) -> F,
) -> FlyRun {
    let profile = uquad::config::load(&profile_2012(), &sets(extra)).unwrap();
    let logs = tempfile::tempdir().unwrap();
    let (feeder, slave) = ImuFeeder::start(plan, link);
    let bus = MockBus::new();
    let cancel = CancellationToken::new();
    let fly = tokio::spawn({
        let bus = bus.clone();
        let cancel = cancel.clone();
        let log_dir = logs.path().to_path_buf();
        async move {
            uquad::app::fly::run(
                &profile,
                uquad::app::fly::Edges {
                    imu: slave,
                    bus: Box::new(bus),
                    gps_fixes: None,
                    live: None,
                    operator: None,
                    rc,
                },
                uquad::app::fly::FlyOptions {
                    log_dir: Some(log_dir),
                    // The control thread at SCHED_FIFO when permitted, as in flight.
                    realtime: true,
                    ..opts
                },
                cancel,
            )
            .await
        }
    });
    // The run ends when `during` is done, or earlier when the watchdog halts it.
    tokio::select! {
        _ = during(bus.clone()) => {}
        _ = cancel.cancelled() => {}
    }
    cancel.cancel();
    let summary = fly.await.unwrap().unwrap();
    let sent = feeder.stop();
    (summary, sent, bus, logs)
}

/// The bus's last transactions are zero to every ESC, then disable every ESC.
pub fn assert_ends_zero_then_disable(tx: &[uquad::hw::esc_bus::Transaction]) {
    use uquad::core::motor::{MotorMap, REG_DISABLE, REG_SPEED};
    let addrs = MotorMap::UQUAD.addresses;
    assert!(tx.len() >= 8, "{} transactions", tx.len());
    let tail: Vec<(u8, u8, u8)> = tx[tx.len() - 8..]
        .iter()
        .map(|t| (t.addr, t.reg, t.value))
        .collect();
    let mut expected: Vec<(u8, u8, u8)> = addrs.map(|a| (a, REG_SPEED, 0)).to_vec();
    expected.extend(addrs.map(|a| (a, REG_DISABLE, 0)));
    assert_eq!(tail, expected);
}

/// A console's lines (or any stream's), collected in the background.
#[allow(dead_code)]
pub fn reader(
    stream: std::os::unix::net::UnixStream,
) -> std::sync::Arc<std::sync::Mutex<Vec<String>>> {
    use std::io::BufRead;
    let lines = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let out = lines.clone();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stream).lines() {
            match line {
                Ok(l) => out.lock().unwrap().push(l),
                Err(_) => break,
            }
        }
    });
    lines
}

/// The run folder under `dir` (named by its start time), waiting up to 10 s for it.
pub fn run_dir(dir: &Path) -> PathBuf {
    let t0 = std::time::Instant::now();
    loop {
        let found = std::fs::read_dir(dir)
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.path())
            .find(|p| {
                p.is_dir()
                    && p.file_name()
                        .is_some_and(|n| n.to_string_lossy().starts_with("20"))
            });
        if let Some(p) = found {
            return p;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "no run folder");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A `--script none` run goes on after a landing, as many flights as its operator flies,
/// until `--duration` or a signal: once its ground station is done, the run is given 3 s to
/// end by itself (a halt, its duration), then SIGTERM (the motors stopped, the report
/// written). Its exit status.
#[allow(dead_code)]
pub fn end_run(run: &mut Uquad) -> std::process::ExitStatus {
    let asked = std::time::Instant::now();
    let mut signalled = false;
    loop {
        if let Some(status) = run.child.try_wait().expect("wait for uquad") {
            return status;
        }
        if !signalled && asked.elapsed() > std::time::Duration::from_secs(3) {
            // SAFETY: kill with a child's pid and a signal number.
            unsafe { libc::kill(run.child.id() as i32, libc::SIGTERM) };
            signalled = true;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

//! `uquad sim --realtime`: fly's own tasks, threads and channels against the simulated edges,
//! paced by the wall clock. A simulator thread steps the physics at `sim.physics_hz`, sends the
//! IMU's frames through an in-memory pipe into fly's IMU reader, publishes simulated gpsd fixes
//! where fly's gpsd client would, and reads fly's newest step for the hover window; the ESC
//! writer's I2C writes reach the simulated ESCs through the bus trait. The true state of each
//! frame sent goes to truth.log as the run goes.

use crate::app::fly::{self, Edges, FlyOptions};
use crate::app::report::SimSummary;
use crate::app::sim::SimOptions;
use crate::config::{GcsEnabled, GpsMode, Profile};
use crate::core::commander::{Mode, OperatorInput};
use crate::core::gps::LiveFix;
use crate::core::motor::FLIGHT_RAMP_STEPS;
use crate::sim::esc::{EscModel, SimBus};
use crate::sim::faults::{Fault, FaultSchedule, LOG_STALL_US, WireFaults};
use crate::sim::hover::{
    CycleTrace, FlightView, HoverStats, HoverWindow, TrueState, progress_line,
};
use crate::sim::operator::SimOperator;
use crate::sim::physics::Plant;
use crate::sim::{FRAME_US, frame_start_byte};
use crate::tasks::controller::Live;
use crate::tasks::imu_reader::BINARY_MODE_COMMAND;
use crate::tasks::logger::LogStall;
use crate::tasks::{Cpu, SIM_PRIORITY};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::{AsyncWriteExt, DuplexStream};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// What the simulator thread needs; it owns the plant and the IMU.
struct SimThread {
    profile: Profile,
    seed: u64,
    faults: FaultSchedule,
    progress: bool,
    start: Instant,
    model: Arc<Mutex<EscModel>>,
    imu_end: DuplexStream,
    gps_tx: Option<watch::Sender<Option<LiveFix>>>,
    live: watch::Receiver<Option<Live>>,
    stop: Arc<AtomicBool>,
    rt: tokio::runtime::Handle,
    /// The scripted operator, and where its inputs go.
    operator: SimOperator,
    operator_tx: mpsc::Sender<OperatorInput>,
    /// Ends the run once the vehicle has landed and disarmed after the script.
    cancel: CancellationToken,
    trace: CycleTrace,
    /// Where the frames' true states go.
    truth: TruthFile,
    /// The pilot's radio (`--rc`): its transmitter, and the pty's end the receiver's frames
    /// are written into (`fly`'s RC reader opens the other end as a UART).
    rc: Option<(crate::sim::transmitter::Transmitter, serialport::TTYPort)>,
}

/// What the simulator thread measured.
#[derive(Debug, Default)]
struct SimResult {
    simulated_us: i64,
    hover: HoverStats,
    /// The true vehicle's figures, one per flight.
    flights: Vec<crate::core::commander::Figures>,
    /// truth.log was written whole.
    truth_whole: bool,
}

/// truth.log's rows (`sim::truth`), one per frame sent, on the simulator's wall clock (the
/// logs' own, give or take the few milliseconds between the two starts). A realtime run's
/// length is not known in advance: the rows go to a file as they come, nothing is held, and
/// the run folder receives it at the end.
struct TruthFile {
    path: std::path::PathBuf,
    out: Option<std::io::BufWriter<std::fs::File>>,
    line: String,
}

impl TruthFile {
    /// A file in the system's temporary folder; without one the run goes on, without truth.log.
    fn create(seed: u64) -> Self {
        let name = format!("uquad-truth-{}-{seed}.log", std::process::id());
        let path = std::env::temp_dir().join(name);
        let out = match std::fs::File::create(&path) {
            Ok(f) => Some(std::io::BufWriter::new(f)),
            Err(e) => {
                tracing::warn!("truth.log: cannot create {}: {e}", path.display());
                None
            }
        };
        TruthFile {
            path,
            out,
            line: String::new(),
        }
    }

    /// One frame's row; a failed write stops the file (named once) and not the run.
    fn row(&mut self, t_us: i64, values: &[f64; 15]) {
        use std::io::Write;
        let Some(out) = self.out.as_mut() else {
            return;
        };
        self.line.clear();
        crate::logs::format::write_values_row(&mut self.line, Some(t_us), values);
        if let Err(e) = out.write_all(self.line.as_bytes()) {
            tracing::warn!(
                "truth.log: writing {}: {e}; no more rows",
                self.path.display()
            );
            self.out = None;
        }
    }

    /// Flushes the file: whether it holds every row.
    fn finish(&mut self) -> bool {
        use std::io::Write;
        self.out.take().is_some_and(|mut out| out.flush().is_ok())
    }
}

/// Moves the simulator's truth file into the run folder (copied when the two are on different
/// file systems); the temporary file is removed either way.
fn place_truth(tmp: &std::path::Path, whole: bool, fly: &mut crate::app::report::FlySummary) {
    let dest = fly.run_dir.join(crate::sim::truth::FILE);
    if whole
        && std::fs::rename(tmp, &dest).is_err()
        && let Err(e) = std::fs::copy(tmp, &dest)
    {
        let why = format!("cannot write {}: {e}", dest.display());
        tracing::error!("{why}");
        fly.error.get_or_insert(why);
    }
    let _ = std::fs::remove_file(tmp);
}

/// With `--rc`: the simulated transmitter, the pty's end it writes into, and the other end
/// opened as `fly` opens `rc.device` (tokio-serial, the protocol's line settings).
#[allow(clippy::type_complexity)]
fn radio(
    profile: &Profile,
    opts: &SimOptions,
    faults: &FaultSchedule,
) -> anyhow::Result<(
    Option<(crate::sim::transmitter::Transmitter, serialport::TTYPort)>,
    Option<Box<dyn tokio::io::AsyncRead + Send + Unpin>>,
)> {
    use anyhow::Context;
    let cfg = &profile.config;
    let script = crate::app::sim::script(opts, profile);
    let Some(tx) = crate::sim::transmitter::Transmitter::new(
        &cfg.rc,
        cfg.failsafe.rc_timeout_s,
        &script.1,
        faults.at_us(Fault::RcLoss),
    ) else {
        return Ok((None, None));
    };
    let (master, slave) = serialport::TTYPort::pair().context("cannot open a pty for the radio")?;
    // Never blocking the simulator's real-time thread: a frame the pty has no room for is
    // lost, as on a wire nobody reads.
    {
        use std::os::fd::AsRawFd;
        let fd = master.as_raw_fd();
        // SAFETY: fcntl on a descriptor this function owns; no memory is passed.
        let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
        // SAFETY: as above.
        if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
            anyhow::bail!("cannot make the radio's pty non-blocking");
        }
    }
    let path = serialport::SerialPort::name(&slave).context("the radio's pty has no name")?;
    let port = crate::hw::serial::open_rc(std::path::Path::new(&path), cfg.rc.protocol)?;
    // The slave's first handle may close: the reader holds its own.
    drop(slave);
    Ok((Some((tx, master)), Some(Box::new(port))))
}

pub async fn run(profile: &Profile, opts: &SimOptions) -> anyhow::Result<SimSummary> {
    let cfg = &profile.config;
    let duration = Duration::from_secs_f64(crate::app::sim::duration_s(opts, profile));
    let seed = opts.seed.unwrap_or(cfg.sim.seed);
    let start = Instant::now();
    let model = Arc::new(Mutex::new(EscModel::new(profile.motor_map())));
    let (host, imu_end) = tokio::io::duplex(64 * 1024);
    let stop = Arc::new(AtomicBool::new(false));
    // gps.mode = "gpsd": fixes through the channel fly's gpsd client would publish on.
    let (gps_tx, gps_rx) = watch::channel(None);
    let gps_live = cfg.gps.mode == GpsMode::Gpsd;
    let (live_tx, live_rx) = watch::channel(None);
    let (operator_tx, operator_rx) = mpsc::channel(64);
    let faults = FaultSchedule::new(&opts.inject);
    let cancel = CancellationToken::new();
    let (rc, rc_port) = radio(profile, opts, &faults)?;
    let thread = SimThread {
        profile: profile.clone(),
        seed,
        operator: SimOperator::new(
            &crate::app::sim::script(opts, profile),
            faults.at_us(Fault::LinkLoss),
        )
        .with_links(),
        operator_tx,
        cancel: cancel.clone(),
        trace: CycleTrace::default(),
        faults: faults.clone(),
        progress: opts.progress,
        start,
        model: model.clone(),
        imu_end,
        gps_tx: gps_live.then_some(gps_tx),
        live: live_rx,
        stop: stop.clone(),
        rt: tokio::runtime::Handle::current(),
        truth: TruthFile::create(seed),
        rc,
    };
    let truth_tmp = thread.truth.path.clone();
    let sim_thread =
        crate::tasks::spawn_thread("sim", true, SIM_PRIORITY, Cpu::First, move || thread.run())?;
    let timer = {
        let cancel = cancel.clone();
        tokio::spawn(async move {
            tokio::select! {
                _ = tokio::time::sleep(duration) => cancel.cancel(),
                _ = cancel.cancelled() => {}
            }
        })
    };
    let mut run_profile = profile.clone();
    run_profile.config.sim.seed = seed;
    let edges = Edges {
        imu: Box::new(host),
        bus: Box::new(SimBus {
            model: model.clone(),
            start,
        }),
        gps_fixes: Some(gps_rx),
        live: Some(live_tx),
        operator: Some(operator_rx),
        rc: rc_port,
    };
    let log_stall = faults.at_us(Fault::LogStall).map(|at| LogStall {
        stream: crate::logs::Stream::XHat,
        after_records: 0,
        not_before: Some(start + Duration::from_micros(at as u64)),
        duration: Duration::from_micros(LOG_STALL_US as u64),
    });
    let opts = FlyOptions {
        log_dir: opts.log_dir.clone(),
        realtime: true,
        handle_signals: true,
        realtime_waived: true,
        log_stall,
        gcs: run_profile.config.gcs.enabled != GcsEnabled::Never,
        ..Default::default()
    };
    let summary = fly::run(&run_profile, edges, opts, cancel).await;
    timer.abort();
    stop.store(true, Ordering::SeqCst);
    let result = tokio::task::spawn_blocking(move || sim_thread.join())
        .await
        .ok()
        .and_then(Result::ok)
        .unwrap_or_default();
    let esc_end = model.lock().map(|m| m.end_state()).unwrap_or_default();
    let mut fly = match summary {
        Ok(fly) => fly,
        Err(e) => {
            let _ = std::fs::remove_file(&truth_tmp);
            return Err(e);
        }
    };
    place_truth(&truth_tmp, result.truth_whole, &mut fly);
    fly.commander.figures = result.flights.first().copied().unwrap_or_default();
    fly.commander.flights = result.flights;
    Ok(SimSummary {
        esc_end,
        kill_switch: fly
            .rc_kills
            .iter()
            .map(|k| crate::app::report::KillFigures {
                frame_s: k.frame_us as f64 / 1e6,
                confirmed_s: Some(k.confirmed_us as f64 / 1e6),
                height_m: None,
                impact_v_m_s: None,
            })
            .collect(),
        fly,
        hover: result.hover,
        track: None,
        truth: None,
        simulated_s: result.simulated_us as f64 / 1e6,
        safety: None,
    })
}

impl SimThread {
    /// The radio's frames due by `t_us`, into the pty without waiting (what finds no room is
    /// lost; a pty whose reader is gone ends the radio: its rc-loss follows, as with a
    /// receiver unplugged).
    fn send_radio(&mut self, t_us: i64) {
        use std::io::Write;
        if let Some((tx, port)) = &mut self.rc {
            let bytes = tx.air_due(t_us);
            match port.write(&bytes) {
                Ok(_) => {}
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(_) => self.rc = None,
            }
        }
    }

    /// Steps the physics on the wall clock until told to stop; returns the simulated time and
    /// the hover figures.
    fn run(mut self) -> SimResult {
        let sc = self.profile.config.sim.clone();
        let (mut plant, mut imu) = crate::sim::vehicle(&self.profile, self.seed);
        let step_us = 1_000_000 / i64::from(sc.physics_hz);
        let mut hover = HoverWindow::new(sc.settle_s);
        let (mut t_us, mut frames_sent) = (0i64, 0u64);
        let mut gps = crate::sim::gps::SimGps::new(&self.profile.config.sim, self.seed);
        let mut wire = WireFaults::new(self.seed);
        // The IMU streams once the host asks (spec 1.1), as the real one: frames sent before
        // the reader runs would arrive in one burst, and the settling check would see it.
        let Some(streaming) = self.wait_for_binary_mode() else {
            return SimResult::default();
        };
        let mut inputs = Vec::with_capacity(4);
        let mut armed_once = false;
        while !self.stop.load(Ordering::SeqCst) {
            t_us += step_us;
            let due = streaming + Duration::from_micros(t_us as u64);
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
            let now_us = self.start.elapsed().as_micros() as i64;
            self.physics(&mut plant, t_us, now_us, step_us);
            imu.gyro_step_rad_s = crate::sim::gyro_step_rad_s(&self.faults, &sc, t_us);
            if t_us % FRAME_US == FRAME_US / 2 {
                imu.first_half(&plant);
            }
            let seen_m = crate::sim::gps_seen_m(&self.faults, &sc, t_us, plant.position_m());
            let fix = gps.step(t_us, seen_m, plant.velocity_m_s(), now_us);
            if let (Some(tx), Some(fix)) = (&self.gps_tx, fix)
                && !self.faults.active(Fault::GpsLoss, t_us)
            {
                tx.send_replace(Some(fix));
            }
            self.send_radio(t_us);
            if t_us % FRAME_US != 0 {
                continue;
            }
            if self.operate(t_us, &mut inputs, &mut armed_once) {
                break;
            }
            if self.faults.active(Fault::ImuStall, t_us) {
                continue;
            }
            let frame = imu.frame(&plant, FRAME_US as u32);
            let bytes = wire.bytes(&self.faults, t_us, frame, frame_start_byte(frames_sent));
            frames_sent += 1;
            if self.rt.block_on(self.imu_end.write_all(&bytes)).is_err() {
                break;
            }
            hover.sample(t_us, self.flight_view(), TrueState::of(&plant));
            let bias_m = self.gps_tx.is_some().then(|| gps.bias_m());
            let row = crate::sim::truth::row(&plant, bias_m);
            self.truth.row(now_us, &row);
            self.watch(t_us, &plant);
        }
        SimResult {
            simulated_us: t_us,
            hover: hover.stats(),
            flights: self.trace.flight_figures(),
            truth_whole: self.truth.finish(),
        }
    }

    /// One physics step: the motors follow the ESCs (and the thrust and gust faults), then
    /// the plant advances.
    fn physics(&self, plant: &mut Plant, t_us: i64, now_us: i64, step_us: i64) {
        plant.w_cmd_rad_s = self.motor_commands(t_us, now_us);
        if self.faults.active(Fault::ThrustLoss, t_us) {
            plant.thrust_scale[0] = 0.7;
        }
        plant.push_n = crate::sim::gust_n(&self.faults, &self.profile.config.sim, t_us);
        plant.step(step_us);
    }

    /// The true takeoff and touchdown, and the progress line every 5 s.
    fn watch(&mut self, t_us: i64, plant: &Plant) {
        let live = *self.live.borrow();
        if let Some(l) = live {
            self.trace.sample(t_us, l.mode, l.height_m, plant);
        }
        if self.progress && t_us % 5_000_000 == 0 {
            let mode = live.map_or("start-up", |l| l.mode.name());
            let steps = live.map_or(0, |l| u64::from(l.step));
            // Through the log queue: a stalled terminal must not stall the physics.
            tracing::info!("{}", progress_line(t_us, plant, mode, steps));
        }
    }

    /// The scripted operator's inputs due at `t_us`, handed to the flight without waiting;
    /// `true` once the vehicle has landed and disarmed after the script (the run ends).
    fn operate(
        &mut self,
        t_us: i64,
        inputs: &mut Vec<(i64, OperatorInput)>,
        armed_once: &mut bool,
    ) -> bool {
        self.operator.due(t_us, inputs);
        for (_, input) in inputs.drain(..) {
            if let Err(e) = self.operator_tx.try_send(input) {
                let input = e.into_inner();
                tracing::warn!("the flight took no operator input at {t_us} us: {input:?}");
            }
        }
        let mode = self.live.borrow().map(|l| l.mode);
        *armed_once |= mode.is_some_and(|m| m != Mode::Disarmed);
        let landed = *armed_once && mode == Some(Mode::Disarmed) && self.operator.done(t_us);
        if landed {
            self.cancel.cancel();
        }
        landed
    }

    /// Waits for the host's binary-mode command ('!'); `None` when the run ends first.
    fn wait_for_binary_mode(&mut self) -> Option<Instant> {
        use tokio::io::AsyncReadExt;
        let mut byte = [0u8; 1];
        while !self.stop.load(Ordering::SeqCst) {
            let read = self.rt.block_on(async {
                tokio::time::timeout(Duration::from_millis(50), self.imu_end.read(&mut byte)).await
            });
            match read {
                Ok(Ok(0) | Err(_)) => return None,
                Ok(Ok(_)) if byte[0] == BINARY_MODE_COMMAND => return Some(Instant::now()),
                Ok(Ok(_)) | Err(_) => {}
            }
        }
        None
    }

    /// What the simulated ESCs make of the writes so far (all refused after `esc-nack`).
    fn motor_commands(&self, t_us: i64, now_us: i64) -> [f64; 4] {
        self.model
            .lock()
            .map(|mut m| {
                m.failing = self.faults.active(Fault::EscNack, t_us);
                m.commands_rad_s(now_us)
            })
            .unwrap_or([0.0; 4])
    }

    /// The flight's newest step, as the hover window reads it.
    fn flight_view(&self) -> FlightView {
        let live = *self.live.borrow();
        FlightView {
            ramp_done: live.is_some_and(|l| l.flying_steps >= u64::from(FLIGHT_RAMP_STEPS)),
            setpoint_m: live.map_or([0.0; 3], |l| l.setpoint_m),
            // A halt ends the run, and with it the window.
            flying: live.is_some_and(|l| matches!(l.mode, Mode::Takeoff | Mode::Hold)),
        }
    }
}

//! The link task's state and its handlers: bytes heard, notices, ticks. Every handler runs
//! to its end without waiting (sends never wait), so one can be timed on its thread's clock.

use super::link::{Link, SendFail};
use super::store::ParamStore;
use crate::config::GcsConfig;
use crate::core::commander::{Command, Event, LinkSource, Mode, OperatorInput};
use crate::core::gps::LiveFix;
use crate::gcs::commands::{self, Args, Request};
use crate::gcs::params::Params;
use crate::gcs::telemetry::{self as tm, Health, Snapshot};
use crate::gcs::wire::{Decoder, Encoder, Received};
use crate::tasks::controller::Live;
use crate::tasks::esc_writer::EscStatus;
use crate::tasks::heartbeats::Heartbeats;
use crate::tasks::imu_reader::ImuStats;
use crate::tasks::notices::Notice;
use crate::tasks::watchdog::WatchdogStatus;
use mavlink::MessageData;
use mavlink::dialects::common::*;
use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc, watch};
use tokio_util::sync::CancellationToken;

/// What the task is given: the link's settings, the flight's shared state, its queues.
pub struct GcsContext {
    pub cfg: GcsConfig,
    pub params: Params,
    pub store: ParamStore,
    pub operator: mpsc::Sender<OperatorInput>,
    pub notices: broadcast::Receiver<Notice>,
    pub live: watch::Receiver<Option<Live>>,
    pub gps: Option<watch::Receiver<Option<LiveFix>>>,
    /// A fix older than this does not hold position, µs.
    pub gps_timeout_us: i64,
    pub watchdog: Arc<WatchdogStatus>,
    pub imu: Arc<ImuStats>,
    pub esc: Arc<EscStatus>,
    pub esc_addresses: [u8; 4],
    /// The run's clock.
    pub beats: Arc<Heartbeats>,
    /// The control thread's CPU clock, for SYS_STATUS's load.
    pub control_cpu: Option<libc::clockid_t>,
    pub stats: Arc<GcsStats>,
    pub cancel: CancellationToken,
}

/// The link's counters, shared with the run's report.
#[derive(Debug, Default)]
pub struct GcsStats {
    pub rx: std::sync::Mutex<crate::gcs::wire::RxCounts>,
    pub flood_drops: AtomicU64,
    pub rx_errors: AtomicU64,
    pub tx_frames: AtomicU64,
    pub tx_drops: AtomicU64,
    pub commands: AtomicU64,
    pub commands_refused: AtomicU64,
    pub input_drops: AtomicU64,
    pub param_sets: AtomicU64,
    pub notices_missed: AtomicU64,
    pub gcs_heartbeats: AtomicU64,
    /// The task's own CPU time and how long it ran, ns.
    pub cpu_ns: AtomicU64,
    pub wall_ns: AtomicU64,
}

/// The link's part of the run's report.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct GcsReport {
    #[serde(flatten)]
    pub rx: crate::gcs::wire::RxCounts,
    pub flood_drops: u64,
    pub rx_errors: u64,
    pub tx_frames: u64,
    pub tx_drops: u64,
    pub commands: u64,
    pub commands_refused: u64,
    pub input_drops: u64,
    pub param_sets: u64,
    pub notices_missed: u64,
    pub gcs_heartbeats: u64,
    pub cpu_ms: f64,
    /// The task's CPU time over its run time, % of one core.
    pub cpu_pct: f64,
}

impl GcsStats {
    pub fn report(&self) -> GcsReport {
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let (cpu, wall) = (get(&self.cpu_ns), get(&self.wall_ns));
        GcsReport {
            rx: self.rx.lock().map(|r| *r).unwrap_or_default(),
            flood_drops: get(&self.flood_drops),
            rx_errors: get(&self.rx_errors),
            tx_frames: get(&self.tx_frames),
            tx_drops: get(&self.tx_drops),
            commands: get(&self.commands),
            commands_refused: get(&self.commands_refused),
            input_drops: get(&self.input_drops),
            param_sets: get(&self.param_sets),
            notices_missed: get(&self.notices_missed),
            gcs_heartbeats: get(&self.gcs_heartbeats),
            cpu_ms: cpu as f64 / 1e6,
            cpu_pct: if wall > 0 {
                100.0 * cpu as f64 / wall as f64
            } else {
                0.0
            },
        }
    }
}

/// Counts what arrives in the current second.
struct Window {
    start: Instant,
    count: u32,
}

impl Window {
    fn new(now: Instant) -> Self {
        Window {
            start: now,
            count: 0,
        }
    }

    /// Whether one more arriving `now` is within `max` a second.
    fn allows(&mut self, now: Instant, max: u32) -> bool {
        if now.duration_since(self.start) >= Duration::from_secs(1) {
            *self = Window::new(now);
        }
        self.count += 1;
        self.count <= max
    }
}

/// Commands taken from the link each second, as from the console and stdin.
const COMMANDS_PER_S: u32 = 20;

/// A command sent on to the commander, waiting for its outcome.
struct Pending {
    command: Command,
    mav_cmd: MavCmd,
    from: (u8, u8),
    at: Instant,
}

/// A message sent every `interval`, or never (`None`).
struct Stream {
    id: u32,
    default: Option<Duration>,
    interval: Option<Duration>,
    next: Instant,
}

/// An outcome that does not come within this is acknowledged as failed.
const OUTCOME_TIMEOUT: Duration = Duration::from_secs(2);
/// A ground station's heartbeats reach the commander at most this often.
const BEAT_EVERY: Duration = Duration::from_millis(500);
/// PARAM_VALUEs sent per tick while a list is requested.
const PARAMS_PER_TICK: usize = 10;
/// The ground station's own component id, for the vehicle's frames: the autopilot.
const COMPONENT_ID: u8 = 1;

pub struct Gcs {
    ctx: GcsContext,
    decoder: Decoder,
    encoder: Encoder,
    frame: Vec<u8>,
    mode: Mode,
    streams: Vec<Stream>,
    pending: VecDeque<Pending>,
    param_cursor: Option<usize>,
    rx_window: Window,
    commands: Window,
    last_beat: Option<Instant>,
    text_id: u16,
    halt_told: bool,
    health: Health,
    health_at: Instant,
    frames_seen: u64,
    load_permille: u16,
    control_cpu_ns: u64,
    started: Instant,
}

impl Gcs {
    pub fn new(ctx: GcsContext, decoder: Decoder) -> Self {
        let now = Instant::now();
        let encoder = Encoder::new(ctx.cfg.system_id, COMPONENT_ID);
        let streams = default_streams(&ctx.cfg, now);
        Gcs {
            ctx,
            decoder,
            encoder,
            frame: Vec::with_capacity(300),
            mode: Mode::Disarmed,
            streams,
            pending: VecDeque::new(),
            param_cursor: None,
            rx_window: Window::new(now),
            commands: Window::new(now),
            last_beat: None,
            text_id: 0,
            halt_told: false,
            health: Health {
                fence: true,
                ..Health::default()
            },
            health_at: now,
            frames_seen: 0,
            load_permille: 0,
            control_cpu_ns: 0,
            started: now,
        }
    }

    pub fn cancel(&self) -> CancellationToken {
        self.ctx.cancel.clone()
    }

    /// Runs a handler, adding its CPU time (on this thread's clock) to the link's.
    pub fn timed(&mut self, f: impl FnOnce(&mut Self)) {
        let t0 = thread_cpu_ns();
        f(self);
        let spent = thread_cpu_ns().saturating_sub(t0);
        let s = &self.ctx.stats;
        s.cpu_ns.fetch_add(spent, Ordering::Relaxed);
        let wall = self.started.elapsed().as_nanos() as u64;
        s.wall_ns.store(wall, Ordering::Relaxed);
    }

    pub fn count_rx_error(&mut self) {
        self.ctx.stats.rx_errors.fetch_add(1, Ordering::Relaxed);
    }

    fn send(&mut self, msg: &MavMessage, link: &mut Link) {
        self.frame.clear();
        self.encoder.encode(msg, &mut self.frame);
        let s = &self.ctx.stats;
        match link.send(&self.frame) {
            Ok(()) => s.tx_frames.fetch_add(1, Ordering::Relaxed),
            Err(SendFail::Full | SendFail::Error) => s.tx_drops.fetch_add(1, Ordering::Relaxed),
        };
    }

    fn text(&mut self, severity: MavSeverity, text: &str, link: &mut Link) {
        self.text_id = self.text_id.wrapping_add(1).max(1);
        for m in tm::statustext(severity, text, self.text_id) {
            self.send(&m, link);
        }
    }

    /// Bytes heard: each whole message within the second's budget is handled.
    pub fn on_bytes(&mut self, bytes: &[u8], link: &mut Link) {
        self.decoder.push(bytes);
        while let Some(m) = self.decoder.next_message() {
            if self
                .rx_window
                .allows(Instant::now(), self.ctx.cfg.max_rx_per_s)
            {
                self.on_message(m, link);
            } else {
                self.ctx.stats.flood_drops.fetch_add(1, Ordering::Relaxed);
            }
        }
        if let Ok(mut rx) = self.ctx.stats.rx.lock() {
            *rx = self.decoder.counts;
        }
    }

    fn for_us(&self, system: u8) -> bool {
        system == 0 || system == self.ctx.cfg.system_id
    }

    fn on_message(&mut self, r: Received, link: &mut Link) {
        let from = (r.header.system_id as u8, r.header.component_id);
        match r.msg {
            MavMessage::HEARTBEAT(h) if h.mavtype == MavType::MAV_TYPE_GCS => self.on_gcs_beat(),
            MavMessage::COMMAND_LONG(c) if self.for_us(c.target_system) => {
                let p = [
                    c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
                ];
                self.on_command(c.command, Args { p, frame: None }, from, link);
            }
            MavMessage::COMMAND_INT(c) if self.for_us(c.target_system) => {
                let p = [
                    c.param1, c.param2, c.param3, c.param4, c.x as f32, c.y as f32, c.z,
                ];
                let args = Args {
                    p,
                    frame: Some(c.frame),
                };
                self.on_command(c.command, args, from, link);
            }
            MavMessage::PARAM_REQUEST_LIST(p) if self.for_us(p.target_system) => {
                self.param_cursor = Some(0);
            }
            MavMessage::PARAM_REQUEST_READ(p) if self.for_us(p.target_system) => {
                self.on_param_read(p.param_index, p.param_id.to_str().unwrap_or(""), link);
            }
            MavMessage::PARAM_SET(p) if self.for_us(p.target_system) => {
                let id = p.param_id.to_str().unwrap_or("").to_string();
                self.on_param_set(&id, p.param_value, link);
            }
            _ => {}
        }
    }

    /// A ground station's heartbeat: a beat of its operator link, at most twice a second.
    fn on_gcs_beat(&mut self) {
        self.ctx
            .stats
            .gcs_heartbeats
            .fetch_add(1, Ordering::Relaxed);
        let now = Instant::now();
        if self
            .last_beat
            .is_some_and(|t| now.duration_since(t) < BEAT_EVERY)
        {
            return;
        }
        self.last_beat = Some(now);
        if self
            .ctx
            .operator
            .try_send(OperatorInput::Beat(LinkSource::Gcs))
            .is_err()
        {
            self.ctx.stats.input_drops.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn on_command(&mut self, cmd: MavCmd, args: Args, from: (u8, u8), link: &mut Link) {
        self.ctx.stats.commands.fetch_add(1, Ordering::Relaxed);
        match commands::map(cmd, args) {
            Ok(Request::Commander(c)) => self.forward_command(c, cmd, from, link),
            Ok(Request::Message(id)) => {
                let result = self.send_by_id(id, link);
                self.ack(cmd, result, from, link);
            }
            Ok(Request::Interval {
                msg_id,
                interval_us,
            }) => {
                let result = self.set_interval(msg_id, interval_us);
                self.ack(cmd, result, from, link);
            }
            // An unsupported command is only acknowledged so: ground stations probe with
            // them, and a text for each would drown the ones that matter.
            Err((MavResult::MAV_RESULT_UNSUPPORTED, _)) => {
                self.ctx
                    .stats
                    .commands_refused
                    .fetch_add(1, Ordering::Relaxed);
                self.ack(cmd, MavResult::MAV_RESULT_UNSUPPORTED, from, link);
            }
            Err((result, why)) => self.refuse(cmd, result, &why, from, link),
        }
    }

    fn ack(&mut self, cmd: MavCmd, result: MavResult, to: (u8, u8), link: &mut Link) {
        let msg = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: cmd,
            result,
            target_system: to.0,
            target_component: to.1,
            ..COMMAND_ACK_DATA::DEFAULT
        });
        self.send(&msg, link);
    }

    fn refuse(&mut self, cmd: MavCmd, result: MavResult, why: &str, to: (u8, u8), link: &mut Link) {
        self.ctx
            .stats
            .commands_refused
            .fetch_add(1, Ordering::Relaxed);
        self.ack(cmd, result, to, link);
        self.text(MavSeverity::MAV_SEVERITY_WARNING, why, link);
    }

    /// A commander's command: queued for the flight, acknowledged once it is taken or
    /// refused (the refusal's reason arrives as the commander's own text).
    fn forward_command(&mut self, c: Command, cmd: MavCmd, from: (u8, u8), link: &mut Link) {
        let busy = MavResult::MAV_RESULT_TEMPORARILY_REJECTED;
        if !self.commands.allows(Instant::now(), COMMANDS_PER_S) {
            let why = format!("{c} refused: more than {COMMANDS_PER_S} commands a second");
            return self.refuse(cmd, busy, &why, from, link);
        }
        match self
            .ctx
            .operator
            .try_send(OperatorInput::Command(c, LinkSource::Gcs))
        {
            Ok(()) => self.pending.push_back(Pending {
                command: c,
                mav_cmd: cmd,
                from,
                at: Instant::now(),
            }),
            Err(_) => {
                self.ctx.stats.input_drops.fetch_add(1, Ordering::Relaxed);
                let why = format!("{c} refused: the flight is not taking commands now");
                self.refuse(cmd, busy, &why, from, link);
            }
        }
    }

    pub fn on_notice(&mut self, n: Result<Notice, broadcast::error::RecvError>, link: &mut Link) {
        let n = match n {
            Ok(n) => n,
            Err(broadcast::error::RecvError::Lagged(missed)) => {
                self.ctx
                    .stats
                    .notices_missed
                    .fetch_add(missed, Ordering::Relaxed);
                return;
            }
            // The flight is over; cancel follows.
            Err(broadcast::error::RecvError::Closed) => return,
        };
        match n {
            Notice::Outcome {
                command,
                source: LinkSource::Gcs,
                refused,
            } => self.on_outcome(command, refused.is_some(), link),
            Notice::Outcome { .. } => {}
            Notice::Event(e) => self.on_event(e, link),
        }
    }

    fn on_outcome(&mut self, command: Command, refused: bool, link: &mut Link) {
        let Some(i) = self.pending.iter().position(|p| p.command == command) else {
            return;
        };
        let Some(p) = self.pending.remove(i) else {
            return;
        };
        let result = if refused {
            self.ctx
                .stats
                .commands_refused
                .fetch_add(1, Ordering::Relaxed);
            MavResult::MAV_RESULT_DENIED
        } else {
            MavResult::MAV_RESULT_ACCEPTED
        };
        self.ack(p.mav_cmd, result, p.from, link);
    }

    /// The commander's events as texts (the err.log line's words, with a severity); a mode
    /// change is also told at once.
    fn on_event(&mut self, e: Event, link: &mut Link) {
        let text = crate::core::flight::sequence::commander_line(&e);
        let severity = match e {
            Event::Mode { mode, .. } => {
                self.mode = mode;
                let snap = self.snapshot();
                self.send(&tm::heartbeat(&snap), link);
                self.send(&tm::extended_sys_state(&snap), link);
                MavSeverity::MAV_SEVERITY_INFO
            }
            Event::Failsafe { kind, .. } => {
                if kind == crate::core::commander::Failsafe::Geofence {
                    self.health.fence = false;
                }
                MavSeverity::MAV_SEVERITY_CRITICAL
            }
            Event::Refusal { .. } => MavSeverity::MAV_SEVERITY_WARNING,
        };
        self.text(severity, &text, link);
    }

    pub fn on_tick(&mut self, link: &mut Link) {
        let now = Instant::now();
        if now.duration_since(self.health_at) >= Duration::from_secs(1) {
            self.check_health(now, link);
        }
        self.expire_pending(now, link);
        self.send_params(link);
        let snap = self.snapshot();
        for i in 0..self.streams.len() {
            let s = &mut self.streams[i];
            let Some(every) = s.interval else { continue };
            if now < s.next {
                continue;
            }
            // Keep the rate without bunching after a late tick.
            s.next = (s.next + every).max(now);
            let id = s.id;
            if let Some(m) = build(id, &snap, self.ctx.cfg.system_id) {
                self.send(&m, link);
            }
        }
    }

    fn expire_pending(&mut self, now: Instant, link: &mut Link) {
        while let Some(p) = self.pending.front() {
            if now.duration_since(p.at) < OUTCOME_TIMEOUT {
                break;
            }
            let Some(p) = self.pending.pop_front() else {
                break;
            };
            let why = format!("{}: no answer from the flight", p.command);
            self.refuse(p.mav_cmd, MavResult::MAV_RESULT_FAILED, &why, p.from, link);
        }
    }

    /// Once a second: the sensors' and motors' health, the control thread's load, a halt.
    fn check_health(&mut self, now: Instant, link: &mut Link) {
        let wall_ns = now.duration_since(self.health_at).as_nanos().max(1) as u64;
        self.health_at = now;
        let frames = self.ctx.imu.frames.load(Ordering::Relaxed);
        let halt = self.ctx.watchdog.halt();
        let silent = self.ctx.esc.silent_addresses(&self.ctx.esc_addresses);
        let ratios_ok = self
            .ctx
            .live
            .borrow()
            .is_none_or(|l| !l.ratios.outside_gate().any());
        self.health = Health {
            imu: frames > self.frames_seen,
            gps_used: self.ctx.gps.is_some(),
            motors: silent.is_empty() && halt.is_none(),
            estimator: ratios_ok,
            // A breach stays told for the rest of the run.
            fence: self.health.fence,
        };
        self.frames_seen = frames;
        if let Some(clock) = self.ctx.control_cpu {
            let cpu = clock_ns(clock);
            let busy = cpu.saturating_sub(self.control_cpu_ns);
            self.control_cpu_ns = cpu;
            self.load_permille = (1000 * busy / wall_ns).min(1000) as u16;
        }
        if let (Some(h), false) = (halt, self.halt_told) {
            self.halt_told = true;
            let text = format!("halt {}: motors stopped", h.trip.reason.name());
            self.text(MavSeverity::MAV_SEVERITY_EMERGENCY, &text, link);
        }
    }

    fn snapshot(&self) -> Snapshot {
        let live = *self.ctx.live.borrow();
        let fix = self.ctx.gps.as_ref().and_then(|rx| *rx.borrow());
        let now_us = self.ctx.beats.us(Instant::now());
        Snapshot {
            t_boot_ms: (now_us / 1000).clamp(0, i64::from(u32::MAX)) as u32,
            mode: self.mode,
            state: live.map(|l| l.x),
            ratios: live.map(|l| l.ratios),
            fix,
            fix_fresh: fix.is_some_and(|f| now_us - f.stamp_us <= self.ctx.gps_timeout_us),
            home_m: live.and_then(|l| l.home_m),
            health: self.health,
            load_permille: self.load_permille,
        }
    }

    /// REQUEST_MESSAGE: the message now, if it can be built.
    fn send_by_id(&mut self, id: u32, link: &mut Link) -> MavResult {
        if !KNOWN.contains(&id) {
            return MavResult::MAV_RESULT_DENIED;
        }
        match build(id, &self.snapshot(), self.ctx.cfg.system_id) {
            Some(m) => {
                self.send(&m, link);
                MavResult::MAV_RESULT_ACCEPTED
            }
            // Known, but not yet available (no estimate, no fix, no takeoff point).
            None => MavResult::MAV_RESULT_FAILED,
        }
    }

    fn set_interval(&mut self, id: u32, interval_us: f32) -> MavResult {
        let Some(s) = self.streams.iter_mut().find(|s| s.id == id) else {
            return MavResult::MAV_RESULT_DENIED;
        };
        s.interval = if interval_us < 0.0 {
            None
        } else if interval_us == 0.0 {
            s.default
        } else {
            // At most the tick's rate.
            Some(Duration::from_micros(interval_us as u64).max(super::TICK))
        };
        s.next = Instant::now();
        MavResult::MAV_RESULT_ACCEPTED
    }
}

/// The messages the link can send, by id.
const KNOWN: [u32; 10] = [
    HEARTBEAT_DATA::ID,
    SYS_STATUS_DATA::ID,
    GPS_RAW_INT_DATA::ID,
    ATTITUDE_DATA::ID,
    LOCAL_POSITION_NED_DATA::ID,
    GLOBAL_POSITION_INT_DATA::ID,
    HOME_POSITION_DATA::ID,
    EXTENDED_SYS_STATE_DATA::ID,
    ESTIMATOR_STATUS_DATA::ID,
    AUTOPILOT_VERSION_DATA::ID,
];

fn build(id: u32, s: &Snapshot, system_id: u8) -> Option<MavMessage> {
    match id {
        HEARTBEAT_DATA::ID => Some(tm::heartbeat(s)),
        SYS_STATUS_DATA::ID => Some(tm::sys_status(s)),
        GPS_RAW_INT_DATA::ID => tm::gps_raw(s),
        ATTITUDE_DATA::ID => tm::attitude(s),
        LOCAL_POSITION_NED_DATA::ID => tm::local_position(s),
        GLOBAL_POSITION_INT_DATA::ID => tm::global_position(s),
        HOME_POSITION_DATA::ID => tm::home_position(s),
        EXTENDED_SYS_STATE_DATA::ID => Some(tm::extended_sys_state(s)),
        ESTIMATOR_STATUS_DATA::ID => tm::estimator_status(s),
        AUTOPILOT_VERSION_DATA::ID => Some(tm::autopilot_version(system_id)),
        _ => None,
    }
}

/// The periodic messages: status each second, attitude and position at `gcs.telemetry_hz`,
/// the takeoff point every 5 s.
fn default_streams(cfg: &GcsConfig, now: Instant) -> Vec<Stream> {
    let fast = Duration::from_secs_f64(1.0 / cfg.telemetry_hz);
    let second = Duration::from_secs(1);
    [
        (HEARTBEAT_DATA::ID, second),
        (SYS_STATUS_DATA::ID, second),
        (EXTENDED_SYS_STATE_DATA::ID, second),
        (ESTIMATOR_STATUS_DATA::ID, second),
        (GPS_RAW_INT_DATA::ID, second),
        (HOME_POSITION_DATA::ID, 5 * second),
        (ATTITUDE_DATA::ID, fast),
        (LOCAL_POSITION_NED_DATA::ID, fast),
        (GLOBAL_POSITION_INT_DATA::ID, fast),
    ]
    .into_iter()
    .map(|(id, every)| Stream {
        id,
        default: Some(every),
        interval: Some(every),
        next: now,
    })
    .collect()
}

impl Gcs {
    fn param_value(&mut self, index: usize, link: &mut Link) {
        let count = self.ctx.params.len() as u16;
        let Some(p) = self.ctx.params.get(index).copied() else {
            return;
        };
        let msg = MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value: p.value as f32,
            param_count: count,
            param_index: index as u16,
            param_id: p.id.into(),
            param_type: p.kind.wire(),
        });
        self.send(&msg, link);
    }

    fn send_params(&mut self, link: &mut Link) {
        let Some(start) = self.param_cursor else {
            return;
        };
        let end = (start + PARAMS_PER_TICK).min(self.ctx.params.len());
        for i in start..end {
            self.param_value(i, link);
        }
        self.param_cursor = (end < self.ctx.params.len()).then_some(end);
    }

    fn on_param_read(&mut self, index: i16, id: &str, link: &mut Link) {
        let found = match usize::try_from(index) {
            Ok(i) => (i < self.ctx.params.len()).then_some(i),
            Err(_) => self.ctx.params.find(id),
        };
        match found {
            Some(i) => self.param_value(i, link),
            None => {
                let text = format!("parameter {id:?} (index {index}): no such parameter");
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &text, link);
            }
        }
    }

    /// PARAM_SET: checked and kept (see `store`); the answer is the parameter's value after
    /// it — the old one, with a text saying why, when the set is refused.
    fn on_param_set(&mut self, id: &str, value: f32, link: &mut Link) {
        let Some(i) = self.ctx.params.find(id) else {
            let text = format!("parameter {id:?}: no such parameter");
            return self.text(MavSeverity::MAV_SEVERITY_WARNING, &text, link);
        };
        let Some(p) = self.ctx.params.get(i).copied() else {
            return;
        };
        let outcome = if p.flight_critical() && self.mode != Mode::Disarmed {
            Err(format!(
                "{}: flight-critical, refused while {}",
                p.key,
                self.mode.name()
            ))
        } else {
            let t_s = self.ctx.beats.us(Instant::now()) as f64 / 1e6;
            p.toml_value(value)
                .map_err(|e| format!("{}: {e}", p.key))
                .and_then(|v| self.ctx.store.set(&p, v.clone(), t_s).map(|()| v))
        };
        match outcome {
            Ok(v) => {
                self.ctx.stats.param_sets.fetch_add(1, Ordering::Relaxed);
                let kept = crate::gcs::params::value_of(&v).unwrap_or(p.value);
                self.ctx.params.set(i, kept);
            }
            Err(why) => {
                let text = format!("parameter {} not set: {why}", p.id);
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &text, link);
            }
        }
        self.param_value(i, link);
    }
}

/// The calling thread's CPU time, ns.
fn thread_cpu_ns() -> u64 {
    clock_ns(libc::CLOCK_THREAD_CPUTIME_ID)
}

fn clock_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into `ts` only.
    if unsafe { libc::clock_gettime(clock, &mut ts) } != 0 {
        return 0;
    }
    (ts.tv_sec as u64) * 1_000_000_000 + ts.tv_nsec as u64
}

/// The CPU clock of a running thread (for the control thread's load).
pub fn thread_clock<T>(handle: &std::thread::JoinHandle<T>) -> Option<libc::clockid_t> {
    use std::os::unix::thread::JoinHandleExt;
    let mut clock: libc::clockid_t = 0;
    // SAFETY: the thread is joinable (not yet joined), so its pthread_t is valid; the call
    // writes the clock id into `clock` only.
    let rc = unsafe { libc::pthread_getcpuclockid(handle.as_pthread_t(), &mut clock) };
    (rc == 0).then_some(clock)
}

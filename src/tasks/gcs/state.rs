//! The link task's state and what it does with the bytes heard, the flight's notices and the
//! tick. Every handler runs to its end without waiting (sends never wait), so each is timed on
//! its thread's CPU clock.

use super::link::{Link, SendFail};
use super::store::ParamStore;
use super::{GcsReport, GcsStats};
use crate::config::GcsConfig;
use crate::core::commander::{Command, Event, Failsafe, LinkSource, Mode, OperatorInput};
use crate::core::gps::LiveFix;
use crate::gcs::commands::Args;
use crate::gcs::params::Params;
use crate::gcs::signing::Signing;
use crate::gcs::telemetry::{self as tm, Health, Snapshot};
use crate::gcs::wire::{Decoder, Encoder, Received};
use crate::tasks::controller::Live;
use crate::tasks::esc_writer::EscStatus;
use crate::tasks::heartbeats::Heartbeats;
use crate::tasks::imu_reader::ImuStats;
use crate::tasks::notices::{Notice, Notices};
use crate::tasks::watchdog::WatchdogStatus;
use mavlink::dialects::common::*;
use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// What the task is given: the link's settings, the flight's shared state, its queues.
pub struct GcsContext {
    pub cfg: GcsConfig,
    pub params: Params,
    pub store: ParamStore,
    pub operator: mpsc::Sender<OperatorInput>,
    /// The flight's notices (taken by the task's loop), and their sending side's count of
    /// what a full queue dropped.
    pub notices: Option<mpsc::Receiver<Notice>>,
    pub notices_tx: Notices,
    pub live: watch::Receiver<Option<Live>>,
    pub gps: Option<watch::Receiver<Option<LiveFix>>>,
    /// A fix older than this does not hold position, µs.
    pub gps_timeout_us: i64,
    /// Why the run folder cannot be written, as last probed.
    pub log_problem: watch::Receiver<Option<String>>,
    pub watchdog: Arc<WatchdogStatus>,
    pub imu: Arc<ImuStats>,
    pub esc: Arc<EscStatus>,
    pub esc_addresses: [u8; 4],
    /// The run's clock.
    pub beats: Arc<Heartbeats>,
    /// The control thread's CPU clock, for SYS_STATUS's load.
    pub control_cpu: Option<libc::clockid_t>,
    pub stats: GcsStats,
    pub cancel: CancellationToken,
    /// Plans ground stations' missions (none: uploads are refused).
    pub missions: Option<super::mission_state::MissionDesk>,
    /// MAVLink 2 signing's key (`gcs.signing_key_file`; none: off).
    pub signing_key: Option<crate::config::SigningKey>,
}

/// Counts what arrives in the current second.
pub(super) struct Window {
    start: Instant,
    count: u64,
}

impl Window {
    pub(super) fn new(now: Instant) -> Self {
        Window {
            start: now,
            count: 0,
        }
    }

    /// Whether `amount` more arriving `now` stay within `max` a second.
    pub(super) fn allows(&mut self, now: Instant, amount: u64, max: u64) -> bool {
        if now.duration_since(self.start) >= Duration::from_secs(1) {
            *self = Window::new(now);
        }
        self.count += amount;
        self.count <= max
    }
}

/// A command sent on to the commander, waiting for its outcome.
pub(super) struct Pending {
    pub(super) command: Command,
    pub(super) mav_cmd: MavCmd,
    pub(super) from: (u8, u8),
    pub(super) at: Instant,
}

/// A message sent every `interval`, or never (`None`).
pub(super) struct Stream {
    pub(super) id: u32,
    pub(super) default: Option<Duration>,
    pub(super) interval: Option<Duration>,
    pub(super) next: Instant,
}

/// A ground station's heartbeats reach the commander at most this often.
const BEAT_EVERY: Duration = Duration::from_millis(500);
/// The vehicle's component id: the autopilot's.
pub(super) const COMPONENT_ID: u8 = 1;
/// The largest MAVLink frame, bytes: `gcs.max_rx_per_s` of them is the byte budget too.
const LARGEST_FRAME: u64 = 280;

pub struct Gcs {
    pub(super) ctx: GcsContext,
    decoder: Decoder,
    encoder: Encoder,
    frame: Vec<u8>,
    /// The mode as the commander's events tell it.
    pub(super) mode: Mode,
    mode_disagreements: u8,
    pub(super) streams: Vec<Stream>,
    pub(super) pending: VecDeque<Pending>,
    pub(super) param_cursor: Option<usize>,
    pub(super) params_per_tick: usize,
    rx_frames: Window,
    rx_bytes: Window,
    pub(super) commands: Window,
    pub(super) param_sets: Window,
    last_beat: Option<Instant>,
    text_id: u16,
    halt_told: bool,
    health: Health,
    health_at: Instant,
    frames_seen: u64,
    load_permille: u16,
    control_cpu_ns: u64,
    started: Instant,
    /// Bytes arrived since the previous tick (a radio's frame still arriving).
    fresh_bytes: bool,
    cpu_ns: u64,
    pub(super) report: GcsReport,
    pub(super) missions: super::mission_state::Missions,
    /// The systems that announced themselves as ground stations and may command, with when
    /// each was last heard (at most [`GCS_SENDERS_MAX`]: a new one takes the place of the
    /// longest silent, so fake heartbeats cannot fill the list against the real one).
    gcs_senders: Vec<(u8, Instant)>,
}

/// Ground stations remembered; a link rarely has more than two.
const GCS_SENDERS_MAX: usize = 16;

impl Gcs {
    pub fn new(
        ctx: GcsContext,
        decoder: Decoder,
        streams: Vec<Stream>,
        params_per_tick: usize,
    ) -> Self {
        let now = Instant::now();
        let mut encoder = Encoder::new(ctx.cfg.system_id, COMPONENT_ID);
        let mut decoder = decoder;
        if let Some(crate::config::SigningKey(key)) = ctx.signing_key {
            let now = crate::gcs::signing::now();
            encoder = encoder.with_signing(Signing::new(key).since(now));
            decoder = decoder.with_signing(Signing::new(key).since(now));
        }
        let control_cpu_ns = ctx.control_cpu.map_or(0, super::clock_ns);
        let mut ctx = ctx;
        let missions = super::mission_state::Missions::new(ctx.missions.take());
        Gcs {
            ctx,
            decoder,
            encoder,
            frame: Vec::with_capacity(300),
            mode: Mode::Disarmed,
            mode_disagreements: 0,
            streams,
            pending: VecDeque::new(),
            param_cursor: None,
            params_per_tick,
            rx_frames: Window::new(now),
            rx_bytes: Window::new(now),
            commands: Window::new(now),
            param_sets: Window::new(now),
            last_beat: None,
            text_id: 0,
            halt_told: false,
            health: Health {
                fence: true,
                ..Health::default()
            },
            // The first tick measures it.
            health_at: now.checked_sub(Duration::from_secs(1)).unwrap_or(now),
            frames_seen: 0,
            load_permille: 0,
            control_cpu_ns,
            started: now,
            fresh_bytes: false,
            cpu_ns: 0,
            report: GcsReport::default(),
            missions,
            gcs_senders: Vec::with_capacity(GCS_SENDERS_MAX),
        }
    }

    pub fn cancel(&self) -> CancellationToken {
        self.ctx.cancel.clone()
    }

    /// The flight's notices, for the task's loop (a closed queue when there are none).
    pub fn take_notices(&mut self) -> mpsc::Receiver<Notice> {
        self.ctx
            .notices
            .take()
            .unwrap_or_else(|| mpsc::channel(1).1)
    }

    /// Runs a handler, adds its CPU time (on this thread's clock) to the link's, and
    /// publishes the report.
    pub fn timed(&mut self, f: impl FnOnce(&mut Self)) {
        let t0 = super::thread_cpu_ns();
        f(self);
        self.cpu_ns += super::thread_cpu_ns().saturating_sub(t0);
        let wall_ns = self.started.elapsed().as_nanos().max(1) as f64;
        let r = &mut self.report;
        r.cpu_ms = self.cpu_ns as f64 / 1e6;
        r.cpu_pct = 100.0 * self.cpu_ns as f64 / wall_ns;
        r.notices_missed = self.ctx.notices_tx.dropped();
        if let Ok(mut shared) = self.ctx.stats.lock() {
            *shared = *r;
        }
    }

    pub fn count_rx_error(&mut self) {
        self.report.rx_errors += 1;
    }

    pub(super) fn send(&mut self, msg: &MavMessage, link: &mut Link) {
        self.frame.clear();
        self.encoder.encode(msg, &mut self.frame);
        match link.send(&self.frame) {
            Ok(()) => self.report.tx_frames += 1,
            Err(SendFail::Full | SendFail::Error) => self.report.tx_drops += 1,
        }
    }

    pub(super) fn text(&mut self, severity: MavSeverity, text: &str, link: &mut Link) {
        self.text_id = self.text_id.wrapping_add(1).max(1);
        for m in tm::statustext(severity, text, self.text_id) {
            self.send(&m, link);
        }
    }

    /// Bytes heard (a datagram, or what the radio had): within the second's budgets, each
    /// whole message is handled; a ground station whose frames pass is answered where it
    /// wrote from.
    pub fn on_bytes(&mut self, bytes: &[u8], from: Option<SocketAddr>, link: &mut Link) {
        let now = Instant::now();
        let max_bytes = u64::from(self.ctx.cfg.max_rx_per_s) * LARGEST_FRAME;
        if !self.rx_bytes.allows(now, bytes.len() as u64, max_bytes) {
            self.report.flood_drops += 1;
            return;
        }
        self.decoder.push(bytes);
        let mut answered = false;
        while let Some(m) = self.decoder.next_message() {
            if let (Some(f), false) = (from, answered) {
                link.heard_from(f);
                answered = true;
            }
            // A ground station's heartbeats always count (a flood must not fake a lost
            // link); they cost little and reach the commander at most twice a second.
            let max = u64::from(self.ctx.cfg.max_rx_per_s);
            let beat = matches!(m.msg, MavMessage::HEARTBEAT(_));
            if beat || self.rx_frames.allows(now, 1, max) {
                self.on_message(m, link);
            } else {
                self.report.flood_drops += 1;
            }
        }
        self.fresh_bytes = true;
        self.report.rx = self.decoder.counts;
    }

    /// Addressed to this vehicle: its system (or all, 0) and the autopilot (or all, 0).
    fn for_us(&self, system: u8, component: u8) -> bool {
        (system == 0 || system == self.ctx.cfg.system_id)
            && (component == 0 || component == COMPONENT_ID)
    }

    /// A sender whose commands are obeyed: it announced itself as a ground station, and
    /// `gcs.allowed_systems` (when set) lists it. Anyone may read (parameters, missions,
    /// telemetry); only such a sender changes the vehicle.
    fn may_command(&self, system: u8) -> bool {
        self.gcs_senders.iter().any(|(s, _)| *s == system)
    }

    /// A GCS heartbeat from `system`: remembered when it may command (`gcs.allowed_systems`
    /// lists it, or lists none; never the broadcast id 0 nor the vehicle's own).
    fn heard_gcs(&mut self, system: u8, now: Instant) {
        let allowed = &self.ctx.cfg.allowed_systems;
        let eligible = system != 0
            && system != self.ctx.cfg.system_id
            && (allowed.is_empty() || allowed.contains(&system));
        if !eligible {
            return;
        }
        if let Some(entry) = self.gcs_senders.iter_mut().find(|(s, _)| *s == system) {
            entry.1 = now;
        } else if self.gcs_senders.len() < GCS_SENDERS_MAX {
            self.gcs_senders.push((system, now));
        } else if let Some(oldest) = self.gcs_senders.iter_mut().min_by_key(|(_, t)| *t) {
            *oldest = (system, now);
        }
    }

    /// Where `m` is addressed when it would change the vehicle (a command, a parameter set,
    /// a mission written); none for a read (asking for a message, capabilities or home).
    #[allow(deprecated)]
    fn write_target(m: &MavMessage) -> Option<(u8, u8)> {
        let read = |c: &MavCmd| {
            matches!(
                c,
                MavCmd::MAV_CMD_REQUEST_MESSAGE
                    | MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
                    | MavCmd::MAV_CMD_GET_HOME_POSITION
            )
        };
        match m {
            MavMessage::COMMAND_LONG(c) if !read(&c.command) => {
                Some((c.target_system, c.target_component))
            }
            MavMessage::COMMAND_INT(c) if !read(&c.command) => {
                Some((c.target_system, c.target_component))
            }
            MavMessage::SET_MODE(c) => Some((c.target_system, 0)),
            MavMessage::PARAM_SET(p) => Some((p.target_system, p.target_component)),
            MavMessage::MISSION_COUNT(_)
            | MavMessage::MISSION_ITEM(_)
            | MavMessage::MISSION_ITEM_INT(_)
            | MavMessage::MISSION_CLEAR_ALL(_) => mission_target(m),
            _ => None,
        }
    }

    fn on_message(&mut self, r: Received, link: &mut Link) {
        let from = (r.header.system_id as u8, r.header.component_id);
        if let MavMessage::HEARTBEAT(h) = &r.msg
            && h.mavtype == MavType::MAV_TYPE_GCS
        {
            self.heard_gcs(from.0, Instant::now());
        }
        // Messages for other systems are not ours to deny (a shared link, a router).
        if let Some((system, component)) = Self::write_target(&r.msg)
            && self.for_us(system, component)
            && !self.may_command(from.0)
        {
            return self.deny_sender(&r.msg, from, link);
        }
        match r.msg {
            MavMessage::HEARTBEAT(h) if h.mavtype == MavType::MAV_TYPE_GCS => {
                if self.may_command(from.0) {
                    self.on_gcs_beat();
                }
            }
            MavMessage::COMMAND_LONG(c) if self.for_us(c.target_system, c.target_component) => {
                let p = [
                    c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
                ];
                self.on_command(c.command, Args { p, frame: None }, from, link);
            }
            MavMessage::COMMAND_INT(c) if self.for_us(c.target_system, c.target_component) => {
                let p = [
                    c.param1, c.param2, c.param3, c.param4, c.x as f32, c.y as f32, c.z,
                ];
                let args = Args {
                    p,
                    frame: Some(c.frame),
                };
                self.on_command(c.command, args, from, link);
            }
            // The superseded SET_MODE is read as DO_SET_MODE (and answered so): one reading
            // of a mode request, refusing what uquad's numbering cannot say.
            #[allow(deprecated)]
            MavMessage::SET_MODE(m) if self.for_us(m.target_system, 0) => {
                let mut p = [0.0; 7];
                p[0] = f32::from(m.base_mode.bits());
                p[1] = m.custom_mode as f32;
                let args = Args { p, frame: None };
                self.on_command(MavCmd::MAV_CMD_DO_SET_MODE, args, from, link);
            }
            MavMessage::PARAM_REQUEST_LIST(p)
                if self.for_us(p.target_system, p.target_component) =>
            {
                self.param_cursor = Some(0);
            }
            MavMessage::PARAM_REQUEST_READ(p)
                if self.for_us(p.target_system, p.target_component) =>
            {
                self.on_param_read(p.param_index, p.param_id.to_str().unwrap_or(""), link);
            }
            MavMessage::PARAM_SET(p) if self.for_us(p.target_system, p.target_component) => {
                let id = p.param_id.to_str().unwrap_or("").to_string();
                self.on_param_set(&id, p.param_value, link);
            }
            m => self.on_mission_message(m, from, link),
        }
    }

    /// The mission protocol's messages addressed to this vehicle (older ground stations'
    /// superseded MISSION_ITEM and MISSION_REQUEST too).
    #[allow(deprecated)]
    fn on_mission_message(&mut self, m: MavMessage, from: (u8, u8), link: &mut Link) {
        use crate::gcs::mission::item_int;
        let Some((system, component)) = mission_target(&m) else {
            return;
        };
        if !self.for_us(system, component) {
            return;
        }
        match m {
            MavMessage::MISSION_COUNT(c) => self.on_mission_count(c, from, link),
            MavMessage::MISSION_ITEM_INT(i) => self.on_mission_item(i, from, link),
            MavMessage::MISSION_ITEM(i) => match item_int(&i) {
                Ok(i) => self.on_mission_item(i, from, link),
                Err((result, why)) => self.on_bad_mission_item(from, result, &why, link),
            },
            MavMessage::MISSION_REQUEST_LIST(r) => self.on_mission_list(from, r.mission_type, link),
            MavMessage::MISSION_REQUEST_INT(r) => self.on_mission_request(r.seq, from, link),
            MavMessage::MISSION_REQUEST(r) => self.on_mission_request(r.seq, from, link),
            MavMessage::MISSION_CLEAR_ALL(r) => self.on_mission_clear(r.mission_type, from, link),
            _ => {}
        }
    }

    /// A ground station's heartbeat: a beat of its operator link, at most twice a second.
    fn on_gcs_beat(&mut self) {
        self.report.gcs_heartbeats += 1;
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
            self.report.input_drops += 1;
        }
    }

    pub fn on_notice(&mut self, n: Notice, link: &mut Link) {
        match n {
            Notice::Outcome {
                command,
                source: LinkSource::Gcs,
                refused,
            } => self.on_outcome(command, refused.is_some(), link),
            Notice::Outcome { .. } => {}
            Notice::Mission { name, refused } => {
                self.on_mission_verdict(&name, refused.is_some(), link)
            }
            Notice::Event(e) => self.on_event(e, link),
        }
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
                // A breach stays told for the rest of the run.
                if kind == Failsafe::Geofence {
                    self.health.fence = false;
                }
                MavSeverity::MAV_SEVERITY_CRITICAL
            }
            Event::Refusal { .. } => MavSeverity::MAV_SEVERITY_WARNING,
            Event::Reached { item, .. } => {
                self.on_item_reached(item, link);
                MavSeverity::MAV_SEVERITY_INFO
            }
        };
        self.text(severity, &text, link);
    }

    /// Disarmed by both accounts: the commander's events and the flight's newest step.
    pub(super) fn disarmed(&self) -> bool {
        let live_mode = self.ctx.live.borrow().map(|l| l.mode);
        self.mode == Mode::Disarmed && live_mode.is_none_or(|m| m == Mode::Disarmed)
    }

    /// The run is over: the notices still queued, a halt, a last heartbeat.
    pub fn on_end(&mut self, notices: &mut mpsc::Receiver<Notice>, link: &mut Link) {
        while let Ok(n) = notices.try_recv() {
            self.on_notice(n, link);
        }
        self.check_health(Instant::now(), link);
        let snap = self.snapshot();
        self.send(&tm::heartbeat(&snap), link);
    }

    pub fn on_tick(&mut self, link: &mut Link) {
        let now = Instant::now();
        if now.duration_since(self.health_at) >= Duration::from_secs(1) {
            self.check_health(now, link);
        }
        self.expire_pending(now, link);
        self.mission_timers(now, link);
        self.mission_changed(link);
        self.send_params(link);
        self.send_due(now, link);
        self.unstick_stream(link);
    }

    /// A radio's bytes held for a frame that has not grown for a tick: the frame's start was
    /// noise claiming a long frame; the frames behind it are read now, not when enough
    /// bytes have come to disprove it (seconds at a ground station's heartbeat rate).
    fn unstick_stream(&mut self, link: &mut Link) {
        if !std::mem::take(&mut self.fresh_bytes) && self.decoder.skip_stalled_start() {
            while let Some(m) = self.decoder.next_message() {
                self.on_message(m, link);
            }
            self.report.rx = self.decoder.counts;
        }
    }

    /// Once a second: the sensors', motors' and log folder's health, the control thread's
    /// load, a halt.
    fn check_health(&mut self, now: Instant, link: &mut Link) {
        let wall_ns = now.duration_since(self.health_at).as_nanos().max(1) as u64;
        self.health_at = now;
        let frames = self.ctx.imu.frames.load(Ordering::Relaxed);
        let halt = self.ctx.watchdog.halt();
        let silent = self.ctx.esc.silent_addresses(&self.ctx.esc_addresses);
        let live = *self.ctx.live.borrow();
        let logging = self.ctx.log_problem.borrow().is_none();
        self.health = Health {
            imu: frames > self.frames_seen,
            gps_used: self.ctx.gps.is_some(),
            motors: silent.is_empty() && halt.is_none(),
            estimator: live.is_none_or(|l| !l.ratios.outside_gate().any()),
            logging,
            fence: self.health.fence,
        };
        self.frames_seen = frames;
        self.reconcile_mode(live.map(|l| l.mode));
        if let Some(clock) = self.ctx.control_cpu {
            let cpu = super::clock_ns(clock);
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

    /// The mode follows the commander's events; should one have been lost (a full queue), the
    /// flight's own step corrects it once it has disagreed at two checks in a row (one
    /// disagreement is an event on its way).
    fn reconcile_mode(&mut self, live_mode: Option<Mode>) {
        match live_mode {
            Some(m) if m != self.mode => {
                self.mode_disagreements += 1;
                if self.mode_disagreements >= 2 {
                    self.mode = m;
                    self.mode_disagreements = 0;
                }
            }
            _ => self.mode_disagreements = 0,
        }
    }

    pub(super) fn snapshot(&self) -> Snapshot {
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
            // A mission flies in `mission`, and its last item in `land`.
            mission: live.and_then(|l| {
                let flying = matches!(l.mode, Mode::Mission | Mode::Land);
                self.mission_status(l.mission_item, flying)
            }),
        }
    }
}

/// The system and component a mission message is for.
#[allow(deprecated)]
fn mission_target(m: &MavMessage) -> Option<(u8, u8)> {
    Some(match m {
        MavMessage::MISSION_COUNT(c) => (c.target_system, c.target_component),
        MavMessage::MISSION_ITEM_INT(i) => (i.target_system, i.target_component),
        MavMessage::MISSION_ITEM(i) => (i.target_system, i.target_component),
        MavMessage::MISSION_REQUEST_LIST(r) => (r.target_system, r.target_component),
        MavMessage::MISSION_REQUEST_INT(r) => (r.target_system, r.target_component),
        MavMessage::MISSION_REQUEST(r) => (r.target_system, r.target_component),
        MavMessage::MISSION_CLEAR_ALL(r) => (r.target_system, r.target_component),
        _ => return None,
    })
}

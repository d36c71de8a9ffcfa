//! The ground-station protocol as a state machine with no I/O and no clock, in the shape of
//! quinn-proto's `Connection`: what happens comes in as calls carrying `now` (bytes heard, the
//! flight's notices, its status, the passing of time), and what the protocol decides comes out
//! of queues its owner drains (frames to send, inputs for the flight, file work). The owner,
//! `tasks::gcs`, holds the socket or serial port and the timer, and nothing else.
//!
//! In: [`Connection::handle_datagram`], [`Connection::handle_notice`],
//! [`Connection::handle_status`], [`Connection::handle_timeout`], and the answers to its file
//! work ([`Connection::handle_param_kept`], [`Connection::handle_plan`]) and to a full
//! operator queue ([`Connection::handle_operator_full`]).
//! Out: [`Connection::poll_transmit`], [`Connection::poll_operator`],
//! [`Connection::poll_effect`], [`Connection::poll_timeout`].
//!
//! - `commands`: commands to the commander and their acknowledgements, a sender's rights;
//! - `streams`: the periodic messages, a message on request, the vehicle's health;
//! - `params`: the parameter protocol; `mission`: the mission protocol and its state;
//! - `ftp`: MAVLink FTP, answered at once (nothing served yet);
//! - `tests`: each rule on simulated time.

mod commands;
mod ftp;
mod guided;
mod joystick;
mod logs;
mod mission;
mod params;
mod streams;
#[cfg(test)]
mod tests;

pub use logs::LogEntry;
pub use mission::MissionSettings;
pub use streams::{PERIODIC_SENT, REQUESTABLE};

use crate::config::GcsConfig;
use crate::core::commander::{Command, Event, Failsafe, LinkSource, Mode, OperatorInput};
use crate::core::gps::LiveFix;
use crate::core::status::VehicleStatus;
use crate::gcs::commands::Args;
use crate::gcs::params::{Param, Params};
use crate::gcs::signing::Signing;
use crate::gcs::telemetry::{self as tm, Snapshot};
use crate::gcs::wire::{Decoder, Encoder, Received, RxCounts};
use mavlink::dialects::common::*;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// What the flight tells the link beside the logs: the commander's events (mode changes,
/// failsafes, refusals, items reached) and what became of each command and mission.
#[derive(Debug, Clone, PartialEq)]
pub enum Notice {
    Event(Event),
    /// A command as the commander took it: refused (and why) or done.
    Outcome {
        command: Command,
        source: LinkSource,
        refused: Option<String>,
    },
    /// A ground station's mission (by its file's name) as the commander took it.
    Mission {
        name: String,
        refused: Option<String>,
    },
}

/// Work the protocol asks of its owner, which touches files.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// A line for the run's err.log.
    ErrLog(String),
    /// Check `value` for `param` against the run's files and keep it for the next start; then
    /// [`Connection::handle_param_kept`] with the outcome. `t_s`: the run's clock, s.
    KeepParam {
        index: usize,
        param: Param,
        value: toml::Value,
        t_s: f64,
    },
    /// Write upload `name` (a mission file's `text`) into the run folder and plan it off the
    /// control path; then [`Connection::handle_plan`] with the plan.
    PlanMission { name: String, text: String },
    /// List the logs a ground station may download; then [`Connection::handle_log_list`].
    ListLogs,
    /// Read log `id` of the last list whole; then [`Connection::handle_log_opened`].
    OpenLog { id: u16 },
}

/// What the protocol is set up with.
pub struct Settings {
    pub cfg: GcsConfig,
    pub params: Params,
    /// The run's start: telemetry's boot time counts from it.
    pub boot: Instant,
    /// MAVLink 2 signing: the key, and the signing clock at `boot` (10 µs units since 2015).
    pub signing: Option<([u8; 32], u64)>,
    /// A fix older than this does not hold position, µs.
    pub gps_timeout_us: i64,
    /// Bytes arrive as whole datagrams (UDP), or as a stream (a serial radio).
    pub datagrams: bool,
    /// PARAM_VALUEs sent per [`PACE`] while a list streams.
    pub params_per_pace: usize,
    /// Planning uploads (none: uploads are refused).
    pub missions: Option<MissionSettings>,
    /// The heights a takeoff may go to above the takeoff point, m (the commander's).
    pub takeoff_heights_m: (f64, f64),
}

/// The link's counters, as the run's report gives them.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Counts {
    #[serde(flatten)]
    pub rx: RxCounts,
    /// Frames over `gcs.max_rx_per_s`, and datagrams over its bytes, dropped unread.
    pub flood_drops: u64,
    pub rx_errors: u64,
    pub tx_frames: u64,
    pub tx_drops: u64,
    pub commands: u64,
    pub commands_refused: u64,
    /// Commands, parameter sets and mission writes from a sender that may not command (not
    /// a ground station, or not in `gcs.allowed_systems`): denied.
    pub senders_denied: u64,
    /// Inputs the flight's full operator queue could not take.
    pub input_drops: u64,
    pub param_sets: u64,
    pub gcs_heartbeats: u64,
    /// Log bytes sent by log download.
    pub log_bytes_sent: u64,
    /// Position targets taken as moves of the hold point, and those ignored (not in hold,
    /// no position, a frame not taken).
    pub targets_taken: u64,
    pub targets_ignored: u64,
    /// A joystick's sticks (MANUAL_CONTROL) passed on to the flight.
    pub sticks_taken: u64,
}

/// Every message the protocol reads, with what it does (the book's reference lists these;
/// `on_message` and `on_mission_message` are the dispatch they describe). Anything else is
/// decoded, counted and left.
pub const RECEIVED: &[(&str, &str)] = &[
    (
        "HEARTBEAT",
        "from a ground station (MAV_TYPE_GCS): it may command (`gcs.allowed_systems` \
         permitting), and its beats, at most two a second, keep the operator link alive",
    ),
    ("COMMAND_LONG", "a command (see the table below)"),
    (
        "COMMAND_INT",
        "a command; x, y and z as numbers, the frame for NAV_TAKEOFF",
    ),
    (
        "SET_MODE",
        "QGroundControl's way to set a PX4 mode: read as DO_SET_MODE with the custom mode's \
         main and sub mode (its low 16 bits must be 0), and answered so",
    ),
    (
        "PARAM_REQUEST_LIST",
        "every parameter as PARAM_VALUE, paced (10 per 20 ms over UDP, 1 over a radio)",
    ),
    ("PARAM_REQUEST_READ", "one parameter, by index or id"),
    (
        "PARAM_SET",
        "checked as `--set` is, kept for the next start, answered with the value after it \
         (the old one, and a text, when refused); the keys that take effect in flight (the \
         commander's speeds and heights, the failsafes' timeouts: `uquad params`) applied at \
         the flight's next step and recorded in mode.log; other flight-critical keys only \
         while disarmed; 5 a second",
    ),
    (
        "MISSION_COUNT",
        "begins an upload (at most 500 items); an empty fence or rally list is accepted",
    ),
    (
        "MISSION_ITEM_INT",
        "an upload's item (asked for again after 1 s, the upload cancelled after 5 asks)",
    ),
    (
        "MISSION_ITEM",
        "the superseded float form, read as MISSION_ITEM_INT (a coordinate not a number \
         refuses the upload)",
    ),
    ("MISSION_REQUEST_LIST", "the last accepted upload's count"),
    (
        "MISSION_REQUEST_INT",
        "an item of the last accepted upload (MISSION_REQUEST too)",
    ),
    (
        "MISSION_CLEAR_ALL",
        "fence and rally: accepted (none kept); the mission: refused (upload another)",
    ),
    (
        "MANUAL_CONTROL",
        "a joystick: x pitch, y roll, r yaw (each -1000..1000), z throttle (0..1000, 500 its \
         centre) flown as the radio's sticks in `position` and `altitude` while no radio is \
         heard (`hold` ignores them); passed on when they move and every 0.2 s; a joystick \
         silent for 0.5 s reads centred (the vehicle holds its height, and in position its point)",
    ),
    (
        "SET_POSITION_TARGET_LOCAL_NED",
        "in `hold`, moves the hold point (as `hold X Y Z` from the takeoff point, the fence \
         and the manual heights refusing what they do not allow): MAV_FRAME_LOCAL_NED or \
         LOCAL_OFFSET_NED, the position taken (velocities, accelerations and yaw not), a move \
         of 5 cm or more at most every 0.2 s; ignored and counted in any other mode",
    ),
    (
        "SET_POSITION_TARGET_GLOBAL_INT",
        "as SET_POSITION_TARGET_LOCAL_NED, the point placed by the newest fix: \
         MAV_FRAME_GLOBAL_RELATIVE_ALT_INT (altitude above the takeoff point) or GLOBAL_INT \
         (above sea level)",
    ),
    (
        "LOG_REQUEST_LIST",
        "a LOG_ENTRY for each log asked for: the run folders' ULog exports, oldest first \
         (the newest 20 runs; the running one exported as it stands)",
    ),
    (
        "LOG_REQUEST_DATA",
        "LOG_DATA packets of 90 bytes from the offset asked, a budget each 20 ms (over UDP \
         50 packets; over a radio what its paced queue can take beside the telemetry, whose \
         fast messages slow to 2 Hz while it runs); disarmed only; stopped when no ground \
         station's heartbeat came for 5 s",
    ),
    (
        "LOG_REQUEST_END",
        "stops the read and lets the log's bytes go",
    ),
    (
        "FILE_TRANSFER_PROTOCOL",
        "MAVLink FTP: no file is served yet; an open, a listing or a read is answered at once \
         with a NAK (file not found), so a client asking for the parameter file falls back to \
         PARAM_REQUEST_LIST without waiting",
    ),
];

/// The shortest interval of a periodic message, and the pace of a parameter list.
pub const PACE: Duration = Duration::from_millis(20);
/// Frames waiting to be sent at most; beyond, dropped and counted. Far above what one call
/// produces: the owner drains the queue after each.
const TX_QUEUE_MAX: usize = 4096;
/// A ground station's heartbeats reach the commander at most this often.
const BEAT_EVERY: Duration = Duration::from_millis(500);
/// The vehicle's component id: the autopilot's.
pub const COMPONENT_ID: u8 = 1;
/// The largest MAVLink frame, bytes: `gcs.max_rx_per_s` of them is the byte budget too.
const LARGEST_FRAME: u64 = 280;
/// A serial stream's bytes that have not grown a claimed frame for this long: the claim was
/// noise (twice a 20 ms gap between a radio's packets).
const STALL: Duration = Duration::from_millis(40);
/// Ground stations remembered; a link rarely has more than two.
const GCS_SENDERS_MAX: usize = 16;

/// Counts what arrives in the current second.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Window {
    start: Instant,
    count: u64,
}

impl Window {
    fn new(now: Instant) -> Self {
        Window {
            start: now,
            count: 0,
        }
    }

    /// Whether `amount` more arriving `now` stay within `max` a second.
    fn allows(&mut self, now: Instant, amount: u64, max: u64) -> bool {
        if now.saturating_duration_since(self.start) >= Duration::from_secs(1) {
            *self = Window::new(now);
        }
        self.count += amount;
        self.count <= max
    }
}

/// The ground-station protocol's state.
pub struct Connection {
    s: Settings,
    decoder: Decoder,
    encoder: Encoder,
    tx: VecDeque<Vec<u8>>,
    operator: VecDeque<OperatorInput>,
    effects: VecDeque<Effect>,
    /// The vehicle as last told (its mode is the one the link reports).
    status: VehicleStatus,
    /// The mode last announced by a heartbeat sent at its change.
    told_mode: Mode,
    commands: commands::Commands,
    streams: streams::Streams,
    params: params::ParamState,
    missions: mission::Missions,
    rx_frames: Window,
    rx_bytes: Window,
    last_beat: Option<Instant>,
    text_id: u16,
    /// The newest `now` the protocol was given.
    latest: Instant,
    /// Where the vehicle stood on the ground by a fix (see `note_ground_home`), and that
    /// fix's altitude above sea level, m.
    ground_home_m: Option<[f64; 3]>,
    ground_alt_m: Option<f64>,
    /// The signing clock as the owner last read it.
    signing_time: Option<u64>,
    /// A serial stream's held bytes are looked at again then (see [`STALL`]).
    stall_check_at: Option<Instant>,
    counts: Counts,
    downloads: logs::Downloads,
    guided: guided::Guided,
    joystick: joystick::Joystick,
    /// The systems that announced themselves as ground stations and may command, with when
    /// each was last heard (at most [`GCS_SENDERS_MAX`]: a new one takes the place of the
    /// longest silent, so fake heartbeats cannot fill the list against the real one).
    gcs_senders: Vec<(u8, Instant)>,
}

impl Connection {
    pub fn new(s: Settings, now: Instant) -> Self {
        let mut encoder = Encoder::new(s.cfg.system_id, COMPONENT_ID);
        let mut decoder = if s.datagrams {
            Decoder::for_datagrams()
        } else {
            Decoder::for_stream()
        };
        if let Some((key, at_boot)) = s.signing {
            let since = at_boot + ticks_10us(now.saturating_duration_since(s.boot));
            encoder = encoder.with_signing(Signing::new(key).since(since));
            decoder = decoder.with_signing(Signing::new(key).since(since));
        }
        let missions = mission::Missions::new(s.missions);
        Connection {
            decoder,
            encoder,
            tx: VecDeque::new(),
            operator: VecDeque::new(),
            effects: VecDeque::new(),
            status: VehicleStatus::default(),
            told_mode: Mode::Disarmed,
            commands: commands::Commands::new(now),
            streams: streams::Streams::new(&s.cfg, now),
            params: params::ParamState::new(now),
            missions,
            rx_frames: Window::new(now),
            rx_bytes: Window::new(now),
            last_beat: None,
            text_id: 0,
            latest: now,
            ground_home_m: None,
            ground_alt_m: None,
            signing_time: None,
            stall_check_at: None,
            counts: Counts::default(),
            downloads: logs::Downloads::default(),
            guided: guided::Guided::default(),
            joystick: joystick::Joystick::default(),
            gcs_senders: Vec::with_capacity(GCS_SENDERS_MAX),
            s,
        }
    }

    /// The next frame to send, whole.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.tx.pop_front()
    }

    /// The next input for the flight's operator queue. A queue that cannot take it is told
    /// back with [`Connection::handle_operator_full`].
    pub fn poll_operator(&mut self) -> Option<OperatorInput> {
        self.operator.pop_front()
    }

    /// The next file work.
    pub fn poll_effect(&mut self) -> Option<Effect> {
        self.effects.pop_front()
    }

    /// When [`Connection::handle_timeout`] is next due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        [
            self.streams.next_due(),
            self.commands.next_expiry(),
            self.missions.next_timer(),
            self.params.next_pace(),
            self.stall_check_at,
            self.downloads.next_due(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// The counters so far.
    pub fn counts(&self) -> Counts {
        Counts {
            log_bytes_sent: self.downloads.sent_bytes,
            ..self.counts
        }
    }

    /// What the owner's link did with a frame: sent, or dropped (full, or failed).
    pub fn count_sent(&mut self, sent: bool) {
        if sent {
            self.counts.tx_frames += 1;
        } else {
            self.counts.tx_drops += 1;
        }
    }

    /// A receive error on the link (a datagram refused on the way).
    pub fn count_rx_error(&mut self) {
        self.counts.rx_errors += 1;
    }

    /// Bytes heard (a datagram, or what the radio had): within the second's budgets, each
    /// whole message is handled. True when a frame passed its checks (a UDP owner answers
    /// where it came from).
    pub fn handle_datagram(&mut self, now: Instant, bytes: &[u8]) -> bool {
        self.tell_time(now);
        let max_bytes = u64::from(self.s.cfg.max_rx_per_s) * LARGEST_FRAME;
        if !self.rx_bytes.allows(now, bytes.len() as u64, max_bytes) {
            self.counts.flood_drops += 1;
            return false;
        }
        self.decoder.push(bytes);
        let mut heard = false;
        while let Some(m) = self.decoder.next_message() {
            heard = true;
            // A ground station's heartbeats always count (a flood must not fake a lost
            // link); they cost little and reach the commander at most twice a second.
            let max = u64::from(self.s.cfg.max_rx_per_s);
            let beat = matches!(m.msg, MavMessage::HEARTBEAT(_));
            if beat || self.rx_frames.allows(now, 1, max) {
                self.on_message(now, m);
            } else {
                self.counts.flood_drops += 1;
            }
        }
        if !self.s.datagrams {
            self.stall_check_at = Some(now + STALL);
        }
        self.counts.rx = self.decoder.counts;
        heard
    }

    /// The flight's notice: a command's or a mission's outcome, or a commander's event told
    /// as a text (the err.log line's words, with a severity).
    pub fn handle_notice(&mut self, now: Instant, n: Notice) {
        self.tell_time(now);
        match n {
            Notice::Outcome {
                command,
                source: LinkSource::Gcs,
                refused,
            } => self.on_outcome(command, refused.is_some()),
            Notice::Outcome { .. } => {}
            Notice::Mission { name, refused } => self.on_mission_verdict(&name, refused.is_some()),
            Notice::Event(e) => self.on_event(now, e),
        }
    }

    /// The vehicle's status now: its mode is the one the link reports, and a change of mode
    /// is told at once (HEARTBEAT, EXTENDED_SYS_STATE), as is a mission's progress.
    pub fn handle_status(&mut self, now: Instant, status: VehicleStatus) {
        self.tell_time(now);
        self.status = status;
        let mode = self.status.mode;
        if self.note_ground_home(now, mode) {
            // A new home is told at once, not at the next 5-s HOME_POSITION.
            if let Some(home) = tm::home_position(&self.snapshot(now)) {
                self.send(&home);
            }
        }
        self.stop_download_when_armed();
        if mode != self.told_mode {
            self.told_mode = mode;
            let snap = self.snapshot(now);
            self.send(&tm::heartbeat(&snap));
            self.send(&tm::current_mode(&snap));
            self.send(&tm::extended_sys_state(&snap));
        }
        self.mission_changed(now);
    }

    /// Whatever is due at `now`: the health, commands' and uploads' timers, a parameter
    /// list's next values, the periodic messages, a stalled stream.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.tell_time(now);
        self.check_health(now, false);
        self.expire_pending(now);
        self.mission_timers(now);
        self.send_params(now);
        self.send_due(now);
        self.unstick_stream(now);
    }

    /// Where the vehicle stands by a fresh 3-D fix, on the ground: the first such fix, and
    /// again at each arming (the takeoff point, once the estimate has one, is HOME_POSITION's
    /// instead).
    /// True when it changed.
    fn note_ground_home(&mut self, now: Instant, mode: Mode) -> bool {
        let on_ground = matches!(mode, Mode::Disarmed | Mode::Armed);
        let arming = mode == Mode::Armed && self.told_mode != Mode::Armed;
        if !on_ground || (self.ground_home_m.is_some() && !arming) {
            return false;
        }
        let now_us = now.saturating_duration_since(self.s.boot).as_micros() as i64;
        let fresh = |f: &LiveFix| now_us - f.stamp_us <= self.s.gps_timeout_us;
        let fix = self.status.fix.filter(|f| f.fix.mode >= 3 && fresh(f));
        if let Some(f) = fix
            && let Some(z) = f.sample.z_m
        {
            let home = Some([f.sample.xy_m[0], f.sample.xy_m[1], z]);
            let changed = home != self.ground_home_m;
            self.ground_home_m = home;
            self.ground_alt_m = f.fix.alt_m;
            return changed;
        }
        false
    }

    /// The run is over: a halt told, a last heartbeat.
    pub fn handle_end(&mut self, now: Instant) {
        self.tell_time(now);
        self.check_health(now, true);
        let snap = self.snapshot(now);
        self.send(&tm::heartbeat(&snap));
    }

    /// The flight's operator queue could not take `input` (from [`Connection::poll_operator`]).
    pub fn handle_operator_full(&mut self, now: Instant, input: OperatorInput) {
        self.tell_time(now);
        self.counts.input_drops += 1;
        match input {
            OperatorInput::Command(c, _) => self.command_not_taken(c),
            OperatorInput::Mission(_) => self.mission_not_taken(),
            OperatorInput::Param { key, .. } => {
                // Kept for the next start, but the running flight did not take it: said.
                let text = format!(
                    "parameter {key} kept for the next start, not applied in flight: the flight's queue is full"
                );
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &text);
            }
            _ => {}
        }
    }

    /// A bytes stream whose held frame has not grown for [`STALL`]: its start was noise
    /// claiming a long frame; the frames behind it are read now, not when enough bytes have
    /// come to disprove it (seconds at a ground station's heartbeat rate).
    fn unstick_stream(&mut self, now: Instant) {
        if self.stall_check_at.is_none_or(|at| now < at) {
            return;
        }
        self.stall_check_at = None;
        if self.decoder.skip_stalled_start() {
            while let Some(m) = self.decoder.next_message() {
                self.on_message(now, m);
            }
            self.counts.rx = self.decoder.counts;
            self.stall_check_at = Some(now + STALL);
        }
    }

    fn send(&mut self, msg: &MavMessage) {
        if self.tx.len() >= TX_QUEUE_MAX {
            self.counts.tx_drops += 1;
            return;
        }
        let mut frame = Vec::with_capacity(64);
        let signing_now = self.signing_now();
        self.encoder.encode_at(msg, &mut frame, signing_now);
        self.tx.push_back(frame);
    }

    /// The signing clock (10 µs units since 2015) as the owner last read it: the wall clock,
    /// which a board without a real-time clock gets only once NTP has set it.
    pub fn set_signing_time(&mut self, now_10us: u64) {
        self.signing_time = Some(now_10us);
    }

    /// The signing clock: the owner's last reading, or the one at boot moved on by the
    /// protocol's own time (signatures stay increasing either way: the encoder's rule).
    fn signing_now(&self) -> u64 {
        self.signing_time.unwrap_or_else(|| {
            let at_boot = self.s.signing.map_or(0, |(_, t)| t);
            at_boot + ticks_10us(self.latest.saturating_duration_since(self.s.boot))
        })
    }

    /// Moves the protocol's own clock on to `now` (never back).
    fn tell_time(&mut self, now: Instant) {
        self.latest = self.latest.max(now);
    }

    fn text(&mut self, severity: MavSeverity, text: &str) {
        self.text_id = self.text_id.wrapping_add(1).max(1);
        for m in tm::statustext(severity, text, self.text_id) {
            self.send(&m);
        }
    }

    fn err_log(&mut self, line: impl Into<String>) {
        self.effects.push_back(Effect::ErrLog(line.into()));
    }

    /// Addressed to this vehicle: its system (or all, 0) and the autopilot (or all, 0).
    fn for_us(&self, system: u8, component: u8) -> bool {
        (system == 0 || system == self.s.cfg.system_id)
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
        let allowed = &self.s.cfg.allowed_systems;
        let eligible = system != 0
            && system != self.s.cfg.system_id
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

    fn on_message(&mut self, now: Instant, r: Received) {
        let from = (r.header.system_id as u8, r.header.component_id);
        if let MavMessage::HEARTBEAT(h) = &r.msg
            && h.mavtype == MavType::MAV_TYPE_GCS
        {
            self.heard_gcs(from.0, now);
        }
        // Messages for other systems are not ours to deny (a shared link, a router).
        if let Some((system, component)) = write_target(&r.msg)
            && self.for_us(system, component)
            && !self.may_command(from.0)
        {
            return self.deny_sender(&r.msg, from);
        }
        match r.msg {
            MavMessage::HEARTBEAT(h) if h.mavtype == MavType::MAV_TYPE_GCS => {
                if self.may_command(from.0) {
                    self.on_gcs_beat(now);
                }
            }
            MavMessage::COMMAND_LONG(c) if self.for_us(c.target_system, c.target_component) => {
                let p = [
                    c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
                ];
                self.on_command(now, c.command, Args { p, frame: None }, from);
            }
            MavMessage::COMMAND_INT(c) if self.for_us(c.target_system, c.target_component) => {
                let p = [
                    c.param1, c.param2, c.param3, c.param4, c.x as f32, c.y as f32, c.z,
                ];
                let args = Args {
                    p,
                    frame: Some(c.frame),
                };
                self.on_command(now, c.command, args, from);
            }
            // The superseded SET_MODE (QGroundControl's way to set a PX4 mode) is read as
            // DO_SET_MODE with its main and sub mode, and answered so.
            #[allow(deprecated)]
            MavMessage::SET_MODE(m) if self.for_us(m.target_system, 0) => {
                let mut p = [0.0; 7];
                p[0] = f32::from(m.base_mode.bits());
                // PX4's packing, read from the integer (a float would round away low bits,
                // which must be 0: anything else is not a PX4 mode, and is refused).
                let (main, sub) = crate::gcs::modes::unpack(m.custom_mode);
                let packed = m.custom_mode & 0xffff == 0;
                p[1] = if packed { f32::from(main) } else { f32::NAN };
                p[2] = f32::from(sub);
                let args = Args { p, frame: None };
                self.on_command(now, MavCmd::MAV_CMD_DO_SET_MODE, args, from);
            }
            MavMessage::PARAM_REQUEST_LIST(p)
                if self.for_us(p.target_system, p.target_component) =>
            {
                self.params.start_list(now);
            }
            MavMessage::PARAM_REQUEST_READ(p)
                if self.for_us(p.target_system, p.target_component) =>
            {
                self.on_param_read(p.param_index, p.param_id.to_str().unwrap_or(""));
            }
            MavMessage::PARAM_SET(p) if self.for_us(p.target_system, p.target_component) => {
                let id = p.param_id.to_str().unwrap_or("").to_string();
                let value = crate::gcs::params::set_value(p.param_value, p.param_type);
                self.on_param_set(now, &id, value);
            }
            MavMessage::SET_POSITION_TARGET_LOCAL_NED(t)
                if self.for_us(t.target_system, t.target_component) =>
            {
                self.on_local_target(now, t)
            }
            MavMessage::SET_POSITION_TARGET_GLOBAL_INT(t)
                if self.for_us(t.target_system, t.target_component) =>
            {
                self.on_global_target(now, t)
            }
            MavMessage::MANUAL_CONTROL(m) if self.for_us(m.target, 0) => {
                self.on_manual_control(now, &m)
            }
            MavMessage::LOG_REQUEST_LIST(l) if self.for_us(l.target_system, l.target_component) => {
                self.on_log_list(l.start, l.end)
            }
            MavMessage::LOG_REQUEST_DATA(d) if self.for_us(d.target_system, d.target_component) => {
                self.on_log_data_request(now, d.id, d.ofs, d.count)
            }
            MavMessage::LOG_REQUEST_END(e) if self.for_us(e.target_system, e.target_component) => {
                self.on_log_end()
            }
            MavMessage::FILE_TRANSFER_PROTOCOL(f)
                if (f.target_system == 0 || f.target_system == self.s.cfg.system_id)
                    && (f.target_component == 0 || f.target_component == COMPONENT_ID) =>
            {
                self.on_ftp(f, from)
            }
            m => self.on_mission_message(now, m, from),
        }
    }

    /// A ground station's heartbeat: a beat of its operator link, at most twice a second.
    fn on_gcs_beat(&mut self, now: Instant) {
        self.counts.gcs_heartbeats += 1;
        if self
            .last_beat
            .is_some_and(|t| now.saturating_duration_since(t) < BEAT_EVERY)
        {
            return;
        }
        self.last_beat = Some(now);
        self.operator
            .push_back(OperatorInput::Beat(LinkSource::Gcs));
    }

    /// The commander's events as texts; a failsafe's with the severity it deserves.
    fn on_event(&mut self, now: Instant, e: Event) {
        let text = crate::core::flight::sequence::commander_line(&e);
        let severity = match e {
            Event::Mode { .. } => MavSeverity::MAV_SEVERITY_INFO,
            Event::Failsafe { kind, .. } => {
                // A breach stays told for the rest of the run.
                if kind == Failsafe::Geofence {
                    self.streams.fence_breached = true;
                    self.streams.health.fence = false;
                }
                MavSeverity::MAV_SEVERITY_CRITICAL
            }
            Event::Refusal { .. } => MavSeverity::MAV_SEVERITY_WARNING,
            Event::Reached { item, .. } => {
                self.on_item_reached(now, item);
                MavSeverity::MAV_SEVERITY_INFO
            }
        };
        self.text(severity, &text);
    }

    /// Disarmed by both accounts: the commander's last change and the flight's newest step.
    fn disarmed(&self) -> bool {
        let live_mode = self.status.live.map(|l| l.mode);
        self.status.mode == Mode::Disarmed && live_mode.is_none_or(|m| m == Mode::Disarmed)
    }

    fn snapshot(&self, now: Instant) -> Snapshot {
        let st = &self.status;
        let live = st.live;
        let now_us = now.saturating_duration_since(self.s.boot).as_micros() as i64;
        let fix = st.fix;
        Snapshot {
            t_boot_ms: (now_us / 1000).clamp(0, i64::from(u32::MAX)) as u32,
            mode: st.mode,
            state: live.map(|l| l.x),
            ratios: live.map(|l| l.ratios),
            fix,
            fix_fresh: fix.is_some_and(|f| now_us - f.stamp_us <= self.s.gps_timeout_us),
            home_m: live.and_then(|l| l.home_m),
            ground_home_m: self.ground_home_m,
            prearm: st.prearm_ok,
            health: self.streams.health,
            load_permille: self.streams.load_permille,
            // A mission flies in `mission`, and its last item in `land`.
            mission: live.and_then(|l| {
                let flying = matches!(l.mode, Mode::Mission | Mode::Land);
                self.mission_status(l.mission_item, flying)
            }),
            rc: st.rc,
        }
    }
}

/// A duration in the signing clock's 10 µs units.
fn ticks_10us(d: Duration) -> u64 {
    u64::try_from(d.as_micros() / 10).unwrap_or(u64::MAX)
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
        MavMessage::MANUAL_CONTROL(m) => Some((m.target, 0)),
        MavMessage::PARAM_SET(p) => Some((p.target_system, p.target_component)),
        MavMessage::SET_POSITION_TARGET_LOCAL_NED(t) => Some((t.target_system, t.target_component)),
        MavMessage::SET_POSITION_TARGET_GLOBAL_INT(t) => {
            Some((t.target_system, t.target_component))
        }
        MavMessage::MISSION_COUNT(_)
        | MavMessage::MISSION_ITEM(_)
        | MavMessage::MISSION_ITEM_INT(_)
        | MavMessage::MISSION_CLEAR_ALL(_) => mission::target(m),
        _ => None,
    }
}

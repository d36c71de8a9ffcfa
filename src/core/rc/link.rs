//! The pilot's radio as operator inputs (spec: none): each frame of channels read through the
//! map (`sticks`) and turned into what the commander takes, so that a replay of mode.log
//! flies the same: a report of the kill switch and the sticks when they change (and
//! [`REPORTS_PER_TIMEOUT`] times a timeout anyway: the receiver is heard), the arm switch's
//! moves as `arm` and
//! `disarm`, the mode switch's as the command of its new position, and the receiver's
//! failsafe as a loss. A switch found on at the first frame (or after a loss) is not a move:
//! it must go off and on again to arm. Also what a watcher sees of the radio ([`RcStatus`]:
//! RC_CHANNELS, the console's line).

use super::RcFrame;
use super::sticks::{RcInput, RcMap};
use crate::core::commander::{Command, LinkSource, OperatorInput, RcReport, StickMode};

/// The receiver is reported heard at least this many times within `failsafe.rc_timeout_s`:
/// a frame or two lost in between is not a loss.
pub const REPORTS_PER_TIMEOUT: f64 = 2.5;

/// Sticks are reported to this resolution (a share of their half travel, about 8 ticks): a
/// gimbal's jitter of a tick or two is not a change.
const STICK_STEP: f64 = 0.01;

/// The mode switch acts once its new position has been read on this many frames in a row: a
/// knob turned across the bands, or a switch's travel between two positions, is not a
/// choice of each mode it passes.
pub const MODE_FRAMES: u32 = 3;

/// What a position of the mode switch selects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RcMode {
    /// Sticks → horizontal velocity, climb rate and yaw rate.
    Position,
    /// Sticks → tilt and yaw rate, throttle → climb rate.
    Altitude,
    Hold,
    Mission,
    Return,
    Land,
}

impl RcMode {
    pub fn name(self) -> &'static str {
        match self {
            RcMode::Position => "position",
            RcMode::Altitude => "altitude",
            RcMode::Hold => "hold",
            RcMode::Mission => "mission",
            RcMode::Return => "return",
            RcMode::Land => "land",
        }
    }

    /// The commander's command for this mode.
    pub fn command(self) -> Command {
        match self {
            RcMode::Hold => Command::Hold(None),
            RcMode::Mission => Command::Start,
            RcMode::Return => Command::Return,
            RcMode::Land => Command::Land,
            RcMode::Position => Command::Sticks(StickMode::Position),
            RcMode::Altitude => Command::Sticks(StickMode::Altitude),
        }
    }

    /// The stick mode this is, if it is one.
    pub fn stick_mode(self) -> Option<StickMode> {
        match self.command() {
            Command::Sticks(m) => Some(m),
            _ => None,
        }
    }
}

/// Frames in, operator inputs out.
#[derive(Debug, Clone)]
pub struct RcLink {
    map: RcMap,
    modes: Vec<RcMode>,
    /// The previous frame as read (none at the start and after a loss).
    last: Option<RcInput>,
    /// The last report sent, and when.
    reported: Option<(RcReport, i64)>,
    lost: bool,
    /// The receiver's link statistics say no packet arrives (CRSF, link quality 0): its
    /// channels are its failsafe's, not the pilot's.
    link_down: bool,
    /// The mode switch's position acted on, and a new one being read (its frames so far).
    mode: Option<usize>,
    mode_seen: (usize, u32),
    /// An unchanged report is sent again this often, µs.
    report_period_us: i64,
    /// What a watcher sees of the radio: the newest frame, the link statistics.
    status: Option<RcStatus>,
}

impl RcLink {
    /// A link whose receiver's loss is judged after `timeout_s` of silence
    /// (`failsafe.rc_timeout_s`).
    pub fn new(map: RcMap, modes: Vec<RcMode>, timeout_s: f64) -> Self {
        RcLink {
            map,
            modes,
            last: None,
            reported: None,
            lost: false,
            link_down: false,
            mode: None,
            mode_seen: (0, 0),
            report_period_us: (timeout_s / REPORTS_PER_TIMEOUT * 1e6).max(10_000.0) as i64,
            status: None,
        }
    }

    /// The radio as a watcher sees it (none before its first frame).
    pub fn status(&self) -> Option<RcStatus> {
        self.status
    }

    pub fn map(&self) -> &RcMap {
        &self.map
    }

    /// The receiver's link statistics: a link quality of 0 is a loss (a CRSF receiver set to
    /// hold or preset its channels keeps sending them).
    pub fn link(&mut self, stats: &crate::core::rc::LinkStats, out: &mut Vec<OperatorInput>) {
        self.link_down = stats.link_quality_pct == 0;
        if let Some(st) = &mut self.status {
            st.link_quality_pct = Some(stats.link_quality_pct);
            st.rssi_dbm = Some(stats.rssi_dbm);
        }
        if self.link_down {
            self.lose(out);
        }
    }

    fn lose(&mut self, out: &mut Vec<OperatorInput>) {
        if let Some(st) = &mut self.status {
            st.lost = true;
        }
        if self.lost {
            return;
        }
        self.lost = true;
        self.last = None;
        self.reported = None;
        self.mode = None;
        out.push(OperatorInput::Rc(RcReport::LOST));
    }

    /// A frame at `t_us`: the inputs it makes, appended to `out`. True while its kill switch
    /// is on (the caller stops the motors at once, every such frame, before the commander
    /// hears of it). A frame the receiver marks lost, or sends while its link is down, is not
    /// a frame of the pilot's.
    pub fn frame(&mut self, f: &RcFrame, t_us: i64, out: &mut Vec<OperatorInput>) -> bool {
        if f.failsafe || self.link_down {
            self.lose(out);
            return false;
        }
        if f.frame_lost {
            return false;
        }
        self.lost = false;
        let input = self.map.read(f);
        let moved_to = self.mode_switch(input.mode);
        self.watched(f, &input);
        let q = |x: f64| (x / STICK_STEP).round() * STICK_STEP;
        let s = input.sticks;
        let report = RcReport {
            lost: false,
            kill: input.kill,
            sticks: [q(s.roll), q(s.pitch), q(s.yaw), q(s.throttle)],
            stick_mode: self.selected().and_then(RcMode::stick_mode),
        };
        let due = self
            .reported
            .is_none_or(|(r, at)| r != report || t_us - at >= self.report_period_us);
        if due {
            self.reported = Some((report, t_us));
            out.push(OperatorInput::Rc(report));
        }
        if let Some(last) = self.last
            && input.arm != last.arm
        {
            let arm = if input.arm {
                Command::Arm
            } else {
                Command::Disarm
            };
            out.push(OperatorInput::Command(arm, LinkSource::Rc));
        }
        if let Some(c) = moved_to {
            out.push(OperatorInput::Command(c, LinkSource::Rc));
        }
        self.last = Some(input);
        input.kill
    }

    /// The status a watcher reads, from a frame of the pilot's read as `input`.
    fn watched(&mut self, f: &RcFrame, input: &RcInput) {
        let old = self.status;
        let s = input.sticks;
        self.status = Some(RcStatus {
            channels_us: f.channels.map(crate::core::rc::ticks_to_us),
            sticks: [s.roll, s.pitch, s.yaw, s.throttle],
            arm: input.arm,
            kill: input.kill,
            mode: self.selected(),
            link_quality_pct: old.and_then(|o| o.link_quality_pct),
            rssi_dbm: old.and_then(|o| o.rssi_dbm),
            lost: false,
        });
    }

    /// What the mode switch's position acted on selects (none before it is read).
    fn selected(&self) -> Option<RcMode> {
        self.mode.and_then(|i| self.modes.get(i)).copied()
    }

    /// The mode switch read at `position`: a position held for [`MODE_FRAMES`] frames, not
    /// the one acted on, is its mode's command (the first one read, or after a loss, is where
    /// the switch is: not a move, though a stick mode's is reported).
    fn mode_switch(&mut self, position: usize) -> Option<Command> {
        let (seen, n) = self.mode_seen;
        self.mode_seen = if seen == position {
            (seen, n.saturating_add(1))
        } else {
            (position, 1)
        };
        if self.mode_seen.1 < MODE_FRAMES || self.mode == Some(position) {
            return None;
        }
        let first = self.mode.is_none();
        self.mode = Some(position);
        if first {
            return None;
        }
        self.modes.get(position).map(|m| m.command())
    }
}

/// The pilot's radio as a watcher reads it (RC_CHANNELS, the console's statistics line).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RcStatus {
    /// Channels 1–16 of the newest frame, µs.
    pub channels_us: [u16; crate::core::rc::CHANNELS],
    /// What they read as through the map: roll, pitch, yaw, throttle (each −1…1) and the
    /// switches; the mode switch's selection.
    pub sticks: [f64; 4],
    pub arm: bool,
    pub kill: bool,
    pub mode: Option<RcMode>,
    /// The receiver's link statistics (CRSF): packets received of the last 100, %, and the
    /// signal strength, dBm.
    pub link_quality_pct: Option<u8>,
    pub rssi_dbm: Option<i16>,
    /// The receiver says its transmitter is gone.
    pub lost: bool,
}

impl RcStatus {
    /// The console's words for it: ` rc=[ROLL,PITCH,YAW,THROTTLE] arm=on|off kill=on|off
    /// mode=NAME` and the link's `lq=PCT rssi=DBM` where the receiver measures them;
    /// ` rc=lost` once its receiver is in failsafe.
    pub fn words(&self) -> String {
        if self.lost {
            return " rc=lost".into();
        }
        let on = |b: bool| if b { "on" } else { "off" };
        let [r, p, y, t] = self.sticks;
        let mut s = format!(
            " rc=[{r:+.2},{p:+.2},{y:+.2},{t:+.2}] arm={} kill={} mode={}",
            on(self.arm),
            on(self.kill),
            self.mode.map_or("-", |m| m.name())
        );
        if let (Some(lq), Some(rssi)) = (self.link_quality_pct, self.rssi_dbm) {
            s += &format!(" lq={lq}% rssi={rssi}dBm");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::rc::sticks::{ChannelCal, Sticks};

    fn link() -> RcLink {
        let cal = |channel, deadband| ChannelCal {
            channel,
            min: 172,
            center: 992,
            max: 1811,
            reversed: false,
            deadband,
        };
        let map = RcMap {
            roll: cal(1, 0.05),
            pitch: cal(2, 0.05),
            throttle: cal(3, 0.05),
            yaw: cal(4, 0.05),
            arm: cal(5, 0.0),
            kill: cal(6, 0.0),
            mode: cal(7, 0.0),
            mode_positions: 3,
        };
        RcLink::new(map, vec![RcMode::Position, RcMode::Hold, RcMode::Land], 0.5)
    }

    fn frame(m: &RcMap, arm: bool, kill: bool, mode: usize, throttle: f64) -> RcFrame {
        let input = RcInput {
            sticks: Sticks {
                throttle,
                ..Sticks::default()
            },
            arm,
            kill,
            mode,
        };
        RcFrame {
            channels: m.frame_for(&input),
            frame_lost: false,
            failsafe: false,
        }
    }

    fn commands(out: &[OperatorInput]) -> Vec<String> {
        out.iter()
            .filter_map(|i| match i {
                OperatorInput::Command(c, LinkSource::Rc) => Some(c.to_string()),
                _ => None,
            })
            .collect()
    }

    /// Feeds `n` frames 10 ms apart from `t_us`; the time after them.
    fn feed(l: &mut RcLink, f: &RcFrame, t_us: i64, n: i64, out: &mut Vec<OperatorInput>) -> i64 {
        for k in 0..n {
            l.frame(f, t_us + k * 10_000, out);
        }
        t_us + n * 10_000
    }

    #[test]
    fn switches_move_the_commander_and_reports_keep_the_receiver_heard() {
        let mut l = link();
        let m = l.map().clone();
        let mut out = Vec::new();
        // On at the start: not a move; the mode switch where it is: not a move either.
        assert!(!l.frame(&frame(&m, true, false, 1, -1.0), 0, &mut out));
        assert_eq!(out.len(), 1, "the first report");
        let t = feed(
            &mut l,
            &frame(&m, true, false, 1, -1.0),
            10_000,
            3,
            &mut out,
        );
        assert_eq!(out.len(), 1, "nothing changed, a report is not due");
        let t = feed(&mut l, &frame(&m, false, false, 1, -1.0), t, 1, &mut out);
        let t = feed(&mut l, &frame(&m, true, false, 1, -1.0), t, 1, &mut out);
        // The mode switch: land held three frames; a pass through position (two frames) is
        // not a choice.
        let t = feed(&mut l, &frame(&m, true, false, 2, -1.0), t, 3, &mut out);
        let t = feed(&mut l, &frame(&m, true, false, 0, -1.0), t, 2, &mut out);
        let t = feed(&mut l, &frame(&m, true, false, 1, -1.0), t, 3, &mut out);
        assert_eq!(commands(&out), ["disarm", "arm", "land", "hold"]);
        out.clear();
        let t = feed(
            &mut l,
            &frame(&m, true, false, 1, -1.0),
            t + 200_000,
            1,
            &mut out,
        );
        assert_eq!(out.len(), 1, "a report every 0.2 s");
        out.clear();
        l.frame(&frame(&m, true, false, 1, 0.5), t, &mut out);
        let OperatorInput::Rc(r) = out[0] else {
            panic!("{out:?}")
        };
        assert_eq!((r.kill, r.sticks[3]), (false, 0.5), "the throttle as sent");
        // The kill switch is a level: every frame with it on stops the motors.
        assert!(l.frame(&frame(&m, true, true, 1, 0.5), t + 10_000, &mut out));
        assert!(l.frame(&frame(&m, true, true, 1, 0.5), t + 20_000, &mut out));
        assert!(!l.frame(&frame(&m, true, false, 1, 0.5), t + 30_000, &mut out));
    }

    #[test]
    fn the_receivers_failsafe_is_a_loss_and_the_switches_start_afresh_after_it() {
        let mut l = link();
        let m = l.map().clone();
        let mut out = Vec::new();
        l.frame(&frame(&m, false, false, 1, -1.0), 0, &mut out);
        let mut lost = frame(&m, false, false, 1, -1.0);
        lost.failsafe = true;
        l.frame(&lost, 10_000, &mut out);
        l.frame(&lost, 20_000, &mut out);
        let losses = |out: &[OperatorInput]| {
            out.iter()
                .filter(|i| matches!(i, OperatorInput::Rc(r) if r.lost))
                .count()
        };
        assert_eq!(losses(&out), 1);
        out.clear();
        // Back with the arm switch on: not an arm.
        l.frame(&frame(&m, true, false, 1, -1.0), 30_000, &mut out);
        assert_eq!(commands(&out), Vec::<String>::new());
        assert!(matches!(out[0], OperatorInput::Rc(r) if !r.lost));
        // A frame the receiver marks lost is no frame: no report, no move.
        out.clear();
        let mut dropped = frame(&m, false, false, 1, -1.0);
        dropped.frame_lost = true;
        l.frame(&dropped, 40_000, &mut out);
        assert!(out.is_empty());
        // A CRSF receiver that holds its channels: link quality 0 is the loss, and its
        // channels are not the pilot's until the link is back.
        let down = crate::core::rc::LinkStats {
            rssi_dbm: -120,
            link_quality_pct: 0,
            snr_db: -20,
        };
        l.link(&down, &mut out);
        assert_eq!(losses(&out), 1);
        assert!(!l.frame(&frame(&m, true, true, 1, -1.0), 50_000, &mut out));
        assert_eq!(out.len(), 1, "held channels are not read");
        l.link(
            &crate::core::rc::LinkStats {
                link_quality_pct: 90,
                ..down
            },
            &mut out,
        );
        l.frame(&frame(&m, true, false, 1, -1.0), 60_000, &mut out);
        assert!(matches!(out.last(), Some(OperatorInput::Rc(r)) if !r.lost));
    }

    #[test]
    fn the_console_says_the_sticks_switches_and_link() {
        let mut rc = RcStatus {
            channels_us: [1500; crate::core::rc::CHANNELS],
            sticks: [0.0, 0.5, -0.25, -1.0],
            arm: true,
            kill: false,
            mode: Some(RcMode::Position),
            link_quality_pct: Some(98),
            rssi_dbm: Some(-61),
            lost: false,
        };
        assert_eq!(
            rc.words(),
            " rc=[+0.00,+0.50,-0.25,-1.00] arm=on kill=off mode=position lq=98% rssi=-61dBm"
        );
        rc.lost = true;
        assert_eq!(rc.words(), " rc=lost");
    }
}

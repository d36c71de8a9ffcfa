//! The protocol's rules on simulated time: a ground station (system 255) and strangers write
//! frames, the test plays the owner (the flight's queue, the files) and reads what comes out.

use super::*;
use crate::config::Config;
use crate::core::commander::Action;
use crate::core::mission::MissionPlan;
use crate::core::status::Live;
use crate::core::watchdog::TripReason;
use crate::gcs::wire::Decoder;

const GCS: (u8, u8) = (255, 190);
const OTHER_GCS: (u8, u8) = (254, 190);

/// The protocol, a simulated clock, and what came out of it.
struct Bench {
    conn: Connection,
    now: Instant,
    encoders: Vec<((u8, u8), Encoder)>,
}

fn settings(boot: Instant) -> Settings {
    let config = Config::default();
    Settings {
        cfg: config.gcs.clone(),
        params: Params::of(&config),
        boot,
        signing: None,
        gps_timeout_us: 1_000_000,
        datagrams: true,
        params_per_pace: 10,
        missions: Some(MissionSettings {
            speed_m_s: 1.0,
            hover_z_m: 1.0,
            loaded_items: None,
        }),
        takeoff_heights_m: (0.2, 3.0),
    }
}

impl Bench {
    fn new() -> Bench {
        Bench::with(|_| {})
    }

    fn with(change: impl FnOnce(&mut Settings)) -> Bench {
        let now = Instant::now();
        let mut s = settings(now);
        change(&mut s);
        Bench {
            conn: Connection::new(s, now),
            now,
            encoders: Vec::new(),
        }
    }

    /// `msg` from `from`, as one datagram.
    fn hear(&mut self, from: (u8, u8), msg: MavMessage) -> bool {
        let bytes = self.frame(from, &msg);
        self.conn.handle_datagram(self.now, &bytes)
    }

    fn frame(&mut self, from: (u8, u8), msg: &MavMessage) -> Vec<u8> {
        let i = match self.encoders.iter().position(|(f, _)| *f == from) {
            Some(i) => i,
            None => {
                self.encoders.push((from, Encoder::new(from.0, from.1)));
                self.encoders.len() - 1
            }
        };
        let mut out = Vec::new();
        self.encoders[i].1.encode_at(msg, &mut out, 0);
        out
    }

    fn beat(&mut self, from: (u8, u8)) {
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_GCS,
            ..HEARTBEAT_DATA::DEFAULT
        });
        self.hear(from, hb);
    }

    /// Moves the clock on by `ms`, calling the timer each time it is due on the way.
    fn pass_ms(&mut self, ms: u64) {
        let end = self.now + Duration::from_millis(ms);
        while let Some(due) = self.conn.poll_timeout().filter(|d| *d <= end) {
            self.now = self.now.max(due);
            self.conn.handle_timeout(self.now);
        }
        self.now = end;
    }

    /// Every frame sent so far, decoded.
    fn sent(&mut self) -> Vec<MavMessage> {
        let mut out = Vec::new();
        while let Some(f) = self.conn.poll_transmit() {
            let mut d = Decoder::for_datagrams();
            d.push(&f);
            out.extend(std::iter::from_fn(|| d.next_message()).map(|r| r.msg));
        }
        out
    }

    /// The texts, long ones put together from their 50-byte chunks (one id, the last chunk
    /// shorter), as a ground station shows them.
    fn texts(msgs: &[MavMessage]) -> Vec<String> {
        let (mut texts, mut open) = (Vec::new(), String::new());
        for m in msgs {
            let MavMessage::STATUSTEXT(t) = m else {
                continue;
            };
            let chunk = t.text.to_str().unwrap_or("");
            open.push_str(chunk);
            if t.id == 0 || chunk.len() < 50 {
                texts.push(std::mem::take(&mut open));
            }
        }
        texts
    }

    fn operator(&mut self) -> Vec<OperatorInput> {
        std::iter::from_fn(|| self.conn.poll_operator()).collect()
    }

    fn effects(&mut self) -> Vec<Effect> {
        std::iter::from_fn(|| self.conn.poll_effect()).collect()
    }

    /// The vehicle flying in `mode`.
    fn status(&mut self, mode: Mode) {
        let live = Live {
            step: 1,
            x: [0.0; 15],
            w_rad_s: [0.0; 4],
            setpoint_m: [0.0; 3],
            mode,
            height_m: 1.0,
            flying_steps: 0,
            ratios: Default::default(),
            home_m: None,
            mission_item: None,
        };
        let status = VehicleStatus {
            mode,
            live: Some(live),
            escs_answering: true,
            ..VehicleStatus::default()
        };
        self.conn.handle_status(self.now, status);
    }
}

/// COMMAND_LONG `cmd` to this vehicle with params 1 to 7.
fn command_long(cmd: MavCmd, p: [f32; 7]) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        target_system: 1,
        target_component: 1,
        command: cmd,
        param1: p[0],
        param2: p[1],
        param3: p[2],
        param4: p[3],
        param5: p[4],
        param6: p[5],
        param7: p[6],
        ..COMMAND_LONG_DATA::DEFAULT
    })
}

fn command(cmd: MavCmd, p1: f32) -> MavMessage {
    command_long(cmd, [p1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
}

/// A fresh 3-D fix at `alt_m` above sea level, at `local_m` in the local frame.
fn fix_at(alt_m: f64, local_m: [f64; 3], stamp_us: i64) -> crate::core::gps::LiveFix {
    use crate::core::gps::{Fix, GpsSample, LiveFix};
    LiveFix {
        seq: 1,
        fix: Fix {
            mode: 3,
            lat_deg: -34.9,
            lon_deg: -56.16,
            alt_m: Some(alt_m),
            eph_m: Some(1.0),
        },
        sample: GpsSample::at(local_m),
        stamp_us,
    }
}

fn acks(msgs: &[MavMessage]) -> Vec<(MavCmd, MavResult)> {
    msgs.iter()
        .filter_map(|m| match m {
            MavMessage::COMMAND_ACK(a) => Some((a.command, a.result)),
            _ => None,
        })
        .collect()
}

const ARM: MavCmd = MavCmd::MAV_CMD_COMPONENT_ARM_DISARM;

#[test]
fn a_command_is_acknowledged_by_the_flights_outcome_or_its_silence() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.hear(GCS, command(ARM, 1.0));
    assert_eq!(
        b.operator(),
        [
            OperatorInput::Beat(LinkSource::Gcs),
            OperatorInput::Command(Command::Arm, LinkSource::Gcs)
        ]
    );
    // No answer until the flight has taken it.
    assert!(acks(&b.sent()).is_empty());
    b.conn.handle_notice(
        b.now,
        Notice::Outcome {
            command: Command::Arm,
            source: LinkSource::Gcs,
            refused: None,
        },
    );
    assert_eq!(acks(&b.sent()), [(ARM, MavResult::MAV_RESULT_ACCEPTED)]);
    // One the flight never answers: FAILED after 5 s, not before.
    b.hear(GCS, command(ARM, 0.0));
    b.pass_ms(4_900);
    assert!(acks(&b.sent()).is_empty());
    b.pass_ms(200);
    let out = b.sent();
    assert_eq!(acks(&out), [(ARM, MavResult::MAV_RESULT_FAILED)]);
    assert_eq!(Bench::texts(&out), ["disarm: no answer from the flight"]);
}

#[test]
fn a_full_operator_queue_refuses_the_command_at_once() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.operator();
    b.hear(GCS, command(ARM, 1.0));
    let input = b.conn.poll_operator().unwrap();
    b.conn.handle_operator_full(b.now, input);
    let out = b.sent();
    assert_eq!(
        acks(&out),
        [(ARM, MavResult::MAV_RESULT_TEMPORARILY_REJECTED)]
    );
    assert_eq!(
        Bench::texts(&out),
        ["arm refused: the flight is not taking commands now"]
    );
    assert_eq!(b.conn.counts().input_drops, 1);
    // Nothing waits for it: no FAILED later.
    b.pass_ms(6_000);
    assert!(acks(&b.sent()).is_empty());
}

#[test]
fn a_flood_is_cut_at_the_seconds_budget_but_heartbeats_always_count() {
    let mut b = Bench::new();
    b.beat(GCS);
    let read = MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
        target_system: 1,
        target_component: 1,
        param_index: 0,
        ..PARAM_REQUEST_READ_DATA::DEFAULT
    });
    // 200 frames a second (gcs.max_rx_per_s) pass; heartbeats are not counted against it.
    for _ in 0..250 {
        b.hear(GCS, read.clone());
    }
    let values = |out: &[MavMessage]| {
        out.iter()
            .filter(|m| matches!(m, MavMessage::PARAM_VALUE(_)))
            .count()
    };
    assert_eq!(values(&b.sent()), 200);
    assert_eq!(b.conn.counts().flood_drops, 50);
    // A heartbeat in the flood still reaches the flight.
    b.operator();
    b.pass_ms(600);
    b.sent();
    b.beat(GCS);
    assert_eq!(b.operator(), [OperatorInput::Beat(LinkSource::Gcs)]);
    // The next second has its own budget.
    b.pass_ms(500);
    b.sent();
    b.hear(GCS, read);
    assert_eq!(values(&b.sent()), 1);
}

#[test]
fn commands_over_twenty_a_second_are_refused() {
    let mut b = Bench::new();
    b.beat(GCS);
    for _ in 0..21 {
        b.hear(GCS, command(MavCmd::MAV_CMD_NAV_LAND, 0.0));
    }
    let out = b.sent();
    assert_eq!(
        acks(&out),
        [(
            MavCmd::MAV_CMD_NAV_LAND,
            MavResult::MAV_RESULT_TEMPORARILY_REJECTED
        )]
    );
    assert_eq!(
        Bench::texts(&out),
        ["land refused: more than 20 commands a second"]
    );
    assert_eq!(b.operator().len(), 21, "the beat and 20 commands");
}

fn param_set(id: &str, value: f32) -> MavMessage {
    MavMessage::PARAM_SET(PARAM_SET_DATA {
        target_system: 1,
        target_component: 1,
        param_id: id.into(),
        param_value: value,
        param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
    })
}

fn param_values(out: &[MavMessage]) -> Vec<(String, f32)> {
    out.iter()
        .filter_map(|m| match m {
            MavMessage::PARAM_VALUE(p) => {
                Some((p.param_id.to_str().unwrap_or("").into(), p.param_value))
            }
            _ => None,
        })
        .collect()
}

#[test]
fn a_parameter_set_is_kept_by_the_owner_or_refused_with_the_old_value() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.hear(GCS, param_set("CMD_CLIMB_M_S", 0.4));
    // Nothing answered until the value is kept.
    assert!(param_values(&b.sent()).is_empty());
    let Some(Effect::KeepParam {
        index,
        param,
        value,
        ..
    }) = b.effects().pop()
    else {
        panic!("no parameter to keep");
    };
    assert_eq!(
        (param.key, value.clone()),
        ("commander.climb_m_s", toml::Value::Float(0.4))
    );
    b.conn.handle_param_kept(b.now, index, &value, Ok(()));
    assert_eq!(param_values(&b.sent()), [("CMD_CLIMB_M_S".into(), 0.4)]);
    assert_eq!(b.conn.counts().param_sets, 1);

    // Refused by the files' rules: the old value comes back, and why.
    b.hear(GCS, param_set("WD_MISSED_ACKS", 50.0));
    let Some(Effect::KeepParam { index, value, .. }) = b.effects().pop() else {
        panic!("no parameter to keep");
    };
    let why = "watchdog.max_missed_acks: 50 is out of range".to_string();
    b.conn.handle_param_kept(b.now, index, &value, Err(why));
    let out = b.sent();
    assert_eq!(param_values(&out), [("WD_MISSED_ACKS".into(), 3.0)]);
    assert_eq!(
        Bench::texts(&out),
        ["parameter WD_MISSED_ACKS not set: watchdog.max_missed_acks: 50 is out of range"]
    );

    // Refused by the link's own rule while flying: no file is touched.
    b.status(Mode::Hold);
    b.sent();
    b.hear(GCS, param_set("CMD_CRASH_TILT", 0.9));
    assert!(b.effects().is_empty());
    let out = b.sent();
    let values = param_values(&out);
    assert!(
        values.len() == 1 && values[0].0 == "CMD_CRASH_TILT" && values[0].1 != 0.9,
        "{values:?}"
    );
    assert_eq!(
        Bench::texts(&out),
        [
            "parameter CMD_CRASH_TILT not set: commander.crash_tilt_rad: flight-critical, refused while hold"
        ]
    );

    // A key that takes effect in flight: kept, then handed to the flight as an input.
    b.hear(GCS, param_set("CMD_LAND_M_S", 0.3));
    let effects = b.effects();
    let [Effect::KeepParam { index, value, .. }] = &effects[..] else {
        panic!("{effects:?}");
    };
    b.conn.handle_param_kept(b.now, *index, value, Ok(()));
    // (The earlier set of CMD_CLIMB_M_S, disarmed, went to the flight too.)
    let inputs = b.operator();
    let param = inputs.last();
    assert!(
        matches!(param, Some(OperatorInput::Param { key: "commander.land_m_s", value }) if (value - 0.3).abs() < 1e-9),
        "{inputs:?}"
    );
    assert_eq!(param_values(&b.sent()), [("CMD_LAND_M_S".into(), 0.3)]);
}

#[test]
fn parameter_sets_over_five_a_second_and_from_strangers_are_refused() {
    let mut b = Bench::new();
    // A sender that never said it is a ground station: denied, nothing kept, no answer;
    // err.log told (once in a hundred).
    b.hear((7, 1), param_set("CMD_CLIMB_M_S", 0.4));
    assert!(matches!(&b.effects()[..], [Effect::ErrLog(l)] if l.contains("may not command")));
    assert!(b.sent().is_empty());
    assert_eq!(b.conn.counts().senders_denied, 1);
    b.beat(GCS);
    for i in 0..6 {
        b.hear(GCS, param_set("CMD_CLIMB_M_S", 0.11 + 0.1 * i as f32));
    }
    let keeps = b
        .effects()
        .into_iter()
        .filter(|e| matches!(e, Effect::KeepParam { .. }))
        .count();
    assert_eq!(keeps, 5);
    let texts = Bench::texts(&b.sent());
    assert_eq!(
        texts,
        ["parameter CMD_CLIMB_M_S not set: more than 5 parameter sets a second"]
    );
}

#[test]
fn a_parameter_list_is_paced() {
    let mut b = Bench::new();
    let n = b.conn.s.params.len();
    b.hear(
        GCS,
        MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        }),
    );
    b.pass_ms(1);
    assert_eq!(param_values(&b.sent()).len(), 10);
    b.pass_ms(20);
    assert_eq!(param_values(&b.sent()).len(), 10);
    b.pass_ms(20 * n as u64);
    let rest = param_values(&b.sent()).len();
    assert_eq!(rest, n - 20);
}

fn mission_count(count: u16) -> MavMessage {
    MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
        target_system: 1,
        target_component: 1,
        count,
        mission_type: MavMissionType::MAV_MISSION_TYPE_MISSION,
        opaque_id: 0,
    })
}

fn item(seq: u16) -> MavMessage {
    let (command, frame, z) = match seq {
        0 => (
            MavCmd::MAV_CMD_NAV_TAKEOFF,
            MavFrame::MAV_FRAME_LOCAL_NED,
            -1.5,
        ),
        1 => (
            MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH,
            MavFrame::MAV_FRAME_MISSION,
            0.0,
        ),
        _ => (MavCmd::MAV_CMD_NAV_LAND, MavFrame::MAV_FRAME_MISSION, 0.0),
    };
    MavMessage::MISSION_ITEM_INT(MISSION_ITEM_INT_DATA {
        target_system: 1,
        target_component: 1,
        seq,
        frame,
        command,
        autocontinue: 1,
        z,
        mission_type: MavMissionType::MAV_MISSION_TYPE_MISSION,
        ..MISSION_ITEM_INT_DATA::DEFAULT
    })
}

/// The MISSION_REQUEST_INTs' sequence numbers, and the MISSION_ACKs' results.
fn mission_answers(out: &[MavMessage]) -> (Vec<u16>, Vec<MavMissionResult>) {
    let asked = out
        .iter()
        .filter_map(|m| match m {
            MavMessage::MISSION_REQUEST_INT(r) => Some(r.seq),
            _ => None,
        })
        .collect();
    let acked = out
        .iter()
        .filter_map(|m| match m {
            MavMessage::MISSION_ACK(a) => Some(a.mavtype),
            _ => None,
        })
        .collect();
    (asked, acked)
}

#[test]
fn an_upload_with_lost_and_repeated_items_completes_and_is_flown() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.operator();
    b.hear(GCS, mission_count(3));
    b.hear(GCS, item(0));
    assert_eq!(mission_answers(&b.sent()).0, [0, 1]);
    // Item 1 is lost: asked again after a second, not before.
    b.pass_ms(900);
    assert_eq!(mission_answers(&b.sent()).0, Vec::<u16>::new());
    b.pass_ms(200);
    assert_eq!(mission_answers(&b.sent()).0, [1]);
    // A repeat of item 0 is ignored; item 2 ahead of 1 asks for 1 again.
    b.hear(GCS, item(0));
    assert!(b.sent().is_empty());
    b.hear(GCS, item(2));
    assert_eq!(mission_answers(&b.sent()).0, [1]);
    b.hear(GCS, item(1));
    b.hear(GCS, item(2));
    let Some(Effect::PlanMission { name, text }) = b.effects().pop() else {
        panic!("the upload was not planned");
    };
    assert_eq!(name, "mission-1.toml");
    assert!(
        text.contains("kind = \"takeoff\"") && text.contains("kind = \"land\""),
        "{text}"
    );
    // Planned: to the flight; the commander's verdict answers the ground station.
    assert!(mission_answers(&b.sent()).1.is_empty());
    b.conn.handle_plan(b.now, &name, Ok(MissionPlan::default()));
    assert!(matches!(b.operator()[..], [OperatorInput::Mission(_)]));
    let verdict = Notice::Mission {
        name: name.clone(),
        refused: None,
    };
    b.conn.handle_notice(b.now, verdict);
    assert_eq!(
        mission_answers(&b.sent()).1,
        [MavMissionResult::MAV_MISSION_ACCEPTED]
    );
    // Downloaded back as uploaded.
    let request = |seq| {
        MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
            target_system: 1,
            target_component: 1,
            seq,
            mission_type: MavMissionType::MAV_MISSION_TYPE_MISSION,
        })
    };
    b.hear(GCS, request(1));
    let back: Vec<MavCmd> = b
        .sent()
        .iter()
        .filter_map(|m| match m {
            MavMessage::MISSION_ITEM_INT(i) => Some(i.command),
            _ => None,
        })
        .collect();
    assert_eq!(back, [MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH]);
}

#[test]
fn an_upload_whose_items_stop_coming_is_cancelled_after_five_asks() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.hear(GCS, mission_count(2));
    b.hear(GCS, item(0));
    b.pass_ms(4_500);
    let (asked, acked) = mission_answers(&b.sent());
    assert_eq!(asked, [0, 1, 1, 1, 1, 1]);
    assert!(acked.is_empty());
    b.pass_ms(1_000);
    let out = b.sent();
    assert_eq!(
        mission_answers(&out).1,
        [MavMissionResult::MAV_MISSION_OPERATION_CANCELLED]
    );
    assert_eq!(
        Bench::texts(&out),
        ["mission upload: item 1 did not come: cancelled"]
    );
    assert!(matches!(&b.effects()[..], [Effect::ErrLog(l)] if l.contains("cancelled")));
}

#[test]
fn a_plan_refused_or_never_answered_fails_the_upload() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.hear(GCS, mission_count(1));
    b.hear(GCS, item(0));
    let name = match b.effects().pop() {
        Some(Effect::PlanMission { name, .. }) => name,
        e => panic!("{e:?}"),
    };
    b.sent();
    b.conn
        .handle_plan(b.now, &name, Err("mission-1.toml: too high".into()));
    let out = b.sent();
    assert_eq!(
        mission_answers(&out).1,
        [MavMissionResult::MAV_MISSION_DENIED]
    );
    assert_eq!(Bench::texts(&out), ["mission-1.toml: too high"]);
    // A second upload whose plan never comes: ERROR after 10 s, and the next is taken.
    b.hear(GCS, mission_count(1));
    b.hear(GCS, item(0));
    b.sent();
    b.pass_ms(10_100);
    assert_eq!(
        mission_answers(&b.sent()).1,
        [MavMissionResult::MAV_MISSION_ERROR]
    );
    b.hear(GCS, mission_count(1));
    assert_eq!(mission_answers(&b.sent()).0, [0]);
}

#[test]
fn a_second_ground_station_may_command_but_not_cut_into_an_upload() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.beat(OTHER_GCS);
    b.hear(GCS, mission_count(2));
    b.sent();
    b.hear(OTHER_GCS, mission_count(1));
    let out = b.sent();
    assert_eq!(
        mission_answers(&out).1,
        [MavMissionResult::MAV_MISSION_DENIED]
    );
    assert_eq!(
        Bench::texts(&out),
        ["mission upload: another ground station is uploading"]
    );
    // Its items do not enter the first one's upload.
    b.hear(OTHER_GCS, item(0));
    assert!(b.sent().is_empty());
    // Its commands are taken.
    b.operator();
    b.hear(OTHER_GCS, command(MavCmd::MAV_CMD_NAV_LAND, 0.0));
    assert_eq!(
        b.operator(),
        [OperatorInput::Command(Command::Land, LinkSource::Gcs)]
    );
}

#[test]
fn allowed_systems_limit_who_commands() {
    let mut b = Bench::with(|s| s.cfg.allowed_systems = vec![255]);
    b.beat(GCS);
    b.beat(OTHER_GCS);
    b.operator();
    b.hear(OTHER_GCS, command(ARM, 1.0));
    assert!(b.operator().is_empty());
    assert_eq!(acks(&b.sent()), [(ARM, MavResult::MAV_RESULT_DENIED)]);
    assert_eq!(b.conn.counts().senders_denied, 1);
    // A read is anyone's.
    let version = command(MavCmd::MAV_CMD_REQUEST_MESSAGE, 148.0);
    b.hear(OTHER_GCS, version);
    let out = b.sent();
    assert!(
        out.iter()
            .any(|m| matches!(m, MavMessage::AUTOPILOT_VERSION(_)))
    );
}

#[test]
fn a_mode_change_is_told_at_once_and_a_halt_once() {
    let mut b = Bench::new();
    b.pass_ms(1);
    b.sent();
    b.status(Mode::Armed);
    let out = b.sent();
    let modes: Vec<(u32, bool)> = out
        .iter()
        .filter_map(|m| match m {
            MavMessage::HEARTBEAT(h) => Some((
                h.custom_mode,
                h.base_mode
                    .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
            )),
            _ => None,
        })
        .collect();
    // Armed on the ground: PX4's hold with the armed flag.
    assert_eq!(modes, [(crate::gcs::modes::custom_mode(Mode::Armed), true)]);
    assert!(out.iter().any(|m| matches!(m, MavMessage::CURRENT_MODE(_))));
    assert!(
        out.iter()
            .any(|m| matches!(m, MavMessage::EXTENDED_SYS_STATE(_)))
    );
    // The same mode again: nothing new.
    b.status(Mode::Armed);
    assert!(b.sent().is_empty());
    let halted = VehicleStatus {
        halt: Some(TripReason::ImuTimeout),
        ..VehicleStatus::default()
    };
    b.conn.handle_status(b.now, halted.clone());
    b.pass_ms(1_000);
    b.conn.handle_status(b.now, halted);
    b.pass_ms(3_000);
    let texts = Bench::texts(&b.sent());
    assert_eq!(texts, ["halt imu-timeout: motors stopped"]);
}

#[test]
fn a_failsafe_is_told_critical_and_a_breach_marks_the_fence_unhealthy() {
    let mut b = Bench::new();
    let e = Event::Failsafe {
        t_us: 0,
        kind: Failsafe::Geofence,
        action: Action::Return,
    };
    b.conn.handle_notice(b.now, Notice::Event(e));
    let out = b.sent();
    let severities: Vec<MavSeverity> = out
        .iter()
        .filter_map(|m| match m {
            MavMessage::STATUSTEXT(t) => Some(t.severity),
            _ => None,
        })
        .collect();
    assert_eq!(severities, [MavSeverity::MAV_SEVERITY_CRITICAL]);
    assert!(!b.conn.streams.health.fence);
}

#[test]
fn the_next_timeout_is_the_earliest_thing_due() {
    let mut b = Bench::new();
    // At start everything periodic is due.
    assert!(b.conn.poll_timeout().is_some_and(|t| t <= b.now));
    b.pass_ms(1);
    // Then the fastest stream: 10 Hz telemetry.
    let next = b.conn.poll_timeout().unwrap();
    assert!(
        next > b.now && next <= b.now + Duration::from_millis(100),
        "{next:?}"
    );
}

#[test]
fn the_commanders_mode_is_told_when_no_step_follows_it() {
    // Armed, the ESCs' ramp and the calibration running: no control step yet.
    let mut b = Bench::new();
    b.beat(GCS);
    b.pass_ms(1);
    b.sent();
    let armed = VehicleStatus {
        mode: Mode::Armed,
        ..VehicleStatus::default()
    };
    b.conn.handle_status(b.now, armed.clone());
    let out = b.sent();
    let armed_bit = MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    let armed_mode = crate::gcs::modes::custom_mode(Mode::Armed);
    let told = out.iter().any(|m| {
        matches!(m, MavMessage::HEARTBEAT(h) if h.custom_mode == armed_mode && h.base_mode.contains(armed_bit))
    });
    assert!(told, "{out:?}");
    // A flight-critical parameter is not changed while armed, step or no step.
    b.hear(GCS, param_set("CMD_CRASH_TILT", 0.9));
    assert!(b.effects().is_empty());
    // A halt's kill after the last step: the last heartbeat says so.
    let killed = VehicleStatus {
        mode: Mode::Kill,
        halt: Some(TripReason::ImuTimeout),
        ..armed
    };
    b.conn.handle_status(b.now, killed);
    b.conn.handle_end(b.now);
    let out = b.sent();
    let last = out.iter().rev().find_map(|m| match m {
        MavMessage::HEARTBEAT(h) => Some((h.custom_mode, h.system_status)),
        _ => None,
    });
    let kill = crate::gcs::modes::custom_mode(Mode::Kill);
    assert_eq!(
        last,
        Some((kill, MavState::MAV_STATE_FLIGHT_TERMINATION)),
        "{out:?}"
    );
    assert!(Bench::texts(&out).contains(&"halt imu-timeout: motors stopped".to_string()));
}

#[test]
fn a_late_timer_does_not_send_a_periodic_message_twice() {
    let mut b = Bench::new();
    b.pass_ms(1);
    b.sent();
    // Called 350 ms late: each message once, then not again until a whole interval later.
    b.now += Duration::from_millis(350);
    b.conn.handle_timeout(b.now);
    let count = |out: &[MavMessage]| {
        out.iter()
            .filter(|m| matches!(m, MavMessage::ATTITUDE(_) | MavMessage::HEARTBEAT(_)))
            .count()
    };
    let first = b.sent();
    b.conn.handle_timeout(b.now);
    assert_eq!(count(&b.sent()), 0, "{first:?}");
    assert!(b.conn.poll_timeout().is_some_and(|t| t > b.now));
}

#[test]
fn before_the_estimate_a_fix_gives_the_home_and_the_position_and_the_prearm_bit_is_told() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.pass_ms(1);
    b.sent();
    let fix = fix_at(40.0, [2.0, 1.0, 0.5], 1_000);
    let status = VehicleStatus {
        fix: Some(fix),
        gps_used: true,
        prearm_ok: Some(false),
        imu_frames: 100,
        ..VehicleStatus::default()
    };
    b.conn.handle_status(b.now, status.clone());
    b.pass_ms(1_100);
    let out = b.sent();
    let position = out.iter().find_map(|m| match m {
        MavMessage::GLOBAL_POSITION_INT(p) => Some(p.clone()),
        _ => None,
    });
    let p = position.expect("GLOBAL_POSITION_INT from the fix");
    assert_eq!(
        (p.lat, p.lon, p.alt, p.relative_alt),
        (-349_000_000, -561_600_000, 40_000, 0)
    );
    let prearm = MavSysStatusSensor::MAV_SYS_STATUS_PREARM_CHECK;
    let bit = |out: &[MavMessage]| {
        out.iter().find_map(|m| match m {
            MavMessage::SYS_STATUS(s) => Some((
                s.onboard_control_sensors_present.contains(prearm),
                s.onboard_control_sensors_health.contains(prearm),
            )),
            _ => None,
        })
    };
    assert_eq!(bit(&out), Some((true, false)));
    // HOME_POSITION on request, from where the vehicle stands.
    b.hear(GCS, command(MavCmd::MAV_CMD_REQUEST_MESSAGE, 242.0));
    let out = b.sent();
    assert_eq!(
        acks(&out),
        [(
            MavCmd::MAV_CMD_REQUEST_MESSAGE,
            MavResult::MAV_RESULT_ACCEPTED
        )]
    );
    let home = out.iter().find_map(|m| match m {
        MavMessage::HOME_POSITION(h) => Some((h.latitude, h.altitude, h.x, h.y)),
        _ => None,
    });
    assert_eq!(home, Some((-349_000_000, 40_000, 2.0, -1.0)));
    // The checks pass: the bit is healthy.
    let passing = VehicleStatus {
        prearm_ok: Some(true),
        imu_frames: 200,
        ..status.clone()
    };
    b.conn.handle_status(b.now, passing.clone());
    b.pass_ms(1_000);
    assert_eq!(bit(&b.sent()), Some((true, true)));
    // No frames since: the check's last word is stale, and not told as healthy.
    b.conn.handle_status(b.now, passing);
    b.pass_ms(1_000);
    assert_eq!(bit(&b.sent()), Some((true, false)));
}

/// A vehicle standing still at `alt_m` above sea level, by a fresh 3-D fix.
fn standing_at(b: &mut Bench, alt_m: f64) {
    let stamp_us = b.now.saturating_duration_since(b.conn.s.boot).as_micros() as i64;
    let fix = fix_at(alt_m, [0.0; 3], stamp_us);
    let status = VehicleStatus {
        fix: Some(fix),
        gps_used: true,
        ..VehicleStatus::default()
    };
    b.conn.handle_status(b.now, status);
}

fn takeoff_to(p7: f32) -> MavMessage {
    command_long(
        MavCmd::MAV_CMD_NAV_TAKEOFF,
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, p7],
    )
}

#[test]
fn a_takeoff_altitude_above_sea_level_is_read_as_the_height_it_means() {
    let mut b = Bench::new();
    b.beat(GCS);
    standing_at(&mut b, 40.0);
    b.operator();
    // PX4's clients: the ground's altitude plus the height; ArduPilot's: the height.
    b.hear(GCS, takeoff_to(42.5));
    b.hear(GCS, takeoff_to(1.5));
    assert_eq!(
        b.operator(),
        [
            OperatorInput::Command(Command::Takeoff(Some(2.5)), LinkSource::Gcs),
            OperatorInput::Command(Command::Takeoff(Some(1.5)), LinkSource::Gcs)
        ]
    );
    // Near sea level both readings are heights: refused, not guessed.
    let mut b = Bench::new();
    b.beat(GCS);
    standing_at(&mut b, 1.0);
    b.operator();
    b.sent();
    b.hear(GCS, takeoff_to(2.5));
    assert!(b.operator().is_empty());
    let out = b.sent();
    assert_eq!(
        acks(&out),
        [(MavCmd::MAV_CMD_NAV_TAKEOFF, MavResult::MAV_RESULT_DENIED)]
    );
    assert!(Bench::texts(&out)[0].contains("above sea level"), "{out:?}");
}

#[test]
fn hold_asked_as_a_mode_pauses_a_mission_and_the_mission_mode_resumes_it() {
    let mut b = Bench::with(|s| {
        if let Some(m) = s.missions.as_mut() {
            m.loaded_items = Some(3);
        }
    });
    b.beat(GCS);
    b.status(Mode::Mission);
    b.operator();
    b.hear(GCS, set_mode([1.0, 4.0, 3.0]));
    assert_eq!(
        b.operator(),
        [OperatorInput::Command(Command::Pause, LinkSource::Gcs)]
    );
    // Paused at item 1, holding: the Mission mode resumes it.
    let mut live = b.conn.status.live.unwrap();
    live.mode = Mode::Hold;
    live.mission_item = Some(1);
    let paused = VehicleStatus {
        mode: Mode::Hold,
        live: Some(live),
        ..b.conn.status.clone()
    };
    b.conn.handle_status(b.now, paused);
    b.hear(GCS, set_mode([1.0, 4.0, 4.0]));
    assert_eq!(
        b.operator(),
        [OperatorInput::Command(Command::Resume, LinkSource::Gcs)]
    );
}

/// DO_SET_MODE with base mode, main mode and sub mode.
fn set_mode(p: [f32; 3]) -> MavMessage {
    command_long(
        MavCmd::MAV_CMD_DO_SET_MODE,
        [p[0], p[1], p[2], 0.0, 0.0, 0.0, 0.0],
    )
}

/// LOG_REQUEST_LIST of every log.
fn log_list() -> MavMessage {
    MavMessage::LOG_REQUEST_LIST(LOG_REQUEST_LIST_DATA {
        start: 0,
        end: 0xffff,
        target_system: 1,
        target_component: 1,
    })
}

/// LOG_REQUEST_DATA of `count` bytes of log `id` from `ofs`.
fn log_read(id: u16, ofs: u32, count: u32) -> MavMessage {
    MavMessage::LOG_REQUEST_DATA(LOG_REQUEST_DATA_DATA {
        ofs,
        count,
        id,
        target_system: 1,
        target_component: 1,
    })
}

#[test]
fn a_log_is_listed_then_sent_in_packets_within_the_links_room_from_the_offset_asked() {
    let mut b = Bench::new();
    b.beat(GCS);
    let list = log_list();
    b.hear(GCS, list.clone());
    assert_eq!(b.effects(), [Effect::ListLogs]);
    let entries = vec![
        LogEntry {
            id: 1,
            size: 10,
            time_utc: 5,
        },
        LogEntry {
            id: 2,
            size: 200,
            time_utc: 6,
        },
    ];
    b.conn.handle_log_list(b.now, Ok(entries));
    let listed: Vec<(u16, u32, u16)> = b
        .sent()
        .into_iter()
        .filter_map(|m| match m {
            MavMessage::LOG_ENTRY(e) => Some((e.id, e.size, e.num_logs)),
            _ => None,
        })
        .collect();
    assert_eq!(listed, [(1, 10, 2), (2, 200, 2)]);
    // Log 2 from byte 100: opened by the owner, then sent two packets a tick at most.
    let read = log_read(2, 100, u32::MAX);
    b.hear(GCS, read);
    assert_eq!(b.effects(), [Effect::OpenLog { id: 2 }]);
    let bytes: std::sync::Arc<[u8]> = (0..200u8).collect::<Vec<u8>>().into();
    b.conn.handle_log_opened(b.now, 2, Ok(bytes));
    let mut got = Vec::new();
    for _ in 0..3 {
        b.conn.poll_download(b.now, 1);
        b.conn.poll_download(b.now, 5);
        for m in b.sent() {
            if let MavMessage::LOG_DATA(d) = m {
                got.push((d.ofs, d.count, d.data[0]));
            }
        }
        b.now += super::logs::TICK;
    }
    assert_eq!(
        got,
        [(100, 90, 100), (190, 10, 190)],
        "one packet a tick, then the rest"
    );
    assert!(b.conn.poll_timeout().is_some());
    assert_eq!(b.conn.counts().log_bytes_sent, 100);
    // A log the list does not have is refused with a text; none at all is one empty entry.
    b.hear(GCS, log_read(9, 0, 10));
    assert_eq!(
        Bench::texts(&b.sent()),
        ["logs: no log 9 (ask for the list first)"]
    );
    b.hear(GCS, list);
    b.conn.handle_log_list(b.now, Ok(Vec::new()));
    let empty = b.sent().into_iter().any(
        |m| matches!(m, MavMessage::LOG_ENTRY(e) if e.num_logs == 0 && e.id == 0 && e.size == 0),
    );
    assert!(empty);
}

/// SET_POSITION_TARGET_LOCAL_NED at north-east-down `ned`, position only.
fn local_target(ned: [f32; 3]) -> MavMessage {
    let ignore_rest = PositionTargetTypemask::from_bits_truncate(0b1111_1111_1000);
    MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
        x: ned[0],
        y: ned[1],
        z: ned[2],
        type_mask: ignore_rest,
        target_system: 1,
        target_component: 1,
        coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
        ..SET_POSITION_TARGET_LOCAL_NED_DATA::DEFAULT
    })
}

#[test]
fn a_position_target_in_hold_moves_the_hold_point_thinned_and_is_ignored_elsewhere() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.status(Mode::Hold);
    b.operator();
    // North 3 m, east 1 m, 1.5 m up: north-west-up (3, -1, 1.5) from the takeoff point (at
    // the origin here).
    b.hear(GCS, local_target([3.0, 1.0, -1.5]));
    let inputs = b.operator();
    assert!(
        matches!(inputs[..], [OperatorInput::Command(Command::Move(p), LinkSource::Gcs)]
            if p == [3.0, -1.0, 1.5]),
        "{inputs:?}"
    );
    // The stream goes on: the same point, and a move within 0.2 s, are not taken again.
    b.hear(GCS, local_target([3.0, 1.0, -1.5]));
    b.now += Duration::from_millis(100);
    b.hear(GCS, local_target([4.0, 1.0, -1.5]));
    assert!(b.operator().is_empty());
    b.now += Duration::from_millis(150);
    b.hear(GCS, local_target([4.0, 1.0, -1.5]));
    assert_eq!(b.operator().len(), 1);
    // Not in hold (a landing): ignored and counted; a stranger's is denied.
    b.status(Mode::Land);
    b.hear(GCS, local_target([5.0, 1.0, -1.5]));
    assert!(b.operator().is_empty());
    assert_eq!(
        (
            b.conn.counts().targets_taken,
            b.conn.counts().targets_ignored
        ),
        (2, 1)
    );
    b.status(Mode::Hold);
    b.hear((77, 1), local_target([6.0, 1.0, -1.5]));
    assert!(b.operator().is_empty());
}

#[test]
fn a_download_stops_when_the_ground_station_falls_silent() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.hear(GCS, log_list());
    let one = LogEntry {
        id: 1,
        size: 1000,
        time_utc: 0,
    };
    b.conn.handle_log_list(b.now, Ok(vec![one]));
    b.hear(GCS, log_read(1, 0, u32::MAX));
    let bytes: std::sync::Arc<[u8]> = vec![7u8; 1000].into();
    b.conn.handle_log_opened(b.now, 1, Ok(bytes));
    b.sent();
    b.now += super::logs::QUIET + Duration::from_millis(1);
    b.conn.poll_download(b.now, 5);
    let out = b.sent();
    assert!(!out.iter().any(|m| matches!(m, MavMessage::LOG_DATA(_))));
    assert_eq!(
        Bench::texts(&out),
        ["logs: download stopped, the ground station is silent"]
    );
    // It stays stopped: nothing more is sent.
    b.now += super::logs::TICK;
    b.conn.poll_download(b.now, 5);
    assert!(
        !b.sent()
            .iter()
            .any(|m| matches!(m, MavMessage::LOG_DATA(_)))
    );
}

#[test]
fn available_modes_answers_the_mode_index_asked_for_or_every_mode_for_0() {
    let mut b = Bench::new();
    b.beat(GCS);
    b.sent();
    let ask = |index: f32| {
        command_long(
            MavCmd::MAV_CMD_REQUEST_MESSAGE,
            [
                <AVAILABLE_MODES_DATA as mavlink::MessageData>::ID as f32,
                index,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
        )
    };
    let modes = |msgs: &[MavMessage]| -> Vec<(u8, u8)> {
        msgs.iter()
            .filter_map(|m| match m {
                MavMessage::AVAILABLE_MODES(a) => Some((a.mode_index, a.number_modes)),
                _ => None,
            })
            .collect()
    };
    b.hear(GCS, ask(2.0));
    let out = b.sent();
    let n = crate::gcs::modes::SELECTABLE.len() as u8;
    assert_eq!(modes(&out), [(2, n)]);
    b.hear(GCS, ask(0.0));
    assert_eq!(modes(&b.sent()).len(), usize::from(n));
    b.hear(GCS, ask(f32::from(n) + 1.0));
    let out = b.sent();
    assert!(modes(&out).is_empty());
    assert_eq!(
        acks(&out),
        [(
            MavCmd::MAV_CMD_REQUEST_MESSAGE,
            MavResult::MAV_RESULT_DENIED
        )]
    );
}

//! The commander's rules, driven by explicit times and observations (no clock passes). Not in
//! the original's spec, except the link rule (spec 8.2).

use super::blind::{BLIND_BASE_MIN, BLIND_BRAKE_MAX, BLIND_RAMP_PER_S};
use super::failsafe::UNAIDED_BIAS_MAX_RAD_S;
use super::*;
use crate::core::ekf::TestRatios;

pub(super) fn params() -> Params {
    Params {
        start: Start::Disarmed,
        hover_z_m: 1.0,
        climb_m_s: 0.5,
        climb_acc_m_s2: 0.5,
        takeoff_tolerance_m: 0.1,
        land_m_s: 0.5,
        land_slow_m_s: 0.25,
        touchdown_v_m_s: 0.15,
        touchdown_thrust: 0.8,
        touchdown_s: 1.0,
        link_sources: [true; 3],
        link_timeout_s: 2.0,
        link_action: Action::Land,
        gps_timeout_s: 3.0,
        gps_loss_land_s: 10.0,
        gps_loss_action: Action::Land,
        fence_radius_m: 5.0,
        fence_alt_max_m: 10.0,
        fence_action: Action::Land,
        ekf_bad_s: 2.0,
        ekf_action: Action::Land,
        gps_live: false,
        disarm_ground_s: 10.0,
        crash_tilt_rad: 1.0,
        crash_s: 1.0,
        takeoff_timeout_s: 15.0,
        input_expiry_s: 1.0,
        rearm: true,
        z_min_m: 0.2,
        z_max_m: 3.0,
        mission: crate::core::mission::Limits {
            acc_m_s2: 0.5,
            yaw_rate_rad_s: 0.8,
            yaw_acc_rad_s2: 1.0,
            return_m_s: 1.0,
        },
        rc: None,
        sticks: StickLimits {
            max_speed_m_s: 3.0,
            max_climb_m_s: 1.0,
            max_yaw_rate_rad_s: 1.0,
            max_tilt_rad: 0.27,
        },
    }
}

fn good_facts() -> ArmFacts {
    ArmFacts {
        imu_stable: true,
        gps_required: true,
        gps_eph_m: Some(1.5),
        gps_max_eph_m: 5.0,
        log_error: None,
        realtime: true,
        esc_silent: vec![],
        estimator: None,
    }
}

/// Resting on the ground at `t_us` (hover thrust: the takeoff's spool-up).
fn at(t_us: i64, z_m: f64) -> Observation {
    Observation {
        t_us,
        pos_m: [0.0, 0.0, z_m],
        vz_m_s: 0.0,
        thrust_ratio: 1.0,
        acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
        tilt_rad: 0.0,
        baro_alt_m: z_m,
        gyro_lost: false,
        gps_fused: t_us % 1_000_000 == 0,
        gps_velocity_fused: false,
        gps_velocity_ratio: None,
        vertical_observed: true,
        ratios: TestRatios {
            attitude: 0.0,
            altitude: 0.0,
            gps: None,
        },
        yaw_cal_rad: 0.25,
        pos_sigma_m: 0.5,
        bias_unaided_rad_s: 0.0,
        acc_rest_m_s2: GRAVITY_M_S2,
    }
}

const STEP_US: i64 = 10_000;

/// A commander armed on the ground with one estimate at 0.
fn armed() -> (Commander, Vec<Event>) {
    let mut c = Commander::new(params());
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    let r = c.command(Command::Arm, 0, good_facts().verdict(), None, &mut ev);
    c.escs_running();
    assert_eq!(r, Some(EscRequest::Start));
    c.on_estimate(&at(0, 0.0), &mut ev);
    (c, ev)
}

/// Flies steps from `t0_us` to `t1_us` with the vehicle exactly on its set point, the
/// operator's link beating each second.
fn follow(c: &mut Commander, t0_us: i64, t1_us: i64, ev: &mut Vec<Event>) -> Guidance {
    follow_with(c, t0_us, t1_us, ev, true)
}

fn follow_with(
    c: &mut Commander,
    t0_us: i64,
    t1_us: i64,
    ev: &mut Vec<Event>,
    beats: bool,
) -> Guidance {
    let mut g = c.guidance();
    let mut t = t0_us;
    while t <= t1_us {
        if beats && t % 1_000_000 == 0 {
            c.link_beat(LinkSource::Gcs, t);
        }
        let mut o = at(t, g.pos_m[2]);
        o.pos_m[0] = g.pos_m[0];
        o.pos_m[1] = g.pos_m[1];
        o.vz_m_s = g.vz_m_s;
        c.tick(t, ev);
        g = c.on_estimate(&o, ev).0;
        t += STEP_US;
    }
    g
}

/// When `mode` was first entered.
fn entered_at(ev: &[Event], mode: Mode) -> Option<i64> {
    ev.iter().find_map(|e| match e {
        Event::Mode { mode: m, t_us, .. } if *m == mode => Some(*t_us),
        _ => None,
    })
}

fn refusals(ev: &[Event]) -> Vec<String> {
    ev.iter()
        .filter_map(|e| match e {
            Event::Refusal { why, .. } => Some(why.clone()),
            _ => None,
        })
        .collect()
}

fn modes(ev: &[Event]) -> Vec<Mode> {
    ev.iter()
        .filter_map(|e| match e {
            Event::Mode { mode, .. } => Some(*mode),
            _ => None,
        })
        .collect()
}

#[test]
fn arming_is_refused_with_the_failing_check_named() {
    type Spoil = fn(&mut ArmFacts);
    let cases: [(Spoil, &str); 6] = [
        (|f| f.imu_stable = false, "imu:"),
        (|f| f.gps_eph_m = None, "gps: no fix"),
        (|f| f.gps_eph_m = Some(9.0), "gps: horizontal error 9.0 m"),
        (
            |f| f.log_error = Some("cannot write in /x".into()),
            "log: cannot write",
        ),
        (|f| f.realtime = false, "realtime:"),
        (
            |f| f.esc_silent = vec![0x69],
            "esc: no acknowledgement from 0x69",
        ),
    ];
    for (spoil, named) in cases {
        let mut f = good_facts();
        spoil(&mut f);
        let mut c = Commander::new(params());
        let mut ev = Vec::new();
        assert_eq!(c.command(Command::Arm, 5, f.verdict(), None, &mut ev), None);
        assert_eq!(c.mode(), Mode::Disarmed);
        let why = refusals(&ev);
        assert!(
            why.len() == 1 && why[0].starts_with(named),
            "{named}: {why:?}"
        );
    }
    let mut f = good_facts();
    f.gps_required = false;
    f.gps_eph_m = None;
    assert_eq!(f.verdict(), Ok(()), "without gpsd no fix is needed");
}

#[test]
fn takeoff_spools_up_then_climbs_limited_and_holds_at_the_target() {
    let (mut c, mut ev) = armed();
    let r = c.command(
        Command::Takeoff(Some(2.0)),
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    assert_eq!((r, c.mode()), (None, Mode::Takeoff));
    // The flight ramp's second: the set point stays on the ground.
    let g = follow(&mut c, 20_000, 1_000_000, &mut ev);
    assert_eq!((g.pos_m[2], g.vz_m_s), (0.0, 0.0));
    let mut prev = g;
    let mut t = 1_010_000;
    let (mut sped_up, mut braked) = (false, false);
    while c.mode() == Mode::Takeoff {
        let g = follow(&mut c, t, t, &mut ev);
        assert!(g.vz_m_s <= 0.5 + 1e-9, "climb speed {}", g.vz_m_s);
        let acc = (g.vz_m_s - prev.vz_m_s).abs() / 0.01;
        assert!(acc <= 0.5 + 1e-6, "acceleration {acc} at {t}");
        // The acceleration to fly is the speed's change.
        let dv = (g.vz_m_s - prev.vz_m_s) / 0.01;
        assert!(
            (g.az_m_s2 - dv).abs() < 1e-6,
            "{} against {dv} at {t}",
            g.az_m_s2
        );
        (sped_up, braked) = (sped_up || g.az_m_s2 > 0.0, braked || g.az_m_s2 < 0.0);
        assert!(g.pos_m[2] <= 2.0, "the set point never passes the target");
        prev = g;
        t += STEP_US;
        assert!(t < 20_000_000, "never reached hold");
    }
    assert_eq!(c.mode(), Mode::Hold);
    assert!(sped_up && braked);
    // 2 m at 0.5 m/s with 1 s to reach the speed and 1 s to stop: 5 s after the spool-up.
    assert!((5_900_000..6_200_000).contains(&t), "hold at {t}");
    // At rest on the target: no acceleration. A landing eases in at its own.
    for _ in 0..200 {
        follow(&mut c, t, t, &mut ev);
        t += STEP_US;
    }
    assert_eq!(follow(&mut c, t, t, &mut ev).az_m_s2, 0.0);
    c.command(Command::Land, t, Ok(()), Some(&at(t, 2.0)), &mut ev);
    assert_eq!(c.mode(), Mode::Land);
    t += STEP_US;
    let g = follow(&mut c, t, t, &mut ev);
    assert!(g.az_m_s2 < 0.0 && g.az_m_s2 >= -0.5 - 1e-9, "{}", g.az_m_s2);
    assert_eq!(
        modes(&ev),
        [
            Mode::Disarmed,
            Mode::Armed,
            Mode::Takeoff,
            Mode::Hold,
            Mode::Land
        ]
    );
}

#[test]
fn takeoff_needs_an_armed_vehicle_and_a_running_estimator() {
    let mut c = Commander::new(params());
    let mut ev = Vec::new();
    c.command(
        Command::Takeoff(None),
        0,
        Ok(()),
        Some(&at(0, 0.0)),
        &mut ev,
    );
    c.command(Command::Arm, 0, good_facts().verdict(), None, &mut ev);
    // Under a running estimate (calibrated before arming) the ESCs still ramp.
    let o = at(1, 0.0);
    c.command(Command::Takeoff(None), 1, Ok(()), Some(&o), &mut ev);
    c.escs_running();
    c.command(Command::Takeoff(None), 1, Ok(()), None, &mut ev);
    let mut bad = at(2, 0.0);
    bad.ratios.altitude = 3.0;
    c.command(Command::Takeoff(None), 2, Ok(()), Some(&bad), &mut ev);
    let why = refusals(&ev);
    assert!(why[0].contains("takeoff needs armed"), "{why:?}");
    assert!(why[1].contains("start-up ramp is not done"), "{why:?}");
    assert!(why[2].starts_with("estimator: not running"), "{why:?}");
    assert!(
        why[3].starts_with(
            "estimator: innovation test ratios outside the gate (attitude 0.00, altitude 3.00"
        ),
        "{why:?}"
    );
    assert_eq!(c.mode(), Mode::Armed);
}

/// Armed and taking off at 0 with parameters `p`.
fn taking_off(p: Params) -> (Commander, Vec<Event>) {
    let mut c = Commander::new(p);
    let mut ev = Vec::new();
    c.command(Command::Arm, 0, good_facts().verdict(), None, &mut ev);
    c.escs_running();
    let o = at(0, 0.0);
    c.command(Command::Takeoff(None), 0, Ok(()), Some(&o), &mut ev);
    (c, ev)
}

#[test]
fn armed_on_the_ground_the_body_rests_but_only_disarmed_its_height_is_told() {
    let mut c = Commander::new(params());
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    assert_eq!((c.ground_contact_m(), c.at_rest()), (Some(0.0), true));
    let (c, _) = armed();
    assert_eq!((c.ground_contact_m(), c.at_rest()), (None, true));
    let (c, _) = holding();
    assert_eq!((c.ground_contact_m(), c.at_rest()), (None, false));
}

/// Armed, took off to 1 m and holding there, at 10 s.
fn holding() -> (Commander, Vec<Event>) {
    let (mut c, mut ev) = armed();
    c.link_beat(LinkSource::Gcs, 10_000);
    c.command(
        Command::Takeoff(None),
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    follow(&mut c, 20_000, 10_000_000, &mut ev);
    assert_eq!(c.mode(), Mode::Hold);
    (c, ev)
}

#[test]
fn disarm_is_refused_in_the_air_and_kill_is_always_taken() {
    let (mut c, mut ev) = holding();
    assert_eq!(
        c.command(Command::Disarm, 10_000_000, Ok(()), None, &mut ev),
        None
    );
    assert!(
        refusals(&ev)[0].starts_with("in the air (hold)"),
        "{:?}",
        refusals(&ev)
    );
    assert_eq!(c.mode(), Mode::Hold);
    let r = c.command(Command::Kill, 10_000_000, Ok(()), None, &mut ev);
    assert_eq!(r, Some(EscRequest::Kill));
    c.on_halt(10_001_000, "kill", &mut ev);
    assert_eq!(c.mode(), Mode::Kill);
    c.command(Command::Arm, 10_002_000, Ok(()), None, &mut ev);
    assert!(
        refusals(&ev)[1].starts_with("killed"),
        "{:?}",
        refusals(&ev)
    );
    // On the ground, disarm is taken.
    let (mut c, mut ev) = armed();
    assert_eq!(
        c.command(Command::Disarm, 5, Ok(()), None, &mut ev),
        Some(EscRequest::Stop)
    );
    assert_eq!(c.mode(), Mode::Disarmed);
}

/// Lands from `t0_us` with the vehicle following the set point down to the ground, where it
/// stops and the thrust falls; returns when the commander asked for the stop.
fn land_to_touchdown(c: &mut Commander, t0_us: i64, ev: &mut Vec<Event>) -> (i64, Vec<f64>) {
    let mut g = c.on_estimate(&at(t0_us, 1.0), ev).0;
    let mut speeds = Vec::new();
    let mut t = t0_us + STEP_US;
    loop {
        let z = g.pos_m[2].max(0.0);
        let mut o = at(t, z);
        o.vz_m_s = if z > 0.0 { g.vz_m_s } else { 0.0 };
        o.thrust_ratio = if z > 0.0 { 1.0 } else { 0.5 };
        speeds.push(-o.vz_m_s);
        let (next, r) = c.on_estimate(&o, ev);
        if r == Some(EscRequest::Stop) {
            return (t, speeds);
        }
        g = next;
        t += STEP_US;
        assert!(t < t0_us + 60_000_000, "no touchdown");
    }
}

#[test]
fn a_landing_descends_slower_in_the_last_metre_and_disarms_at_touchdown() {
    let (mut c, mut ev) = holding();
    c.link_beat(LinkSource::Gcs, 10_000_000);
    c.command(
        Command::Hold(Some([0.0, 0.0, 3.0])),
        10_000_000,
        Ok(()),
        None,
        &mut ev,
    );
    follow(&mut c, 10_010_000, 20_000_000, &mut ev);
    c.link_beat(LinkSource::Gcs, 20_000_000);
    let o = at(20_000_000, 3.0);
    c.command(Command::Land, 20_000_000, Ok(()), Some(&o), &mut ev);
    assert_eq!(c.mode(), Mode::Land);
    let mut g = c.on_estimate(&o, &mut ev).0;
    let mut t = 20_010_000;
    let mut fastest_high: f64 = 0.0;
    let mut fastest_low: f64 = 0.0;
    while g.pos_m[2] > 0.0 {
        let o = Observation {
            vz_m_s: g.vz_m_s,
            ..at(t, g.pos_m[2])
        };
        g = c.on_estimate(&o, &mut ev).0;
        if o.pos_m[2] > 1.5 {
            fastest_high = fastest_high.max(-g.vz_m_s);
        } else if o.pos_m[2] < 1.0 {
            fastest_low = fastest_low.max(-g.vz_m_s);
        }
        t += STEP_US;
        if t % 1_000_000 == 0 {
            c.link_beat(LinkSource::Gcs, t);
        }
    }
    assert!((fastest_high - 0.5).abs() < 1e-9, "descent {fastest_high}");
    assert!(fastest_low <= 0.25 + 1e-9, "last metre {fastest_low}");
    let (t_down, _) = land_to_touchdown(&mut c, t, &mut ev);
    assert!(
        t_down - t >= 1_000_000,
        "touchdown needs touchdown_s at rest"
    );
    assert_eq!(c.mode(), Mode::Disarmed);
    assert!(c.figures().touchdown.is_some());
    let why = match ev.last() {
        Some(Event::Mode { why, .. }) => why.clone(),
        e => panic!("{e:?}"),
    };
    assert_eq!(why, "touchdown");
    // A profile that calibrates after arming flies once per run.
    let mut once = c.clone();
    once.p.rearm = false;
    once.spent = true;
    once.command(Command::Arm, t_down, good_facts().verdict(), None, &mut ev);
    assert!(refusals(&ev).last().unwrap().starts_with("landed"));
    // Otherwise the next flight arms, and the first keeps its figures.
    let first = c.figures();
    let refused = refusals(&ev).len();
    c.command(Command::Arm, t_down, good_facts().verdict(), None, &mut ev);
    assert_eq!((c.mode(), refusals(&ev).len()), (Mode::Armed, refused));
    assert_eq!(c.flight_figures(), [first, Figures::default()]);
}

#[test]
fn the_ground_push_is_a_touchdown_even_when_the_estimate_keeps_falling() {
    let (mut c, mut ev) = holding();
    c.command(
        Command::Land,
        10_000_000,
        Ok(()),
        Some(&at(10_000_000, 1.0)),
        &mut ev,
    );
    let mut t = 10_010_000;
    let stop = loop {
        // The filter's model has no ground: with a low thrust its estimate falls on.
        let o = Observation {
            vz_m_s: -0.8,
            thrust_ratio: 0.5,
            ..at(t, -0.3)
        };
        if let (_, Some(r)) = c.on_estimate(&o, &mut ev) {
            break (t, r);
        }
        t += STEP_US;
        assert!(t < 20_000_000);
    };
    assert_eq!(stop.1, EscRequest::Stop);
    assert!(stop.0 - 10_010_000 >= 1_000_000);
}

fn failsafes(ev: &[Event]) -> Vec<(Failsafe, Action)> {
    ev.iter()
        .filter_map(|e| match e {
            Event::Failsafe { kind, action, .. } => Some((*kind, *action)),
            _ => None,
        })
        .collect()
}

/// When the first failsafe of `kind` struck, µs.
fn failsafe_us(ev: &[Event], kind: Failsafe) -> Option<i64> {
    ev.iter().find_map(|e| match e {
        Event::Failsafe { t_us, kind: k, .. } if *k == kind => Some(*t_us),
        _ => None,
    })
}

#[test]
fn a_silent_link_lands_once_and_the_operator_may_then_choose() {
    let (mut c, mut ev) = holding();
    // Beats each second until 12 s; then silence.
    follow(&mut c, 10_000_000, 12_990_000, &mut ev);
    assert!(failsafes(&ev).is_empty());
    follow_with(&mut c, 13_000_000, 14_500_000, &mut ev, false);
    assert_eq!(failsafes(&ev), [(Failsafe::LinkLoss, Action::Land)]);
    assert_eq!(c.mode(), Mode::Land);
    // An operator back on the link holds: the failsafe does not take it back.
    c.command(
        Command::Hold(None),
        14_000_000,
        Ok(()),
        Some(&at(14_000_000, 0.9)),
        &mut ev,
    );
    follow(&mut c, 14_010_000, 15_000_000, &mut ev);
    assert_eq!(c.mode(), Mode::Hold);
    assert_eq!(failsafes(&ev).len(), 1);
}

#[test]
fn a_link_never_seen_is_not_lost_and_sources_not_counted_are_ignored() {
    let mut p = params();
    p.link_sources = [true, false, false];
    let (mut c, mut ev) = taking_off(p);
    c.link_beat(LinkSource::Console, 0);
    follow(&mut c, 10_000, 30_000_000, &mut ev);
    assert!(failsafes(&ev).is_empty(), "{ev:?}");
}

#[test]
fn a_lost_gps_holds_attitude_then_lands_after_its_grace_time() {
    let (mut c, mut ev) = holding();
    let mut t = 10_000_000;
    let mut g = Guidance::OFF;
    while t < 30_000_000 {
        let mut o = at(t, 1.0);
        o.gps_fused = t <= 12_000_000 && t % 1_000_000 == 0;
        if t % 1_000_000 == 0 {
            c.link_beat(LinkSource::Gcs, t);
        }
        c.tick(t, &mut ev);
        g = c.on_estimate(&o, &mut ev).0;
        if (15_100_000..25_000_000).contains(&t) {
            assert!(!g.hold_xy && c.mode() == Mode::Hold, "at {t}");
        }
        t += STEP_US;
    }
    assert!(!g.hold_xy);
    assert_eq!(failsafes(&ev), [(Failsafe::GpsLoss, Action::Land)]);
    let land_at = entered_at(&ev, Mode::Land);
    // Last fix at 12 s, lost 3 s later (at 15 s, whichever step notices), land 10 s later.
    assert_eq!(land_at, Some(25_000_000));
}

/// Holds from 10 s with the last fix at 12 s while the filter's learnt gyro bias moves from
/// 16 s at `bias_rate` rad/s per second; when the landing began.
fn gps_lost_with_a_bias_learnt(bias_rate: f64) -> Option<i64> {
    let (mut c, mut ev) = holding();
    let mut t = 10_000_000;
    while t < 30_000_000 {
        let mut o = at(t, 1.0);
        o.gps_fused = t <= 12_000_000 && t % 1_000_000 == 0;
        o.bias_unaided_rad_s = bias_rate * ((t - 16_000_000) as f64 / 1e6).max(0.0);
        if t % 1_000_000 == 0 {
            c.link_beat(LinkSource::Gcs, t);
        }
        c.tick(t, &mut ev);
        c.on_estimate(&o, &mut ev);
        t += STEP_US;
    }
    assert_eq!(failsafes(&ev), [(Failsafe::GpsLoss, Action::Land)]);
    entered_at(&ev, Mode::Land)
}

#[test]
fn a_bias_learnt_without_fixes_ends_the_gps_loss_ride_through_at_once() {
    // 0.005 rad/s more every second from 16 s passes the 0.015 limit just after 19 s, six
    // seconds before the grace would end (25 s); a wander under it waits the grace out.
    assert_eq!(
        gps_lost_with_a_bias_learnt(0.005),
        Some(19_010_000),
        "past {UNAIDED_BIAS_MAX_RAD_S} rad/s"
    );
    assert_eq!(gps_lost_with_a_bias_learnt(0.001), Some(25_000_000));
}

#[test]
fn a_receiver_whose_fixes_are_all_gated_is_lost_after_its_timeout() {
    // Fixes keep arriving once a second, but from 12 s the filter leaves each out (outside
    // its gate): the receiver is as good as lost, on the gps-loss path.
    let (mut c, mut ev) = armed_with_receiver();
    c.link_beat(LinkSource::Gcs, 1_000_000);
    let o = at(1_000_000, 0.0);
    c.command(Command::Takeoff(None), 1_000_000, Ok(()), Some(&o), &mut ev);
    let mut t = 1_000_000;
    let mut lost_at = None;
    while t < 20_000_000 {
        let mut o = at(t, 1.0);
        if t % 1_000_000 == 0 {
            c.gps_fix(t);
            c.link_beat(LinkSource::Gcs, t);
        }
        o.gps_fused = t <= 12_000_000 && t % 1_000_000 == 0;
        c.tick(t, &mut ev);
        c.on_estimate(&o, &mut ev);
        if lost_at.is_none() && !failsafes(&ev).is_empty() {
            lost_at = Some(t);
        }
        t += STEP_US;
    }
    assert_eq!(failsafes(&ev), [(Failsafe::GpsLoss, Action::Land)]);
    // The last fused at 12 s, lost 3 s later.
    assert_eq!(lost_at, Some(15_010_000));
}

#[test]
fn without_fixes_the_fence_holds_for_where_the_vehicle_may_be() {
    // Holding 3 m from home inside a 5 m fence; the fixes stop at 12 s and the position's
    // uncertainty grows by 0.5 m a second from then: the fence is judged 2 σ of that growth
    // further out, and breached once 3 m + 2·σ passes 5 m (σ grown 1 m: at 14 s, but the
    // fixes are only judged lost 3 s after the last, at 15 s).
    let run = |sigma_grows: bool| {
        let (mut c, mut ev) = holding();
        let mut t = 10_000_000;
        while t < 20_000_000 {
            let mut o = at(t, 1.0);
            o.pos_m[0] = 3.0;
            o.gps_fused = t <= 12_000_000 && t % 1_000_000 == 0;
            if sigma_grows && t > 12_000_000 {
                o.pos_sigma_m += 0.5 * (t - 12_000_000) as f64 / 1e6;
            }
            c.link_beat(LinkSource::Gcs, t);
            c.tick(t, &mut ev);
            c.on_estimate(&o, &mut ev);
            t += STEP_US;
        }
        ev
    };
    let ev = run(true);
    let at_us = failsafe_us(&ev, Failsafe::Geofence);
    assert!(
        at_us.is_some_and(|t| (15_000_000..15_100_000).contains(&t)),
        "{ev:?}"
    );
    // The same place with an uncertainty that does not grow: no breach.
    let ev = run(false);
    assert!(
        !failsafes(&ev).contains(&(Failsafe::Geofence, Action::Land)),
        "{ev:?}"
    );
}

#[test]
fn the_fence_lands_only_while_the_position_is_observed() {
    let (mut c, mut ev) = holding();
    let mut t = 10_000_000;
    while t < 12_000_000 {
        let mut o = at(t, 1.0);
        o.pos_m[0] = 6.0;
        o.gps_fused = false;
        c.link_beat(LinkSource::Gcs, t);
        c.on_estimate(&o, &mut ev);
        t += STEP_US;
    }
    // The fixes of the takeoff (each second until 10 s) are fresh for 3 s: breached at once.
    assert_eq!(failsafes(&ev), [(Failsafe::Geofence, Action::Land)]);
    // A vehicle that never had a fix has no fence.
    let mut c = Commander::new(params());
    let mut ev = Vec::new();
    c.command(Command::Arm, 0, good_facts().verdict(), None, &mut ev);
    c.escs_running();
    let mut o = at(1, 0.0);
    o.gps_fused = false;
    c.command(Command::Takeoff(None), 1, Ok(()), Some(&o), &mut ev);
    o.pos_m = [60.0, 0.0, 1.0];
    for k in 0..100 {
        o.t_us = 2 + k * STEP_US;
        c.on_estimate(&o, &mut ev);
    }
    assert!(failsafes(&ev).is_empty());
}

#[test]
fn an_estimator_outside_its_gate_for_long_lands() {
    let (mut c, mut ev) = holding();
    let mut t = 10_000_000;
    while t < 14_000_000 {
        let mut o = at(t, 1.0);
        // A spike of 0.5 s, then from 11 s on for good.
        o.ratios.altitude = if (10_200_000..10_700_000).contains(&t) || t >= 11_000_000 {
            2.0
        } else {
            0.1
        };
        c.link_beat(LinkSource::Gcs, t);
        c.on_estimate(&o, &mut ev);
        t += STEP_US;
    }
    assert_eq!(failsafes(&ev), [(Failsafe::Estimator, Action::Land)]);
    assert_eq!(failsafe_us(&ev, Failsafe::Estimator), Some(13_000_000));
}

/// The first failsafe's time when `sense` shapes each hover step from 10 s to 14 s.
fn first_failsafe_us(sense: impl Fn(&mut Observation)) -> Option<(i64, Failsafe, Action)> {
    let (mut c, mut ev) = holding();
    let mut t = 10_000_000;
    while t < 14_000_000 {
        let mut o = at(t, 1.0);
        sense(&mut o);
        c.link_beat(LinkSource::Gcs, t);
        c.on_estimate(&o, &mut ev);
        t += STEP_US;
    }
    ev.iter().find_map(|e| match e {
        Event::Failsafe { t_us, kind, action } => Some((*t_us, *kind, *action)),
        _ => None,
    })
}

#[test]
fn a_lost_gyro_lands_where_the_estimator_failsafe_would_hold_and_refuses_a_takeoff() {
    let (mut c, mut ev) = armed();
    let mut stuck = at(STEP_US, 0.0);
    stuck.gyro_lost = true;
    c.on_estimate(&stuck, &mut ev);
    c.command(
        Command::Takeoff(None),
        STEP_US,
        Ok(()),
        Some(&stuck),
        &mut ev,
    );
    assert_eq!(refusals(&ev), ["estimator: gyro stuck (its counts repeat)"]);
    assert_eq!(c.mode(), Mode::Armed);
    // In the air, an ekf_action of hold does not fly on the model's attitude.
    let mut p = params();
    p.ekf_action = Action::Hold;
    let (mut c, mut ev) = taking_off(p);
    let t = 2 * STEP_US;
    c.link_beat(LinkSource::Gcs, t);
    c.on_estimate(&stuck_at(t), &mut ev);
    assert_eq!(failsafes(&ev), [(Failsafe::Estimator, Action::Land)]);
    assert_eq!(c.mode(), Mode::Land);
    // Its set point, from the ground the takeoff had not yet left, eases down to a floor
    // below it and brakes there (at 2 m/s² without the gyro): none of that is flown as
    // thrust with the vehicle on the ground.
    let mut braked = false;
    for k in 3..800 {
        let (g, _) = c.on_estimate(&stuck_at(k * STEP_US), &mut ev);
        assert!(g.pos_m[2] <= 0.0, "step {k}: {}", g.pos_m[2]);
        assert_eq!(g.az_m_s2, 0.0, "step {k}");
        braked |= g.vz_m_s.abs() < 0.4 && k > 100;
    }
    assert!(braked, "the set point reached its floor");
}

fn stuck_at(t_us: i64) -> Observation {
    let mut o = at(t_us, 0.5);
    o.gyro_lost = true;
    o
}

#[test]
fn a_lost_sensor_lands_at_once_and_a_missed_reading_does_not() {
    let land = |t_us| Some((t_us, Failsafe::Estimator, Action::Land));
    // The gyro lost at 11 s: that step.
    let gyro = first_failsafe_us(|o| o.gyro_lost = o.t_us >= 11_000_000);
    assert_eq!(gyro, land(11_000_000));
    // The barometer silent from 11 s: lost half a second later, not ekf_bad_s (2 s).
    let baro = first_failsafe_us(|o| {
        if o.t_us >= 11_000_000 {
            o.baro_alt_m = f64::NAN;
        }
    });
    assert_eq!(baro, land(11_500_000));
    // Silent for 0.49 s, twice: ridden through.
    let gaps = first_failsafe_us(|o| {
        let gap = |t0: i64| (t0..t0 + 490_000).contains(&o.t_us);
        if gap(11_000_000) || gap(12_000_000) {
            o.baro_alt_m = f64::NAN;
        }
    });
    assert_eq!(gaps, None);
}

#[test]
fn a_kill_action_asks_for_the_halt() {
    let mut p = params();
    p.link_action = Action::Kill;
    let (mut c, mut ev) = taking_off(p);
    c.link_beat(LinkSource::Gcs, 0);
    let mut kill = None;
    let mut t = STEP_US;
    while kill.is_none() && t < 5_000_000 {
        kill = c.tick(t, &mut ev).or(c.on_estimate(&at(t, 0.0), &mut ev).1);
        t += STEP_US;
    }
    assert_eq!(kill, Some(EscRequest::Kill));
    assert_eq!(failsafes(&ev), [(Failsafe::LinkLoss, Action::Kill)]);
}

#[test]
fn a_flying_start_arms_at_once_and_steps_to_the_hover_point() {
    let mut p = params();
    p.start = Start::Flying;
    let mut c = Commander::new(p);
    let mut ev = Vec::new();
    assert_eq!(c.start(0, &mut ev), Some(EscRequest::Start));
    let (g, _) = c.on_estimate(&at(8_000_000, -0.1), &mut ev);
    assert_eq!(c.mode(), Mode::Takeoff);
    assert!(g.fly);
    assert_eq!(
        g.pos_m,
        [0.0, 0.0, 1.0],
        "the original's set point, over (0, 0)"
    );
    assert_eq!(modes(&ev), [Mode::Disarmed, Mode::Armed, Mode::Takeoff]);
}

#[test]
fn the_altitude_keys_move_the_hold_target_within_bounds() {
    let (mut c, _) = holding();
    let up = ManualCommand::Altitude(Dir::Up);
    assert_eq!(c.manual(up), KeyOutcome::Moved(1.2));
    for _ in 0..20 {
        c.manual(up);
    }
    assert_eq!(c.manual(up), KeyOutcome::OutOfBounds);
    assert!((c.target_m()[2] - 3.0).abs() < 1e-9, "{}", c.target_m()[2]);
    assert_eq!(c.manual(ManualCommand::Roll(Dir::Up)), KeyOutcome::Planner);
    c.command(Command::Land, 0, Ok(()), None, &mut Vec::new());
    assert_eq!(c.manual(up), KeyOutcome::Ignored(Mode::Land));
    // Under the fence's ceiling too, where `hold` and missions stop (the keys went past it).
    let (mut c, _) = holding();
    c.p.fence_alt_max_m = 2.0;
    let moved = (0..100)
        .take_while(|_| c.manual(up) != KeyOutcome::OutOfBounds)
        .count();
    let steps = (1.0 / crate::core::control::MANUAL_Z_STEP_M).round() as usize;
    assert_eq!(moved, steps, "1 m to 2 m in the keys' steps");
    assert!((c.target_m()[2] - 2.0).abs() < 1e-9, "{}", c.target_m()[2]);
}

#[test]
fn operator_lines_are_commands_keys_or_errors() {
    let c = |l| OperatorInput::parse_line(l, LinkSource::Console);
    assert_eq!(
        c("arm").unwrap(),
        [OperatorInput::Command(Command::Arm, LinkSource::Console)]
    );
    assert_eq!(
        c(" takeoff 1.5 ").unwrap(),
        [OperatorInput::Command(
            Command::Takeoff(Some(1.5)),
            LinkSource::Console
        )]
    );
    assert_eq!(
        c("hold").unwrap(),
        [OperatorInput::Command(
            Command::Hold(None),
            LinkSource::Console
        )],
        "hold is a command though h, o, l, d are keys or not"
    );
    assert_eq!(c("ee").unwrap().len(), 2);
    assert_eq!(
        c("quit").unwrap(),
        [OperatorInput::Key(ManualCommand::Quit)]
    );
    assert!(c("").unwrap().is_empty());
    assert!(c("fly").unwrap_err().contains("unknown command"));
    assert!(c("takeoff -1").is_err());
    assert!(c("takeoff NaN").is_err());
    assert!(c("hold 1 2").is_err());
    assert!(c("arm now").is_err());
    let cmd = Command::parse("hold 1 -2 3").unwrap();
    assert_eq!(
        Command::parse(&cmd.to_string()),
        Ok(cmd),
        "Display reads back"
    );
}

#[test]
fn a_failsafe_fires_again_when_its_cause_returns_and_others_are_still_watched() {
    let mut p = params();
    p.link_action = Action::Hold;
    let (mut c, mut ev) = taking_off(p);
    follow(&mut c, 10_000, 10_000_000, &mut ev);
    // The link silent from 10 s: hold (the action), and the fence still watched meanwhile.
    follow_with(&mut c, 10_010_000, 13_000_000, &mut ev, false);
    assert_eq!(failsafes(&ev), [(Failsafe::LinkLoss, Action::Hold)]);
    let mut o = at(13_010_000, 1.0);
    o.pos_m[0] = 6.0;
    c.on_estimate(&o, &mut ev);
    assert_eq!(
        failsafes(&ev)[1],
        (Failsafe::Geofence, Action::Land),
        "{ev:?}"
    );
    // Back on the link and holding, then lost again: it fires again.
    c.link_beat(LinkSource::Gcs, 13_020_000);
    c.command(
        Command::Hold(None),
        13_020_000,
        Ok(()),
        Some(&at(13_020_000, 1.0)),
        &mut ev,
    );
    follow_with(&mut c, 13_030_000, 16_000_000, &mut ev, false);
    let kinds: Vec<Failsafe> = failsafes(&ev).into_iter().map(|f| f.0).collect();
    assert_eq!(kinds.last(), Some(&Failsafe::LinkLoss), "{ev:?}");
    assert_eq!(
        kinds.iter().filter(|k| **k == Failsafe::LinkLoss).count(),
        2
    );
}

#[test]
fn a_landing_begun_again_watches_its_touchdown_afresh() {
    let (mut c, mut ev) = holding();
    c.command(
        Command::Land,
        10_000_000,
        Ok(()),
        Some(&at(10_000_000, 1.0)),
        &mut ev,
    );
    // Resting-like for 0.6 s (a gust's pause), then the operator holds again.
    for k in 0..60 {
        let o = Observation {
            thrust_ratio: 0.5,
            ..at(10_010_000 + k * STEP_US, 0.5)
        };
        c.link_beat(LinkSource::Gcs, o.t_us);
        assert_eq!(c.on_estimate(&o, &mut ev).1, None);
    }
    c.command(
        Command::Hold(None),
        10_610_000,
        Ok(()),
        Some(&at(10_610_000, 0.5)),
        &mut ev,
    );
    c.command(
        Command::Land,
        11_000_000,
        Ok(()),
        Some(&at(11_000_000, 0.5)),
        &mut ev,
    );
    // The first resting steps of the new landing are not a touchdown.
    for k in 0..50 {
        let o = Observation {
            thrust_ratio: 0.5,
            ..at(11_010_000 + k * STEP_US, 0.5)
        };
        c.link_beat(LinkSource::Gcs, o.t_us);
        assert_eq!(c.on_estimate(&o, &mut ev).1, None, "step {k}");
    }
    assert_eq!(c.mode(), Mode::Land);
}

#[test]
fn an_estimate_whose_velocity_the_fixes_contradict_lands() {
    let (mut c, mut ev) = holding();
    let mut t = 10_000_000;
    while t < 14_000_000 {
        let mut o = at(t, 1.0);
        // The fixes' velocity outside its gate at each fix; nothing measured in between.
        let fix = t % 1_000_000 == 0;
        o.ratios.gps = fix.then_some(4.0);
        o.gps_velocity_ratio = fix.then_some(4.0);
        c.link_beat(LinkSource::Gcs, t);
        c.on_estimate(&o, &mut ev);
        t += STEP_US;
    }
    assert_eq!(failsafes(&ev), [(Failsafe::Estimator, Action::Land)]);
}

/// Holds from 10 s to `end_us` with a fix a second whose position the gate leaves out from
/// 12 s on while its velocity is fused (a receiver's position glitch); the events.
fn glitch_from_12_s(end_us: i64) -> Vec<Event> {
    let (mut c, mut ev) = holding();
    let mut t = 10_000_000;
    while t < end_us {
        let mut o = at(t, 1.0);
        let fix = t % 1_000_000 == 0;
        o.gps_fused = fix && t <= 12_000_000;
        o.gps_velocity_fused = fix;
        o.ratios.gps = fix.then_some(if t <= 12_000_000 { 0.1 } else { 16.0 });
        o.gps_velocity_ratio = fix.then_some(0.1);
        c.link_beat(LinkSource::Gcs, t);
        c.tick(t, &mut ev);
        c.on_estimate(&o, &mut ev);
        t += STEP_US;
    }
    ev
}

#[test]
fn a_position_glitch_with_a_consistent_velocity_is_ridden_through() {
    // 9 s of positions left out (under failsafe.gps_loss_land_s, 10 s): no failsafe at all.
    assert!(failsafes(&glitch_from_12_s(22_000_000)).is_empty());
}

#[test]
fn a_receiver_whose_positions_stay_inconsistent_is_lost() {
    // Positions left out from 13 s: healthy until 23 s, then lost as a silent receiver is,
    // control.gps_hold_timeout_s (3 s) after its last counted fix (22 s).
    let ev = glitch_from_12_s(40_000_000);
    assert_eq!(failsafes(&ev)[0], (Failsafe::GpsLoss, Action::Land));
    let lost_at = failsafe_us(&ev, Failsafe::GpsLoss);
    assert!(
        lost_at.is_some_and(|t| (25_000_000..25_100_000).contains(&t)),
        "{ev:?}"
    );
}

#[test]
fn targets_outside_the_bounds_or_the_fence_are_refused() {
    let (mut c, mut ev) = holding();
    let o = at(10_000_000, 1.0);
    c.command(
        Command::Hold(Some([6.0, 0.0, 1.0])),
        10_000_000,
        Ok(()),
        Some(&o),
        &mut ev,
    );
    c.command(
        Command::Hold(Some([0.0, 0.0, 3.5])),
        10_000_000,
        Ok(()),
        Some(&o),
        &mut ev,
    );
    let why = refusals(&ev);
    assert!(why[0].contains("outside fence.radius_m = 5 m"), "{why:?}");
    assert!(
        why[1].starts_with("height 3.5 m outside 0.2..3 m"),
        "{why:?}"
    );
    c.command(
        Command::Hold(Some([1.0, -1.0, 2.0])),
        10_000_000,
        Ok(()),
        Some(&o),
        &mut ev,
    );
    assert_eq!(
        c.target_m(),
        [1.0, -1.0, 2.0],
        "relative to the takeoff point at 0"
    );
    let (mut c, mut ev) = armed();
    c.command(
        Command::Takeoff(Some(12.0)),
        1,
        Ok(()),
        Some(&at(1, 0.0)),
        &mut ev,
    );
    assert!(
        refusals(&ev)[0].starts_with("height 12 m outside"),
        "{ev:?}"
    );
    assert_eq!(c.mode(), Mode::Armed);
}

fn plan(
    mission: crate::core::mission::Mission,
) -> std::sync::Arc<crate::core::mission::MissionPlan> {
    std::sync::Arc::new(crate::core::mission::MissionPlan {
        name: "test.toml".into(),
        mission,
        gains: std::sync::Arc::default(),
    })
}

fn out_and_back() -> crate::core::mission::Mission {
    use crate::core::mission::Item;
    crate::core::mission::Mission {
        items: vec![
            Item::Takeoff { height_m: 1.5 },
            Item::Goto {
                at_m: [3.0, 0.0, 1.5],
                speed_m_s: 1.0,
            },
            Item::Hold { seconds: 1.0 },
            Item::Return,
            Item::Land,
        ],
    }
}

fn reached(ev: &[Event]) -> Vec<usize> {
    ev.iter()
        .filter_map(|e| match e {
            Event::Reached { item, .. } => Some(*item),
            _ => None,
        })
        .collect()
}

#[test]
fn start_flies_the_mission_from_the_ground_to_its_landing() {
    let (c, mut ev) = armed();
    let mut c = c.with_mission(plan(out_and_back()));
    c.command(
        Command::Start,
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    assert_eq!(c.mode(), Mode::Takeoff);
    let mut t = 20_000;
    let mut far = 0.0f64;
    while c.mode() != Mode::Land {
        let g = follow(&mut c, t, t, &mut ev);
        if let Some((p, _, _)) = g.path {
            far = far.max(p.pos_m[0]);
            // The heading starts from the calibration's and turns toward the point.
            assert!(g.yaw_rad.is_some());
        }
        t += STEP_US;
        assert!(t < 60_000_000, "never landed: {:?}", modes(&ev));
    }
    assert_eq!(
        modes(&ev),
        [
            Mode::Disarmed,
            Mode::Armed,
            Mode::Takeoff,
            Mode::Mission,
            Mode::Land
        ]
    );
    // The takeoff is reached as the mission's first item; the landing at its touchdown.
    assert_eq!(reached(&ev), [0, 1, 2, 3]);
    assert!((far - 3.0).abs() < 1e-9, "{far}");
    // Landing above the takeoff point, the mission's set point left at rest.
    let g = c.guidance();
    assert!(g.path.is_none() && g.pos_m[0].abs() < 1e-6 && g.pos_m[1].abs() < 1e-6);
    let f = c.mission_figures();
    let flown_s = (f.ended_us.unwrap() - f.started_us.unwrap()) as f64 / 1e6;
    assert!(
        (flown_s - f.ideal_s).abs() < 0.03,
        "{flown_s} vs {}",
        f.ideal_s
    );
}

#[test]
fn pause_holds_where_the_mission_got_to_and_resume_goes_on() {
    let (c, mut ev) = armed();
    let mut c = c.with_mission(plan(out_and_back()));
    c.command(
        Command::Start,
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    let mut t = 20_000;
    while c.mode() != Mode::Mission || c.guidance().path.is_some_and(|p| p.0.pos_m[0] < 1.0) {
        follow(&mut c, t, t, &mut ev);
        t += STEP_US;
    }
    let o = at(t, 1.5);
    c.command(Command::Pause, t, Ok(()), Some(&o), &mut ev);
    let held = c.guidance();
    assert_eq!((c.mode(), held.path), (Mode::Hold, None));
    let g = follow(&mut c, t + STEP_US, t + 3_000_000, &mut ev);
    assert_eq!(g.pos_m, held.pos_m, "the hold stays put");
    t += 3_010_000;
    c.command(Command::Resume, t, Ok(()), Some(&at(t, 1.5)), &mut ev);
    assert_eq!(c.mode(), Mode::Mission);
    while c.mode() == Mode::Mission {
        follow(&mut c, t, t, &mut ev);
        t += STEP_US;
    }
    assert_eq!(reached(&ev), [0, 1, 2, 3]);
    // Resume twice, pause outside a mission: refused with the reason.
    c.command(Command::Resume, t, Ok(()), Some(&at(t, 1.5)), &mut ev);
    c.command(Command::Pause, t, Ok(()), Some(&at(t, 1.5)), &mut ev);
    let why = refusals(&ev);
    assert!(why[0].contains("no paused mission") && why[1].contains("no mission flying"));
}

#[test]
fn start_is_refused_without_a_mission_or_without_its_takeoff() {
    let (mut c, mut ev) = armed();
    c.command(
        Command::Start,
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    let mut m = out_and_back();
    m.items.remove(0);
    let (c2, _) = armed();
    let mut c2 = c2.with_mission(plan(m));
    c2.command(
        Command::Start,
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    let why = refusals(&ev);
    assert!(why[0].starts_with("no mission loaded"), "{why:?}");
    assert!(why[1].contains("does not begin with a takeoff"), "{why:?}");
    assert_eq!((c.mode(), c2.mode()), (Mode::Armed, Mode::Armed));
}

#[test]
fn a_return_failsafe_flies_home_then_lands() {
    let mut p = params();
    p.link_action = Action::Return;
    let mut c = Commander::new(p);
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    c.command(Command::Arm, 0, good_facts().verdict(), None, &mut ev);
    c.escs_running();
    c.on_estimate(&at(0, 0.0), &mut ev);
    c.command(
        Command::Takeoff(Some(1.5)),
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    let mut t = 20_000;
    while c.mode() != Mode::Hold {
        follow(&mut c, t, t, &mut ev);
        t += STEP_US;
    }
    c.command(
        Command::Hold(Some([2.0, 1.0, 1.5])),
        t,
        Ok(()),
        Some(&at(t, 1.5)),
        &mut ev,
    );
    let g = follow(&mut c, t, t + 3_000_000, &mut ev);
    assert_eq!([g.pos_m[0], g.pos_m[1]], [2.0, 1.0]);
    // The link falls silent: after its timeout, return; then land above the takeoff point.
    t += 3_010_000;
    while c.mode() != Mode::Land {
        follow_with(&mut c, t, t, &mut ev, false);
        t += STEP_US;
        assert!(t < 60_000_000, "{:?}", modes(&ev));
    }
    assert!(modes(&ev).ends_with(&[Mode::Hold, Mode::Hold, Mode::Return, Mode::Land]));
    // A landing goes on: `return` is refused while it lasts.
    c.command(Command::Return, t, Ok(()), Some(&at(t, 1.0)), &mut ev);
    assert_eq!(c.mode(), Mode::Land);
    assert!(
        refusals(&ev)
            .last()
            .is_some_and(|w| w.starts_with("landing"))
    );
    let g = c.guidance();
    assert!(
        g.pos_m[0].abs() < 1e-6 && g.pos_m[1].abs() < 1e-6,
        "{:?}",
        g.pos_m
    );
}

/// A commander with a receiver (gps.mode = "gpsd"), armed at 1 s with the last fix at 0.5 s.
fn armed_with_receiver() -> (Commander, Vec<Event>) {
    let mut p = params();
    p.gps_live = true;
    let mut c = Commander::new(p);
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    c.gps_fix(500_000);
    c.command(Command::Arm, 1_000_000, Ok(()), None, &mut ev);
    c.escs_running();
    (c, ev)
}

#[test]
fn a_receiver_silent_from_arming_disarms_on_the_ground_during_the_start_up() {
    let (mut c, mut ev) = armed_with_receiver();
    // No Kalman step yet (the ESC ramp, the calibration): only the frames' ticks.
    let mut t = 1_000_000;
    let stop = loop {
        if let Some(r) = c.tick(t, &mut ev) {
            break (t, r);
        }
        t += STEP_US;
        assert!(t < 10_000_000, "{ev:?}");
    };
    // Last fix at 0.5 s, stale after 3 s.
    assert_eq!(stop, (3_510_000, EscRequest::Stop));
    assert_eq!(c.mode(), Mode::Disarmed);
    assert_eq!(failsafes(&ev), [(Failsafe::GpsLoss, Action::Land)]);
}

#[test]
fn a_takeoff_with_a_receiver_needs_a_fix_delivered_lately() {
    let (mut c, mut ev) = armed_with_receiver();
    c.gps_fix(2_000_000);
    c.on_estimate(&at(2_000_000, 0.0), &mut ev);
    let est = at(5_500_000, 0.0);
    c.command(
        Command::Takeoff(None),
        5_500_000,
        Ok(()),
        Some(&est),
        &mut ev,
    );
    assert_eq!(c.mode(), Mode::Armed);
    assert!(refusals(&ev)[0].starts_with("gps: no fix within"), "{ev:?}");
    c.gps_fix(5_600_000);
    // Delivered but not fused (the last fused at 2 s): not yet.
    c.command(
        Command::Takeoff(None),
        5_605_000,
        Ok(()),
        Some(&est),
        &mut ev,
    );
    assert_eq!(c.mode(), Mode::Armed);
    // Fused at the next step: a fix delivered but never fused (left out by the gate) would
    // not do.
    let mut fused = at(5_610_000, 0.0);
    fused.gps_fused = true;
    c.on_estimate(&fused, &mut ev);
    c.command(
        Command::Takeoff(None),
        5_700_000,
        Ok(()),
        Some(&est),
        &mut ev,
    );
    assert_eq!(c.mode(), Mode::Takeoff);
}

#[test]
fn an_armed_vehicle_left_on_the_ground_disarms() {
    let (mut c, mut ev) = armed();
    let mut t = STEP_US;
    let stop = loop {
        c.link_beat(LinkSource::Gcs, t);
        let r = c.tick(t, &mut ev).or(c.on_estimate(&at(t, 0.0), &mut ev).1);
        if let Some(r) = r {
            break (t, r);
        }
        t += STEP_US;
        assert!(t < 20_000_000);
    };
    // The start-up ended with the estimate at 0: 10 s later.
    assert_eq!(stop, (10_000_000, EscRequest::Stop));
    assert_eq!(c.mode(), Mode::Disarmed);
    assert!(failsafes(&ev).is_empty());
}

#[test]
fn a_link_lost_on_the_ground_disarms() {
    let (mut c, mut ev) = armed();
    c.link_beat(LinkSource::Gcs, 0);
    let mut t = STEP_US;
    while c.tick(t, &mut ev).is_none() {
        c.on_estimate(&at(t, 0.0), &mut ev);
        t += STEP_US;
        assert!(t < 5_000_000);
    }
    assert_eq!(t, 2_010_000);
    assert_eq!(c.mode(), Mode::Disarmed);
    assert_eq!(failsafes(&ev), [(Failsafe::LinkLoss, Action::Land)]);
}

#[test]
fn a_flip_or_a_takeoff_that_never_leaves_the_ground_is_a_crash() {
    // Lying on its side: the estimate may say level (a failed gyro), the accelerometer not.
    let (mut c, mut ev) = taking_off(params());
    let mut t = STEP_US;
    let crash = loop {
        let mut o = at(t, 0.0);
        if t >= 2_000_000 {
            o.acc_m_s2 = [GRAVITY_M_S2, 0.0, 0.5];
        }
        if let (_, Some(r)) = c.on_estimate(&o, &mut ev) {
            break (t, r);
        }
        t += STEP_US;
        assert!(t < 20_000_000);
    };
    assert_eq!(crash, (3_000_000, EscRequest::Crash));
    // Level but still on the ground 15 s after the takeoff.
    let (mut c, mut ev) = taking_off(params());
    let mut t = STEP_US;
    let crash = loop {
        if let (_, Some(r)) = c.on_estimate(&at(t, 0.05), &mut ev) {
            break (t, r);
        }
        t += STEP_US;
        assert!(t < 30_000_000);
    };
    assert_eq!(crash, (15_010_000, EscRequest::Crash));
}

/// Steps a blind landing for `s` seconds at 100 Hz with the vertical specific force
/// `up_m_s2`.
fn blind_for(b: Blind, up_m_s2: f64, s: f64) -> Blind {
    (0..(s * 100.0) as usize).fold(b, |b, _| b.step([0.0, 0.0, up_m_s2], REST, 0.25, 0.01))
}

/// An accelerometer that reads 0.3 % short at rest (the simulator's does).
const REST: f64 = GRAVITY_M_S2 * 0.997;

#[test]
fn a_blind_landing_brakes_a_fast_sink_and_never_climbs_on_it() {
    // Falling faster and faster (the thrust a little under the hover's): the brake holds the
    // sink, a little above the thrust it began with, no more.
    let b = blind_for(Blind::new(1.0), REST - 0.5, 2.0);
    assert!((b.sink_m_s - 1.0).abs() < 1e-9, "{b:?}");
    assert!(
        b.thrust > 1.0 && b.thrust <= 1.0 + BLIND_BRAKE_MAX + 1e-12,
        "{b:?}"
    );
    // Climbing: the thrust falls.
    let b = blind_for(Blind::new(1.0), REST + 0.5, 1.0);
    assert!(b.thrust < 1.0 - 0.5 * BLIND_RAMP_PER_S, "{b:?}");
    // At rest, read against the accelerometer's own rest: no sink grows (against the
    // textbook g it would, 0.03 m/s a second, and brake a hovering vehicle upward).
    let b = blind_for(Blind::new(1.0), REST, 30.0);
    assert!(b.sink_m_s.abs() < 1e-9 && b.thrust < 0.2, "{b:?}");
    // Not a number from the accelerometer: the sink stands.
    let b = Blind::new(1.0).step([f64::NAN; 3], REST, 0.25, 0.01);
    assert!(b.sink_m_s == 0.0 && b.thrust.is_finite(), "{b:?}");
    // A push from the side is no touchdown's shock.
    let b = Blind::new(1.0).step([3.0 * REST, 0.0, REST], REST, 0.25, 0.01);
    assert!(!b.shock, "{b:?}");
}

#[test]
fn a_blind_landing_that_feels_the_ground_lets_the_thrust_fall() {
    // Sinking at 0.4 m/s (the brake on), then a touchdown's shock: the brake is off and the
    // thrust falls under the touchdown threshold within a second and a half, though the
    // sink the accelerometer gave back may be short of the whole stop.
    let mut b = blind_for(Blind::new(1.0), REST - 0.4, 1.0);
    assert!(b.thrust > 1.0, "{b:?}");
    b = b.step([0.0, 0.0, 3.0 * REST], REST, 0.25, 0.01);
    b = blind_for(b, REST, 1.5);
    assert!(b.shock && b.thrust < 0.8, "{b:?}");
    // A thrust far off the weight is no hover to begin from.
    assert_eq!(Blind::new(5.0).base, 1.0 / BLIND_BASE_MIN);
    assert_eq!(Blind::new(f64::NAN).base, 1.0);
}

#[test]
fn an_asking_that_waited_past_the_expiry_is_refused_a_beat_never_expires() {
    let c = Commander::new(params());
    let arm = OperatorInput::Command(Command::Arm, LinkSource::Gcs);
    assert_eq!(
        c.aged(arm.clone(), 1_000_000),
        arm,
        "1 s is within the expiry"
    );
    let aged = c.aged(arm.clone(), 1_000_001);
    assert_eq!(
        aged,
        OperatorInput::Expired {
            input: Box::new(arm),
            waited_us: 1_000_001
        }
    );
    let beat = OperatorInput::Beat(LinkSource::Gcs);
    assert_eq!(c.aged(beat.clone(), 60_000_000), beat);
    let mut events = Vec::new();
    c.refuse_expired(&aged, 5, &mut events);
    assert_eq!(
        events,
        [Event::Refusal {
            t_us: 5,
            command: "arm".into(),
            why: expiry_reason(1.0)
        }]
    );
    assert_eq!(c.mode(), Mode::Disarmed, "refused, not applied");
}

/// The refusal `ev` holds, its words.
fn refusal_of(ev: &[Event]) -> Option<String> {
    ev.iter().find_map(|e| match e {
        Event::Refusal { why, .. } => Some(why.clone()),
        _ => None,
    })
}

#[test]
fn a_motor_test_runs_one_motor_disarmed_within_its_bounds_and_holds_off_the_arm() {
    let mut c = Commander::new(params());
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    let test = |motor, throttle_pct, duration_s| Command::MotorTest {
        motor,
        throttle_pct,
        duration_s,
    };
    for (motor, pct, s) in [
        (0, 10.0, 1.0),
        (5, 10.0, 1.0),
        (1, -1.0, 1.0),
        (1, 31.0, 1.0),
    ]
    .into_iter()
    .chain([(1, 10.0, 0.0), (1, 10.0, 5.5), (1, f64::NAN, 1.0)])
    {
        ev.clear();
        let r = c.command(test(motor, pct, s), 0, Ok(()), None, &mut ev);
        assert_eq!(r, None, "motor {motor} {pct} % {s} s");
        let why = refusal_of(&ev).unwrap_or_default();
        assert!(why.contains("motor 1 to 4"), "{why}");
    }
    ev.clear();
    let why = "esc: no acknowledgement from 0x6b".to_string();
    assert_eq!(
        c.command(test(2, 10.0, 2.0), 0, Err(why.clone()), None, &mut ev),
        None
    );
    assert_eq!(refusal_of(&ev), Some(why), "the motor test's own checks");
    let r = c.command(test(2, 10.0, 2.0), 1_000_000, Ok(()), None, &mut ev);
    let want = crate::core::esc::MotorTest::new(1, 10.0, 2.0);
    assert_eq!(r, Some(EscRequest::MotorTest(want)));
    assert_eq!(c.mode(), Mode::Disarmed, "a motor test arms nothing");
    let end_us = 1_000_000 + want.total_us();
    assert_eq!(c.motor_testing(end_us - 1), Some(2));
    for cmd in [Command::Arm, Command::Calibrate, test(3, 10.0, 1.0)] {
        ev.clear();
        assert_eq!(c.command(cmd, end_us - 1, Ok(()), None, &mut ev), None);
        let why = refusal_of(&ev).unwrap_or_default();
        assert!(
            why.contains("a motor test of motor 2 runs until 5.4 s"),
            "{cmd}: {why}"
        );
    }
    // A disarm ends it early, and so does a throttle of 0 (a ground station's stop); then
    // the arm is taken.
    let r = c.command(Command::Disarm, 2_000_000, Ok(()), None, &mut ev);
    assert_eq!(r, Some(EscRequest::EndMotorTest));
    assert_eq!(c.motor_testing(2_000_001), None);
    c.command(test(2, 10.0, 2.0), 2_000_000, Ok(()), None, &mut ev);
    let r = c.command(test(2, 0.0, 0.0), 2_000_000, Ok(()), None, &mut ev);
    assert_eq!(r, Some(EscRequest::EndMotorTest));
    ev.clear();
    let r = c.command(test(1, 0.0, 0.0), 2_000_000, Ok(()), None, &mut ev);
    assert_eq!(
        (r, refusal_of(&ev)),
        (None, None),
        "a stop with nothing running"
    );
    assert_eq!(
        c.command(Command::Arm, 2_000_001, Ok(()), None, &mut ev),
        Some(EscRequest::Start)
    );
    // Armed: refused, named.
    ev.clear();
    assert_eq!(
        c.command(test(1, 10.0, 1.0), 2_100_000, Ok(()), None, &mut ev),
        None
    );
    assert_eq!(
        refusal_of(&ev).as_deref(),
        Some("armed: a motor test runs only disarmed, on the ground")
    );
}

fn rc_params() -> Params {
    Params {
        rc: Some(RcLossParams {
            timeout_s: 0.5,
            action: Action::Return,
        }),
        ..params()
    }
}

fn rc(kill: bool, throttle: f64) -> RcReport {
    RcReport {
        lost: false,
        kill,
        sticks: [0.0, 0.0, 0.0, throttle],
        stick_mode: None,
    }
}

/// Armed with a radio, taken off and holding at 1 m by 6 s, the radio reporting every 0.1 s.
fn holding_with_radio() -> (Commander, Vec<Event>) {
    holding_with(rc_params())
}

fn holding_with(p: Params) -> (Commander, Vec<Event>) {
    let mut c = Commander::new(p);
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    c.rc_report(rc(false, -1.0), 0, &mut ev);
    assert_eq!(
        c.command(Command::Arm, 0, Ok(()), None, &mut ev),
        Some(EscRequest::Start)
    );
    c.escs_running();
    c.on_estimate(&at(0, 0.0), &mut ev);
    c.command(
        Command::Takeoff(None),
        10_000,
        Ok(()),
        Some(&at(10_000, 0.0)),
        &mut ev,
    );
    let mut t = 20_000;
    while t <= 6_000_000 {
        if t % 100_000 == 0 {
            c.rc_report(rc(false, 0.0), t, &mut ev);
        }
        let g = c.guidance();
        let mut o = at(t, g.pos_m[2]);
        o.vz_m_s = g.vz_m_s;
        c.tick(t, &mut ev);
        c.on_estimate(&o, &mut ev);
        t += STEP_US;
    }
    assert_eq!(c.mode(), Mode::Hold, "{ev:?}");
    (c, ev)
}

#[test]
fn with_a_radio_an_arm_needs_its_frames_the_kill_switch_off_and_the_throttle_low() {
    let mut c = Commander::new(rc_params());
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    let arm = |c: &mut Commander, t_us| {
        let mut ev = Vec::new();
        c.command(Command::Arm, t_us, Ok(()), None, &mut ev);
        refusals(&ev).first().cloned().unwrap_or_default()
    };
    assert!(arm(&mut c, 0).starts_with("rc: no frames"));
    c.rc_report(rc(true, -1.0), 1_000_000, &mut ev);
    assert_eq!(arm(&mut c, 1_000_000), "rc: kill switch on");
    c.rc_report(rc(false, 0.2), 1_100_000, &mut ev);
    assert!(arm(&mut c, 1_100_000).starts_with("rc: throttle not low (0.20"));
    c.rc_report(rc(false, -1.0), 1_200_000, &mut ev);
    assert!(
        arm(&mut c, 1_800_000).starts_with("rc: no frames"),
        "0.6 s silent"
    );
    let lost = RcReport {
        lost: true,
        ..rc(false, -1.0)
    };
    c.rc_report(lost, 1_900_000, &mut ev);
    assert!(
        arm(&mut c, 1_900_000).starts_with("rc: no frames"),
        "in failsafe"
    );
    c.rc_report(rc(false, -1.0), 2_000_000, &mut ev);
    assert_eq!(arm(&mut c, 2_000_000), "");
    assert_eq!(c.mode(), Mode::Armed);
}

#[test]
fn the_kill_switch_stops_the_motors_in_the_air_and_the_vehicle_may_arm_again_once_it_is_off() {
    let (mut c, mut ev) = holding_with_radio();
    ev.clear();
    let r = c.rc_report(rc(true, 0.0), 6_010_000, &mut ev);
    assert_eq!(
        (r, c.mode()),
        (Some(EscRequest::KillSwitch), Mode::Disarmed)
    );
    assert!(
        ev.iter()
            .any(|e| matches!(e, Event::Mode { why, .. } if why == "kill switch")),
        "{ev:?}"
    );
    assert_eq!(c.rc_report(rc(true, 0.0), 6_020_000, &mut ev), None, "once");
    ev.clear();
    c.command(Command::Arm, 6_030_000, Ok(()), None, &mut ev);
    assert_eq!(refusals(&ev), ["rc: kill switch on"]);
    // A motor test is held by the switch too.
    let test = Command::MotorTest {
        motor: 1,
        throttle_pct: 10.0,
        duration_s: 1.0,
    };
    ev.clear();
    c.command(test, 6_035_000, Ok(()), None, &mut ev);
    assert_eq!(refusals(&ev), ["rc: kill switch on"]);
    // Off: not while it falls; once seen at rest, a second after the kill.
    c.rc_report(rc(false, -1.0), 6_040_000, &mut ev);
    ev.clear();
    c.command(Command::Arm, 6_050_000, Ok(()), None, &mut ev);
    assert_eq!(
        refusals(&ev),
        ["rc: killed in the air: the vehicle has not been seen at rest since"]
    );
    let mut falling = at(6_500_000, 0.5);
    falling.vz_m_s = -3.0;
    c.on_estimate(&falling, &mut ev);
    c.on_estimate(&at(7_100_000, 0.0), &mut ev);
    c.rc_report(rc(false, -1.0), 7_100_000, &mut ev);
    assert_eq!(
        c.command(Command::Arm, 7_110_000, Ok(()), None, &mut ev),
        Some(EscRequest::Start)
    );
}

#[test]
fn a_lost_radios_hold_does_not_stop_a_landing() {
    let p = Params {
        rc: Some(RcLossParams {
            timeout_s: 0.5,
            action: Action::Hold,
        }),
        ..params()
    };
    let (mut c, mut ev) = holding_with(p);
    c.command(Command::Land, 6_010_000, Ok(()), None, &mut ev);
    assert_eq!(c.mode(), Mode::Land);
    let lost = RcReport {
        lost: true,
        ..rc(false, 0.0)
    };
    c.rc_report(lost, 6_020_000, &mut ev);
    c.tick(6_030_000, &mut ev);
    assert!(
        ev.iter().any(|e| matches!(
            e,
            Event::Failsafe {
                kind: Failsafe::RcLoss,
                ..
            }
        )),
        "{ev:?}"
    );
    assert_eq!(c.mode(), Mode::Land, "the landing goes on");
}

#[test]
fn a_lost_radio_returns_in_the_air_and_disarms_on_the_ground() {
    let (mut c, mut ev) = holding_with_radio();
    ev.clear();
    // Silent from 6 s: lost after rc_timeout_s (0.5 s), acted on once.
    let mut t = 6_010_000;
    while t <= 7_000_000 {
        c.tick(t, &mut ev);
        t += STEP_US;
    }
    let failsafes: Vec<(i64, Failsafe, Action)> = ev
        .iter()
        .filter_map(|e| match e {
            Event::Failsafe { t_us, kind, action } => Some((*t_us, *kind, *action)),
            _ => None,
        })
        .collect();
    assert_eq!(failsafes, [(6_510_000, Failsafe::RcLoss, Action::Return)]);
    assert_eq!(c.mode(), Mode::Return);
    // On the ground, armed: a lost radio disarms.
    let mut c = Commander::new(rc_params());
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    c.rc_report(rc(false, -1.0), 0, &mut ev);
    c.command(Command::Arm, 0, Ok(()), None, &mut ev);
    let lost = RcReport {
        lost: true,
        ..rc(false, -1.0)
    };
    c.rc_report(lost, 100_000, &mut ev);
    assert_eq!(c.tick(110_000, &mut ev), Some(EscRequest::Stop));
    assert_eq!(c.mode(), Mode::Disarmed);
}

/// Holding at 1 m (no radio), then `position` from a ground station; `steps` of the
/// joystick's `sticks` from 10 s, the vehicle exactly on its set point.
fn fly_sticks(mode: StickMode, sticks: [f64; 4], seconds: f64) -> (Commander, Guidance) {
    let (mut c, mut ev) = holding();
    c.command(
        Command::Sticks(mode),
        10_000_000,
        Ok(()),
        Some(&at(10_000_000, 1.0)),
        &mut ev,
    );
    assert_eq!(c.mode(), mode.mode(), "{ev:?}");
    let mut g = c.guidance();
    let end = 10_000_000 + (seconds * 1e6) as i64;
    let mut t = 10_010_000;
    while t <= end {
        if t % 100_000 == 0 {
            c.gcs_sticks(sticks, t);
        }
        if t % 1_000_000 == 0 {
            c.link_beat(LinkSource::Gcs, t);
        }
        let mut o = at(t, g.pos_m[2]);
        o.pos_m[0] = g.pos_m[0];
        o.pos_m[1] = g.pos_m[1];
        c.tick(t, &mut ev);
        g = c.on_estimate(&o, &mut ev).0;
        t += STEP_US;
    }
    (c, g)
}

#[test]
fn the_sticks_fly_forward_right_and_clockwise_as_a_pilot_expects() {
    // The heading at calibration is 0.25 rad: forward is (cos, sin) of it, right is
    // (sin, −cos); z up.
    let (s, co) = 0.25f64.sin_cos();
    let (_, g) = fly_sticks(StickMode::Position, [0.0, 1.0, 0.0, 0.0], 3.0);
    let (p, _, _) = g.path.expect("position flies a path");
    let along = p.pos_m[0] * co + p.pos_m[1] * s;
    let across = p.pos_m[0] * s - p.pos_m[1] * co;
    // About 3 s at most 0.5 m/s² (the profile's mission.acc_m_s2): 2.2 m.
    assert!(
        (along - 2.2).abs() < 0.15 && across.abs() < 1e-6,
        "forward: {p:?}"
    );
    let (_, g) = fly_sticks(StickMode::Position, [1.0, 0.0, 0.0, 0.0], 3.0);
    let (p, _, _) = g.path.expect("a path");
    let across = p.pos_m[0] * s - p.pos_m[1] * co;
    assert!((across - 2.2).abs() < 0.15, "right: {p:?}");
    // Yaw right: clockwise seen from above, the heading decreases (1 rad/s for 2 s).
    let (_, g) = fly_sticks(StickMode::Position, [0.0, 0.0, 1.0, 0.0], 2.0);
    let yaw = g.yaw_rad.expect("a heading");
    // The joystick's first message at 10.1 s: 1.9 s of turning.
    assert!((yaw - (0.25 - 1.9)).abs() < 0.02, "{yaw}");
    // Throttle up: a climb (the sticks read centred till the joystick's first message).
    let (_, g) = fly_sticks(StickMode::Position, [0.0, 0.0, 0.0, 1.0], 1.0);
    assert!(g.pos_m[2] > 1.15 && g.vz_m_s > 0.4, "{g:?}");
    // Altitude: the sticks are a tilt (roll right ψ > 0, pitch forward φ > 0), the heading
    // set at every step.
    let (_, g) = fly_sticks(StickMode::Altitude, [0.5, -1.0, 0.0, 0.0], 0.5);
    assert_eq!(g.tilt_rad, Some([0.5 * 0.27, -0.27]));
    assert!(!g.hold_xy && g.path.is_none());
    let (_, g) = fly_sticks(StickMode::Altitude, [0.02, 0.0, 0.0, 0.0], 0.5);
    assert_eq!(g.tilt_rad, None, "a joystick's jitter is not a tilt");
}

#[test]
fn a_throttle_away_from_its_centre_climbs_only_once_it_has_been_there() {
    let (mut c, _) = fly_sticks(StickMode::Position, [0.0, 0.0, 0.0, -1.0], 0.0);
    let mut ev = Vec::new();
    // The mode was entered with the throttle low (a radio's resting throttle): held.
    let mut g = c.guidance();
    for k in 1..=100 {
        let t = 10_000_000 + k * STEP_US;
        c.gcs_sticks([0.0, 0.0, 0.0, -1.0], t);
        g = c.on_estimate(&at(t, g.pos_m[2]), &mut ev).0;
    }
    assert!((g.pos_m[2] - 1.0).abs() < 1e-9, "{g:?}");
    // Centred once, then low: it descends.
    for k in 101..=400 {
        let t = 10_000_000 + k * STEP_US;
        let throttle = if k < 110 { 0.0 } else { -1.0 };
        c.gcs_sticks([0.0, 0.0, 0.0, throttle], t);
        g = c.on_estimate(&at(t, g.pos_m[2]), &mut ev).0;
    }
    assert!(g.pos_m[2] < 0.5, "{g:?}");
}

#[test]
fn the_fence_bounds_the_sticks_set_point_and_the_leash_keeps_it_near_the_vehicle() {
    let p = Params {
        fence_radius_m: 5.0,
        ..params()
    };
    let (mut c, mut ev) = holding_with(p);
    c.command(
        Command::Sticks(StickMode::Position),
        6_000_000,
        Ok(()),
        Some(&at(6_000_000, 1.0)),
        &mut ev,
    );
    // The vehicle stays put while the stick asks full speed: the leash holds the set point
    // 2 m ahead of it.
    let mut g = c.guidance();
    for k in 1..=300 {
        let t = 6_000_000 + k * STEP_US;
        c.gcs_sticks([0.0, 1.0, 0.0, 0.0], t);
        g = c.on_estimate(&at(t, 1.0), &mut ev).0;
    }
    let (p, _, _) = g.path.unwrap_or_else(|| panic!("{:?}: {ev:?}", c.mode()));
    assert!(
        (p.pos_m[0].hypot(p.pos_m[1]) - sticks::LEASH_M).abs() < 1e-6,
        "{p:?}"
    );
    // Following it, the vehicle meets the fence less its margin.
    for k in 301..=1300 {
        let t = 6_000_000 + k * STEP_US;
        c.gcs_sticks([0.0, 1.0, 0.0, 0.0], t);
        let mut o = at(t, 1.0);
        (o.pos_m[0], o.pos_m[1]) = (g.pos_m[0], g.pos_m[1]);
        g = c.on_estimate(&o, &mut ev).0;
    }
    let r = g.pos_m[0].hypot(g.pos_m[1]);
    assert!((r - (5.0 - sticks::FENCE_MARGIN_M)).abs() < 1e-6, "{r}");
}

#[test]
fn without_fixes_the_sticks_fly_altitude_and_the_gps_landing_waits_for_no_one_on_them() {
    let (mut c, mut ev) = holding();
    c.command(
        Command::Sticks(StickMode::Position),
        10_000_000,
        Ok(()),
        Some(&at(10_000_000, 1.0)),
        &mut ev,
    );
    let mut t = 10_010_000;
    // The fixes stop at 12 s (lost at 15 s); the joystick sends till 40 s.
    while t < 60_000_000 {
        let mut o = at(t, 1.0);
        o.gps_fused = t <= 12_000_000 && t % 1_000_000 == 0;
        if t % 1_000_000 == 0 {
            c.link_beat(LinkSource::Gcs, t);
        }
        if t < 40_000_000 && t % 100_000 == 0 {
            c.gcs_sticks([0.0; 4], t);
        }
        c.tick(t, &mut ev);
        c.on_estimate(&o, &mut ev);
        if (15_100_000..40_000_000).contains(&t) {
            assert_eq!(c.mode(), Mode::Altitude, "at {t}: {ev:?}");
        }
        t += STEP_US;
    }
    // No one on the sticks from 40 s (the last message at 39.9 s, read for 0.5 s): land.
    let land_at = entered_at(&ev, Mode::Land);
    assert!(
        land_at.is_some_and(|t| (40_400_000..40_500_000).contains(&t)),
        "{land_at:?}"
    );
}

#[test]
fn a_throttle_takeoff_needs_a_stick_mode_and_a_raise_from_low_after_the_ramp() {
    let (mut c, mut ev) = armed();
    let step = |c: &mut Commander, t: i64, throttle: f64, ev: &mut Vec<Event>| {
        c.gcs_sticks([0.0, 0.0, 0.0, throttle], t);
        c.on_estimate(&at(t, 0.0), ev);
    };
    // No stick mode chosen: the throttle is nothing.
    for k in 1..=20 {
        step(&mut c, k * STEP_US, 1.0, &mut ev);
    }
    assert_eq!(c.mode(), Mode::Armed);
    c.command(
        Command::Sticks(StickMode::Position),
        300_000,
        Ok(()),
        None,
        &mut ev,
    );
    // Chosen, the throttle left up is not a raise.
    for k in 31..=60 {
        step(&mut c, k * STEP_US, 1.0, &mut ev);
    }
    assert_eq!(c.mode(), Mode::Armed);
    // Low, then up: the takeoff, then position once at its height.
    step(&mut c, 610_000, -1.0, &mut ev);
    step(&mut c, 620_000, 0.8, &mut ev);
    assert_eq!(c.mode(), Mode::Takeoff, "{ev:?}");
    assert!(
        ev.iter()
            .any(|e| matches!(e, Event::Mode { why, .. } if why == "throttle raised in position"))
    );
    follow(&mut c, 630_000, 8_000_000, &mut ev);
    assert_eq!(c.mode(), Mode::Position, "{ev:?}");
}

#[test]
fn a_throttle_raised_under_another_mode_is_not_a_raise_in_a_stick_mode() {
    let mut c = Commander::new(rc_params());
    let mut ev = Vec::new();
    c.start(0, &mut ev);
    let report = |throttle: f64, stick_mode: Option<StickMode>| RcReport {
        stick_mode,
        ..rc(false, throttle)
    };
    c.rc_report(report(-1.0, Some(StickMode::Position)), 0, &mut ev);
    c.command(Command::Arm, 0, Ok(()), None, &mut ev);
    c.escs_running();
    let mut t = 0;
    let mut fly = |c: &mut Commander, throttle: f64, mode: Option<StickMode>, steps: i64| {
        for _ in 0..steps {
            c.rc_report(report(throttle, mode), t, &mut ev);
            c.on_estimate(&at(t, 0.0), &mut ev);
            t += STEP_US;
        }
    };
    // Low in position, then the switch at hold and the throttle up, then back to position:
    // the throttle was never raised in position.
    fly(&mut c, -1.0, Some(StickMode::Position), 10);
    fly(&mut c, 1.0, None, 10);
    fly(&mut c, 1.0, Some(StickMode::Position), 10);
    assert_eq!(c.mode(), Mode::Armed);
    // Low again in position, then up: the takeoff.
    fly(&mut c, -1.0, Some(StickMode::Position), 2);
    fly(&mut c, 1.0, Some(StickMode::Position), 2);
    assert_eq!(c.mode(), Mode::Takeoff);
}

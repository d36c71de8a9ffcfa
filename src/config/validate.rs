//! Validation: the list of rules a deserialised configuration must meet, each saying what it
//! allows. A numeric rule is built from one Rust range, and its "allowed" text is written from
//! that same range, so the range checked and the range printed cannot disagree.

use super::schema::{Config, Esc, Imu, Sim, WatchdogConfig};
use crate::core::control::{IntegralRule, Integrators};
use crate::core::model::{MotorLimits, mass_for_w_min_kg};
use crate::core::motor::{I2C_MAX, esc_max_rad_s, esc_start_rad_s};
use std::fmt;
use std::ops::Bound::{self, Excluded, Included, Unbounded};
use std::ops::{RangeBounds, RangeInclusive};

/// Take-off mass, kg: at 368 rad/s the motors lift at most 2.38 kg. Also bounds the manual
/// mass commands.
const MASS_KG: RangeInclusive<f64> = 0.1..=2.3;
/// Hover altitude set point, m.
const HOVER_Z_M: RangeInclusive<f64> = 0.0..=10.0;
/// Highest altitude a manual command may reach, m.
const MANUAL_Z_MAX_M: f64 = 20.0;
/// Consecutive good frame intervals before calibrating, frames. 0 would skip settling, and
/// with it the ESC start that follows it.
const SETTLE_FRAMES: RangeInclusive<u32> = 1..=10_000;
/// Highest settle frame count, frames.
const SETTLE_MAX_FRAMES: u32 = 100_000;
/// Highest accepted IMU frame interval, µs.
const PERIOD_MAX_US: u32 = 100_000;
/// The IMU's frame period, ms (spec 1.5). The flight-time limits below are counted in it: a
/// limit of seconds lets the vehicle fly blind or on a stale command for hundreds of frames.
const IMU_PERIOD_MS: u32 = 10;
/// Longest time from a frame to its motor command, ms: at most 10 IMU periods, which still
/// rides out the scheduling stalls of a loaded machine (tens of ms) in `sim --realtime`.
const DEADLINE_MS: RangeInclusive<u32> = 1..=10 * IMU_PERIOD_MS;
/// Longest time without a frame while the motors run, ms: more than one IMU period (the
/// normal wait for the next frame), at most 10 (the original waited 1 s: 100 frames).
const IMU_TIMEOUT_MS: RangeInclusive<u32> = IMU_PERIOD_MS + 1..=10 * IMU_PERIOD_MS;
/// The ESC writer's own timeout must leave the watchdog one IMU period after its deadline, ms.
const COMMAND_TIMEOUT_MARGIN_MS: u32 = IMU_PERIOD_MS;
/// Longest ESC writer timeout, ms: 15 IMU periods, room above the longest watchdog limits
/// (a 100 ms deadline + the margin).
const COMMAND_TIMEOUT_MAX_MS: u32 = 15 * IMU_PERIOD_MS;
/// Consecutive failed ESC write cycles before a halt; the original allowed 20 missed acks.
const MAX_MISSED_ACKS: RangeInclusive<u32> = 1..=20;
/// Net insane steps tolerated by the sanity rules; the original: 20 (0.2 s at 100 Hz). At
/// most 1 s of a vehicle hotter or more tilted than its limits.
const SANITY_MAX: RangeInclusive<u32> = 1..=100;
/// Lowest top motor speed, rad/s (a little above the ESC start threshold).
const W_MAX_MIN_RAD_S: f64 = 100.0;
/// The longest simulated run, s (`sim.duration_s` and `--duration`).
const SIM_DURATION_MAX_S: f64 = 86_400.0;
/// Simulated seconds of a run.
const SIM_DURATION_S: (Bound<f64>, Bound<f64>) = positive_to(SIM_DURATION_MAX_S);
/// When an injected fault strikes, s: a fault after the longest run would never strike.
const FAULT_TIME_S: RangeInclusive<f64> = 0.0..=SIM_DURATION_MAX_S;
/// Consecutive refused EKF updates before a halt: at least one; at most half a second of a
/// blind estimator at 100 Hz.
const ESTIMATOR_MAX_REFUSED: RangeInclusive<u32> = 1..=50;
/// Innovation gate width, standard deviations: any positive finite width.
const GATE_SIGMA: (Bound<f64>, Bound<f64>) = (Excluded(0.0), Unbounded);
/// How long a refused stop is retried, ms: at least a few re-send periods; at most 2 s, the
/// longest the shutdown waits for the motors.
const HALT_RETRY_MS: RangeInclusive<u32> = 10..=2000;

/// One rule applied to one value of a configuration.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Check {
    /// The dotted key of the value (with `[i]` for an element of a list).
    pub key: String,
    pub passed: bool,
    /// The value as the message shows it.
    pub value: String,
    /// What the rule allows, as the message shows it.
    pub allowed: String,
}

impl Check {
    /// A rule whose test and text are given as they are (for rules that are not a range).
    fn new(key: &str, passed: bool, value: String, allowed: impl Into<String>) -> Check {
        Check {
            key: key.to_string(),
            passed,
            value,
            allowed: allowed.into(),
        }
    }

    /// Appends an explanation in parentheses to the allowed text.
    fn note(mut self, note: &str) -> Check {
        self.allowed = format!("{} ({note})", self.allowed);
        self
    }

    /// Adds a second condition, described after the allowed text.
    fn and(mut self, passed: bool, condition: &str) -> Check {
        self.passed &= passed;
        self.allowed = format!("{}, {condition}", self.allowed);
        self
    }

    /// Names what the allowed range is, before it.
    fn described_as(mut self, what: &str) -> Check {
        self.allowed = format!("{what}, {}", self.allowed);
        self
    }
}

/// A number a range rule can check and print.
trait Number: Copy + PartialOrd + fmt::Display {
    /// False for values no range holds: the checks of floating-point values refuse NaN and
    /// the infinities even where the range is open on one side.
    fn is_number(self) -> bool {
        true
    }

    /// The text of a bound in an "allowed" message.
    fn bound_text(self) -> String {
        self.to_string()
    }
}

impl Number for u32 {}
impl Number for i16 {}

impl Number for f64 {
    fn is_number(self) -> bool {
        self.is_finite()
    }

    /// Large bounds (variances up to 1e12) read better with an exponent than with 12 zeros.
    fn bound_text(self) -> String {
        if self.abs() >= 1e6 {
            format!("{self:e}")
        } else {
            self.to_string()
        }
    }
}

/// An I2C address, shown in hexadecimal as the datasheets write it.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd)]
struct Hex(u8);

impl fmt::Display for Hex {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:02x}", self.0)
    }
}

impl Number for Hex {}

/// The text of a range: "0.1 to 2.3 kg", "more than 0, at most 1 s", "more than 0"...
fn range_text<T: Number>(range: &impl RangeBounds<T>, unit: &str) -> String {
    let unit = if unit.is_empty() {
        String::new()
    } else {
        format!(" {unit}")
    };
    let text = |b: &T| b.bound_text();
    match (range.start_bound(), range.end_bound()) {
        (Included(lo), Included(hi)) => format!("{} to {}{unit}", text(lo), text(hi)),
        (Excluded(lo), Included(hi)) => {
            format!("more than {}, at most {}{unit}", text(lo), text(hi))
        }
        (Included(lo), Excluded(hi)) => {
            format!("at least {}, less than {}{unit}", text(lo), text(hi))
        }
        (Excluded(lo), Excluded(hi)) => {
            format!("more than {}, less than {}{unit}", text(lo), text(hi))
        }
        (Included(lo), Unbounded) => format!("at least {}{unit}", text(lo)),
        (Excluded(lo), Unbounded) => format!("more than {}{unit}", text(lo)),
        (Unbounded, Included(hi)) => format!("at most {}{unit}", text(hi)),
        (Unbounded, Excluded(hi)) => format!("less than {}{unit}", text(hi)),
        (Unbounded, Unbounded) => "any number".to_string(),
    }
}

/// The range "more than 0, at most `max`" (a Rust range cannot open at its start).
const fn positive_to(max: f64) -> (Bound<f64>, Bound<f64>) {
    (Excluded(0.0), Included(max))
}

/// Whether `value` is a number (not NaN, not infinite) inside `range`.
fn holds<T: Number>(range: &impl RangeBounds<T>, value: T) -> bool {
    value.is_number() && range.contains(&value)
}

/// `value` must lie in `range`; the allowed text is the range's, with its unit.
fn in_range<T: Number>(key: &str, value: T, range: impl RangeBounds<T>, unit: &str) -> Check {
    Check::new(
        key,
        holds(&range, value),
        value.to_string(),
        range_text(&range, unit),
    )
}

/// `value` must be 0 (the feature off) or lie in `range`.
fn off_or_in_range(key: &str, value: f64, range: impl RangeBounds<f64>, unit: &str) -> Check {
    Check::new(
        key,
        value == 0.0 || holds(&range, value),
        value.to_string(),
        format!("0 (off) or {}", range_text(&range, unit)),
    )
}

/// `value` must be within ± `limit`.
fn within(key: &str, value: f64, limit: f64, unit: &str) -> Check {
    Check::new(
        key,
        holds(&(-limit..=limit), value),
        value.to_string(),
        format!("within ±{} {unit}", limit.bound_text()),
    )
}

/// Every element of `values` must be within ± `limit`; the list is one value.
fn each_within(key: &str, values: &[f64], limit: f64, unit: &str) -> Check {
    Check::new(
        key,
        values.iter().all(|v| holds(&(-limit..=limit), *v)),
        format!("{values:?}"),
        format!("each within ±{} {unit}", limit.bound_text()),
    )
}

/// `value` must be one of `allowed`.
fn one_of(key: &str, value: u32, allowed: &[u32]) -> Check {
    let list: Vec<String> = allowed.iter().map(u32::to_string).collect();
    Check::new(
        key,
        allowed.contains(&value),
        value.to_string(),
        format!("one of {}", list.join(", ")),
    )
}

/// `value` must be above the value of `other_key`, and at most `max`.
fn above_key(key: &str, value: u32, other_key: &str, other: u32, max: u32, unit: &str) -> Check {
    Check::new(
        key,
        value > other && value <= max,
        value.to_string(),
        format!("above {other_key}, at most {max} {unit}"),
    )
}

/// The rules that fail for `c`, in the order of the rule list.
pub(super) fn validate(c: &Config) -> Vec<Check> {
    all_rules(c).into_iter().filter(|r| !r.passed).collect()
}

/// What each rule allows, by key, as its error message words it (the book's reference of the
/// configuration is written from these). A key with several rules has each, in order.
pub fn allowed_by_key() -> Vec<(String, String)> {
    all_rules(&Config::default())
        .into_iter()
        .map(|r| (r.key, r.allowed))
        .collect()
}

/// Every rule applied to `c`, passed or not, in order.
fn all_rules(c: &Config) -> Vec<Check> {
    let rules = [
        flight_rules(c),
        imu_rules(&c.imu),
        esc_rules(&c.esc),
        watchdog_rules(&c.watchdog, &c.esc),
        log_motor_gps_rules(c),
        lowest_speed_rules(c),
        sim_rules(&c.sim),
        vec![in_range(
            "gps.fake_span_m",
            c.gps.fake_span_m,
            0.0..=100.0,
            "m",
        )],
        ekf_rules(c),
        states_rule(c),
        manual_rules(c),
        integral_rules(c),
        commander_rules(c),
        failsafe_rules(c),
        gcs_rules(c),
        mission_rules(c),
        rc_rules(c),
    ];
    rules.into_iter().flatten().collect()
}

/// The vehicle, the set points and the motor lag.
fn flight_rules(c: &Config) -> Vec<Check> {
    vec![
        in_range("vehicle.mass_kg", c.vehicle.mass_kg, MASS_KG, "kg")
            .note("at 368 rad/s the motors lift at most 2.38 kg"),
        in_range("control.hover_z_m", c.control.hover_z_m, HOVER_Z_M, "m"),
        in_range(
            "control.gps_hold_timeout_s",
            c.control.gps_hold_timeout_s,
            positive_to(3600.0),
            "s",
        ),
        in_range("motor.tau_s", c.motor.tau_s, positive_to(1.0), "s"),
        off_or_in_range(
            "control.torque_observer_s",
            c.control.torque_observer_s,
            0.01..=10.0,
            "s",
        ),
    ]
}

/// The IMU's serial link, settling and calibration.
fn imu_rules(imu: &Imu) -> Vec<Check> {
    vec![
        in_range(
            "imu.settle_frames",
            imu.settle_frames,
            SETTLE_FRAMES,
            "frames",
        )
        .note("0 would skip settling and the ESC start"),
        Check::new(
            "imu.settle_max_frames",
            (imu.settle_frames..=SETTLE_MAX_FRAMES).contains(&imu.settle_max_frames),
            imu.settle_max_frames.to_string(),
            format!("imu.settle_frames to {SETTLE_MAX_FRAMES} frames"),
        ),
        in_range(
            "imu.settle_timeout_s",
            imu.settle_timeout_s,
            positive_to(600.0),
            "s",
        ),
        in_range(
            "imu.period_min_us",
            imu.period_min_us,
            1_000..=PERIOD_MAX_US,
            "µs",
        ),
        above_key(
            "imu.period_max_us",
            imu.period_max_us,
            "imu.period_min_us",
            imu.period_min_us,
            PERIOD_MAX_US,
            "µs",
        ),
        in_range("imu.calib_frames", imu.calib_frames, 6..=100_000, "frames")
            .note("at least the FIR length"),
        one_of(
            "imu.baud",
            imu.baud,
            &[9_600, 19_200, 38_400, 57_600, 115_200, 230_400],
        ),
    ]
}

/// The ESC wiring, trims and re-send period.
fn esc_rules(esc: &Esc) -> Vec<Check> {
    let addresses = esc.addresses.iter().enumerate().map(|(i, a)| {
        in_range(
            &format!("esc.addresses[{i}]"),
            Hex(*a),
            Hex(0x08)..=Hex(0x77),
            "",
        )
        .described_as("a 7-bit I2C address")
    });
    let mut sorted = esc.addresses;
    sorted.sort_unstable();
    let distinct = Check::new(
        "esc.addresses",
        sorted.windows(2).all(|w| w[0] != w[1]),
        format!("{:?}", esc.addresses),
        "four different addresses",
    );
    let trims = esc
        .trims
        .iter()
        .enumerate()
        .map(|(i, t)| in_range(&format!("esc.trims[{i}]"), *t, -50..=50, ""));
    let resend = in_range("esc.resend_ms", esc.resend_ms, 1..=20, "ms");
    addresses
        .chain([distinct])
        .chain(trims)
        .chain([resend])
        .collect()
}

/// The watchdog's limits, and the ESC writer's timeout, which must leave the watchdog time to
/// act first. Each is a few IMU periods at most: the vehicle flies on while they run out.
fn watchdog_rules(wd: &WatchdogConfig, esc: &Esc) -> Vec<Check> {
    let imu_timeout_ms = wd.imu_timeout_ms;
    // Saturating: the products and sums of values far out of range must not overflow.
    let failing_ms = wd.max_missed_acks.saturating_mul(esc.resend_ms);
    let failing_max_ms = *IMU_TIMEOUT_MS.end();
    vec![
        in_range("watchdog.deadline_ms", wd.deadline_ms, DEADLINE_MS, "ms"),
        in_range(
            "watchdog.imu_timeout_ms",
            imu_timeout_ms,
            IMU_TIMEOUT_MS,
            "ms",
        )
        .and(imu_timeout_ms > esc.resend_ms, "above esc.resend_ms"),
        command_timeout_rule(wd, esc),
        in_range(
            "watchdog.max_missed_acks",
            wd.max_missed_acks,
            MAX_MISSED_ACKS,
            "",
        )
        .and(
            failing_ms <= failing_max_ms,
            &format!("and at most {failing_max_ms} ms of failing cycles (times esc.resend_ms)"),
        ),
        in_range(
            "watchdog.sanity_temp_max_c",
            wd.sanity_temp_max_c,
            0.0..=125.0,
            "°C",
        ),
        in_range(
            "watchdog.sanity_tilt_max_rad",
            wd.sanity_tilt_max_rad,
            positive_to(1.57),
            "rad",
        ),
        in_range("watchdog.sanity_max", wd.sanity_max, SANITY_MAX, "steps"),
        in_range(
            "watchdog.estimator_max_refused",
            wd.estimator_max_refused,
            ESTIMATOR_MAX_REFUSED,
            "steps",
        ),
        in_range(
            "watchdog.halt_retry_ms",
            wd.halt_retry_ms,
            HALT_RETRY_MS,
            "ms",
        ),
    ]
}

/// The ESC writer's own timeout: a backup that must leave the watchdog, which names the
/// reason, time to act first. Compared only with watchdog limits that are themselves in
/// range, so one bad value is reported once.
fn command_timeout_rule(wd: &WatchdogConfig, esc: &Esc) -> Check {
    let timeout_ms = esc.command_timeout_ms;
    let after_imu_timeout =
        !IMU_TIMEOUT_MS.contains(&wd.imu_timeout_ms) || timeout_ms > wd.imu_timeout_ms;
    let after_deadline = !DEADLINE_MS.contains(&wd.deadline_ms)
        || timeout_ms > wd.deadline_ms + COMMAND_TIMEOUT_MARGIN_MS;
    Check::new(
        "esc.command_timeout_ms",
        after_imu_timeout && after_deadline && timeout_ms <= COMMAND_TIMEOUT_MAX_MS,
        timeout_ms.to_string(),
        format!(
            "above watchdog.imu_timeout_ms and watchdog.deadline_ms + \
             {COMMAND_TIMEOUT_MARGIN_MS}, at most {COMMAND_TIMEOUT_MAX_MS} ms"
        ),
    )
}

/// The log queue, the motors' top speed (the mass must hover below it) and gpsd's address.
fn log_motor_gps_rules(c: &Config) -> Vec<Check> {
    let server_ok = c
        .gps
        .server
        .rsplit_once(':')
        .is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok());
    vec![
        in_range("log.queue_records", c.log.queue_records, 1..=1_000_000, ""),
        in_range(
            "motor.w_max_rad_s",
            c.motor.w_max_rad_s,
            w_max_range_rad_s(),
            "rad/s",
        )
        .note(&format!(
            "the speed of the ESC's largest I2C value, {I2C_MAX}"
        )),
        hover_rule(c),
        Check::new(
            "gps.server",
            server_ok,
            format!("{:?}", c.gps.server),
            "HOST:PORT, e.g. 127.0.0.1:2947",
        ),
    ]
}

/// The top motor speeds allowed, rad/s: up to the fastest the ESC's I2C value range carries.
fn w_max_range_rad_s() -> RangeInclusive<f64> {
    W_MAX_MIN_RAD_S..=esc_max_rad_s()
}

/// The mass must hover below the motors' top speed. Checked only when the mass is itself in
/// range, so one bad mass is reported once.
fn hover_rule(c: &Config) -> Check {
    let mass_kg = c.vehicle.mass_kg;
    let w_max_rad_s = c.motor.w_max_rad_s;
    let w_hover_rad_s = crate::core::model::w_hover_rad_s(mass_kg);
    Check::new(
        "vehicle.mass_kg",
        !holds(&MASS_KG, mass_kg) || !w_max_rad_s.is_finite() || w_hover_rad_s < w_max_rad_s,
        format!("{mass_kg} (hover needs {w_hover_rad_s:.1} rad/s)"),
        "a mass that hovers below motor.w_max_rad_s",
    )
}

/// The slowest motor command, w_min = 2·w_hover − motor.w_max_rad_s (spec 4.2), falls with
/// the mass: at or below the ESC start threshold a motor is commanded to stop in flight. So the
/// lightest mass flown - vehicle.mass_kg, or control.manual.mass_min_kg when the manual mass
/// keys go lower - must keep it above. Checked only when the keys it derives from are in
/// range, so one bad value is reported once.
fn lowest_speed_rules(c: &Config) -> Vec<Check> {
    let w_max_rad_s = c.motor.w_max_rad_s;
    let mass_kg = c.vehicle.mass_kg;
    let mass_min_kg = c.control.manual.mass_min_kg;
    let Some(lightest_kg) = lightest_mass_kg(w_max_rad_s) else {
        return Vec::new();
    };
    let rule = |key: &str, what: &str, mass_kg: f64| {
        in_range(key, mass_kg, lightest_kg.., "kg").note(&lowest_speed_reason(
            what,
            mass_kg,
            w_max_rad_s,
        ))
    };
    let mut checks = Vec::new();
    if holds(&MASS_KG, mass_kg) {
        checks.push(rule("vehicle.mass_kg", "the profile's mass", mass_kg));
    }
    if holds(&MASS_KG, mass_min_kg) && mass_min_kg < mass_kg {
        let what = "the lightest mass the manual mass keys reach";
        checks.push(rule("control.manual.mass_min_kg", what, mass_min_kg));
    }
    checks
}

/// The lightest mass that keeps the slowest motor command above the ESC start threshold at
/// top speed `w_max_rad_s`, kg; None when that top speed is itself out of range. It is the
/// mass where w_min meets the threshold, rounded up to the next 0.01 kg: the bound checked is
/// the bound printed, and every mass from it on is strictly above the threshold.
fn lightest_mass_kg(w_max_rad_s: f64) -> Option<f64> {
    if !holds(&w_max_range_rad_s(), w_max_rad_s) {
        return None;
    }
    let exact_kg = mass_for_w_min_kg(esc_start_rad_s(), w_max_rad_s);
    Some(((exact_kg * 100.0).floor() + 1.0) / 100.0)
}

/// Why a mass is too light: the slowest motor command it gives, against the threshold.
fn lowest_speed_reason(what: &str, mass_kg: f64, w_max_rad_s: f64) -> String {
    let w_min_rad_s = MotorLimits::new(mass_kg, w_max_rad_s).w_min_rad_s;
    format!(
        "at {what}, {mass_kg} kg, with motor.w_max_rad_s = {w_max_rad_s}, the lowest motor \
         speed 2·w_hover − w_max is {w_min_rad_s:.1} rad/s; it must stay above the ESC start \
         threshold {:.1} rad/s",
        esc_start_rad_s()
    )
}

/// The simulator's physics and sensors.
fn sim_rules(sim: &Sim) -> Vec<Check> {
    let physics_hz = sim.physics_hz;
    // `is_multiple_of(0)` is false rather than a division by zero, so a rate of 0 (refused by
    // the range) is safe here.
    let divides = 1_000_000u32.is_multiple_of(physics_hz) && (physics_hz / 100).is_multiple_of(2);
    vec![
        in_range("sim.duration_s", sim.duration_s, SIM_DURATION_S, "s"),
        in_range("sim.settle_s", sim.settle_s, 0.0..=3600.0, "s"),
        in_range("sim.physics_hz", physics_hz, 1000..=100_000, "").and(
            divides,
            "dividing 1 s into whole µs and each 5 ms into whole steps",
        ),
        in_range("sim.motor_tau_s", sim.motor_tau_s, positive_to(1.0), "s"),
        in_range(
            "sim.drag_n_per_m_s",
            sim.drag_n_per_m_s,
            0.0..=10.0,
            "N per m/s",
        ),
        each_within("sim.wind_m_s", &sim.wind_m_s, 30.0, "m/s"),
        in_range("sim.acc_noise_m_s2", sim.acc_noise_m_s2, 0.0..=10.0, "m/s²"),
        in_range(
            "sim.gyro_noise_rad_s",
            sim.gyro_noise_rad_s,
            0.0..=1.0,
            "rad/s",
        ),
        each_within("sim.gyro_bias_rad_s", &sim.gyro_bias_rad_s, 1.0, "rad/s"),
        in_range("sim.baro_noise_pa", sim.baro_noise_pa, 0.0..=1000.0, "Pa"),
        in_range("sim.mag_noise", sim.mag_noise, 0.0..=1.0, ""),
        in_range(
            "sim.gyro_bias_walk_rad_s_per_sqrt_s",
            sim.gyro_bias_walk_rad_s_per_sqrt_s,
            0.0..=0.1,
            "rad/s/√s",
        ),
        in_range(
            "sim.acc_bias_walk_m_s2_per_sqrt_s",
            sim.acc_bias_walk_m_s2_per_sqrt_s,
            0.0..=1.0,
            "m/s²/√s",
        ),
        in_range("sim.temp_c", sim.temp_c, -20.0..=50.0, "°C"),
        within("sim.initial_yaw_rad", sim.initial_yaw_rad, 3.2, "rad"),
        in_range("sim.gust_n", sim.gust_n, 0.0..=100.0, "N"),
        in_range("sim.gust_s", sim.gust_s, 0.0..=600.0, "s"),
        in_range("sim.gps_glitch_m", sim.gps_glitch_m, 0.0..=1000.0, "m"),
        in_range("sim.gps_glitch_s", sim.gps_glitch_s, 0.0..=600.0, "s"),
        within(
            "sim.gyro_bias_step_rad_s",
            sim.gyro_bias_step_rad_s,
            1.0,
            "rad/s",
        ),
        in_range("sim.gps_rate_hz", sim.gps_rate_hz, 1.0..=10.0, "Hz"),
        in_range("sim.gps_delay_s", sim.gps_delay_s, 0.0..=1.0, "s"),
        in_range("sim.gps_noise_h_m", sim.gps_noise_h_m, 0.0..=50.0, "m"),
        in_range("sim.gps_noise_v_m", sim.gps_noise_v_m, 0.0..=50.0, "m"),
        in_range("sim.gps_bias_h_m", sim.gps_bias_h_m, 0.0..=50.0, "m"),
        in_range("sim.gps_bias_v_m", sim.gps_bias_v_m, 0.0..=50.0, "m"),
        in_range("sim.gps_bias_tau_s", sim.gps_bias_tau_s, 1.0..=3600.0, "s"),
        in_range(
            "sim.gps_noise_vel_m_s",
            sim.gps_noise_vel_m_s,
            0.0..=10.0,
            "m/s",
        ),
    ]
}

/// Arming, takeoff and landing: each a positive number up to a limit, the landing's slow
/// speed no faster than its speed.
fn commander_rules(c: &Config) -> Vec<Check> {
    let m = &c.commander;
    let limits = [
        ("commander.climb_m_s", m.climb_m_s, 5.0, "m/s"),
        ("commander.climb_acc_m_s2", m.climb_acc_m_s2, 10.0, "m/s²"),
        (
            "commander.takeoff_tolerance_m",
            m.takeoff_tolerance_m,
            2.0,
            "m",
        ),
        ("commander.land_m_s", m.land_m_s, 3.0, "m/s"),
        ("commander.touchdown_v_m_s", m.touchdown_v_m_s, 1.0, "m/s"),
        ("commander.touchdown_s", m.touchdown_s, 10.0, "s"),
        ("commander.gps_max_eph_m", m.gps_max_eph_m, 100.0, "m"),
        ("commander.input_expiry_s", m.input_expiry_s, 10.0, "s"),
    ];
    let mut checks: Vec<Check> = limits
        .into_iter()
        .map(|(key, v, max, unit)| in_range(key, v, positive_to(max), unit))
        .collect();
    checks.push(
        in_range(
            "commander.land_slow_m_s",
            m.land_slow_m_s,
            positive_to(1.0),
            "m/s",
        )
        .and(m.land_slow_m_s <= m.land_m_s, "at most commander.land_m_s"),
    );
    checks.extend([
        in_range(
            "commander.disarm_ground_s",
            m.disarm_ground_s,
            positive_to(600.0),
            "s",
        ),
        in_range(
            "commander.crash_tilt_rad",
            m.crash_tilt_rad,
            0.3..=std::f64::consts::PI,
            "rad",
        ),
        in_range("commander.crash_s", m.crash_s, positive_to(10.0), "s"),
        takeoff_timeout_rule(c),
        touchdown_thrust_rule(c),
        flight_time_rule(c),
    ]);
    checks
}

/// A landing or a takeoff must end within this, s: a ground station may set speeds and
/// accelerations one at a time, and some small enough together never finish.
const FLIGHT_PHASE_MAX_S: f64 = 600.0;

/// How long a set point takes over `height_m` at `speed_m_s`, reaching that speed at
/// `acc_m_s2` (and slowing again), s.
fn phase_s(height_m: f64, speed_m_s: f64, acc_m_s2: f64) -> f64 {
    height_m / speed_m_s + speed_m_s / acc_m_s2
}

/// A takeoff to `fence.alt_max_m` and a landing from it (the last metre at
/// `commander.land_slow_m_s`) each within [`FLIGHT_PHASE_MAX_S`].
fn flight_time_rule(c: &Config) -> Check {
    let m = &c.commander;
    let h_m = c.fence.alt_max_m;
    let takeoff_s = phase_s(h_m, m.climb_m_s, m.climb_acc_m_s2);
    let landing_s = phase_s((h_m - 1.0).max(0.0), m.land_m_s, m.climb_acc_m_s2)
        + phase_s(1.0, m.land_slow_m_s, m.climb_acc_m_s2);
    let worst_s = takeoff_s.max(landing_s);
    Check::new(
        "commander.climb_acc_m_s2",
        worst_s <= FLIGHT_PHASE_MAX_S,
        format!(
            "{} (with climb_m_s {}, land_m_s {}, land_slow_m_s {}: a takeoff to fence.alt_max_m \
             = {h_m} m takes {takeoff_s:.0} s, a landing from it {landing_s:.0} s)",
            m.climb_acc_m_s2, m.climb_m_s, m.land_m_s, m.land_slow_m_s
        ),
        format!(
            "speeds and acceleration with which a takeoff and a landing each end within \
             {FLIGHT_PHASE_MAX_S} s"
        ),
    )
}

/// The takeoff's timeout must leave the spool-up (1 s), the set point's climb to the lift-off
/// height (0.3 m) and 3 s for the vehicle to follow.
fn takeoff_timeout_rule(c: &Config) -> Check {
    let m = &c.commander;
    let needed_s = 1.0 + phase_s(0.3, m.climb_m_s, m.climb_acc_m_s2) + 3.0;
    in_range(
        "commander.takeoff_timeout_s",
        m.takeoff_timeout_s,
        positive_to(600.0),
        "s",
    )
    .and(
        m.takeoff_timeout_s >= needed_s,
        &format!(
            "at least {needed_s:.1} s (the 1 s spool-up, the climb to 0.3 m at \
             commander.climb_m_s and climb_acc_m_s2, 3 s to follow)"
        ),
    )
}

/// A touchdown is seen only once the thrust falls under `commander.touchdown_thrust` of the
/// weight; the controller's slowest command, w_min = 2·w_hover − w_max, gives (w_min/w_hover)²
/// of it, which grows with the mass. So the threshold must clear that floor, with a margin, at
/// the profile's mass (the manual mass keys may still raise the floor in flight: the
/// touchdown also takes the floor itself, see `core::commander`).
fn touchdown_thrust_rule(c: &Config) -> Check {
    const MARGIN: f64 = 0.05;
    let m = &c.commander;
    let heaviest_kg = c.vehicle.mass_kg;
    let w_hover_rad_s = crate::core::model::w_hover_rad_s(heaviest_kg);
    let floor = (2.0 - c.motor.w_max_rad_s / w_hover_rad_s).max(0.0).powi(2);
    let range = in_range(
        "commander.touchdown_thrust",
        m.touchdown_thrust,
        positive_to(1.0),
        "",
    );
    if !floor.is_finite() {
        return range;
    }
    range.and(
        m.touchdown_thrust >= floor + MARGIN,
        &format!(
            "above {:.2}: the thrust of the slowest motor command at {heaviest_kg} kg is \
             {floor:.2} of the weight, and a landing must fall under the threshold to end",
            floor + MARGIN
        ),
    )
}

/// The ground-station link: addresses that parse, a radio speed a radio has, rates that a
/// link can carry.
fn gcs_rules(c: &Config) -> Vec<Check> {
    let g = &c.gcs;
    let address = |key: &str, text: &str| {
        Check::new(
            key,
            text.parse::<std::net::SocketAddr>().is_ok(),
            format!("{text:?}"),
            "an IP address and port, like \"127.0.0.1:14550\"",
        )
    };
    vec![
        address("gcs.udp_remote", &g.udp_remote),
        address("gcs.udp_local", &g.udp_local),
        one_of(
            "gcs.baud",
            g.baud,
            &[
                9_600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600,
            ],
        ),
        in_range("gcs.system_id", u32::from(g.system_id), 1..=254, ""),
        in_range("gcs.telemetry_hz", g.telemetry_hz, 0.1..=50.0, "Hz"),
        in_range("gcs.max_rx_per_s", g.max_rx_per_s, 10..=10_000, "frames/s"),
        Check::new(
            "gcs.allowed_systems",
            g.allowed_systems.len() <= 16
                && g.allowed_systems
                    .iter()
                    .all(|s| *s != 0 && *s != g.system_id),
            format!("{:?}", g.allowed_systems),
            "at most 16 system ids, each 1 to 255 and not gcs.system_id (the vehicle's own)",
        ),
    ]
}

/// The RC receiver: each function on its own channel, each channel's calibration in order
/// within 11 bits, sticks that ask what the vehicle can fly, a mode switch of 1 to 6
/// positions, an RC-loss action a pilot can follow.
fn rc_rules(c: &Config) -> Vec<Check> {
    let rc = &c.rc;
    let mut rules = Vec::new();
    for (name, ch) in rc.functions() {
        let key = |field: &str| format!("rc.{name}.{field}");
        rules.push(in_range(&key("channel"), u32::from(ch.channel), 1..=16, ""));
        let used_by: Vec<&str> = rc
            .functions()
            .into_iter()
            .filter(|(other, o)| *other != name && o.channel == ch.channel)
            .map(|(other, _)| other)
            .collect();
        let value = if used_by.is_empty() {
            ch.channel.to_string()
        } else {
            format!("{} (also {})", ch.channel, used_by.join(", "))
        };
        rules.push(Check::new(
            &key("channel"),
            used_by.is_empty(),
            value,
            "a channel no other function uses",
        ));
        rules.push(Check::new(
            &format!("rc.{name}"),
            ch.min < ch.center && ch.center < ch.max && ch.max <= crate::core::rc::TICKS_MAX,
            format!("min {}, center {}, max {}", ch.min, ch.center, ch.max),
            "min < center < max ≤ 2047 ticks",
        ));
        rules.push(in_range(&key("deadband"), ch.deadband, 0.0..=0.5, ""));
    }
    rules.extend([
        in_range(
            "rc.max_speed_m_s",
            rc.max_speed_m_s,
            positive_to(10.0),
            "m/s",
        ),
        in_range(
            "rc.max_climb_m_s",
            rc.max_climb_m_s,
            positive_to(5.0),
            "m/s",
        ),
        in_range(
            "rc.max_yaw_rate_rad_s",
            rc.max_yaw_rate_rad_s,
            positive_to(3.0),
            "rad/s",
        ),
        Check::new(
            "rc.modes",
            (1..=6).contains(&rc.modes.len())
                && rc
                    .modes
                    .iter()
                    .enumerate()
                    .all(|(i, m)| !rc.modes[..i].contains(m)),
            format!(
                "{:?}",
                rc.modes.iter().map(|m| m.name()).collect::<Vec<_>>()
            ),
            "1 to 6 modes, each once, one per position of the mode switch",
        ),
        in_range(
            "failsafe.rc_timeout_s",
            c.failsafe.rc_timeout_s,
            0.2..=10.0,
            "s",
        ),
        Check::new(
            "failsafe.rc_loss_action",
            c.failsafe.rc_loss_action != crate::core::commander::Action::Kill,
            c.failsafe.rc_loss_action.name().to_string(),
            "\"land\", \"return\" or \"hold\" (a pilot who lost the radio is not killed)",
        ),
    ]);
    rules
}

/// How missions are flown: accelerations and rates a vehicle can follow.
fn mission_rules(c: &Config) -> Vec<Check> {
    let m = &c.mission;
    vec![
        in_range("mission.acc_m_s2", m.acc_m_s2, positive_to(5.0), "m/s²"),
        in_range(
            "mission.yaw_rate_rad_s",
            m.yaw_rate_rad_s,
            positive_to(3.0),
            "rad/s",
        ),
        in_range(
            "mission.yaw_acc_rad_s2",
            m.yaw_acc_rad_s2,
            positive_to(10.0),
            "rad/s²",
        ),
        in_range("mission.return_m_s", m.return_m_s, 0.05..=10.0, "m/s"),
        in_range("mission.speed_m_s", m.speed_m_s, 0.05..=10.0, "m/s"),
    ]
}

/// The failsafes and the fence: known link sources, a link timeout longer than the links'
/// one-second beat, a fence above the takeoff's default height.
fn failsafe_rules(c: &Config) -> Vec<Check> {
    let (f, fence) = (&c.failsafe, &c.fence);
    let unknown: Vec<&String> = f
        .link_sources
        .iter()
        .filter(|s| crate::core::commander::LinkSource::from_name(s).is_none())
        .collect();
    vec![
        Check::new(
            "failsafe.link_sources",
            unknown.is_empty(),
            format!("{:?}", f.link_sources),
            "a list of \"terminal\", \"console\", \"gcs\"",
        ),
        in_range(
            "failsafe.link_timeout_s",
            f.link_timeout_s,
            1.5..=600.0,
            "s",
        )
        .note("the links beat once a second"),
        in_range(
            "failsafe.gps_loss_land_s",
            f.gps_loss_land_s,
            0.0..=600.0,
            "s",
        ),
        in_range("failsafe.ekf_bad_s", f.ekf_bad_s, positive_to(600.0), "s").and(
            f.ekf_bad_s >= 2.0 * c.ekf.angle_period_s,
            "at least twice ekf.angle_period_s (the attitude's ratio is held between the \
             angles' fusions: one fusion outside its gate must not be the failsafe)",
        ),
        in_range(
            "fence.radius_m",
            fence.radius_m,
            positive_to(100_000.0),
            "m",
        ),
        in_range(
            "fence.alt_max_m",
            fence.alt_max_m,
            positive_to(10_000.0),
            "m",
        )
        .and(
            fence.alt_max_m > c.control.hover_z_m,
            "above control.hover_z_m (the takeoff's default height)",
        ),
    ]
}

/// Every element of the estimator's noise diagonals is a variance; the innovation gate has a
/// width (a gate of 0 would refuse every measurement, one of infinity none).
fn ekf_rules(c: &Config) -> Vec<Check> {
    let lists: [(&str, &[f64]); 5] = [
        ("ekf.q", &c.ekf.q),
        ("ekf.r_imu", &c.ekf.r_imu),
        ("ekf.r_gps", &c.ekf.r_gps),
        ("ekf.p0", &c.ekf.p0),
        ("ekf.r_ground", &c.ekf.r_ground),
    ];
    let variance = positive_to(1e12);
    lists
        .into_iter()
        .flat_map(|(key, values)| {
            values.iter().enumerate().map(move |(i, v)| {
                in_range(&format!("{key}[{i}]"), *v, variance, "").note("a variance")
            })
        })
        .chain([in_range(
            "ekf.gate_sigma",
            c.ekf.gate_sigma,
            GATE_SIGMA,
            "standard deviations",
        )
        .note("finite")])
        .chain([in_range("ekf.r_gps_vel", c.ekf.r_gps_vel, variance, "(m/s)²").note("a variance")])
        .chain([in_range(
            "ekf.drag_per_s",
            c.ekf.drag_per_s,
            0.0..=10.0,
            "1/s",
        )])
        .chain([
            in_range("ekf.angle_period_s", c.ekf.angle_period_s, 0.0..=10.0, "s")
                .note("0: every step"),
            in_range("ekf.q_gyro_bias", c.ekf.q_gyro_bias, 0.0..=1.0, "(rad/s)²").note("0: none"),
            in_range(
                "ekf.p0_gyro_bias",
                c.ekf.p0_gyro_bias,
                0.0..=1.0,
                "(rad/s)²",
            )
            .note("0: none"),
            // Unused by the joint fusion, as ekf.r_gps_vel is: a profile switched to it keeps
            // its value for when it is switched back.
            in_range("ekf.gps_bias_m", c.ekf.gps_bias_m, 0.0..=100.0, "m").note("0: none"),
            in_range(
                "ekf.gps_bias_tau_s",
                c.ekf.gps_bias_tau_s,
                1.0..=3600.0,
                "s",
            ),
            in_range("ekf.r_angles_rest", c.ekf.r_angles_rest, 0.0..=1.0, "rad²")
                .note("0: r_imu's"),
            in_range("ekf.r_field", c.ekf.r_field, 0.0..=1.0, "(unit vector)²").note("0: off"),
        ])
        .collect()
}

/// The controlled states and the integrators must go together: 12 states with ψ φ z θ or
/// x y z θ, 8 states with z θ. A bad state count is reported alone.
fn states_rule(c: &Config) -> Vec<Check> {
    let control = &c.control;
    let paired = matches!(
        (control.states, control.integrator_set()),
        (12, Some(Integrators::PsiPhiZTheta | Integrators::XYZTheta))
            | (8, Some(Integrators::ZTheta))
    );
    if !matches!(control.states, 8 | 12) {
        vec![Check::new(
            "control.states",
            false,
            control.states.to_string(),
            "12 (full) or 8 (reduced)",
        )]
    } else if !paired {
        let allowed = if control.states == 12 {
            "\"psi,phi,z,theta\" or \"x,y,z,theta\" with control.states = 12"
        } else {
            "\"z,theta\" with control.states = 8"
        };
        let value = format!("{:?}", control.integrators);
        vec![Check::new("control.integrators", false, value, allowed)]
    } else {
        Vec::new()
    }
}

/// How far manual commands may move the set point. A bound relative to another key is
/// checked only when that key is itself valid, so one bad value is reported once.
fn manual_rules(c: &Config) -> Vec<Check> {
    let man = &c.control.manual;
    let z_m = c.control.hover_z_m;
    let mass_kg = c.vehicle.mass_kg;
    let z_ok = holds(&HOVER_Z_M, z_m);
    // A mass too light for the ESC start threshold is reported by its own rule.
    let mass_ok = holds(&MASS_KG, mass_kg)
        && lightest_mass_kg(c.motor.w_max_rad_s).is_none_or(|lightest_kg| mass_kg >= lightest_kg);
    let (mass_lo_kg, mass_hi_kg) = (*MASS_KG.start(), *MASS_KG.end());
    vec![
        in_range(
            "control.manual.max_tilt_rad",
            man.max_tilt_rad,
            0.0..=1.0,
            "rad",
        )
        .note("the sanity check trips at 1 rad"),
        in_range(
            "control.manual.max_yaw_offset_rad",
            man.max_yaw_offset_rad,
            0.0..=6.3,
            "rad",
        ),
        Check::new(
            "control.manual.z_min_m",
            man.z_min_m.is_finite() && man.z_min_m >= 0.0 && (!z_ok || man.z_min_m <= z_m),
            man.z_min_m.to_string(),
            "0 up to control.hover_z_m",
        ),
        Check::new(
            "control.manual.z_max_m",
            man.z_max_m.is_finite()
                && (!z_ok || man.z_max_m >= z_m)
                && man.z_max_m <= MANUAL_Z_MAX_M,
            man.z_max_m.to_string(),
            format!("control.hover_z_m up to {MANUAL_Z_MAX_M} m"),
        ),
        Check::new(
            "control.manual.mass_min_kg",
            man.mass_min_kg.is_finite()
                && man.mass_min_kg >= mass_lo_kg
                && (!mass_ok || man.mass_min_kg <= mass_kg),
            man.mass_min_kg.to_string(),
            format!("{mass_lo_kg} kg up to vehicle.mass_kg"),
        ),
        Check::new(
            "control.manual.mass_max_kg",
            man.mass_max_kg.is_finite()
                && (!mass_ok || man.mass_max_kg >= mass_kg)
                && man.mass_max_kg <= mass_hi_kg,
            man.mass_max_kg.to_string(),
            format!("vehicle.mass_kg up to {mass_hi_kg} kg"),
        ),
    ]
}

/// Each integrator's rule, named by its state.
fn integral_rules(c: &Config) -> Vec<Check> {
    let i = &c.control.integral;
    let rules = [
        ("psi", i.psi),
        ("phi", i.phi),
        ("z", i.z),
        ("theta", i.theta),
        ("x", i.x),
        ("y", i.y),
    ];
    rules
        .into_iter()
        .flat_map(|(name, rule)| integral_rule(name, &rule))
        .collect()
}

/// One integrator's step, cap, optional threshold and seed.
fn integral_rule(name: &str, rule: &IntegralRule) -> Vec<Check> {
    let key = |leaf: &str| format!("control.integral.{name}.{leaf}");
    let mut checks = vec![
        in_range(&key("step_max"), rule.step_max, positive_to(10.0), ""),
        in_range(&key("cap"), rule.cap, positive_to(100.0), ""),
    ];
    if let Some(threshold) = rule.threshold {
        checks.push(
            in_range(&key("threshold"), threshold, (Excluded(0.0), Unbounded), "")
                .note("leave the key out for no threshold"),
        );
    }
    checks.push(Check::new(
        &key("seed"),
        rule.seed.is_finite() && rule.seed.abs() <= rule.cap,
        rule.seed.to_string(),
        "within ± the cap",
    ));
    checks
}

/// A number given on the command line, checked against the range of what it stands for; the
/// error says what is allowed (the parser's caller names the flag).
fn number_arg(text: &str, range: impl RangeBounds<f64>, unit: &str) -> Result<f64, String> {
    let allowed = range_text(&range, unit);
    match text.trim().parse::<f64>() {
        Ok(value) if holds(&range, value) => Ok(value),
        Ok(_) => Err(format!("{text} is out of range: allowed {allowed}")),
        Err(_) => Err(format!("{text:?} is not a number: allowed {allowed}")),
    }
}

/// `--duration S`: simulated seconds, in the range of `sim.duration_s`.
pub fn parse_duration_s(text: &str) -> Result<f64, String> {
    number_arg(text, SIM_DURATION_S, "s")
}

/// The time T of `--inject FAULT@T`, simulated seconds: from 0 up to the longest run.
pub fn parse_fault_time_s(text: &str) -> Result<f64, String> {
    number_arg(text, FAULT_TIME_S, "s")
}

/// `--seed N`: any integer from 0 that the run folder's config.toml can hold as `sim.seed`
/// (a TOML integer is at most `i64::MAX`), so that the run replays.
pub fn parse_seed(text: &str) -> Result<u64, String> {
    let allowed = format!("an integer from 0 to {}", i64::MAX);
    match text.trim().parse::<i128>() {
        Ok(seed) if (0..=i128::from(i64::MAX)).contains(&seed) => {
            u64::try_from(seed).map_err(|_| format!("{text} is out of range: allowed {allowed}"))
        }
        Ok(_) => Err(format!("{text} is out of range: allowed {allowed}")),
        Err(_) => Err(format!("{text:?} is not an integer: allowed {allowed}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Checks `value` against `range` with `in_range`.
    fn passes<T: Number>(value: T, range: impl RangeBounds<T>) -> bool {
        in_range("k", value, range, "u").passed
    }

    #[test]
    fn closed_range_text_and_bounds() {
        let check = in_range("vehicle.mass_kg", 1.0, MASS_KG, "kg");
        assert_eq!(check.allowed, "0.1 to 2.3 kg");
        assert!(check.passed);
        assert!(passes(0.1, MASS_KG) && passes(2.3, MASS_KG));
        assert!(!passes(0.1f64.next_down(), MASS_KG));
        assert!(!passes(2.3f64.next_up(), MASS_KG));
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert!(!passes(bad, MASS_KG), "{bad}");
        }
    }

    #[test]
    fn open_lower_bound_text_and_bounds() {
        let range = positive_to(1.0);
        assert_eq!(range_text(&range, "s"), "more than 0, at most 1 s");
        assert!(!passes(0.0, range));
        assert!(passes(f64::MIN_POSITIVE, range) && passes(1.0, range));
        assert!(!passes(1.0f64.next_up(), range));
    }

    #[test]
    fn unbounded_range_still_refuses_infinity() {
        let range = (Excluded(0.0), Unbounded);
        assert_eq!(range_text(&range, ""), "more than 0");
        assert!(passes(1e300, range));
        assert!(!passes(f64::INFINITY, range) && !passes(0.0, range));
    }

    #[test]
    fn integer_range_text_and_bounds() {
        assert_eq!(
            in_range("esc.resend_ms", 1u32, 1..=20, "ms").allowed,
            "1 to 20 ms"
        );
        assert!(passes(1u32, 1..=20) && passes(20u32, 1..=20));
        assert!(!passes(0u32, 1..=20) && !passes(21u32, 1..=20));
        assert_eq!(range_text(&(-50i16..=50), ""), "-50 to 50");
        assert!(passes(-50i16, -50..=50) && !passes(-51i16, -50..=50));
    }

    #[test]
    fn value_is_shown_as_given() {
        let check = in_range("vehicle.mass_kg", -3.0, MASS_KG, "kg");
        assert!(!check.passed);
        assert_eq!(check.value, "-3");
        let hex = in_range("esc.addresses[0]", Hex(0x05), Hex(0x08)..=Hex(0x77), "");
        assert_eq!(
            (hex.value.as_str(), hex.allowed.as_str()),
            ("0x05", "0x08 to 0x77")
        );
        assert!(!hex.passed);
        assert!(passes(Hex(0x08), Hex(0x08)..=Hex(0x77)));
        assert!(passes(Hex(0x77), Hex(0x08)..=Hex(0x77)));
        assert!(!passes(Hex(0x78), Hex(0x08)..=Hex(0x77)));
    }

    #[test]
    fn large_bounds_print_with_an_exponent() {
        let range = positive_to(1e12);
        assert_eq!(range_text(&range, ""), "more than 0, at most 1e12");
        assert!(passes(1e12, range) && !passes(1e12f64.next_up(), range));
    }

    #[test]
    fn notes_and_extra_conditions_extend_the_text() {
        let noted = in_range("k", 0.5, 0.0..=1.0, "rad").note("why");
        assert_eq!(noted.allowed, "0 to 1 rad (why)");
        let both = in_range("k", 1000u32, 1000..=100_000, "").and(false, "dividing");
        assert_eq!(both.allowed, "1000 to 100000, dividing");
        assert!(!both.passed);
    }

    #[test]
    fn off_or_in_range_accepts_zero_and_the_range() {
        let check = |v: f64| off_or_in_range("k", v, 0.01..=10.0, "s");
        assert_eq!(check(0.0).allowed, "0 (off) or 0.01 to 10 s");
        assert!(check(0.0).passed && check(0.01).passed && check(10.0).passed);
        assert!(!check(0.01f64.next_down()).passed && !check(10f64.next_up()).passed);
        assert!(!check(f64::NAN).passed);
    }

    #[test]
    fn within_is_symmetric() {
        let check = |v: f64| within("k", v, 3.2, "rad");
        assert_eq!(check(0.0).allowed, "within ±3.2 rad");
        assert!(check(3.2).passed && check(-3.2).passed);
        assert!(!check(3.2f64.next_up()).passed && !check((-3.2f64).next_down()).passed);
        let list = each_within("k", &[0.0, 30.0, -30.0], 30.0, "m/s");
        assert_eq!(list.allowed, "each within ±30 m/s");
        assert!(list.passed);
        assert!(!each_within("k", &[0.0, 30.5], 30.0, "m/s").passed);
    }

    #[test]
    fn one_of_lists_the_choices() {
        let check = one_of("imu.baud", 9_600, &[9_600, 115_200]);
        assert_eq!(check.allowed, "one of 9600, 115200");
        assert!(check.passed);
        assert!(!one_of("imu.baud", 9_601, &[9_600, 115_200]).passed);
    }

    #[test]
    fn the_default_configuration_meets_every_rule() {
        assert_eq!(validate(&Config::default()), Vec::new());
    }

    /// The keys of the rules `change` makes the default configuration fail.
    fn failing_keys(change: impl FnOnce(&mut Config)) -> Vec<String> {
        let mut c = Config::default();
        change(&mut c);
        validate(&c).into_iter().map(|check| check.key).collect()
    }

    #[test]
    fn a_light_mass_is_refused_where_it_is_set() {
        assert_eq!(
            failing_keys(|c| c.vehicle.mass_kg = 0.5),
            ["vehicle.mass_kg"]
        );
        assert_eq!(
            failing_keys(|c| c.control.manual.mass_min_kg = 0.5),
            ["control.manual.mass_min_kg"]
        );
        let mut c = Config::default();
        c.vehicle.mass_kg = 0.5;
        let check = &validate(&c)[0];
        assert!(
            check.allowed.starts_with("at least 0.92 kg"),
            "{}",
            check.allowed
        );
        assert!(check.allowed.contains("-18.2 rad/s"), "{}", check.allowed);
        assert!(check.allowed.contains("ESC start threshold 96.0 rad/s"));
    }

    #[test]
    fn every_mass_allowed_keeps_the_motors_above_the_esc_start() {
        for w_max_rad_s in [W_MAX_MIN_RAD_S, 250.0, 368.0, esc_max_rad_s()] {
            let Some(lightest_kg) = lightest_mass_kg(w_max_rad_s) else {
                panic!("{w_max_rad_s} is in range");
            };
            let too_light_kg = lightest_kg - 0.01;
            let limits = |m: f64| MotorLimits::new(m, w_max_rad_s).w_min_rad_s;
            assert!(limits(too_light_kg) <= esc_start_rad_s(), "{w_max_rad_s}");
            // From the bound up to the heaviest mass, by the manual keys' step.
            let steps = ((*MASS_KG.end() - lightest_kg) / 0.05) as u32;
            for m in (0..=steps).map(|i| lightest_kg + f64::from(i) * 0.05) {
                assert!(limits(m) > esc_start_rad_s(), "{w_max_rad_s} rad/s, {m} kg");
            }
        }
        assert_eq!(lightest_mass_kg(500.0), None);
    }

    #[test]
    fn a_top_speed_beyond_the_esc_byte_is_refused() {
        assert_eq!(
            failing_keys(|c| c.motor.w_max_rad_s = 500.0),
            ["motor.w_max_rad_s"]
        );
        assert_eq!(
            failing_keys(|c| c.motor.w_max_rad_s = 368.2),
            ["motor.w_max_rad_s"]
        );
        assert!(failing_keys(|c| c.motor.w_max_rad_s = 368.1).is_empty());
    }

    #[test]
    fn the_innovation_gate_has_a_positive_finite_width() {
        for bad in [0.0, -1.0, f64::INFINITY, f64::NAN] {
            assert_eq!(
                failing_keys(|c| c.ekf.gate_sigma = bad),
                ["ekf.gate_sigma"],
                "{bad}"
            );
        }
        assert!(failing_keys(|c| c.ekf.gate_sigma = 0.1).is_empty());
        assert!(failing_keys(|c| c.ekf.gate_sigma = 1e6).is_empty());
    }

    #[test]
    fn frame_and_sanity_counts_start_at_one() {
        assert_eq!(
            failing_keys(|c| c.imu.settle_frames = 0),
            ["imu.settle_frames"]
        );
        for bad in [0, 101, 10_000] {
            assert_eq!(
                failing_keys(|c| c.watchdog.sanity_max = bad),
                ["watchdog.sanity_max"]
            );
        }
        assert!(failing_keys(|c| c.watchdog.sanity_max = 100).is_empty());
    }

    #[test]
    fn timeouts_are_a_few_imu_periods() {
        assert_eq!(
            failing_keys(|c| c.watchdog.imu_timeout_ms = 5000),
            ["watchdog.imu_timeout_ms"]
        );
        assert_eq!(
            failing_keys(|c| c.watchdog.imu_timeout_ms = 10),
            ["watchdog.imu_timeout_ms"]
        );
        assert_eq!(
            failing_keys(|c| c.watchdog.deadline_ms = 5000),
            ["watchdog.deadline_ms"]
        );
        assert_eq!(
            failing_keys(|c| c.esc.command_timeout_ms = 5000),
            ["esc.command_timeout_ms"]
        );
        // The limits a loaded machine's runs use.
        let tolerant = failing_keys(|c| {
            c.watchdog.deadline_ms = 100;
            c.watchdog.imu_timeout_ms = 100;
            c.esc.command_timeout_ms = 150;
        });
        assert!(tolerant.is_empty(), "{tolerant:?}");
    }

    #[test]
    fn failing_esc_writes_are_bounded_in_count_and_time() {
        assert!(failing_keys(|c| c.watchdog.max_missed_acks = 20).is_empty());
        for change in [
            |c: &mut Config| c.watchdog.max_missed_acks = 21,
            |c: &mut Config| {
                // 120 ms of failing cycles at the slowest re-send period.
                c.watchdog.max_missed_acks = 6;
                c.esc.resend_ms = 20;
                c.watchdog.imu_timeout_ms = 50;
                c.esc.command_timeout_ms = 60;
            },
        ] {
            assert_eq!(failing_keys(change), ["watchdog.max_missed_acks"]);
        }
    }

    #[test]
    fn command_line_numbers_are_checked() {
        assert_eq!(parse_duration_s("40"), Ok(40.0));
        for bad in ["0", "-1", "nan", "inf", "1e9", "soon"] {
            let err = parse_duration_s(bad).err().unwrap_or_default();
            assert!(
                err.contains(bad) && err.contains("at most 86400 s"),
                "{bad}: {err}"
            );
        }
        assert_eq!(parse_fault_time_s("0"), Ok(0.0));
        assert!(parse_fault_time_s("-0.5").is_err() && parse_fault_time_s("1e9").is_err());
        assert_eq!(parse_seed("0"), Ok(0));
        assert_eq!(parse_seed("9223372036854775807"), Ok(i64::MAX as u64));
        for bad in ["-1", "9223372036854775808", "1.5", "x"] {
            assert!(parse_seed(bad).is_err(), "{bad}");
        }
    }
}

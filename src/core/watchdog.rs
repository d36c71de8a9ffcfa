//! Watchdog policy: when the motors must be halted, as a pure state machine (time passed in).
//!
//! Spec sections 2.5 (sanity: temperature, tilt, with its counter), 8.4 (timing) and the
//! flight stack's own rules: the 10 ms frame → command deadline, a silent IMU while the motors
//! run, consecutive missed ESC acknowledgements. Times are µs since the run's start.

/// Why the motors were halted. The names are the report's and the err log's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TripReason {
    Deadline,
    ImuTimeout,
    EscAck,
    SanityTemp,
    SanityTilt,
    /// The estimator refused its measurement update too many steps in a row: it runs blind.
    Estimator,
    /// The operator's `kill`, or a failsafe whose action is kill.
    Kill,
    /// The commander saw a crash or a flip (tilted too long, or a takeoff that never left the
    /// ground).
    Crash,
}

impl TripReason {
    pub fn name(self) -> &'static str {
        match self {
            TripReason::Deadline => "deadline",
            TripReason::ImuTimeout => "imu-timeout",
            TripReason::EscAck => "esc-ack",
            TripReason::SanityTemp => "sanity-temp",
            TripReason::SanityTilt => "sanity-tilt",
            TripReason::Estimator => "estimator",
            TripReason::Kill => "kill",
            TripReason::Crash => "crash",
        }
    }

    /// Every reason, in the order above.
    pub const ALL: [TripReason; 8] = [
        TripReason::Deadline,
        TripReason::ImuTimeout,
        TripReason::EscAck,
        TripReason::SanityTemp,
        TripReason::SanityTilt,
        TripReason::Estimator,
        TripReason::Kill,
        TripReason::Crash,
    ];

    /// The causes for which the motors may be cut in the air: the watchdog's own (the loop's
    /// deadline, a silent IMU, unacknowledged ESCs, the original's sanity rules), `kill`, a
    /// crash, and an estimator that can no longer give an attitude. Every other fault lands on
    /// what is left. One list, read by the safety campaign and the commander's exhaustive
    /// check alike.
    pub fn may_halt_in_air(self) -> bool {
        // Every reason is one; the list is written out so that a new reason must be placed.
        match self {
            TripReason::Deadline
            | TripReason::ImuTimeout
            | TripReason::EscAck
            | TripReason::SanityTemp
            | TripReason::SanityTilt
            | TripReason::Estimator
            | TripReason::Kill
            | TripReason::Crash => true,
        }
    }

    pub fn from_name(name: &str) -> Option<TripReason> {
        TripReason::ALL.into_iter().find(|r| r.name() == name)
    }
}

/// A decision to halt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trip {
    pub reason: TripReason,
    /// When the triggering event happened: the late frame's arrival (deadline), the last frame
    /// (imu-timeout), the first failed write of the run (esc-ack), the step that exhausted the
    /// sanity counter (sanity-*).
    pub event_us: i64,
    /// When the policy decided.
    pub decided_us: i64,
}

/// A halt as it happened: the decision, and how the stop (zero, then disable, retried until
/// acknowledged) ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Halt {
    pub trip: Trip,
    /// When the stop settled, µs since start: the last ESC acknowledged its disable
    /// (confirmed), or the retries ran out.
    pub halt_us: i64,
    /// The addresses of the ESCs that never acknowledged a zero speed and then a disable,
    /// in motor order; none when the stop was confirmed.
    pub unconfirmed: [Option<u8>; 4],
}

impl Halt {
    /// From the triggering event to the settled stop, ms.
    pub fn latency_ms(&self) -> f64 {
        (self.halt_us - self.trip.event_us) as f64 / 1000.0
    }

    /// From the triggering event to the decision, ms.
    pub fn decision_ms(&self) -> f64 {
        (self.trip.decided_us - self.trip.event_us) as f64 / 1000.0
    }

    /// Every ESC acknowledged a zero speed and then a disable.
    pub fn confirmed(&self) -> bool {
        self.unconfirmed.iter().all(Option::is_none)
    }

    /// The addresses of the ESCs that never confirmed the stop.
    pub fn unconfirmed_addresses(&self) -> impl Iterator<Item = u8> + '_ {
        self.unconfirmed.iter().flatten().copied()
    }
}

/// What the flight's parts report to the watchdog (times in µs since the run's start). `fly`
/// queues them from several threads; `sim --fast` hands them over at once; both dispatch them
/// through [`Watchdog::on_event`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// A frame arrived.
    Frame(i64),
    /// The commander asks for a halt (`kill`).
    Kill(i64),
    /// The commander saw a crash or a flip.
    Crash(i64),
    /// The commander disarms on the ground: no more flight commands, so the deadline no
    /// longer applies (the IMU timeout does, until the stop has settled).
    Disarming(i64),
    /// A stop of the ESCs settled (zero, then disable, acknowledged): nothing spins, so the
    /// IMU timeout no longer applies either.
    MotorsStopped(i64),
    /// The ESCs were enabled (the first write of their start-up ramp): the motors may spin
    /// from now on, so a silent IMU halts them.
    MotorsEnabled(i64),
    /// The command for the frame that arrived at `frame_us` was written at `written_us`.
    Command { frame_us: i64, written_us: i64 },
    /// A Kalman step's sanity inputs.
    Estimate {
        step_us: i64,
        temp_c: f64,
        psi_rad: f64,
        phi_rad: f64,
        /// The step's measurement update was refused (a non-finite measurement, a covariance
        /// that is not positive definite): the estimate ran on the model alone.
        refused: bool,
    },
    /// `cycles` consecutive failed ESC write cycles, the first at `first_us`.
    EscFailures { cycles: u32, first_us: i64 },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WatchdogParams {
    pub deadline_us: i64,
    pub imu_timeout_us: i64,
    pub max_missed_acks: u32,
    /// Sanity (spec 2.5): temperature above this, °C, or |ψ̂| or |φ̂| above the tilt, rad,
    /// make a step insane; the counter goes up by one per insane step and down by one (to 0)
    /// per sane one; above `sanity_max` the motors halt.
    pub temp_max_c: f64,
    pub tilt_max_rad: f64,
    pub sanity_max: u32,
    /// Consecutive refused measurement updates that halt the motors.
    pub estimator_max_refused: u32,
}

impl WatchdogParams {
    /// The defaults: 10 ms deadline, 12 ms IMU timeout (the original's longest accepted
    /// period), 3 missed acks (6 ms at the 2 ms re-send period), the original's sanity rules.
    pub const DEFAULT: WatchdogParams = WatchdogParams {
        deadline_us: 10_000,
        imu_timeout_us: 12_000,
        max_missed_acks: 3,
        temp_max_c: 55.0,
        tilt_max_rad: 1.0,
        sanity_max: 20,
        estimator_max_refused: 10,
    };
}

/// Frames remembered without a command: far more than arrive within a deadline.
const UNCOMMANDED_CAP: usize = 64;

/// Host stalls remembered: each reported one follows at least 1.5 ms of observed time, so at
/// most about 70 fit in the longest limit (100 ms). Forgetting the oldest only makes the
/// watchdog stricter.
const UNOBSERVED_CAP: usize = 72;

/// The policy's state.
#[derive(Debug, Clone)]
pub struct Watchdog {
    params: WatchdogParams,
    /// Arrival of the newest frame.
    last_frame_us: Option<i64>,
    /// Arrivals of the frames not yet commanded, oldest first (tracked while flying).
    uncommanded_us: std::collections::VecDeque<i64>,
    /// Motors under flight commands (the deadline applies from then on).
    flying: bool,
    /// The commander disarmed: no flight command is expected any more.
    disarmed: bool,
    /// When the ESCs were enabled (the IMU timeout applies from then on).
    motors_on_us: Option<i64>,
    sanity_counter: u32,
    /// Consecutive refused measurement updates.
    refused_updates: u32,
    deadline_misses: u64,
    /// Spans the watchdog itself did not run (the host stalled it), oldest first: time in
    /// them is neither the IMU's silence nor the control path's delay.
    unobserved: std::collections::VecDeque<(i64, i64)>,
    trip: Option<Trip>,
}

impl Watchdog {
    pub fn new(params: WatchdogParams) -> Self {
        Watchdog {
            params,
            last_frame_us: None,
            uncommanded_us: std::collections::VecDeque::with_capacity(UNCOMMANDED_CAP),
            flying: false,
            disarmed: false,
            motors_on_us: None,
            sanity_counter: 0,
            refused_updates: 0,
            deadline_misses: 0,
            unobserved: std::collections::VecDeque::with_capacity(UNOBSERVED_CAP),
            trip: None,
        }
    }

    pub fn trip(&self) -> Option<Trip> {
        self.trip
    }

    pub fn deadline_misses(&self) -> u64 {
        self.deadline_misses
    }

    fn decide(&mut self, reason: TripReason, event_us: i64, now_us: i64) -> Option<Trip> {
        if self.trip.is_none() {
            self.trip = Some(Trip {
                reason,
                event_us,
                decided_us: now_us,
            });
            return self.trip;
        }
        None
    }

    /// A frame arrived.
    pub fn on_frame(&mut self, arrival_us: i64) {
        self.last_frame_us = Some(self.last_frame_us.map_or(arrival_us, |l| l.max(arrival_us)));
        if self.flying && self.uncommanded_us.len() < UNCOMMANDED_CAP {
            self.uncommanded_us.push_back(arrival_us);
        }
    }

    /// The command for the frame that arrived at `frame_us` was written at `written_us`. It
    /// answers that frame and any older one (the ESC writer keeps only the newest command).
    pub fn on_command(&mut self, frame_us: i64, written_us: i64) -> Option<Trip> {
        // A command written after the disarm (queued before it) does not restart the deadline.
        self.flying = !self.disarmed;
        // A flight command spins the motors, whether or not their enable was reported.
        self.motors_on_us.get_or_insert(frame_us);
        while self.uncommanded_us.front().is_some_and(|&f| f <= frame_us) {
            self.uncommanded_us.pop_front();
        }
        if self.observed_us(frame_us, written_us) > self.params.deadline_us {
            self.deadline_misses += 1;
            return self.decide(TripReason::Deadline, frame_us, written_us);
        }
        None
    }

    /// `failures` consecutive failed ESC write cycles, the first at `first_failure_us`.
    pub fn on_esc_failures(
        &mut self,
        failures: u32,
        first_failure_us: i64,
        now_us: i64,
    ) -> Option<Trip> {
        if failures >= self.params.max_missed_acks {
            return self.decide(TripReason::EscAck, first_failure_us, now_us);
        }
        None
    }

    /// A Kalman step at `step_us` whose measurement update was `refused` or not: the
    /// estimator's health. A run of `estimator_max_refused` refusals halts.
    pub fn on_update(&mut self, step_us: i64, refused: bool) -> Option<Trip> {
        self.refused_updates = if refused {
            self.refused_updates.saturating_add(1)
        } else {
            0
        };
        if self.refused_updates >= self.params.estimator_max_refused {
            return self.decide(TripReason::Estimator, step_us, step_us);
        }
        None
    }

    /// A Kalman step at `step_us` estimated roll `psi_rad` and pitch `phi_rad` with the IMU at
    /// `temp_c` (spec 2.5).
    pub fn on_estimate(
        &mut self,
        step_us: i64,
        temp_c: f64,
        psi_rad: f64,
        phi_rad: f64,
    ) -> Option<Trip> {
        // NaN is insane too: only a reading known to be within its limit is sane.
        let within = |v: f64, limit: f64| v.partial_cmp(&limit).is_some_and(|o| o.is_le());
        let hot = !within(temp_c, self.params.temp_max_c);
        let tilted = !(within(psi_rad.abs(), self.params.tilt_max_rad)
            && within(phi_rad.abs(), self.params.tilt_max_rad));
        if hot || tilted {
            self.sanity_counter += 1;
        } else {
            self.sanity_counter = self.sanity_counter.saturating_sub(1);
        }
        if self.sanity_counter > self.params.sanity_max {
            let reason = if hot {
                TripReason::SanityTemp
            } else {
                TripReason::SanityTilt
            };
            return self.decide(reason, step_us, step_us);
        }
        None
    }

    /// Dispatches one reported event, handled at `now_us`.
    pub fn on_event(&mut self, e: Event, now_us: i64) -> Option<Trip> {
        match e {
            Event::Frame(at) => {
                self.on_frame(at);
                None
            }
            Event::MotorsEnabled(at) => {
                self.motors_on_us.get_or_insert(at);
                // The next flight of the run: its commands are expected again, and its
                // estimates judged afresh (none were judged while the motors were off).
                self.disarmed = false;
                self.sanity_counter = 0;
                self.refused_updates = 0;
                None
            }
            Event::Kill(at) => self.decide(TripReason::Kill, at, now_us),
            Event::Crash(at) => self.decide(TripReason::Crash, at, now_us),
            Event::Disarming(_) => {
                self.disarmed = true;
                self.flying = false;
                self.uncommanded_us.clear();
                None
            }
            Event::MotorsStopped(_) => {
                self.flying = false;
                self.motors_on_us = None;
                self.uncommanded_us.clear();
                None
            }
            Event::Command {
                frame_us,
                written_us,
            } => self.on_command(frame_us, written_us),
            // An estimate while the motors are off (calibrated at rest before the first arm,
            // or between flights) is the pre-arm check's: a vehicle carried tilted spins
            // nothing to halt. From the enable to the stop's settling the rules judge every
            // estimate.
            Event::Estimate { .. } if self.motors_on_us.is_none() => None,
            Event::Estimate {
                step_us,
                temp_c,
                psi_rad,
                phi_rad,
                refused,
            } => self
                .on_update(step_us, refused)
                .or_else(|| self.on_estimate(step_us, temp_c, psi_rad, phi_rad)),
            Event::EscFailures { cycles, first_us } => {
                self.on_esc_failures(cycles, first_us, now_us.max(first_us))
            }
        }
    }

    /// Where the IMU's silence counts from while the motors may spin: the newest frame, or the
    /// enable at the earliest (the frame that asked for the ESC start may be older than the
    /// enable by the writer's wake-up).
    fn silence_since_us(&self) -> Option<i64> {
        let on_us = self.motors_on_us?;
        Some(self.last_frame_us.map_or(on_us, |l| l.max(on_us)))
    }

    /// The watchdog itself did not run from `from_us` to `to_us`: the host stalled it, and
    /// every flight thread with it. Frames sent meanwhile wait in the port's buffer, and a
    /// command computed before the stall is written after it: that span is neither the IMU's
    /// silence nor the control path's delay, and neither rule counts it. The time before and
    /// after it still counts. Which stalls are reported here is the caller's rule
    /// (`tasks::host_stall`: within a budget).
    pub fn on_unobserved(&mut self, from_us: i64, to_us: i64) {
        // Spans never overlap: time is left out once.
        let from_us = from_us.max(self.unobserved.back().map_or(i64::MIN, |s| s.1));
        if to_us <= from_us {
            return;
        }
        if self.unobserved.len() == UNOBSERVED_CAP {
            self.unobserved.pop_front();
        }
        self.unobserved.push_back((from_us, to_us));
    }

    /// The time from `from_us` to `to_us` the watchdog observed: the whole of it, less the
    /// host's stalls within it.
    fn observed_us(&self, from_us: i64, to_us: i64) -> i64 {
        let stalled_us: i64 = self
            .unobserved
            .iter()
            .map(|&(a, b)| (b.min(to_us) - a.max(from_us)).max(0))
            .sum();
        to_us - from_us - stalled_us
    }

    /// Time passes: no frame for the IMU timeout since the ESCs were enabled, or a frame left
    /// without command past the deadline while flying.
    pub fn tick(&mut self, now_us: i64) -> Option<Trip> {
        let since_us = self.silence_since_us()?;
        if self.observed_us(since_us, now_us) > self.params.imu_timeout_us {
            let last = self.last_frame_us.unwrap_or(since_us);
            return self.decide(TripReason::ImuTimeout, last, now_us);
        }
        if !self.flying {
            return None;
        }
        // The oldest frame still without a command, past the deadline.
        if let Some(&oldest) = self.uncommanded_us.front()
            && self.observed_us(oldest, now_us) > self.params.deadline_us
        {
            self.deadline_misses += 1;
            return self.decide(TripReason::Deadline, oldest, now_us);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wd() -> Watchdog {
        Watchdog::new(WatchdogParams::DEFAULT)
    }

    #[test]
    fn nothing_trips_before_flight_or_when_healthy() {
        let mut w = wd();
        w.on_frame(0);
        assert_eq!(w.tick(1_000_000), None, "not flying: no timeout");
        let mut t = 2_000_000;
        for _ in 0..1000 {
            w.on_frame(t);
            assert_eq!(w.on_command(t, t + 300), None);
            assert_eq!(w.on_estimate(t, 38.0, 0.1, -0.1), None);
            for dt in [2_000, 4_000, 6_000, 8_000, 10_000] {
                assert_eq!(w.tick(t + dt), None);
            }
            t += 10_000;
        }
        assert_eq!(w.deadline_misses(), 0);
    }

    #[test]
    fn late_command_trips_deadline() {
        let mut w = wd();
        w.on_frame(100);
        let trip = w.on_command(100, 10_101).unwrap();
        assert_eq!(trip.reason, TripReason::Deadline);
        assert_eq!((trip.event_us, trip.decided_us), (100, 10_101));
        assert_eq!(w.deadline_misses(), 1);
        // Decided once.
        assert_eq!(w.on_command(200, 90_000), None);
        assert_eq!(w.trip().unwrap().reason, TripReason::Deadline);
    }

    #[test]
    fn missing_command_trips_deadline() {
        let mut w = wd();
        w.on_frame(0);
        w.on_command(0, 500);
        w.on_frame(10_000);
        assert_eq!(w.tick(19_000), None);
        let trip = w.tick(20_001).unwrap();
        assert_eq!((trip.reason, trip.event_us), (TripReason::Deadline, 10_000));
    }

    #[test]
    fn a_late_frame_is_caught_even_when_newer_frames_arrive() {
        let mut w = wd();
        w.on_frame(0);
        w.on_command(0, 400);
        w.on_frame(10_000); // its command is late
        w.on_frame(20_000);
        assert_eq!(w.tick(19_000), None);
        let trip = w.tick(20_001).unwrap();
        assert_eq!((trip.reason, trip.event_us), (TripReason::Deadline, 10_000));
        // A command answers its frame and the older ones.
        let mut w = wd();
        w.on_command(0, 100);
        w.on_frame(10_000);
        w.on_frame(10_001);
        assert_eq!(w.on_command(10_001, 10_400), None);
        // Both frames are answered: no deadline trip, only the IMU timeout later.
        assert_eq!(w.tick(21_000), None);
        assert_eq!(w.tick(22_002).unwrap().reason, TripReason::ImuTimeout);
    }

    #[test]
    fn silent_imu_trips_timeout() {
        let mut w = wd();
        w.on_frame(0);
        w.on_command(0, 500);
        assert_eq!(w.tick(12_000), None);
        let trip = w.tick(12_001).unwrap();
        assert_eq!((trip.reason, trip.event_us), (TripReason::ImuTimeout, 0));
    }

    #[test]
    fn the_watchdogs_own_stall_is_neither_the_imus_silence_nor_a_late_command() {
        // Enabled at 0, the last frame at 0, then the host stalls the watchdog (and the reader)
        // from 2 ms to 102 ms: 100 ms of which are not judged; 2 ms before and 10 ms after are.
        let mut w = wd();
        w.on_event(Event::MotorsEnabled(0), 0);
        w.on_frame(0);
        w.on_command(0, 500);
        w.on_unobserved(2_000, 102_000);
        assert_eq!(w.tick(102_000), None, "the buffered frames come next");
        assert_eq!(w.tick(112_000), None, "2 + 10 ms observed");
        let trip = w.tick(112_001).unwrap();
        assert_eq!((trip.reason, trip.event_us), (TripReason::ImuTimeout, 0));

        // A frame after the stall starts the silence afresh: the old span is forgotten.
        let mut w = wd();
        w.on_event(Event::MotorsEnabled(0), 0);
        w.on_frame(0);
        w.on_unobserved(2_000, 102_000);
        w.on_frame(103_000);
        assert_eq!(w.tick(115_000), None);
        assert_eq!(w.tick(115_001).unwrap().reason, TripReason::ImuTimeout);

        // A span that began before the last frame counts only after it; none counts while the
        // motors are off.
        let mut w = wd();
        w.on_unobserved(0, 1_000_000);
        w.on_event(Event::MotorsEnabled(1_000_000), 1_000_000);
        w.on_frame(1_000_000);
        w.on_unobserved(990_000, 1_005_000);
        assert_eq!(w.tick(1_017_000), None);
        assert_eq!(w.tick(1_017_001).unwrap().reason, TripReason::ImuTimeout);

        // The deadline likewise: a command written after a stall is judged without it, and a
        // frame left uncommanded across one trips 10 ms of observed time after it.
        let mut w = wd();
        w.on_command(0, 100);
        w.on_frame(10_000);
        w.on_unobserved(11_000, 150_000);
        assert_eq!(w.on_command(10_000, 152_000), None);
        w.on_frame(160_000);
        w.on_unobserved(162_000, 300_000);
        assert_eq!(w.tick(308_000), None);
        let trip = w.tick(308_001).unwrap();
        assert_eq!(
            (trip.reason, trip.event_us),
            (TripReason::Deadline, 160_000)
        );
        assert_eq!(w.deadline_misses(), 1);
    }
    #[test]
    fn missed_acks_trip() {
        let mut w = wd();
        assert_eq!(w.on_esc_failures(2, 1_000, 3_000), None);
        let trip = w.on_esc_failures(3, 1_000, 5_000).unwrap();
        assert_eq!((trip.reason, trip.event_us), (TripReason::EscAck, 1_000));
    }

    #[test]
    fn a_disarm_ends_the_deadline_and_a_settled_stop_the_imu_timeout() {
        let mut w = wd();
        w.on_event(Event::MotorsEnabled(0), 0);
        w.on_frame(10_000);
        assert_eq!(w.on_command(10_000, 10_100), None);
        w.on_frame(15_000);
        w.on_event(Event::Disarming(20_000), 20_000);
        w.on_frame(20_000);
        // A command queued before the disarm, written after it, restarts nothing.
        assert_eq!(w.on_command(15_000, 20_500), None);
        w.on_frame(30_000);
        // Frames of 20 ms and 30 ms without a command: no deadline once disarming.
        assert_eq!(w.tick(39_000), None);
        // Until the stop settles, a silent IMU still halts.
        let trip = w.clone().tick(60_000).unwrap();
        assert_eq!(trip.reason, TripReason::ImuTimeout);
        w.on_event(Event::MotorsStopped(46_000), 46_000);
        assert_eq!(w.tick(1_000_000), None, "nothing spins: no IMU timeout");
    }

    #[test]
    fn the_next_flight_is_judged_again_and_the_ground_between_flights_is_not() {
        let tilted = |step_us| Event::Estimate {
            step_us,
            temp_c: 30.0,
            psi_rad: 1.2,
            phi_rad: 0.0,
            refused: false,
        };
        let mut w = wd();
        w.on_event(Event::MotorsEnabled(0), 0);
        w.on_event(Event::Disarming(10_000), 10_000);
        w.on_event(Event::MotorsStopped(12_000), 12_000);
        // Carried tilted between flights, motors off: nothing to halt.
        for k in 0..100 {
            assert_eq!(w.on_event(tilted(20_000 + k), 20_000 + k), None);
        }
        // The next flight: enabled, commanded, and its deadline watched again.
        w.on_event(Event::MotorsEnabled(1_000_000), 1_000_000);
        w.on_frame(1_010_000);
        assert_eq!(w.on_command(1_010_000, 1_010_100), None);
        w.on_frame(1_020_000);
        let trip = w.tick(1_030_001).unwrap();
        assert_eq!(
            (trip.reason, trip.event_us),
            (TripReason::Deadline, 1_020_000)
        );
    }

    #[test]
    fn sanity_counter_as_the_original() {
        let mut w = wd();
        // 20 insane steps are tolerated, the 21st trips; a sane step takes one back.
        for k in 0..20 {
            assert_eq!(w.on_estimate(k, 60.0, 0.0, 0.0), None);
        }
        assert_eq!(w.on_estimate(20, 20.0, 0.0, 0.0), None);
        assert_eq!(w.on_estimate(21, 60.0, 0.0, 0.0), None);
        let trip = w.on_estimate(22, 60.0, 0.0, 0.0).unwrap();
        assert_eq!((trip.reason, trip.event_us), (TripReason::SanityTemp, 22));
        let mut w = wd();
        for k in 0..20 {
            assert_eq!(w.on_estimate(k, 30.0, 0.0, -1.2), None);
        }
        assert_eq!(
            w.on_estimate(20, 30.0, 1.1, 0.0).unwrap().reason,
            TripReason::SanityTilt
        );
        // NaN counts as insane.
        let mut w = wd();
        for k in 0..21 {
            w.on_estimate(k, f64::NAN, 0.0, 0.0);
        }
        assert_eq!(w.trip().unwrap().reason, TripReason::SanityTemp);
    }

    #[test]
    fn silent_imu_trips_from_the_esc_enable_before_any_command() {
        let mut w = wd();
        w.on_frame(0);
        assert_eq!(w.tick(500_000), None, "motors off: no timeout");
        w.on_frame(1_000_000);
        w.on_event(Event::MotorsEnabled(1_000_500), 1_000_500);
        // The silence counts from the enable when the frame before it is older.
        assert_eq!(w.tick(1_012_500), None);
        let trip = w.tick(1_012_501).unwrap();
        assert_eq!(
            (trip.reason, trip.event_us),
            (TripReason::ImuTimeout, 1_000_000)
        );
        // Frames keep it quiet through the ramp and the calibration.
        let mut w = wd();
        w.on_event(Event::MotorsEnabled(0), 0);
        for k in 0..500 {
            w.on_frame(k * 10_000);
            assert_eq!(w.tick(k * 10_000 + 9_999), None);
        }
        assert_eq!(w.deadline_misses(), 0, "no deadline before flight commands");
    }

    #[test]
    fn a_run_of_refused_updates_trips_estimator() {
        let est = |refused| Event::Estimate {
            step_us: 0,
            temp_c: 30.0,
            psi_rad: 0.0,
            phi_rad: 0.0,
            refused,
        };
        let mut w = wd();
        // Before the motors were ever enabled (estimating at rest, disarmed) nothing spins:
        // the estimate is the pre-arm check's.
        for _ in 0..20 {
            assert_eq!(w.on_event(est(true), 0), None);
        }
        assert_eq!(w.on_event(Event::MotorsEnabled(0), 0), None);
        // Nine refusals, then a fused update: the run starts again.
        for _ in 0..9 {
            assert_eq!(w.on_event(est(true), 0), None);
        }
        assert_eq!(w.on_event(est(false), 0), None);
        for _ in 0..9 {
            assert_eq!(w.on_event(est(true), 0), None);
        }
        let trip = w.on_event(est(true), 0).unwrap();
        assert_eq!(trip.reason, TripReason::Estimator);
        assert_eq!(trip.reason.name(), "estimator");
    }
}

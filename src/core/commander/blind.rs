//! The landing without a vertical reference: its thrust set outright from the
//! accelerometer once its estimate is down to the ground (see [`Blind`]). Not in the
//! original's spec (it had no failsafe landings).

use crate::core::model::GRAVITY_M_S2;

/// How fast the blind landing's thrust falls in the air while the vehicle sinks slower than
/// `land_slow_m_s`, share of the weight per second.
pub(super) const BLIND_RAMP_PER_S: f64 = 0.03;

/// The blind landing's brake on a sink faster than `land_slow_m_s`, share of the weight per
/// m/s: a third of a second's time constant, so a vehicle still metres up sinks at about the
/// slow speed instead of falling faster and faster.
pub(super) const BLIND_BRAKE_PER_M_S: f64 = 0.3;

/// A landing without a vertical reference (no barometer, no fixes), once its estimate is
/// down to the ground: nothing then tells the estimate where the ground is, and the
/// controller's vertical would chase an estimate that drifts (the filter even takes the
/// ground's push for a thrust error). The thrust is set outright (the attitude stays the
/// controller's): it falls until the vehicle sinks at about `land_slow_m_s` (a little faster:
/// the brake is proportional), and keeps falling on the ground, whose push the touchdown
/// watch feels. The sink is the accelerometer's own integral since then, against what it
/// read at rest (its noise is small over the seconds this lasts; a touchdown's shock stops
/// it); the brake rises little above the thrust it began with, and a climb lowers the
/// thrust by the ramp's 0.03 of the weight a second.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Blind {
    /// How fast the vehicle sinks, by the accelerometer, m/s.
    pub(super) sink_m_s: f64,
    /// The thrust when it began, share of the weight: the hover's, as the controller had
    /// found it (the model's thrust curve is right only to a few per cent).
    pub(super) base: f64,
    /// The thrust's slow part, share of the weight: it only falls.
    pub(super) ramp: f64,
    /// The thrust this step, share of the weight.
    pub(super) thrust: f64,
    /// A touchdown's shock was felt: the vehicle is on the ground, the brake is off.
    pub(super) shock: bool,
}

impl Blind {
    /// From the thrust `thrust_ratio` the controller gave (its hover, as its integrators
    /// found it, when it was holding a slow descent); the sink counted from 0, though the
    /// vehicle may then be sinking or climbing a little (the estimate it flew on drifts).
    pub(super) fn new(thrust_ratio: f64) -> Self {
        let base = if thrust_ratio.is_finite() {
            thrust_ratio.clamp(BLIND_BASE_MIN, 1.0 / BLIND_BASE_MIN)
        } else {
            1.0
        };
        Blind {
            sink_m_s: 0.0,
            base,
            ramp: base,
            thrust: base,
            shock: false,
        }
    }

    /// The ground's push felt for [`GROUND_PUSH_STEPS`](super::GROUND_PUSH_STEPS) steps in a
    /// row (the accelerometer reading more than the thrust gives) is a touchdown as much as a
    /// shock: a soft one (0.15 m/s) has none, and the air's ramp (0.03 of the weight a second)
    /// took 7 s to bring the thrust down to the touchdown watch's limit.
    pub(super) fn grounded(mut self, pushed: bool) -> Self {
        self.shock |= pushed;
        self
    }

    /// One step, with the accelerometer `acc_m_s2` (body axes) and what it read at rest,
    /// `rest_m_s2` (the calibration's: the gravity as this accelerometer reads it, so its
    /// scale error does not integrate into a sink): the ramp falls while the vehicle sinks
    /// slower than `slow_m_s`; a faster sink is braked at once, a little above the thrust it
    /// began with, until a touchdown's shock is felt.
    pub(super) fn step(
        mut self,
        acc_m_s2: [f64; 3],
        rest_m_s2: f64,
        slow_m_s: f64,
        dt_s: f64,
    ) -> Self {
        // Along the thrust axis: in the air the accelerometer reads there the thrust, and
        // across it only the air's drag or a push, which must not count as a climb; a
        // landing flies nearly level (0.05 rad: 0.1 % of the weight), and the estimated tilt,
        // without a reference, may be off by more than that.
        let up_m_s2 = acc_m_s2[2];
        let rest_m_s2 = if rest_m_s2.is_finite() && rest_m_s2 > 0.0 {
            rest_m_s2
        } else {
            GRAVITY_M_S2
        };
        if up_m_s2.is_finite() {
            self.sink_m_s -= (up_m_s2 - rest_m_s2) * dt_s;
            self.shock |= up_m_s2 > BLIND_SHOCK_G * rest_m_s2;
        }
        let fall_per_s = if self.shock {
            BLIND_GROUND_RAMP_PER_S
        } else if self.sink_m_s < slow_m_s {
            BLIND_RAMP_PER_S
        } else {
            0.0
        };
        self.ramp = (self.ramp - fall_per_s * dt_s).max(0.0);
        let brake = if self.shock {
            0.0
        } else {
            BLIND_BRAKE_PER_M_S * (self.sink_m_s - slow_m_s).max(0.0)
        };
        self.thrust = (self.ramp + brake).min(self.base + BLIND_BRAKE_MAX);
        self
    }
}

/// The blind landing's brake rises at most this share of the weight above the thrust it
/// began with: enough for the model's few per cent, too little to climb far on a wrong sink.
pub(super) const BLIND_BRAKE_MAX: f64 = 0.1;

/// How fast the blind landing's thrust falls once a touchdown's shock was felt, share of
/// the weight per second: the touchdown watch's threshold within a second or two, before
/// the attitude's integrators, which cannot turn a vehicle on the ground, wind up and hold
/// two motors high.
pub(super) const BLIND_GROUND_RAMP_PER_S: f64 = 0.2;

/// A specific force along the thrust axis above this many times the rest's is a touchdown's
/// shock (a 0.25 m/s touchdown on stiff legs reads more than 2 g; a level descent about 1,
/// a push from the side nothing on that axis).
pub(super) const BLIND_SHOCK_G: f64 = 1.5;

/// The blind landing's starting thrust is taken within this share of the weight and its
/// inverse: a controller's thrust far off the weight is not a hover.
pub(super) const BLIND_BASE_MIN: f64 = 0.7;

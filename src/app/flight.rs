//! The flight sequence's two sides as a profile builds them for a live run (`fly` and both
//! ways of simulating): settle, then calibrate at once (`imu.calibrate = "before-arm"`) or
//! hold for the arm and the ESC start-up ramp first; the GPS feed the profile's `gps.mode`
//! asks for.

use crate::config::{GpsMode, Profile};
use crate::core::flight::{ControllerSide, EstimatorSide, GpsFeed};

/// The GPS feed of a live run: gpsd's (or the simulator's) fixes, the fake-GPS rule, or none.
pub fn live_gps_feed(profile: &Profile) -> GpsFeed {
    match profile.config.gps.mode {
        GpsMode::Off => GpsFeed::Off,
        GpsMode::Gpsd => GpsFeed::Live(None),
        GpsMode::FakeZero | GpsMode::FakeRandom => GpsFeed::fake(profile.fake_positions()),
    }
}

/// The estimator and controller sides of a live run.
pub fn live_sides(profile: &Profile) -> (EstimatorSide, ControllerSide) {
    let core = profile.estimator_core(false);
    let before_arm = profile.config.calibrates_before_arm();
    let core = if before_arm {
        core
    } else {
        core.hold_after_settle()
    };
    let estimator = EstimatorSide::new(core, live_gps_feed(profile), profile.commander())
        .with_imu_timeout(i64::from(profile.config.watchdog.imu_timeout_ms) * 1000);
    let estimator = if before_arm {
        estimator.calibrating_before_arm()
    } else {
        estimator
    };
    (estimator, ControllerSide::new(profile.controller_core()))
}

//! The ground-station link task: MAVLink 2 over UDP or a serial radio, on the main runtime and
//! never on the control path. The protocol is `crate::gcs`; this task moves its messages.
//!
//! In: frames from the link, at most `gcs.max_rx_per_s` a second (beyond: dropped, counted);
//! the flight's notices (mode changes, failsafes, refusals, commands' outcomes), its newest
//! step, GPS fix and watchdog status.
//! Out: operator inputs (commands; the ground station's heartbeats as link beats) into the
//! flight's bounded operator queue, never waited on (a full queue refuses the command);
//! telemetry, acknowledgements and texts to the link (a full link drops and counts).
//! Rate: a tick every 20 ms sends what is due. Ends: on cancel.

mod link;
mod state;
mod store;

pub use link::Link;
pub use state::{GcsContext, GcsReport, GcsStats, thread_clock};
pub use store::ParamStore;

use std::time::Duration;

/// How often the task looks at what is due.
const TICK: Duration = Duration::from_millis(20);

/// Serves the link until cancel.
pub async fn run(mut link: Link, ctx: GcsContext) {
    let mut notices = ctx.notices.resubscribe();
    let mut g = state::Gcs::new(ctx, link.decoder());
    let mut buf = vec![0u8; 4096];
    let mut tick = tokio::time::interval(TICK);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let cancel = g.cancel();
    loop {
        tokio::select! {
            _ = cancel.cancelled() => break,
            r = link.recv(&mut buf) => match r {
                Ok(0) if matches!(link, Link::Serial { .. }) => {
                    tracing::warn!("gcs: the serial radio closed");
                    break;
                }
                Ok(n) => g.timed(|g| g.on_bytes(&buf[..n], &mut link)),
                // A datagram refused on the way (ICMP): nothing to read, go on.
                Err(_) => g.timed(|g| g.count_rx_error()),
            },
            n = notices.recv() => g.timed(|g| g.on_notice(n, &mut link)),
            _ = tick.tick() => g.timed(|g| g.on_tick(&mut link)),
        }
    }
}

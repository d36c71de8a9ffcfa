//! `uquad gps`: a diagnostic to run before flying — the fixes gpsd gives, as JSON lines.

use crate::core::gps::{LocalFrame, Report};
use crate::tasks::gps_client::GpsdSession;
use std::io::Write;

/// One fix as printed: one JSON object per line.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FixLine {
    pub mode: u8,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// null for a 2D fix without altitude.
    pub alt_m: Option<f64>,
    /// Local frame: north, west, up from the first fix printed (with an altitude), m; z_m is
    /// null for a fix without altitude.
    pub x_m: f64,
    pub y_m: f64,
    pub z_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time: Option<String>,
}

/// Prints `count` fixes from gpsd at `server` to `out`; errors when gpsd cannot be reached or
/// goes away first.
pub async fn run(server: &str, count: u64, out: &mut impl Write) -> anyhow::Result<()> {
    let mut session = GpsdSession::connect(server).await?;
    tracing::info!(server, "connected to gpsd; waiting for {count} fixes");
    let mut frame = LocalFrame::default();
    let mut printed = 0;
    while printed < count {
        match session.next_report().await? {
            Some(Report::Tpv(tpv)) => match tpv.fix() {
                Some(fix) => {
                    let local = frame.to_local(fix.lat_deg, fix.lon_deg, fix.alt_m);
                    let [x, y] = local.xy_m;
                    let line = FixLine {
                        mode: fix.mode,
                        lat_deg: fix.lat_deg,
                        lon_deg: fix.lon_deg,
                        alt_m: fix.alt_m,
                        x_m: x,
                        y_m: y,
                        z_m: local.z_m,
                        time: tpv.time.clone(),
                    };
                    writeln!(out, "{}", serde_json::to_string(&line)?)?;
                    out.flush()?;
                    printed += 1;
                }
                None => tracing::info!(mode = tpv.mode, "no fix yet"),
            },
            Some(Report::Version(v)) => tracing::info!(release = v.release, "gpsd version"),
            Some(Report::Error { message }) => tracing::warn!("gpsd error: {message}"),
            Some(_) => {}
            None => tracing::debug!("a line that is not a gpsd report"),
        }
    }
    Ok(())
}

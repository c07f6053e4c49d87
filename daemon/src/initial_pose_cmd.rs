//! `glintd initial-pose`: send a running daemon one initial-pose hint (`base_link` at x, y on the
//! floor of the site map, facing yaw), so its localiser searches near it instead of the whole
//! map. Also the Rust example of a hint sender: the whole work is
//! [`glint_ipc::send_initial_pose`].

use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result};
use clap::Args;
use glint_ipc::{send_initial_pose, Domain, InitialPose, Stream};

/// Arguments of `glintd initial-pose`.
#[derive(Args, Debug)]
pub struct InitialPoseArgs {
    /// The daemon's domain (service-name prefix).
    #[arg(long, default_value = "default")]
    pub domain: String,
    /// x of base_link in the map frame, m.
    #[arg(allow_negative_numbers = true)]
    pub x: f64,
    /// y of base_link in the map frame, m.
    #[arg(allow_negative_numbers = true)]
    pub y: f64,
    /// Heading of base_link about the map's z axis, rad (0 = facing +x).
    #[arg(allow_negative_numbers = true)]
    pub yaw: f64,
    /// How far off the position may be (1 sigma), m; 0 = unknown.
    #[arg(long, default_value_t = 0.0)]
    pub sigma: f64,
}

/// Runs the command: validates, sends, waits the sender linger so the daemon takes the hint.
pub fn run(args: InitialPoseArgs) -> Result<()> {
    let domain =
        Domain::new(&args.domain).with_context(|| format!("invalid --domain {:?}", args.domain))?;
    // A clock before 1970 is a broken clock, not a reason to refuse the hint; 0 says "unknown".
    let now_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
    let hint = InitialPose::on_floor(now_ns, args.x, args.y, args.yaw, args.sigma);
    let service = domain.service_name(Stream::InitialPose);
    let delivered = send_initial_pose(&domain, &hint)
        .with_context(|| format!("cannot send the initial pose on {service}"))?;
    say!(
        "sent x={} y={} yaw={} sigma={} on {service} to {delivered} subscriber(s)",
        args.x,
        args.y,
        args.yaw,
        args.sigma
    );
    Ok(())
}

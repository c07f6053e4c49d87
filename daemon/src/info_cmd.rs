//! `glintd info`: what a capture holds, in a few lines.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use glint_driver::clock::TimeSource;

use crate::capture::{describe_sources, replay, SensorArgs};

/// Arguments of `glintd info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// The capture (pcap or pcapng).
    pub capture: PathBuf,
    #[command(flatten)]
    pub sensor: SensorArgs,
}

/// Runs the command.
pub fn run(args: InfoArgs) -> Result<()> {
    let mut whole_rpm = Vec::new();
    let report = replay(&args.capture, &args.sensor, |s| {
        if !s.partial {
            whole_rpm.extend(s.rpm());
        }
        Ok(())
    })?;
    let st = report.stream.stats();
    let (data, position, other) = report.port_counts;
    let cap = report.capture;
    say!("capture: {}", args.capture.display());
    for line in describe_sources(&report.sources) {
        say!("{line}");
    }
    match report.stream.detection() {
        Some(d) => say!("model: {}", d.describe()),
        None => say!("model: undecided (no data packets)"),
    }
    say!(
        "return mode: {}",
        st.return_mode.map_or("none", |m| m.name())
    );
    say!(
        "packets: {data} data (port {}), {position} position (port {}), {other} to other ports",
        args.sensor.data_port,
        args.sensor.position_port
    );
    let refused = report.sources.stats();
    if refused.foreign() > 0 {
        say!(
            "refused from other sources: {} data, {} position packets (the figures below are the source read's)",
            refused.foreign_data,
            refused.foreign_position
        );
    }
    say!(
        "skipped traffic: {} records not UDP/IPv4 ({} not IPv4, {} not UDP, {} fragments, {} unsupported link, {} malformed frames), {other} datagrams to other ports",
        cap.skipped(),
        cap.not_ipv4,
        cap.not_udp,
        cap.fragments,
        cap.unsupported_link,
        cap.malformed
    );
    say!(
        "dropped sensor packets: {} truncated, {} malformed; {} packets with a block azimuth of 36000 read as 0",
        st.truncated, st.malformed, st.full_turn_azimuths
    );
    say!(
        "sweeps: {} ({} whole, {} partial), {} returns",
        st.sweeps,
        st.sweeps - st.partial_sweeps,
        st.partial_sweeps,
        st.points
    );
    whole_rpm.sort_by(f64::total_cmp);
    match (whole_rpm.get(whole_rpm.len() / 2), st.rpm()) {
        (Some(median), _) => say!("rpm: {median:.1} (median of whole sweeps)"),
        (None, Some(rpm)) => say!("rpm: {rpm:.1} (from the azimuth advance; no whole sweep)"),
        _ => say!("rpm: unknown"),
    }
    let source = match report.stream.clock().source() {
        TimeSource::Gps => "GPS ($GPRMC with PPS locked)",
        TimeSource::ReceiveTime => "receive time (no GPS lock)",
        TimeSource::None => "none",
    };
    match st.first_ns {
        Some(first) => say!(
            "time: {:.6} s to {:.6} s (span {:.6} s), from {source}",
            first as f64 * 1e-9,
            st.last_ns as f64 * 1e-9,
            (st.last_ns - first) as f64 * 1e-9
        ),
        None => say!("time: no data"),
    }
    say!(
        "gaps: {} packets missing; clock: {} hour wraps, {} backward jumps, {} forward jumps, {} reordered",
        st.packets_missing, st.clock.hour_wraps, st.clock.backward_jumps, st.clock.forward_jumps, st.clock.reordered
    );
    if st.product_id_changes > 0 {
        say!(
            "warning: the product-id byte changed {} times within the capture",
            st.product_id_changes
        );
    }
    if let Some(damage) = report.damage {
        return Err(anyhow::Error::new(damage).context(
            "the capture is damaged; the figures above cover the part before the damage",
        ));
    }
    Ok(())
}

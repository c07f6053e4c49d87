//! Helpers shared by the integration tests: run a simulation in memory into a pcap with its
//! truth, and decode a pcap with the driver exactly as the daemon would (GPS clock from the
//! position packets, packet times from the counter, the decoder's own VLP-16 table).

#![allow(dead_code)]

use std::io::Cursor;

use glint_driver::clock::Clock;
use glint_driver::pcap::{CaptureReader, CaptureWriter};
use glint_driver::wire::{DataPacket, PositionPacket};
use glint_driver::{Decoder, Model, Point};
use glint_sim::output::endpoints;
use glint_sim::{PacketKind, Simulation, TruthReturn};

/// Runs `sim` to the end, writing every packet into an in-memory pcap and collecting the truth.
pub fn capture(sim: &mut Simulation) -> (Vec<u8>, Vec<TruthReturn>) {
    let mut writer = CaptureWriter::new(Vec::new()).expect("pcap header");
    let mut truth = Vec::new();
    while let Some(p) = sim.next_packet_with_truth(|t| truth.push(*t)) {
        writer
            .write_udp(p.time_ns, endpoints(p.kind), p.payload)
            .expect("in-memory write");
    }
    (writer.finish().expect("flush"), truth)
}

/// What the driver makes of a capture.
pub struct Decoded {
    /// Every point, in packet order.
    pub points: Vec<Point>,
    /// Data packets decoded.
    pub data_packets: usize,
    /// Position packets seen.
    pub position_packets: usize,
    /// (packet time from the clock, receive time) per data packet.
    pub packet_times: Vec<(u64, u64)>,
}

/// Decodes a capture with the driver's VLP-16 decoder and clock.
pub fn decode(pcap: Vec<u8>) -> Decoded {
    let mut reader = CaptureReader::from_reader(Cursor::new(pcap)).expect("a pcap");
    let decoder = Decoder::for_model(Model::Vlp16);
    let mut clock = Clock::new();
    let mut out = Decoded {
        points: Vec::new(),
        data_packets: 0,
        position_packets: 0,
        packet_times: Vec::new(),
    };
    while let Some(d) = reader.next().expect("readable capture") {
        match d.destination_port {
            8308 => {
                let p = PositionPacket::new_checked(d.payload).expect("position packet");
                assert!(
                    clock.observe_position(&p),
                    "GPS-locked position packet with a valid $GPRMC"
                );
                out.position_packets += 1;
            }
            2368 => {
                let p = DataPacket::new_checked(d.payload).expect("valid data packet");
                let t = clock.packet_time(p.timestamp_us(), d.time_ns);
                out.packet_times.push((t, d.time_ns));
                decoder.decode_into(&p, t, &mut out.points);
                out.data_packets += 1;
            }
            other => panic!("unexpected port {other}"),
        }
    }
    out
}

/// Ring of a laser index by elevation order, from the manual's elevations (the decoder
/// numbers rings the same way).
pub fn ring_of(laser: u8) -> u8 {
    let el = glint_sim::sensor::ELEVATION_DEG;
    el.iter().filter(|&&e| e < el[usize::from(laser)]).count() as u8
}

/// `PacketKind` of a port, for readers of in-memory packets.
pub fn kind_of(port: u16) -> PacketKind {
    if port == 2368 {
        PacketKind::Data
    } else {
        PacketKind::Position
    }
}

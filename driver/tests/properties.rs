//! Property tests: random valid packets survive the writer and the views bit for bit (also
//! through a pcap file), and no truncation or corruption of a real packet panics anywhere in the
//! stream.

use std::io::Cursor;
use std::net::Ipv4Addr;

use glint_driver::pcap::{CaptureReader, CaptureWriter, UdpEndpoints};
use glint_driver::wire::{BLOCKS_PER_PACKET, BLOCK_FLAG, DATA_PAYLOAD_LEN, RECORDS_PER_BLOCK};
use glint_driver::{
    DataPacket, PacketError, PacketKind, PcapSource, Ports, ReturnMode, SensorStream, StreamConfig,
};
use proptest::prelude::*;

#[derive(Debug, Clone)]
struct PacketFields {
    azimuths: Vec<u16>,
    records: Vec<(u16, u8)>,
    timestamp: u32,
    mode: ReturnMode,
    product_id: u8,
}

fn fields() -> impl Strategy<Value = PacketFields> {
    (
        prop::collection::vec(0u16..36_000, BLOCKS_PER_PACKET),
        prop::collection::vec(
            (any::<u16>(), any::<u8>()),
            BLOCKS_PER_PACKET * RECORDS_PER_BLOCK,
        ),
        any::<u32>(),
        prop_oneof![
            Just(ReturnMode::Strongest),
            Just(ReturnMode::Last),
            Just(ReturnMode::Dual)
        ],
        any::<u8>(),
    )
        .prop_map(
            |(azimuths, records, timestamp, mode, product_id)| PacketFields {
                azimuths,
                records,
                timestamp,
                mode,
                product_id,
            },
        )
}

fn encode(f: &PacketFields) -> [u8; DATA_PAYLOAD_LEN] {
    let mut buf = [0u8; DATA_PAYLOAD_LEN];
    let mut p = DataPacket::new_unchecked(&mut buf[..]);
    for b in 0..BLOCKS_PER_PACKET {
        p.set_block_flag(b, BLOCK_FLAG);
        p.set_azimuth(b, f.azimuths[b]);
        for r in 0..RECORDS_PER_BLOCK {
            let (d, i) = f.records[b * RECORDS_PER_BLOCK + r];
            p.set_record(b, r, d, i);
        }
    }
    p.set_timestamp_us(f.timestamp);
    p.set_return_mode(f.mode);
    p.set_product_id(f.product_id);
    buf
}

fn endpoints() -> UdpEndpoints {
    UdpEndpoints {
        source: (Ipv4Addr::new(192, 168, 1, 201), 2368),
        destination: (Ipv4Addr::BROADCAST, 2368),
    }
}

proptest! {
    #[test]
    fn writer_and_views_round_trip_bit_exactly(f in fields()) {
        let buf = encode(&f);
        let p = DataPacket::new_checked(&buf[..]).unwrap();
        for b in 0..BLOCKS_PER_PACKET {
            prop_assert_eq!(p.block_flag(b), BLOCK_FLAG);
            prop_assert_eq!(p.azimuth(b), f.azimuths[b]);
            for r in 0..RECORDS_PER_BLOCK {
                prop_assert_eq!(p.record(b, r), f.records[b * RECORDS_PER_BLOCK + r]);
            }
        }
        prop_assert_eq!(p.timestamp_us(), f.timestamp);
        prop_assert_eq!(p.return_mode().unwrap(), f.mode);
        prop_assert_eq!(p.product_id(), f.product_id);
        // Re-encoding what was read gives the same bytes.
        let again = encode(&PacketFields {
            azimuths: (0..BLOCKS_PER_PACKET).map(|b| p.azimuth(b)).collect(),
            records: (0..BLOCKS_PER_PACKET * RECORDS_PER_BLOCK).map(|i| p.record(i / 32, i % 32)).collect(),
            timestamp: p.timestamp_us(),
            mode: p.return_mode().unwrap(),
            product_id: p.product_id(),
        });
        prop_assert_eq!(&again[..], &buf[..]);
    }

    #[test]
    fn packets_survive_a_pcap_file_bit_exactly(fs in prop::collection::vec(fields(), 1..6), t0 in 0u64..4_000_000_000_000_000_000) {
        let mut w = CaptureWriter::new(Vec::new()).unwrap();
        let bufs: Vec<_> = fs.iter().map(encode).collect();
        for (i, b) in bufs.iter().enumerate() {
            w.write_udp(t0 + i as u64 * 1_327_000, endpoints(), b).unwrap();
        }
        let bytes = w.finish().unwrap();
        let mut r = CaptureReader::from_reader(Cursor::new(bytes)).unwrap();
        for (i, b) in bufs.iter().enumerate() {
            let d = r.next().unwrap().unwrap();
            prop_assert_eq!(d.payload, &b[..]);
            // pcap records keep µs.
            prop_assert_eq!(d.time_ns, (t0 + i as u64 * 1_327_000) / 1000 * 1000);
        }
        prop_assert!(r.next().unwrap().is_none());
    }

    #[test]
    fn decoding_any_valid_packet_gives_finite_points(f in fields(), t in 0u64..(1u64 << 62)) {
        let buf = encode(&f);
        let p = DataPacket::new_checked(&buf[..]).unwrap();
        for model in glint_driver::Model::ALL {
            let mut out = Vec::new();
            glint_driver::Decoder::for_model(model).decode_into(&p, t, &mut out);
            for q in &out {
                prop_assert!(q.x.is_finite() && q.y.is_finite() && q.z.is_finite() && q.azimuth.is_finite());
                prop_assert!((0.0..std::f32::consts::TAU).contains(&q.azimuth));
                prop_assert!(q.time_ns >= t);
            }
        }
    }

    #[test]
    fn corrupting_a_real_packet_never_panics(flips in prop::collection::vec((0usize..DATA_PAYLOAD_LEN, any::<u8>()), 1..8), cut in 0usize..=DATA_PAYLOAD_LEN) {
        let Some(packets) = real_packets() else { return Ok(()) };
        let mut stream = SensorStream::new(StreamConfig::default());
        for (i, (kind, payload, t)) in packets.iter().enumerate() {
            let mut bytes = payload.clone();
            if i % 7 == 3 {
                for &(at, value) in &flips {
                    if at < bytes.len() { bytes[at] = value; }
                }
                bytes.truncate(cut.min(bytes.len()));
            }
            let _ = match kind {
                PacketKind::Data => stream.push_data(&bytes, *t),
                PacketKind::Position => stream.push_position(&bytes),
            };
            while stream.take_sweep().is_some() {}
        }
        let _ = stream.finish();
    }
}

#[test]
fn every_truncation_of_a_real_packet_is_a_truncation_error() {
    let Some(packets) = real_packets() else {
        return;
    };
    let (_, payload, _) = packets
        .iter()
        .find(|(k, _, _)| *k == PacketKind::Data)
        .unwrap();
    for len in 0..payload.len() {
        assert_eq!(
            DataPacket::new_checked(&payload[..len]).unwrap_err(),
            PacketError::Truncated {
                expected: DATA_PAYLOAD_LEN,
                actual: len
            }
        );
    }
}

#[test]
fn every_structural_corruption_of_a_real_packet_is_an_error() {
    let Some(packets) = real_packets() else {
        return;
    };
    let (_, payload, _) = packets
        .iter()
        .find(|(k, _, _)| *k == PacketKind::Data)
        .unwrap();
    for block in 0..BLOCKS_PER_PACKET {
        for byte in 0..2 {
            for value in 0..=255u8 {
                let mut bad = payload.clone();
                if bad[block * 100 + byte] == value {
                    continue;
                }
                bad[block * 100 + byte] = value;
                assert!(
                    matches!(DataPacket::new_checked(&bad[..]), Err(PacketError::BadBlockFlag { block: b, .. }) if b == block)
                );
            }
        }
        let mut bad = payload.clone();
        bad[block * 100 + 3] = 0xFF; // azimuth ≥ 65280
        assert!(matches!(
            DataPacket::new_checked(&bad[..]),
            Err(PacketError::AzimuthOutOfRange { .. })
        ));
    }
    for value in (0..=255u8).filter(|v| !(0x37..=0x39).contains(v)) {
        let mut bad = payload.clone();
        bad[1204] = value;
        assert_eq!(
            DataPacket::new_checked(&bad[..]).unwrap_err(),
            PacketError::UnknownReturnMode(value)
        );
    }
}

type Packets = Vec<(PacketKind, Vec<u8>, u64)>;

fn real_packets() -> Option<Packets> {
    static PACKETS: std::sync::OnceLock<Option<Packets>> = std::sync::OnceLock::new();
    PACKETS
        .get_or_init(|| {
            let path = glint_testkit::shared_data(
                "properties on real VLP-16 packets",
                "vlp16_real_short.pcap",
            )?;
            let mut source = PcapSource::open(&path, Ports::default()).unwrap();
            let mut out = Vec::new();
            while let Some(p) = source.next().unwrap() {
                out.push((p.kind, p.payload.to_vec(), p.receive_ns));
            }
            Some(out)
        })
        .clone()
}

//! Driver throughput on one core, in packets per second: parse-only (checked view of every
//! packet) and full decode to timed points (x, y, z, time, ring, reflectivity) through sweep
//! assembly. Uses the real 20 Hz capture when `../shared/data` is present, otherwise synthetic
//! VLP-16 packets.
//!
//!     cargo bench -p glint-driver --bench decode

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glint_driver::sweep::SweepAssembler;
use glint_driver::wire::{BLOCKS_PER_PACKET, BLOCK_FLAG, DATA_PAYLOAD_LEN};
use glint_driver::{
    DataPacket, Decoder, Model, PacketKind, PcapSource, Ports, ReturnMode, SweepConfig,
};

fn packets() -> Vec<Vec<u8>> {
    let path = glint_testkit::shared_data(
        "the decode bench on the real 20 Hz capture",
        "vlp16_20hz_50_rotations.pcap",
    );
    if let Some(mut source) = path.and_then(|p| PcapSource::open(&p, Ports::default()).ok()) {
        let mut out = Vec::new();
        while let Ok(Some(p)) = source.next() {
            if p.kind == PacketKind::Data && DataPacket::new_checked(p.payload).is_ok() {
                out.push(p.payload.to_vec());
            }
        }
        return out;
    }
    eprintln!("benchmarking synthetic packets");
    (0..1000u32)
        .map(|i| {
            let mut buf = vec![0u8; DATA_PAYLOAD_LEN];
            let mut p = DataPacket::new_unchecked(&mut buf[..]);
            for b in 0..BLOCKS_PER_PACKET {
                p.set_block_flag(b, BLOCK_FLAG);
                p.set_azimuth(b, ((i * 480 + b as u32 * 40) % 36_000) as u16);
                for r in 0..32 {
                    p.set_record(b, r, 1000 + (r as u16) * 37, 20);
                }
            }
            p.set_timestamp_us(i * 1327);
            p.set_return_mode(ReturnMode::Strongest);
            buf
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let packets = packets();
    let mut group = c.benchmark_group("vlp16");
    group.throughput(Throughput::Elements(packets.len() as u64));
    group.bench_function("parse_only", |b| {
        b.iter(|| {
            let mut sum = 0u64;
            for p in &packets {
                let v = DataPacket::new_checked(&p[..]).unwrap();
                sum += u64::from(v.timestamp_us());
            }
            black_box(sum)
        })
    });
    let decoder = Decoder::for_model(Model::Vlp16);
    let mut points = Vec::with_capacity(400);
    group.bench_function("decode_points", |b| {
        b.iter(|| {
            let mut n = 0;
            for (i, p) in packets.iter().enumerate() {
                let v = DataPacket::new_checked(&p[..]).unwrap();
                points.clear();
                decoder.decode_into(&v, i as u64 * 1_327_104, &mut points);
                n += points.len();
            }
            black_box(n)
        })
    });
    let mut assembler = SweepAssembler::new(decoder.clone(), SweepConfig::default());
    let recycler = assembler.recycler();
    group.bench_function("decode_into_sweeps", |b| {
        b.iter(|| {
            let mut n = 0;
            for (i, p) in packets.iter().enumerate() {
                let v = DataPacket::new_checked(&p[..]).unwrap();
                assembler.push(&v, i as u64 * 663_552, 0);
                while let Some(s) = assembler.take_sweep() {
                    n += s.points.len();
                    recycler.recycle(s);
                }
            }
            black_box(n)
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

//! Fuzzes the packet parser and everything behind it: checked views, the decoder for every
//! model, and the stream (detection, clock, sweeps). Bytes 0..1206 are a data payload, the rest
//! a position payload; a mutated length exercises truncation.
#![no_main]

use glint_driver::{DataPacket, Decoder, Model, PositionPacket, SensorStream, StreamConfig};
use libfuzzer_sys::fuzz_target;

fn decoders() -> &'static [Decoder] {
    static DECODERS: std::sync::OnceLock<Vec<Decoder>> = std::sync::OnceLock::new();
    DECODERS.get_or_init(|| Model::ALL.into_iter().map(Decoder::for_model).collect())
}

fuzz_target!(|data: &[u8]| {
    let (payload, rest) = data.split_at(data.len().min(1206));
    if let Ok(p) = DataPacket::new_checked(payload) {
        let mut out = Vec::new();
        for decoder in decoders() {
            out.clear();
            decoder.decode_into(&p, u64::from(p.timestamp_us()) * 1000, &mut out);
            for q in &out {
                assert!(q.x.is_finite() && q.y.is_finite() && q.z.is_finite());
            }
        }
    }
    if let Ok(p) = PositionPacket::new_checked(rest) {
        let _ = p.nmea();
        let _ = glint_driver::nmea::parse_rmc(p.nmea());
    }
    // The stream builds its decoder once the model is decided: only worth it on inputs long
    // enough to hold several packets.
    if data.len() < 2 * 1206 {
        return;
    }
    let mut stream = SensorStream::new(StreamConfig::default());
    for (i, chunk) in data.chunks(1206).enumerate() {
        let _ = stream.push_data(chunk, i as u64 * 1_327_000);
        let _ = stream.push_position(chunk);
        while stream.take_sweep().is_some() {}
    }
    let _ = stream.finish();
});

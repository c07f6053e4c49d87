//! Fuzzes the capture reader (pcap and pcapng, link and IP layers): any bytes give datagrams
//! and then at most one error, never a panic or a hang.
#![no_main]

use glint_driver::pcap::CaptureReader;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(mut reader) = CaptureReader::with_buffer(std::io::Cursor::new(data.to_vec()), 0) else { return };
    let mut n = 0usize;
    loop {
        match reader.next() {
            Ok(Some(d)) => {
                assert!(d.payload.len() <= data.len());
                n += 1;
            }
            Ok(None) => break,
            Err(_) => {
                // After an error the reader is done.
                assert!(matches!(reader.next(), Ok(None)));
                break;
            }
        }
        assert!(n <= data.len());
    }
});

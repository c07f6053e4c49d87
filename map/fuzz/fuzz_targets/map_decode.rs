//! Fuzzes the site-map reader: any bytes give a map or an error, never a panic, a hang or an
//! allocation beyond what the bytes could hold. Each input is decoded twice: as given, which
//! exercises the envelope (magic, version, declared length, checksum), and sealed — the
//! declared length, the trailer and the CRC made to agree with the bytes — since a mutation
//! almost never keeps the checksum right, and the parser behind it is where the counts are.
#![no_main]

use glint_map::format::{field, HEADER_LENGTH, TRAILER_LENGTH};
use libfuzzer_sys::fuzz_target;

/// A decoded map is one `check` accepts, and it encodes to bytes that decode to the same map
/// (the same bytes once more: the writer is deterministic).
fn decode(bytes: &[u8]) {
    let Ok(map) = glint_map::decode(bytes) else {
        return;
    };
    glint_map::check(&map).expect("a decoded map passes check");
    let again = glint_map::encode(&map);
    let back = glint_map::decode(&again).expect("an encoded map decodes");
    assert_eq!(glint_map::encode(&back), again);
}

/// `content` followed by a trailer, with the header's length field set to match.
fn sealed(content: &[u8]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(content.len() + TRAILER_LENGTH);
    bytes.extend_from_slice(content);
    let length = (content.len() + TRAILER_LENGTH) as u64;
    bytes[field::LENGTH].copy_from_slice(&length.to_le_bytes());
    bytes.extend_from_slice(&(content.len() as u64).to_le_bytes());
    let crc = crc32fast::hash(&bytes);
    bytes.extend_from_slice(&crc.to_le_bytes());
    bytes
}

fuzz_target!(|data: &[u8]| {
    decode(data);
    // The input's own trailer, if it has one, is replaced: a real file seeds this path as is.
    let content =
        if data.len() >= HEADER_LENGTH + TRAILER_LENGTH && data[..8] == glint_map::MAGIC[..] {
            &data[..data.len() - TRAILER_LENGTH]
        } else {
            data
        };
    if content.len() >= HEADER_LENGTH {
        decode(&sealed(content));
    }
});

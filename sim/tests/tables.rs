//! The simulator's laser and timing tables are its own, written from the manual; the decoder has
//! its own too. Here they are held against each other (and the library is checked not to borrow
//! the decoder's): elevations equal, beam-origin offsets within 0.05 mm of the manual's rounded
//! table, firing times equal.

use glint_driver::wire::ReturnMode;
use glint_driver::Model;
use glint_sim::sensor::{
    record_offset_ns, vertical_offset_m, BLOCK_NS, ELEVATION_DEG, LASERS, LASER_INTERVAL_NS,
    SEQUENCE_NS,
};

#[test]
fn simulator_and_decoder_tables_agree() {
    let table = Model::Vlp16.laser_table();
    assert_eq!(table.len(), LASERS);
    for (l, laser) in table.lasers().iter().enumerate() {
        assert!(
            (laser.elevation.to_degrees() - ELEVATION_DEG[l]).abs() < 1e-12,
            "laser {l} elevation"
        );
        assert!(
            (laser.vertical_offset - vertical_offset_m(l)).abs() < 5e-5,
            "laser {l}: {} vs {}",
            laser.vertical_offset,
            vertical_offset_m(l)
        );
    }
    let timing = Model::Vlp16.timing();
    assert_eq!(
        (
            timing.lasers,
            timing.laser_ns,
            timing.sequence_ns,
            timing.block_ns()
        ),
        (LASERS, LASER_INTERVAL_NS, SEQUENCE_NS, BLOCK_NS)
    );
    assert_eq!(
        timing.packet_ns(ReturnMode::Strongest),
        record_offset_ns(12, 0)
    );
    assert_eq!(timing.packet_ns(ReturnMode::Dual), record_offset_ns(6, 0));
}

#[test]
fn the_library_does_not_use_the_decoders_tables() {
    fn walk(dir: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    walk(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src"),
        &mut files,
    );
    assert!(files.len() > 10);
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        // Code only: the docs may name what is not used.
        let code: String = text
            .lines()
            .filter(|l| !l.trim_start().starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n");
        for forbidden in [
            "glint_driver::model",
            "glint_driver::decode",
            "glint_driver::Decoder",
            "glint_driver::Model",
            "glint_driver::{",
        ] {
            assert!(
                !code.contains(forbidden),
                "{} uses {forbidden}",
                f.display()
            );
        }
    }
}

//! `glintd decode`: every return of a capture, as CSV or PLY, for inspection and for comparison
//! with other decoders.

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use glint_driver::{Point, Sweep};

use crate::capture::{replay, SensorArgs};

/// Arguments of `glintd decode`.
#[derive(Args, Debug)]
pub struct DecodeArgs {
    /// The capture (pcap or pcapng).
    pub capture: PathBuf,
    /// Output file: CSV, or binary PLY when the name ends in `.ply`.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub sensor: SensorArgs,
}

/// The columns, in order, of both formats.
pub const CSV_HEADER: &str = "sweep,time_ns,ring,laser,azimuth_deg,x,y,z,reflectivity,return";

/// Runs the command.
pub fn run(args: DecodeArgs) -> Result<()> {
    let ply = args
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"));
    let file =
        File::create(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut out = BufWriter::with_capacity(1 << 20, file);
    let mut count = 0u64;
    if ply {
        write_ply_header(&mut out, 0)?;
    } else {
        writeln!(out, "{CSV_HEADER}")?;
    }
    let report = replay(&args.capture, &args.sensor, |sweep: &Sweep| {
        for p in &sweep.points {
            if ply {
                write_ply_point(&mut out, sweep.index, p)?;
            } else {
                write_csv_point(&mut out, sweep.index, p)?;
            }
        }
        count += sweep.points.len() as u64;
        Ok(())
    })?;
    if ply {
        // The vertex count is known only now: rewrite the fixed-width header in place.
        out.flush()?;
        let mut file = out.into_inner().context("cannot flush the output")?;
        file.seek(SeekFrom::Start(0))?;
        let mut header = BufWriter::new(&mut file);
        write_ply_header(&mut header, count)?;
        header.flush()?;
    } else {
        out.flush()
            .with_context(|| format!("cannot write {}", args.out.display()))?;
    }
    let stats = report.stream.stats();
    if let Some(d) = report.stream.detection() {
        eprintln!("{}", d.describe());
    }
    eprintln!(
        "{count} returns in {} sweeps written to {}",
        stats.sweeps,
        args.out.display()
    );
    if let Some(damage) = report.damage {
        return Err(damage)
            .context("the capture is damaged; the returns before the damage were written");
    }
    Ok(())
}

fn write_csv_point(out: &mut impl Write, sweep: u64, p: &Point) -> std::io::Result<()> {
    writeln!(
        out,
        "{sweep},{},{},{},{:.4},{:.4},{:.4},{:.4},{},{}",
        p.time_ns,
        p.ring,
        p.laser,
        p.azimuth.to_degrees(),
        p.x,
        p.y,
        p.z,
        p.reflectivity,
        p.return_kind.name()
    )
}

/// The vertex count is written zero-padded so the header has the same length before and after
/// it is known.
fn write_ply_header(out: &mut impl Write, count: u64) -> std::io::Result<()> {
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\n\
         comment glintd decode: REP-103 sensor frame, metres; time_ns since the Unix epoch (a double: +-128 ns)\n\
         comment return: 0 strongest, 1 last, 2 both\n\
         element vertex {count:020}\n\
         property uint sweep\nproperty double time_ns\nproperty uchar ring\nproperty uchar laser\n\
         property float azimuth_deg\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar reflectivity\nproperty uchar return\nend_header\n"
    )
}

fn write_ply_point(out: &mut impl Write, sweep: u64, p: &Point) -> std::io::Result<()> {
    let kind: u8 = match p.return_kind {
        glint_driver::ReturnKind::Strongest => 0,
        glint_driver::ReturnKind::Last => 1,
        glint_driver::ReturnKind::Both => 2,
    };
    out.write_all(&(sweep as u32).to_le_bytes())?;
    out.write_all(&(p.time_ns as f64).to_le_bytes())?;
    out.write_all(&[p.ring, p.laser])?;
    for v in [p.azimuth.to_degrees(), p.x, p.y, p.z] {
        out.write_all(&v.to_le_bytes())?;
    }
    out.write_all(&[p.reflectivity, kind])
}

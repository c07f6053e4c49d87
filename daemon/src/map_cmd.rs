//! `glintd map`: look into a saved site map (`*.glintmap`): `info` prints its header, extent,
//! counts and size after verifying it; `export` writes its points in the map frame as a point
//! cloud any viewer opens (PCD, or PLY by the file name); `fetch` gets a map from any peer on
//! the fleet link that serves it (`glintd bridge --serve-map`) and replaces the local file only
//! once the whole map is verified. Reading and checking the file is `glint-map`'s; placing the
//! points is the map's poses'; the transfer is `glint-fleet`'s.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use glint_core::world_map::WorldMap;
use nalgebra::Point3;

use crate::outputs::write_map;

/// Arguments of `glintd map`.
#[derive(Args, Debug)]
pub struct MapArgs {
    #[command(subcommand)]
    pub command: MapCommand,
}

/// What to do with the map.
#[derive(Subcommand, Debug)]
pub enum MapCommand {
    /// Verify a map and print its header, extent, keyframes and size.
    Info {
        /// The map file.
        map: PathBuf,
    },
    /// Write a map's points (map frame, calibrated intensity) as PCD, or PLY when the name
    /// ends in .ply.
    Export {
        /// The map file.
        map: PathBuf,
        /// The point cloud to write.
        #[arg(long)]
        out: PathBuf,
        /// Voxel size of the exported cloud, m.
        #[arg(long, default_value_t = 0.1)]
        voxel: f32,
    },
    /// Fetch a site map from the fleet link (glint/<site>/maps/<NAME>), verify it and install
    /// it at --out; on any failure the file at --out is left as it was.
    Fetch(FetchArgs),
}

/// Arguments of `glintd map fetch`.
#[derive(Args, Debug)]
pub struct FetchArgs {
    /// The map's name (the served file's stem).
    pub name: String,
    /// Where to install it.
    #[arg(long)]
    pub out: PathBuf,
    /// The bridge's TOML configuration, for its [link] settings and site.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The site.
    #[arg(long)]
    pub site: Option<String>,
    /// A peer or router to connect to (`tls/fleet.example:7447`); repeatable.
    #[arg(long)]
    pub connect: Vec<String>,
    /// An endpoint to listen on; repeatable.
    #[arg(long)]
    pub listen: Vec<String>,
    /// Allow plain TCP without TLS settings.
    #[arg(long)]
    pub insecure: bool,
    /// Seconds to wait for a peer serving the map (and for each chunk).
    #[arg(long, default_value_t = 30.0)]
    pub timeout: f64,
}

/// Runs the command.
pub fn run(args: MapArgs) -> Result<()> {
    match args.command {
        MapCommand::Info { map } => info(&map),
        MapCommand::Export { map, out, voxel } => export(&map, &out, voxel),
        MapCommand::Fetch(args) => fetch(&args),
    }
}

fn fetch(args: &FetchArgs) -> Result<()> {
    anyhow::ensure!(
        args.timeout.is_finite() && args.timeout > 0.0,
        "--timeout must be a positive number of seconds"
    );
    let config = crate::bridge_cmd::LinkArgs {
        config: &args.config,
        listen: &args.listen,
        connect: &args.connect,
        insecure: args.insecure,
    }
    .resolve()?;
    let site = args
        .site
        .clone()
        .or(config.site)
        .unwrap_or_else(|| "site".into());
    let session = glint_fleet::open(&config.link).context("cannot open the fleet link")?;
    let fetched = glint_fleet::fetch_map(
        &session,
        &site,
        &args.name,
        &args.out,
        std::time::Duration::from_secs_f64(args.timeout),
    );
    let _ = zenoh::Wait::wait(session.close());
    let report = fetched?;
    say!(
        "{}: {} bytes from {} in {:.2} s ({} chunks), verified: {} keyframes, {} points",
        args.out.display(),
        report.bytes,
        report.key,
        report.seconds,
        report.chunks,
        report.counts.keyframes,
        report.counts.points
    );
    Ok(())
}

fn info(path: &std::path::Path) -> Result<()> {
    let started = Instant::now();
    let info = glint_map::info(path)?;
    let read_ms = started.elapsed().as_secs_f64() * 1e3;
    let c = &info.counts;
    say!(
        "{}: glintmap format {}",
        path.display(),
        info.format_version
    );
    say!(
        "created: {:.3} s since the Unix epoch, sensor {}",
        info.created_ns as f64 * 1e-9,
        info.sensor_model
    );
    let m = &info.base_from_sensor;
    let (roll, pitch, yaw) = m.rotation.euler_angles();
    say!(
        "mapping robot's mounting (sensor in base_link): translation {:.3} {:.3} {:.3} m, roll {roll:.4} pitch {pitch:.4} yaw {yaw:.4} rad",
        m.translation.x,
        m.translation.y,
        m.translation.z
    );
    match info.extent {
        Some((lo, hi)) => say!(
            "extent (map frame): x {:.1} … {:.1} m, y {:.1} … {:.1} m, z {:.1} … {:.1} m",
            lo[0],
            hi[0],
            lo[1],
            hi[1],
            lo[2],
            hi[2]
        ),
        None => say!("extent: empty map"),
    }
    say!(
        "keyframes: {} ({} holding points, {} released), {} points, {} intensity cells, {} graph edges",
        c.keyframes,
        c.keyframes - c.released,
        c.released,
        c.points,
        c.intensity_cells,
        c.edges
    );
    say!(
        "size: {} bytes ({:.2} MiB); read and verified in {read_ms:.1} ms",
        info.file_bytes,
        info.file_bytes as f64 / (1024.0 * 1024.0)
    );
    Ok(())
}

fn export(path: &std::path::Path, out: &std::path::Path, voxel: f32) -> Result<()> {
    anyhow::ensure!(
        voxel.is_finite() && voxel > 0.0,
        "--voxel {voxel}: must be a positive size in metres"
    );
    let map = glint_map::load(path)?;
    let mut cloud = WorldMap::new(voxel);
    for k in &map.keyframes {
        let pose = k.pose.cast::<f32>();
        for c in &k.keyframe.cloud {
            cloud.insert(&(pose * Point3::from(c.position)).coords, c.eta);
        }
    }
    let points = cloud.points();
    write_map(out, &points).with_context(|| format!("exporting {}", path.display()))?;
    say!(
        "wrote {} points of {} keyframes to {}",
        points.len(),
        map.keyframes.len(),
        out.display()
    );
    Ok(())
}

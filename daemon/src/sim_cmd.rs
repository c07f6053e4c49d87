//! `glintd sim`: the virtual VLP-16 from the command line. Writes a run's capture, ground truth
//! and scene description (`--out DIR`), streams the same packets live over UDP at real-time
//! pace (`--udp HOST`), or prints a scenario's layout (`--describe`). Runs of one scene may
//! differ in route, direction, start, sensor unit, goods and movers, and may include a kidnap.
//! Flags are parsed here and validated once into a `glint_sim::SimConfig`; the simulation
//! itself lives in `glint-sim`.

use std::net::{IpAddr, Ipv4Addr};
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use glint_sim::{
    parse_start_time, scenarios, ReturnMode, RunOptions, Scenario, SimConfig, UdpTarget,
};

/// Which returns the virtual sensor reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ReturnModeArg {
    /// The strongest echo of each firing (factory byte 0x37).
    Strongest,
    /// The last echo (0x38).
    Last,
    /// Both, in paired blocks (0x39).
    Dual,
}

impl From<ReturnModeArg> for ReturnMode {
    fn from(mode: ReturnModeArg) -> Self {
        match mode {
            ReturnModeArg::Strongest => ReturnMode::Strongest,
            ReturnModeArg::Last => ReturnMode::Last,
            ReturnModeArg::Dual => ReturnMode::Dual,
        }
    }
}

/// Simulate a VLP-16 on a robot driving through a scenario.
#[derive(Args, Debug)]
pub struct SimArgs {
    /// The scenario: warehouse, corridor or yard.
    pub scenario: String,
    /// Seed: varies the layout, the sensor unit, the start time and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated duration in seconds; the robot's loop repeats until it is reached.
    #[arg(long, default_value_t = 60.0, allow_negative_numbers = true)]
    pub seconds: f64,
    /// Write scan.pcap, groundtruth.tum, groundtruth_dense.tum and scene.json into this
    /// directory (created if needed).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Rotor speed in revolutions per minute (300–1200).
    #[arg(long, default_value_t = 600.0, allow_negative_numbers = true)]
    pub rpm: f64,
    /// Which returns to report.
    #[arg(long, value_enum, default_value_t = ReturnModeArg::Strongest)]
    pub return_mode: ReturnModeArg,
    /// Range noise σ in metres.
    #[arg(long, default_value_t = 0.015, allow_negative_numbers = true)]
    pub noise_sigma: f64,
    /// Turn off range and reflectivity noise (the per-laser gain bias stays: it is the unit's).
    #[arg(long)]
    pub no_noise: bool,
    /// Spread of the per-laser reflectivity gain (±fraction, 0–0.2; 0 for an ideal unit).
    #[arg(long, default_value_t = 0.03, allow_negative_numbers = true)]
    pub laser_gain_bias: f64,
    /// Probability that a data packet is lost, in [0, 1).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub packet_loss: f64,
    /// Time of the first firing, as Unix seconds (e.g. 1700000000.25) or RFC 3339 (e.g.
    /// 2024-05-01T12:00:00Z, 2024-05-01T14:00:00.5+02:00). Default: fixed by the seed.
    #[arg(long, value_name = "TIME")]
    pub start_time: Option<String>,
    /// Print the scenario's layout for this seed and exit.
    #[arg(long)]
    pub describe: bool,
    /// Stream the packets live at real-time pace to this host (e.g. 127.0.0.1).
    #[arg(long, value_name = "HOST")]
    pub udp: Option<String>,
    /// Destination port of data packets when streaming.
    #[arg(long, default_value_t = 2368)]
    pub data_port: u16,
    /// Destination port of position packets when streaming.
    #[arg(long, default_value_t = 8308)]
    pub position_port: u16,
    /// The sensor's IPv4 address written as the source of the capture's packets.
    #[arg(long, value_name = "ADDR", default_value_t = glint_sim::output::SENSOR_ADDRESS)]
    pub source_address: Ipv4Addr,
    /// Local address to stream from (e.g. 127.0.0.2 and 127.0.0.3 for two simulated sensors
    /// on loopback). Default: the kernel's choice.
    #[arg(long, value_name = "ADDR")]
    pub udp_bind: Option<IpAddr>,
    /// Drive another closed route through the same scene (same layout, same frame), chosen by
    /// this seed. Default: the scenario's own route.
    #[arg(long, value_name = "M")]
    pub path_seed: Option<u64>,
    /// Drive the route in the opposite direction.
    #[arg(long)]
    pub reverse: bool,
    /// Start this fraction of the lap length along the route, in [0, 1).
    #[arg(
        long,
        value_name = "F",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub start_fraction: f64,
    /// Teleport the robot T s after the start (at the end of the sweep in progress) to a place
    /// on the route at least 10 m away; writes kidnaps.txt beside the ground truth.
    #[arg(long, value_name = "T", allow_negative_numbers = true)]
    pub kidnap: Option<f64>,
    /// Another sensor unit: per-laser gains, start angle and noise drawn from this seed instead
    /// of --seed.
    #[arg(long, value_name = "U")]
    pub unit_seed: Option<u64>,
    /// Remove or shift (0.3–1.5 m, onto free floor) this fraction of the movable objects
    /// (pallets and loads, floor stacks, parked vehicles), in [0, 1].
    #[arg(
        long,
        value_name = "FRAC",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub change: f64,
    /// Decides which movable objects --change moves or removes, and how.
    #[arg(long, value_name = "C", default_value_t = 1)]
    pub change_seed: u64,
    /// Number of moving occluders (pedestrians, forklifts, cars): fewer than the scenario's
    /// keeps the first ones, more adds copies on their lanes. Default: the scenario's.
    #[arg(long, value_name = "N")]
    pub movers: Option<usize>,
}

impl SimArgs {
    /// The validated configuration these flags describe.
    pub fn config(&self) -> Result<SimConfig> {
        let scenario: Scenario = self.scenario.parse()?;
        let start_time_ns = self
            .start_time
            .as_deref()
            .map(parse_start_time)
            .transpose()?;
        let config = SimConfig {
            scenario,
            seed: self.seed,
            seconds: self.seconds,
            rpm: self.rpm,
            return_mode: self.return_mode.into(),
            range_noise_m: self.noise_sigma,
            noise: !self.no_noise,
            laser_gain_bias: self.laser_gain_bias,
            packet_loss: self.packet_loss,
            start_time_ns,
            path_seed: self.path_seed,
            reverse: self.reverse,
            start_fraction: self.start_fraction,
            kidnap_s: self.kidnap,
            unit_seed: self.unit_seed,
            change: self.change,
            change_seed: self.change_seed,
            movers: self.movers,
            ..SimConfig::default()
        };
        config.validate()?;
        Ok(config)
    }
}

/// Runs `glintd sim`.
pub fn run(args: SimArgs) -> Result<()> {
    if args.describe {
        let config = args.config()?;
        let text = scenarios::build_run(&config)
            .with_context(|| format!("describing {}", config.scenario))?
            .description;
        say!("{}", text.trim_end());
        return Ok(());
    }
    let config = args.config()?;
    if args.out.is_none() && args.udp.is_none() {
        bail!("nothing to do: give --out DIR to write files, --udp HOST to stream live, or --describe");
    }
    let target = args.udp.as_ref().map(|host| UdpTarget {
        host: host.clone(),
        data_port: args.data_port,
        position_port: args.position_port,
        bind: args.udp_bind,
    });
    if let Some(t) = &target {
        eprintln!(
            "streaming {} to {} (data port {}, position port {}) at real-time pace for {} s",
            config.scenario, t.host, t.data_port, t.position_port, config.seconds
        );
    }
    let options = RunOptions {
        out_dir: args.out.as_deref(),
        udp: target.as_ref(),
        stop: None,
        source_address: Some(args.source_address),
    };
    let summary = glint_sim::run(&config, &options)
        .with_context(|| format!("simulating {}", config.scenario))?;
    say!("{}", summary.report());
    if let Some(dir) = &args.out {
        say!(
            "wrote {0}/scan.pcap, {0}/groundtruth.tum, {0}/groundtruth_dense.tum, {0}/scene.json",
            dir.display()
        );
        if config.kidnap_s.is_some() {
            say!("wrote {}/kidnaps.txt", dir.display());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser, Debug)]
    struct Cli {
        #[command(flatten)]
        sim: SimArgs,
    }

    fn parse(args: &[&str]) -> SimArgs {
        Cli::try_parse_from(std::iter::once("sim").chain(args.iter().copied()))
            .expect("flags parse")
            .sim
    }

    #[test]
    fn defaults_are_the_documented_ones() {
        let a = parse(&["warehouse"]);
        assert_eq!(
            (a.seed, a.seconds, a.rpm, a.data_port, a.position_port),
            (1, 60.0, 600.0, 2368, 8308)
        );
        assert_eq!(a.source_address, Ipv4Addr::new(192, 168, 1, 201));
        assert_eq!(a.udp_bind, None);
        let c = a.config().unwrap();
        assert_eq!(c.return_mode, ReturnMode::Strongest);
        assert!(c.noise && c.start_time_ns.is_none());
        assert!(!c.is_variant(), "no flag, no variation of the scene");
    }

    #[test]
    fn run_variation_flags_reach_the_config() {
        let c = parse(&[
            "warehouse",
            "--seconds",
            "30",
            "--path-seed",
            "4",
            "--reverse",
            "--start-fraction",
            "0.25",
            "--kidnap",
            "12.5",
            "--unit-seed",
            "9",
            "--change",
            "0.2",
            "--change-seed",
            "5",
            "--movers",
            "3",
        ])
        .config()
        .unwrap();
        assert_eq!(c.path_seed, Some(4));
        assert!(c.reverse);
        assert_eq!(c.start_fraction, 0.25);
        assert_eq!(c.kidnap_s, Some(12.5));
        assert_eq!(c.unit_seed, Some(9));
        assert_eq!((c.change, c.change_seed), (0.2, 5));
        assert_eq!(c.movers, Some(3));
        for bad in [
            &["warehouse", "--start-fraction", "1"][..],
            &["warehouse", "--start-fraction", "-0.1"],
            &["warehouse", "--seconds", "10", "--kidnap", "10"],
            &["warehouse", "--kidnap", "-1"],
            &["warehouse", "--change", "1.5"],
            &["warehouse", "--movers", "1000"],
        ] {
            assert!(parse(bad).config().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn flags_reach_the_config() {
        let a = parse(&[
            "corridor",
            "--seed",
            "7",
            "--seconds",
            "12.5",
            "--rpm",
            "900",
            "--return-mode",
            "dual",
            "--no-noise",
            "--packet-loss",
            "0.01",
            "--start-time",
            "2024-05-01T12:00:00Z",
        ]);
        let c = a.config().unwrap();
        assert_eq!(
            (c.scenario, c.seed, c.seconds, c.rpm),
            (Scenario::Corridor, 7, 12.5, 900.0)
        );
        assert_eq!(c.return_mode, ReturnMode::Dual);
        assert!(!c.noise);
        assert_eq!(c.start_time_ns, Some(1_714_564_800_000_000_000));
    }

    #[test]
    fn network_flags_parse() {
        let a = parse(&[
            "yard",
            "--source-address",
            "192.168.1.202",
            "--udp-bind",
            "127.0.0.3",
        ]);
        assert_eq!(a.source_address, Ipv4Addr::new(192, 168, 1, 202));
        assert_eq!(a.udp_bind, Some(IpAddr::V4(Ipv4Addr::new(127, 0, 0, 3))));
        let cli = |args: &[&str]| {
            Cli::try_parse_from(std::iter::once("sim").chain(args.iter().copied())).is_err()
        };
        assert!(cli(&["yard", "--source-address", "::1"]), "IPv4 only");
        assert!(
            cli(&["yard", "--udp-bind", "localhost"]),
            "an address, not a name"
        );
    }

    #[test]
    fn bad_values_are_errors_not_panics() {
        assert!(parse(&["warehouse", "--seconds", "0"]).config().is_err());
        assert!(parse(&["warehouse", "--seconds", "-3"]).config().is_err());
        assert!(parse(&["parking-lot"]).config().is_err());
        assert!(parse(&["yard", "--rpm", "2000"]).config().is_err());
        assert!(parse(&["yard", "--start-time", "yesterday"])
            .config()
            .is_err());
        assert!(
            run(parse(&["yard"])).is_err(),
            "no --out, --udp or --describe"
        );
    }
}

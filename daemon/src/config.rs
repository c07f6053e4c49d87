//! The daemon's configuration: one TOML file (`glintd run --config FILE`), every key optional
//! with a default, unknown keys refused, and every value checked at start so a mistake is a
//! clear error naming its key rather than a surprise on the robot. `systemd/glintd.toml` is the
//! documented example.

use std::net::{IpAddr, Ipv4Addr};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use glint_core::backend::config::BackEndConfig;
use glint_core::config::OdometryConfig;
use glint_core::localiser::LocaliserConfig;
use glint_driver::calibration::load_calibration;
use glint_driver::udp::UdpConfig;
use glint_driver::{Model, Ports, StreamConfig, SweepConfig};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde::Deserialize;

/// The whole file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DaemonConfig {
    /// Where the packets come from and how to read them.
    pub sensor: SensorConfig,
    /// Threads and queues.
    pub pipeline: PipelineConfig,
    /// The algorithm's parameters (`glint_core::config`), by section.
    pub odometry: OdometryConfig,
    /// The back end's parameters (`glint_core::backend::config`), by section.
    pub backend: BackEndConfig,
    /// Where the sensor sits on the robot.
    pub mounting: MountingConfig,
    /// The iceoryx2 services.
    pub ipc: IpcConfig,
    /// Files written while running.
    pub output: OutputConfig,
    /// Mapping a site, or localising in its saved map.
    pub site_map: SiteMapConfig,
    /// The localiser's tuning (`glint_core::localiser`).
    pub localiser: LocaliserConfig,
}

/// What `glintd run` does with a saved site map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SiteMapMode {
    /// No site map: every run's `map` frame starts where the robot booted.
    #[default]
    Off,
    /// Build the site's map and save it to `path` (on shutdown and every `autosave_s`).
    Mapping,
    /// Localise in the map saved at `path`; it stays fixed.
    Localisation,
}

/// `[site_map]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SiteMapConfig {
    /// `off`, `mapping` or `localisation`.
    pub mode: SiteMapMode,
    /// The map file (`*.glintmap`).
    pub path: Option<PathBuf>,
    /// Mapping: save this often while running, s (0: only on shutdown).
    pub autosave_s: f64,
    /// Localisation: where `base_link` is believed to be at start, `[x, y, yaw]` in the map
    /// (m, m, rad); none to search the whole map.
    pub initial_pose: Option<[f64; 3]>,
    /// Localisation: at shutdown, write the saved map extended by the places this run drove
    /// through beyond it here (`path` itself makes the next start localise in the extended
    /// map); none: the map is only read.
    pub extend_to: Option<PathBuf>,
}

impl Default for SiteMapConfig {
    fn default() -> Self {
        Self {
            mode: SiteMapMode::Off,
            path: None,
            autosave_s: 60.0,
            initial_pose: None,
            extend_to: None,
        }
    }
}

/// The sensor's pose in the map from a `base_link` pose `[x, y, yaw]` there (m, m, rad) and
/// the mounting: a relocalisation hint.
pub fn initial_pose(xy_yaw: &[f64], base_from_sensor: &Isometry3<f64>) -> Result<Isometry3<f64>> {
    let [x, y, yaw] = xy_yaw else {
        bail!(
            "an initial pose is x, y, yaw: three numbers, not {}",
            xy_yaw.len()
        );
    };
    if !(x.is_finite() && y.is_finite() && yaw.is_finite()) {
        bail!("an initial pose must be finite numbers");
    }
    let base = Isometry3::from_parts(
        Translation3::new(*x, *y, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.0, *yaw),
    );
    Ok(base * base_from_sensor)
}

/// `[sensor]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    /// Local address to bind (0.0.0.0: every interface).
    pub address: IpAddr,
    /// The sensor's own address: only packets sent from it are decoded. None: the first
    /// address to send a valid data packet, any other refused and counted (`FOREIGN_SENSOR`).
    pub source: Option<Ipv4Addr>,
    /// UDP port of data packets.
    pub data_port: u16,
    /// UDP port of position packets.
    pub position_port: u16,
    /// Multicast group the sensor sends to, if any.
    pub multicast_group: Option<Ipv4Addr>,
    /// Interface address for the multicast join.
    pub multicast_interface: Ipv4Addr,
    /// Requested socket receive buffer, bytes.
    pub receive_buffer: usize,
    /// `vlp16`, `puck-hires` or `hdl32e`: overrides detection from the packets' timing.
    pub model: Option<String>,
    /// Laser calibration file (ROS `VLP16db.yaml` layout).
    pub calibration: Option<PathBuf>,
    /// Azimuth where sweeps are cut, degrees clockwise from the sensor's +x axis.
    pub cut_azimuth_deg: f64,
    /// No data packet for this long means the sensor is silent (flagged and logged), s.
    pub silence_timeout_s: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        let udp = UdpConfig::default();
        Self {
            address: udp.bind,
            source: None,
            data_port: udp.ports.data,
            position_port: udp.ports.position,
            multicast_group: None,
            multicast_interface: Ipv4Addr::UNSPECIFIED,
            receive_buffer: udp.receive_buffer,
            model: None,
            calibration: None,
            cut_azimuth_deg: 0.0,
            silence_timeout_s: 0.5,
        }
    }
}

/// `[pipeline]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineConfig {
    /// Use intensity (false: the geometry-only ablation).
    pub intensity: bool,
    /// Close loops and correct the `map` frame (false: odometry only, `map` = `odom`).
    pub loop_closure: bool,
    /// Sweeps that may wait between stages. Live, a sweep that finds its queue full is dropped
    /// whole (counted): a late pose is worth less than the next one.
    pub queue_sweeps: usize,
    /// Pin the odometry thread to this core (0-based), e.g. one kept free of navigation.
    pub odometry_cpu: Option<usize>,
    /// Run the odometry thread under `SCHED_FIFO` at this priority (1–99); needs
    /// `CAP_SYS_NICE` (systemd's `CPUSchedulingPolicy=` instead: see `systemd/README.md`).
    pub odometry_priority: Option<u8>,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            intensity: true,
            loop_closure: true,
            queue_sweeps: 2,
            odometry_cpu: None,
            odometry_priority: None,
        }
    }
}

/// `[mounting]`: the sensor's pose in `base_link` (x forward, y left, z up; REP-103).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MountingConfig {
    /// Sensor origin in `base_link`, m.
    pub translation: [f64; 3],
    /// Sensor orientation in `base_link` as roll, pitch, yaw (rad; applied yaw, then pitch,
    /// then roll about the moving axes — the ROS `rpy` convention).
    pub rotation_rpy: [f64; 3],
}

impl MountingConfig {
    /// `base_link` ← sensor.
    pub fn base_from_sensor(&self) -> Isometry3<f64> {
        let [x, y, z] = self.translation;
        let [r, p, yaw] = self.rotation_rpy;
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(r, p, yaw),
        )
    }
}

/// `[ipc]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IpcConfig {
    /// Publish over iceoryx2 at all.
    pub publish: bool,
    /// Service-name prefix: services are `glint/<domain>/odom`, `…/map`, `…/predicted`,
    /// `…/status`.
    pub domain: String,
    /// Rate of the predicted pose stream, Hz (0 turns it off).
    pub predicted_rate_hz: f64,
    /// Publish every sweep's returns, deskewed in `base_link`, on `glint/<domain>/sweep`.
    pub sweeps: bool,
    /// Publish the map as keyframes on `glint/<domain>/map_update` (with loop closure or a
    /// saved map to localise in).
    pub map_updates: bool,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            publish: true,
            domain: "default".into(),
            predicted_rate_hz: 50.0,
            sweeps: true,
            map_updates: true,
        }
    }
}

/// `[output]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputConfig {
    /// Trajectory of the sensor in the map frame (TUM) as published, streamed as it grows.
    pub trajectory: Option<PathBuf>,
    /// The odometry's own trajectory (odom frame), likewise.
    pub odom_trajectory: Option<PathBuf>,
    /// When the trajectory file reaches this size it is renamed to `<name>.1` (replacing the
    /// previous one) and a new one is started, bytes.
    pub trajectory_max_bytes: u64,
    /// The run's map (PCD, or PLY by extension), written at shutdown.
    pub map: Option<PathBuf>,
    /// Voxel size of that map, m.
    pub map_voxel: f32,
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            trajectory: None,
            odom_trajectory: None,
            trajectory_max_bytes: 64 << 20,
            map: None,
            map_voxel: 0.1,
        }
    }
}

impl DaemonConfig {
    /// Reads and validates `path`.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the configuration {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("in {}", path.display()))
    }

    /// [`Self::load`] when a path is given, the defaults otherwise.
    pub fn load_or_default(path: Option<&Path>) -> Result<Self> {
        path.map_or_else(|| Ok(Self::default()), Self::load)
    }

    /// Parses and validates a configuration text.
    pub fn parse(text: &str) -> Result<Self> {
        // toml's message names the key and shows the line (unknown field, wrong type).
        let mut config: Self = toml::from_str(text).map_err(|e| anyhow::anyhow!("{e}"))?;
        if !config.pipeline.intensity {
            config.odometry = config.odometry.without_intensity();
        }
        config.validate()?;
        Ok(config)
    }

    fn validate(&self) -> Result<()> {
        self.odometry
            .validate()
            .map_err(|e| anyhow::anyhow!("odometry.{e}"))?;
        let s = &self.sensor;
        if s.data_port == s.position_port && s.data_port != 0 {
            bail!(
                "sensor.data_port and sensor.position_port are both {}",
                s.data_port
            );
        }
        if !(s.cut_azimuth_deg.is_finite() && (0.0..360.0).contains(&s.cut_azimuth_deg)) {
            bail!(
                "sensor.cut_azimuth_deg = {}: must be in [0, 360)",
                s.cut_azimuth_deg
            );
        }
        if !(s.silence_timeout_s.is_finite() && s.silence_timeout_s >= 0.05) {
            bail!(
                "sensor.silence_timeout_s = {}: must be at least 0.05",
                s.silence_timeout_s
            );
        }
        if let Some(m) = &s.model {
            m.parse::<Model>()
                .map_err(|e| anyhow::anyhow!("sensor.model = {m:?}: {e}"))?;
        }
        if let Some(a) = s.source {
            if a.is_unspecified() || a.is_multicast() || a.is_broadcast() {
                bail!("sensor.source = {a}: the sensor's own address, not a group or wildcard");
            }
        }
        if let Some(g) = s.multicast_group {
            if !g.is_multicast() {
                bail!("sensor.multicast_group = {g}: not a multicast address");
            }
        }
        if s.receive_buffer < 64 << 10 {
            bail!(
                "sensor.receive_buffer = {}: must be at least 65536 bytes",
                s.receive_buffer
            );
        }
        if let Some(p) = self.pipeline.odometry_priority {
            anyhow::ensure!(
                (1..=99).contains(&p),
                "pipeline.odometry_priority = {p}: must be in 1..=99"
            );
        }
        if !(1..=64).contains(&self.pipeline.queue_sweeps) {
            bail!(
                "pipeline.queue_sweeps = {}: must be in 1..=64",
                self.pipeline.queue_sweeps
            );
        }
        let f = &self.backend.floor;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        for (key, value) in [
            ("radius", f.radius),
            ("min_spread", f.min_spread),
            ("max_rms", f.max_rms),
            ("search_band", f.search_band),
            ("max_tilt", f.max_tilt),
            ("sigma_height", f.sigma_height),
            ("sigma_tilt", f.sigma_tilt),
        ] {
            if !positive(value) {
                bail!("backend.floor.{key} = {value}: must be a finite number > 0");
            }
        }
        if !(f.min_clearance.is_finite() && f.min_clearance >= 0.0) {
            bail!(
                "backend.floor.min_clearance = {}: must be a finite number >= 0",
                f.min_clearance
            );
        }
        if f.optimize_every == 0 {
            bail!("backend.floor.optimize_every = 0: must be at least 1");
        }
        let m = &self.mounting;
        if m.translation
            .iter()
            .chain(&m.rotation_rpy)
            .any(|v| !v.is_finite())
        {
            bail!("mounting: translation and rotation_rpy must be finite numbers");
        }
        let site = &self.site_map;
        if site.mode != SiteMapMode::Off && site.path.is_none() {
            bail!(
                "site_map.path: mode {:?} needs the map file's path",
                site.mode
            );
        }
        if !(site.autosave_s.is_finite() && site.autosave_s >= 0.0) {
            bail!(
                "site_map.autosave_s = {}: must be finite and >= 0",
                site.autosave_s
            );
        }
        if let Some(p) = site.initial_pose {
            initial_pose(&p, &Isometry3::identity()).context("site_map.initial_pose")?;
        }
        if site.extend_to.is_some() && site.mode != SiteMapMode::Localisation {
            bail!(
                "site_map.extend_to: extending a map needs mode = \"localisation\" (mode is {:?})",
                site.mode
            );
        }
        if site.mode == SiteMapMode::Mapping && !self.pipeline.loop_closure {
            bail!("site_map.mode = \"mapping\" needs pipeline.loop_closure = true");
        }
        glint_ipc::Domain::new(&self.ipc.domain)
            .map_err(|e| anyhow::anyhow!("ipc.domain = {:?}: {e}", self.ipc.domain))?;
        let rate = self.ipc.predicted_rate_hz;
        if !(rate.is_finite() && (0.0..=1000.0).contains(&rate)) {
            bail!("ipc.predicted_rate_hz = {rate}: must be in [0, 1000]");
        }
        if self.output.trajectory_max_bytes < 4096 {
            bail!(
                "output.trajectory_max_bytes = {}: must be at least 4096",
                self.output.trajectory_max_bytes
            );
        }
        if !(self.output.map_voxel.is_finite() && self.output.map_voxel > 0.0) {
            bail!("output.map_voxel = {}: must be > 0", self.output.map_voxel);
        }
        Ok(())
    }

    /// The driver's stream configuration (loads the calibration file, if any).
    pub fn stream_config(&self) -> Result<StreamConfig> {
        let s = &self.sensor;
        let calibration = match &s.calibration {
            Some(path) => Some(
                load_calibration(path)
                    .with_context(|| format!("sensor.calibration = {}", path.display()))?,
            ),
            None => None,
        };
        Ok(StreamConfig {
            model: s.model.as_deref().map(str::parse).transpose()?,
            calibration,
            sweep: SweepConfig {
                cut_azimuth: s.cut_azimuth_deg.to_radians(),
                ..SweepConfig::default()
            },
        })
    }

    /// The odometry thread's placement.
    pub fn odometry_thread(&self) -> crate::pipeline::ThreadPlacement {
        crate::pipeline::ThreadPlacement {
            cpu: self.pipeline.odometry_cpu,
            realtime_priority: self.pipeline.odometry_priority,
        }
    }

    /// The sockets to bind.
    pub fn udp_config(&self) -> UdpConfig {
        let s = &self.sensor;
        UdpConfig {
            bind: s.address,
            ports: Ports {
                data: s.data_port,
                position: s.position_port,
            },
            multicast_group: s.multicast_group,
            multicast_interface: s.multicast_interface,
            receive_buffer: s.receive_buffer,
            clock: glint_driver::udp::ReceiveClock::host(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn an_empty_file_is_the_defaults() {
        let c = DaemonConfig::parse("").unwrap();
        assert_eq!(c.sensor.data_port, 2368);
        assert_eq!(c.ipc.domain, "default");
        assert_eq!(c.odometry, OdometryConfig::default());
        assert_eq!(c.mounting.base_from_sensor(), Isometry3::identity());
    }

    #[test]
    fn the_example_file_parses() {
        let text = include_str!("../../systemd/glintd.toml");
        let c = DaemonConfig::parse(text).unwrap();
        assert_eq!(c.ipc.predicted_rate_hz, 50.0);
    }

    #[test]
    fn the_source_is_the_senders_address() {
        let c = DaemonConfig::parse("[sensor]\nsource = \"192.168.1.201\"\n").unwrap();
        assert_eq!(c.sensor.source, Some(Ipv4Addr::new(192, 168, 1, 201)));
        assert_eq!(DaemonConfig::parse("").unwrap().sensor.source, None);
        for bad in ["0.0.0.0", "255.255.255.255", "239.255.0.1", "::1", "sensor"] {
            let text = format!("[sensor]\nsource = \"{bad}\"\n");
            let e = format!("{:#}", DaemonConfig::parse(&text).unwrap_err());
            assert!(e.contains("source"), "{bad}: {e}");
        }
    }

    #[test]
    fn an_unknown_key_is_named() {
        let e = DaemonConfig::parse("[sensor]\ndata_prot = 2368\n").unwrap_err();
        assert!(format!("{e:#}").contains("data_prot"), "{e:#}");
        let e = DaemonConfig::parse("[odometry.solver]\nhuber = 0.1\n").unwrap_err();
        assert!(format!("{e:#}").contains("huber"), "{e:#}");
    }

    #[test]
    fn an_impossible_value_is_named() {
        for (text, key) in [
            (
                "[sensor]\ncut_azimuth_deg = 400.0\n",
                "sensor.cut_azimuth_deg",
            ),
            ("[sensor]\nmodel = \"hdl64\"\n", "sensor.model"),
            ("[ipc]\ndomain = \"a/b\"\n", "ipc.domain"),
            ("[ipc]\npredicted_rate_hz = -1.0\n", "ipc.predicted_rate_hz"),
            ("[pipeline]\nqueue_sweeps = 0\n", "pipeline.queue_sweeps"),
            (
                "[pipeline]\nodometry_priority = 0\n",
                "pipeline.odometry_priority",
            ),
            (
                "[odometry.local_map]\nradius = 0.1\n",
                "odometry.local_map.radius",
            ),
            ("[sensor]\ndata_port = 70000\n", "data_port"),
            (
                "[backend.floor]\nsigma_tilt = 0.0\n",
                "backend.floor.sigma_tilt",
            ),
            (
                "[site_map]\nmode = \"mapping\"\npath = \"a\"\nextend_to = \"b\"\n",
                "site_map.extend_to",
            ),
        ] {
            let e = format!("{:#}", DaemonConfig::parse(text).unwrap_err());
            assert!(e.contains(key), "{text}: {e}");
        }
    }

    #[test]
    fn the_mounting_is_applied_in_ros_order() {
        let m = MountingConfig {
            translation: [0.5, 0.0, 1.2],
            rotation_rpy: [0.0, 0.0, std::f64::consts::FRAC_PI_2],
        };
        let p = m.base_from_sensor() * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((p.coords - Vector3::new(0.5, 1.0, 1.2)).norm() < 1e-12);
    }
}

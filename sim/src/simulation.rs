//! The packet stream of a run: data packets (every laser fired at its own instant, with the
//! rotor angle and robot pose of that instant) and GPS-locked position packets, in the order
//! they leave the sensor, each with its send time; optional per-return truth; the ground-truth
//! instants (sweep ends, 100 Hz).
//!
//! Timing: firing sequence n starts at `start + n × 55.296 µs`, continuously; a single-return
//! packet carries 24 sequences (12 blocks), a dual-return packet 12 (6 block pairs). A data
//! packet leaves [`SEND_LATENCY_NS`] after its last firing; position packets leave every
//! [`POSITION_PERIOD_NS`], the first at the start time, so a reader has the GPS hour before the
//! first data packet.
//!
//! A kidnap teleports the robot at the end of a sweep, so that no sweep spans the jump: the
//! sweep ends before and after it are consecutive ground-truth instants, and the dense ground
//! truth leaves out its instants in between, so no ground-truth line lies inside a jump.

use glint_driver::nmea::format_rmc;
use glint_driver::wire::{
    DataPacket, PositionPacket, PpsStatus, ReturnMode, BLOCKS_PER_PACKET, BLOCK_FLAG,
    DATA_PAYLOAD_LEN, POSITION_PAYLOAD_LEN,
};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::changes::ChangedObject;
use crate::config::{seeded_rng, SimConfig, Stream, KIDNAP_MIN_DISTANCE_M};
use crate::error::SimError;
use crate::scenarios;
use crate::scene::{Reflect, Scene};
use crate::sensor::{
    record_offset_ns, Echo, Selection, Vlp16, BLOCK_NS, LASERS, LASER_INTERVAL_NS, MAX_ECHOES,
    PRODUCT_ID, SEQUENCE_NS,
};
use crate::trajectory::{Pose, PoseBuffer, Trajectory};

/// Delay between a data packet's last firing and its departure, ns.
pub const SEND_LATENCY_NS: u64 = 30_000;
/// Interval between position packets, ns: five single-return data packets' worth, close to
/// the 16 position per 84 data packets of the real captures.
pub const POSITION_PERIOD_NS: u64 = 5 * BLOCKS_PER_PACKET as u64 * BLOCK_NS;
/// Default destination port of data packets.
pub const DATA_PORT: u16 = 2368;
/// Default destination port of position packets.
pub const POSITION_PORT: u16 = 8308;
/// Interval of the dense ground truth, ns (100 Hz).
pub const DENSE_PERIOD_NS: u64 = 10_000_000;
const HOUR_US: u64 = 3_600_000_000;

/// Which of the sensor's two streams a packet belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PacketKind {
    /// A 1206-byte data packet.
    Data,
    /// A 512-byte position packet.
    Position,
}

impl PacketKind {
    /// The sensor's default destination (and source) port.
    pub fn default_port(self) -> u16 {
        match self {
            PacketKind::Data => DATA_PORT,
            PacketKind::Position => POSITION_PORT,
        }
    }
}

/// A packet as it leaves the sensor, borrowing the generator's buffer.
#[derive(Debug, Clone, Copy)]
pub struct PacketRef<'a> {
    /// When it leaves the sensor, ns since the Unix epoch (the pcap record time).
    pub time_ns: u64,
    /// Data or position.
    pub kind: PacketKind,
    /// The UDP payload.
    pub payload: &'a [u8],
}

impl PacketRef<'_> {
    /// Its default destination port.
    pub fn port(&self) -> u16 {
        self.kind.default_port()
    }

    /// An owned copy.
    pub fn to_packet(&self) -> Packet {
        Packet {
            time_ns: self.time_ns,
            kind: self.kind,
            payload: self.payload.to_vec(),
        }
    }
}

/// An owned packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet {
    /// When it leaves the sensor, ns since the Unix epoch.
    pub time_ns: u64,
    /// Data or position.
    pub kind: PacketKind,
    /// The UDP payload.
    pub payload: Vec<u8>,
}

impl Packet {
    /// Its default destination port.
    pub fn port(&self) -> u16 {
        self.kind.default_port()
    }
}

/// Which return of a firing a truth record describes (as the decoder will label it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TruthKind {
    /// Strongest-return mode, or the strongest (or second-strongest) block of a dual pair.
    Strongest,
    /// Last-return mode, or the last block of a dual pair.
    Last,
    /// Dual mode where both blocks carry the same echo.
    Both,
}

/// What the simulator knows about one reported return.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthReturn {
    /// Firing time, ns since the Unix epoch (exact).
    pub time_ns: u64,
    /// Laser index (firing order, = record mod 16).
    pub laser: u8,
    /// Index of the data packet among all generated (lost ones included).
    pub packet: u64,
    /// Block within the packet.
    pub block: u8,
    /// Record within the block.
    pub record: u8,
    /// Which return.
    pub kind: TruthKind,
    /// The hit point in the sensor frame at the firing instant, before noise and quantisation.
    pub point: [f64; 3],
    /// Exact rotor azimuth at the firing, rad clockwise from +x, in [0, 2π).
    pub azimuth: f64,
    /// True distance from the beam origin, m.
    pub range_m: f64,
    /// Distance field written, 2 mm units.
    pub distance: u16,
    /// Reflectivity written.
    pub reflectivity: u8,
    /// The model's mean reflectivity for this echo, before noise and rounding.
    pub expected_reflectivity: f64,
    /// The scene object hit.
    pub object: u32,
    /// cos of the incidence angle.
    pub cos_incidence: f64,
    /// The surface is retro-reflective.
    pub retro: bool,
}

/// A teleport of the robot during a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kidnap {
    /// The last ground-truth instant before the jump (a sweep end), ns since the Unix epoch.
    pub before_ns: u64,
    /// The first ground-truth instant after it (the next sweep end).
    pub after_ns: u64,
    /// The base's position at `before_ns`, scene frame, m.
    pub from: [f64; 2],
    /// The base's position at `after_ns`, scene frame, m.
    pub to: [f64; 2],
}

/// How much farther than [`KIDNAP_MIN_DISTANCE_M`] the destination is chosen from where the
/// base is, m: the sensor sits off the base's centre and moves on for up to a sweep before
/// the next ground-truth instant, so the sensor's jump between the instants that bracket it
/// still exceeds the minimum.
const KIDNAP_MARGIN_M: f64 = 1.0;

/// Counts of a run so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SimStats {
    /// Data packets produced (lost ones excluded).
    pub data_packets: u64,
    /// Position packets produced.
    pub position_packets: u64,
    /// Data packets lost on purpose.
    pub dropped_packets: u64,
    /// Laser firings simulated.
    pub rays: u64,
    /// Returns written (a dual-return firing with two echoes counts two).
    pub returns: u64,
}

/// A run: the scene, the motion and the sensor, producing packets one at a time.
#[derive(Debug)]
pub struct Simulation {
    config: SimConfig,
    scene: Scene,
    trajectory: Trajectory,
    sensor: Vlp16,
    description: String,
    start_ns: u64,
    sequences_per_packet: u64,
    data_total: u64,
    next_data: u64,
    next_position_ns: u64,
    noise_rng: ChaCha8Rng,
    loss_rng: ChaCha8Rng,
    data: Box<[u8; DATA_PAYLOAD_LEN]>,
    position: Box<[u8; POSITION_PAYLOAD_LEN]>,
    poses: PoseBuffer,
    stats: SimStats,
    kidnaps: Vec<Kidnap>,
    changes: Vec<ChangedObject>,
}

impl Simulation {
    /// A run of the configured scenario.
    pub fn new(config: &SimConfig) -> Result<Simulation, SimError> {
        config.validate()?;
        let built = scenarios::build_run(config).map_err(|source| SimError::Layout {
            scenario: config.scenario.to_string(),
            seed: config.seed,
            source: Box::new(source),
        })?;
        let mut sim =
            Simulation::from_parts(config, built.scene, built.trajectory, built.description)?;
        sim.changes = built.changes;
        Ok(sim)
    }

    /// A run in a scene and motion of the caller's (tests on known geometry). The config's
    /// scenario is then only a label; its kidnap, if any, is applied to the motion.
    pub fn from_parts(
        config: &SimConfig,
        scene: Scene,
        trajectory: Trajectory,
        description: String,
    ) -> Result<Simulation, SimError> {
        config.validate()?;
        let sensor = Vlp16::new(config);
        let sequences_per_packet = match config.return_mode {
            ReturnMode::Dual => BLOCKS_PER_PACKET as u64 / 2,
            _ => BLOCKS_PER_PACKET as u64,
        } * 2;
        let packet_ns = sequences_per_packet * SEQUENCE_NS;
        let data_total = config.duration_ns().div_ceil(packet_ns).max(1);
        let start_ns = config.start_time_ns();
        let mut sim = Simulation {
            config: config.clone(),
            scene,
            trajectory,
            sensor,
            description,
            start_ns,
            sequences_per_packet,
            data_total,
            next_data: 0,
            next_position_ns: start_ns,
            noise_rng: seeded_rng(config.sensor_unit_seed(), Stream::Noise),
            loss_rng: seeded_rng(config.seed, Stream::Loss),
            data: Box::new([0; DATA_PAYLOAD_LEN]),
            position: Box::new([0; POSITION_PAYLOAD_LEN]),
            poses: PoseBuffer::default(),
            stats: SimStats::default(),
            kidnaps: Vec::new(),
            changes: Vec::new(),
        };
        if let Some(time_s) = config.kidnap_s {
            sim.kidnap(time_s)?;
        }
        Ok(sim)
    }

    /// Teleports the robot at the first sweep end at or after `time_s` s into the run to a
    /// place on the route drawn from the seed's kidnap stream among those far enough away.
    fn kidnap(&mut self, time_s: f64) -> Result<(), SimError> {
        let error = |reason: String| SimError::Kidnap { time_s, reason };
        let target = self.start_ns + (time_s * 1e9).round() as u64;
        let ends = self.sweep_end_times();
        let k = ends.partition_point(|&t| t < target);
        let (Some(&before_ns), Some(&after_ns)) = (ends.get(k), ends.get(k + 1)) else {
            return Err(error("no sweep ends after it within the run".into()));
        };
        let before = self.rel(before_ns);
        let here = self.trajectory.base_state(before);
        let from = [here.x, here.y];
        let min_distance = KIDNAP_MIN_DISTANCE_M + KIDNAP_MARGIN_M;
        let places = self.trajectory.lap_times_away_from(from, min_distance);
        if places.is_empty() {
            return Err(error(format!(
                "no place on the route is {min_distance} m from ({:.2}, {:.2}) m, where the robot is then",
                from[0], from[1]
            )));
        }
        let mut rng = seeded_rng(self.config.seed, Stream::Kidnap);
        let lap_time = places[rng.random_range(0..places.len())];
        // Half a laser interval past the sweep's last firing: no firing instant is near the
        // switch, whatever the rounding of its time.
        let switch = before + 0.5 * LASER_INTERVAL_NS as f64 * 1e-9;
        self.trajectory = self.trajectory.clone().with_jump(switch, lap_time);
        let there = self.trajectory.base_state(self.rel(after_ns));
        self.kidnaps.push(Kidnap {
            before_ns,
            after_ns,
            from,
            to: [there.x, there.y],
        });
        Ok(())
    }

    /// The robot's teleports, in time order.
    pub fn kidnaps(&self) -> &[Kidnap] {
        &self.kidnaps
    }

    /// The movable objects the run's scene has removed or shifted.
    pub fn changes(&self) -> &[ChangedObject] {
        &self.changes
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The motion.
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }

    /// The sensor unit.
    pub fn sensor(&self) -> &Vlp16 {
        &self.sensor
    }

    /// The scenario's printable description.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// Counts so far.
    pub fn stats(&self) -> SimStats {
        self.stats
    }

    /// Time of the first firing, ns since the Unix epoch.
    pub fn start_ns(&self) -> u64 {
        self.start_ns
    }

    /// Time of the last firing of the run, ns since the Unix epoch.
    pub fn last_firing_ns(&self) -> u64 {
        self.sequence_time(self.data_total * self.sequences_per_packet - 1)
            + (LASERS as u64 - 1) * LASER_INTERVAL_NS
    }

    /// Data packets the run generates (before loss).
    pub fn data_packets_total(&self) -> u64 {
        self.data_total
    }

    /// Data packets generated so far, lost ones included.
    pub fn generated_packets(&self) -> u64 {
        self.next_data
    }

    /// Sensor time one data packet covers, ns.
    pub fn packet_span_ns(&self) -> u64 {
        self.sequences_per_packet * SEQUENCE_NS
    }

    /// The last firing of the data generated so far (`None` before the first packet).
    pub fn last_generated_firing_ns(&self) -> Option<u64> {
        (self.next_data > 0).then(|| {
            self.sequence_time(self.next_data * self.sequences_per_packet - 1)
                + (LASERS as u64 - 1) * LASER_INTERVAL_NS
        })
    }

    /// Seconds since the start at an absolute time.
    #[inline]
    fn rel(&self, time_ns: u64) -> f64 {
        (time_ns as i128 - self.start_ns as i128) as f64 * 1e-9
    }

    fn sequence_time(&self, n: u64) -> u64 {
        self.start_ns + n * SEQUENCE_NS
    }

    /// The sensor's pose in the scene frame at an absolute time.
    pub fn sensor_pose_at(&self, time_ns: u64) -> Pose {
        self.trajectory.sensor_pose(self.rel(time_ns))
    }

    /// The time of every sweep's last firing: the last firing (laser 15) of the last sequence
    /// that starts before the rotor crosses azimuth 0, for every crossing in the run, and the
    /// run's last firing for the sweep the end of the run cuts off.
    pub fn sweep_end_times(&self) -> Vec<u64> {
        let total = self.data_total * self.sequences_per_packet;
        let omega = self.sensor.angular_speed();
        let theta0 = self.sensor.start_azimuth();
        let last_laser = (LASERS as u64 - 1) * LASER_INTERVAL_NS;
        let mut out = Vec::new();
        for m in 1u64.. {
            let crossing_s = (m as f64 * std::f64::consts::TAU - theta0) / omega;
            let first_after = (crossing_s * 1e9 / SEQUENCE_NS as f64).ceil() as u64;
            if first_after >= total {
                break;
            }
            if first_after >= 1 {
                out.push(self.sequence_time(first_after - 1) + last_laser);
            }
        }
        let end = self.last_firing_ns();
        if out.last() != Some(&end) {
            out.push(end);
        }
        out
    }

    /// Instants of the dense ground truth: every 10 ms from the start to the last firing,
    /// except those strictly inside a kidnap's jump.
    pub fn dense_times(&self) -> Vec<u64> {
        let end = self.last_firing_ns();
        (0..)
            .map(|k| self.start_ns + k * DENSE_PERIOD_NS)
            .take_while(|&t| t <= end)
            .filter(|&t| {
                !self
                    .kidnaps
                    .iter()
                    .any(|j| j.before_ns < t && t < j.after_ns)
            })
            .collect()
    }

    fn data_send_time(&self, i: u64) -> u64 {
        let blocks = (self.sequences_per_packet / 2) as usize;
        self.sequence_time(i * self.sequences_per_packet)
            + record_offset_ns(blocks - 1, 31)
            + SEND_LATENCY_NS
    }

    /// The next packet, or `None` at the end of the run.
    pub fn next_packet(&mut self) -> Option<PacketRef<'_>> {
        self.next_packet_with_truth(|_| {})
    }

    /// The next packet, calling `on_return` for every return it carries.
    pub fn next_packet_with_truth(
        &mut self,
        mut on_return: impl FnMut(&TruthReturn),
    ) -> Option<PacketRef<'_>> {
        let last_send = self.data_send_time(self.data_total - 1);
        loop {
            let data_send =
                (self.next_data < self.data_total).then(|| self.data_send_time(self.next_data));
            let position_due = self.next_position_ns <= last_send
                && data_send.is_none_or(|d| self.next_position_ns <= d);
            if position_due {
                let t = self.next_position_ns;
                self.next_position_ns += POSITION_PERIOD_NS;
                self.fill_position(t);
                self.stats.position_packets += 1;
                return Some(PacketRef {
                    time_ns: t,
                    kind: PacketKind::Position,
                    payload: &self.position[..],
                });
            }
            let send = data_send?;
            let i = self.next_data;
            self.next_data += 1;
            if self.config.packet_loss > 0.0
                && self.loss_rng.random::<f64>() < self.config.packet_loss
            {
                self.stats.dropped_packets += 1;
                continue;
            }
            self.fill_data(i, &mut on_return);
            self.stats.data_packets += 1;
            return Some(PacketRef {
                time_ns: send,
                kind: PacketKind::Data,
                payload: &self.data[..],
            });
        }
    }

    /// Every remaining packet, owned.
    pub fn into_packets(self) -> Packets {
        Packets(self)
    }

    fn fill_position(&mut self, time_ns: u64) {
        self.position.fill(0);
        let mut p = PositionPacket::new_unchecked(&mut self.position[..]);
        p.set_timestamp_us(((time_ns / 1000) % HOUR_US) as u32);
        p.set_pps_status(PpsStatus::Locked);
        p.set_nmea(format_rmc(time_ns).as_bytes());
    }

    fn fill_data(&mut self, index: u64, on_return: &mut impl FnMut(&TruthReturn)) {
        let Simulation {
            config,
            scene,
            trajectory,
            sensor,
            noise_rng,
            data,
            stats,
            start_ns,
            sequences_per_packet,
            poses,
            ..
        } = self;
        let (start_ns, sequences_per_packet) = (*start_ns, *sequences_per_packet);
        let rel = |time_ns: u64| (time_ns - start_ns) as f64 * 1e-9;
        let mode = config.return_mode;
        let dual = mode == ReturnMode::Dual;
        let single_kind = if mode == ReturnMode::Last {
            TruthKind::Last
        } else {
            TruthKind::Strongest
        };
        let firing_blocks = (sequences_per_packet / 2) as usize;
        let packet_time = start_ns + index * sequences_per_packet * SEQUENCE_NS;
        let mut packet = DataPacket::new_unchecked(&mut data[..]);
        let mut echoes = [NO_ECHO; MAX_ECHOES];
        let laser_step = LASER_INTERVAL_NS as f64 * 1e-9;
        // Every laser gets the pose of its own firing instant: the packet's firing grid at once.
        let sequences = 2 * firing_blocks;
        trajectory.sensor_poses(
            rel(packet_time),
            SEQUENCE_NS as f64 * 1e-9,
            sequences,
            laser_step,
            LASERS,
            poses,
        );
        let poses = poses.poses();
        // The rotor turns by a fixed angle between lasers: advance its sine and cosine by angle
        // addition rather than calling sin_cos per firing.
        let rotor_step = sensor.angular_speed() * laser_step;
        let (step_sin, step_cos) = rotor_step.sin_cos();
        for fb in 0..firing_blocks {
            let block_time = packet_time + fb as u64 * BLOCK_NS;
            let block_azimuth = sensor.azimuth_field(rel(block_time));
            let blocks: &[usize] = if dual { &[2 * fb, 2 * fb + 1] } else { &[fb] };
            for &b in blocks {
                packet.set_block_flag(b, BLOCK_FLAG);
                packet.set_azimuth(b, block_azimuth);
            }
            for seq in 0..2 {
                let seq_time = block_time + seq as u64 * SEQUENCE_NS;
                let t0 = rel(seq_time);
                let alpha0 = sensor.azimuth_unwrapped(t0);
                let (mut sin_a, mut cos_a) = alpha0.sin_cos();
                let first = (2 * fb + seq) * LASERS;
                for (laser, pose) in poses[first..first + LASERS].iter().enumerate() {
                    let record = seq * LASERS + laser;
                    let time_ns = seq_time + laser as u64 * LASER_INTERVAL_NS;
                    let t = rel(time_ns);
                    let (o_local, d_local) = sensor.beam_sin_cos(laser, sin_a, cos_a);
                    (sin_a, cos_a) = (
                        sin_a * step_cos + cos_a * step_sin,
                        cos_a * step_cos - sin_a * step_sin,
                    );
                    let origin = pose.transform_point(&o_local);
                    let dir = pose.rotation * d_local;
                    let n = sensor.echoes(scene, laser, origin.into(), dir.into(), t, &mut echoes);
                    stats.rays += 1;
                    let truth = |echo: &Echo,
                                 kind: TruthKind,
                                 (distance, reflectivity): (u16, u8),
                                 block: usize| {
                        let p = o_local + d_local * echo.range;
                        TruthReturn {
                            time_ns,
                            laser: laser as u8,
                            packet: index,
                            block: block as u8,
                            record: record as u8,
                            kind,
                            point: p.into(),
                            azimuth: (alpha0 + laser as f64 * rotor_step)
                                .rem_euclid(std::f64::consts::TAU),
                            range_m: echo.range,
                            distance,
                            reflectivity,
                            expected_reflectivity: echo.strength,
                            object: echo.id,
                            cos_incidence: echo.cos_incidence,
                            retro: matches!(echo.reflect, Reflect::Retro(_)),
                        }
                    };
                    match (sensor.select(&echoes[..n]), dual) {
                        (Selection::Nothing, _) => {
                            for &b in blocks {
                                packet.set_record(b, record, 0, 0);
                            }
                        }
                        (Selection::One(k), false) => {
                            let m = sensor.measure(&echoes[k], noise_rng);
                            packet.set_record(fb, record, m.0, m.1);
                            on_return(&truth(&echoes[k], single_kind, m, fb));
                            stats.returns += 1;
                        }
                        (Selection::One(k), true) => {
                            // The same echo in both blocks: identical records, as the sensor sends.
                            let m = sensor.measure(&echoes[k], noise_rng);
                            packet.set_record(2 * fb, record, m.0, m.1);
                            packet.set_record(2 * fb + 1, record, m.0, m.1);
                            on_return(&truth(&echoes[k], TruthKind::Both, m, 2 * fb));
                            stats.returns += 1;
                        }
                        (Selection::Two { last, strong }, _) => {
                            let ml = sensor.measure(&echoes[last], noise_rng);
                            let ms = sensor.measure(&echoes[strong], noise_rng);
                            packet.set_record(2 * fb, record, ml.0, ml.1);
                            packet.set_record(2 * fb + 1, record, ms.0, ms.1);
                            on_return(&truth(&echoes[last], TruthKind::Last, ml, 2 * fb));
                            on_return(&truth(
                                &echoes[strong],
                                TruthKind::Strongest,
                                ms,
                                2 * fb + 1,
                            ));
                            stats.returns += 2;
                        }
                    }
                }
            }
        }
        packet.set_timestamp_us(((packet_time / 1000) % HOUR_US) as u32);
        packet.set_return_mode(mode);
        packet.set_product_id(PRODUCT_ID);
    }
}

const NO_ECHO: Echo = Echo {
    range: 0.0,
    id: 0,
    cos_incidence: 0.0,
    reflect: Reflect::Diffuse(0.0),
    weight: 0.0,
    strength: 0.0,
    detected: false,
};

/// The owned-packet iterator over a run.
#[derive(Debug)]
pub struct Packets(Simulation);

impl Iterator for Packets {
    type Item = Packet;
    fn next(&mut self) -> Option<Packet> {
        self.0.next_packet().map(|p| p.to_packet())
    }
}

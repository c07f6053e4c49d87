//! The `map_update` service's part of the pipeline: a thread of its own holds the map as
//! keyframes (points in each keyframe's sensor frame, poses in the frame of the `map` stream,
//! loop edges) and publishes what changed at most once a second, and the whole map again
//! whenever a subscriber connects. Mapping, the back end hands it each new keyframe and, after
//! an optimisation, every pose; localising, it is given the saved map once and it never
//! changes. Nothing on the pose path waits for it: the back end offers without blocking, and
//! what the thread sends is paced so a reader polling every 100 ms keeps up.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};
use glint_core::backend::keyframe::Keyframe;
use glint_core::backend::BackEnd;
use glint_core::site_map::SiteMap;
use glint_ipc::settings::MAP_UPDATE_REPLAY_RATE;
use glint_ipc::{
    Domain, KeyframePose, MapEdge, MapPoint, MapUpdateFlags, MapUpdateHeader, MapUpdatePublisher,
};
use nalgebra::Isometry3;

/// Changes a consumer is sent at most this often.
const UPDATE_PERIOD: Duration = Duration::from_secs(1);

/// How often the thread looks for new subscribers and sends paced parts.
const TICK: Duration = Duration::from_millis(50);

/// Keyframe events allowed to wait for the thread; more are dropped (counted, logged), which
/// only a thread stalled for minutes of mapping would see.
pub(super) const MAP_EVENT_QUEUE: usize = 256;

/// What the back end tells the map thread.
pub(super) enum MapEvent {
    /// A keyframe joined the map at this pose (sensor → map).
    Keyframe {
        index: usize,
        pose: Isometry3<f64>,
        time_ns: u64,
        points: Vec<MapPoint>,
    },
    /// The graph moved: every keyframe's pose (sensor → map) and the loop edges.
    Optimised {
        poses: Vec<Isometry3<f64>>,
        edges: Vec<MapEdge>,
    },
}

/// The back end's side: offers events without ever blocking.
pub(super) struct MapOutlet {
    events: Sender<MapEvent>,
    /// `map ← world`: the back end's world is the first sensor pose; the `map` stream's frame
    /// is the first `base_link` pose.
    map_from_world: Isometry3<f64>,
    dropped: u64,
}

impl MapOutlet {
    pub(super) fn new(events: Sender<MapEvent>, map_from_world: Isometry3<f64>) -> Self {
        Self {
            events,
            map_from_world,
            dropped: 0,
        }
    }

    fn offer(&mut self, event: MapEvent) {
        if let Err(TrySendError::Full(_)) = self.events.try_send(event) {
            self.dropped += 1;
            tracing::warn!(
                dropped = self.dropped,
                "map_update service busy: a map change was not published"
            );
        }
    }

    /// The keyframe `index` the back end just added.
    pub(super) fn keyframe_added(&mut self, backend: &BackEnd, index: usize) {
        let (Some(keyframe), Some(pose)) = (
            backend.keyframes().get(index),
            backend.keyframe_poses().get(index),
        ) else {
            return;
        };
        self.offer(MapEvent::Keyframe {
            index,
            pose: self.map_from_world * pose,
            time_ns: keyframe.time_ns,
            points: cloud_of(keyframe),
        });
    }

    /// The back end's graph after an optimisation.
    pub(super) fn optimised(&mut self, backend: &BackEnd) {
        let poses = backend
            .keyframe_poses()
            .iter()
            .map(|p| self.map_from_world * p)
            .collect();
        let edges = backend
            .loops()
            .iter()
            .map(|l| edge(l.candidate, l.query))
            .collect();
        self.offer(MapEvent::Optimised { poses, edges });
    }
}

fn edge(a: usize, b: usize) -> MapEdge {
    MapEdge {
        from: a.min(b) as u32,
        to: a.max(b) as u32,
    }
}

/// A keyframe's calibrated returns as map points (its sensor frame).
fn cloud_of(keyframe: &Keyframe) -> Vec<MapPoint> {
    keyframe
        .cloud
        .iter()
        .map(|c| MapPoint {
            position: c.position,
            intensity: c.eta,
        })
        .collect()
}

fn keyframe_pose(index: usize, time_ns: u64, pose: &Isometry3<f64>) -> KeyframePose {
    let q = pose.rotation.coords;
    KeyframePose {
        keyframe: index as u32,
        reserved: 0,
        sensor_time_ns: time_ns,
        position: pose.translation.vector.into(),
        orientation: [q.x, q.y, q.z, q.w],
    }
}

/// The map as consumers get it.
#[derive(Default)]
pub(super) struct HeldMap {
    map_id: u64,
    flags: MapUpdateFlags,
    clouds: Vec<Vec<MapPoint>>,
    poses: Vec<KeyframePose>,
    edges: Vec<MapEdge>,
    /// Changes not yet queued: keyframes from this index, every pose, the edges.
    new_from: usize,
    poses_moved: bool,
    edges_changed: bool,
}

impl HeldMap {
    /// An empty map being made by this run (its id: when the run started).
    pub(super) fn mapping(started_ns: u64) -> Self {
        Self {
            map_id: started_ns,
            ..Self::default()
        }
    }

    /// The saved map a run localises in: keyframe poses are already sensor → map.
    pub(super) fn saved(map: &SiteMap) -> Self {
        let mut edges: Vec<MapEdge> = map
            .edges
            .iter()
            .filter(|e| e.from.abs_diff(e.to) > 1)
            .map(|e| edge(e.from, e.to))
            .collect();
        edges.sort_unstable_by_key(|e| (e.from, e.to));
        edges.dedup();
        Self {
            map_id: map.created_ns,
            flags: MapUpdateFlags::SAVED_MAP,
            clouds: map
                .keyframes
                .iter()
                .map(|k| cloud_of(&k.keyframe))
                .collect(),
            poses: map
                .keyframes
                .iter()
                .enumerate()
                .map(|(i, k)| keyframe_pose(i, k.keyframe.time_ns, &k.pose))
                .collect(),
            edges,
            new_from: map.keyframes.len(),
            poses_moved: false,
            edges_changed: false,
        }
    }

    fn apply(&mut self, event: MapEvent) {
        match event {
            MapEvent::Keyframe {
                index,
                pose,
                time_ns,
                points,
            } => {
                if index != self.poses.len() {
                    // Keyframes come in order; one lost on the way would shift every index.
                    tracing::warn!(index, held = self.poses.len(), "map keyframe out of order");
                    return;
                }
                self.clouds.push(points);
                self.poses.push(keyframe_pose(index, time_ns, &pose));
            }
            MapEvent::Optimised { poses, edges } => {
                for (held, pose) in self.poses.iter_mut().zip(&poses) {
                    *held = keyframe_pose(held.keyframe as usize, held.sensor_time_ns, pose);
                }
                self.poses_moved = true;
                if edges != self.edges {
                    self.edges = edges;
                    self.edges_changed = true;
                }
            }
        }
    }

    fn has_changes(&self) -> bool {
        self.new_from < self.poses.len() || self.poses_moved || self.edges_changed
    }

    fn newest_ns(&self) -> u64 {
        self.poses.last().map_or(0, |p| p.sensor_time_ns)
    }
}

/// One message waiting to be sent; it reads the held map when it goes, so it carries the
/// latest poses.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Outgoing {
    /// Poses of keyframes from this index.
    Poses {
        from: usize,
        replay: bool,
    },
    Edges {
        replay: bool,
    },
    Cloud {
        index: usize,
        replay: bool,
    },
}

impl Outgoing {
    fn is_replay(self) -> bool {
        match self {
            Self::Poses { replay, .. } | Self::Edges { replay } | Self::Cloud { replay, .. } => {
                replay
            }
        }
    }
}

/// What the thread did, for the logs at its end.
#[derive(Debug, Default)]
struct Sent {
    parts: u64,
    replays: u64,
    failures: u64,
}

/// The map thread: creates the service, then keeps `map` up to date from `events` and
/// publishes until `events` closes (mapping: the back end is gone; localising: the run ended),
/// sending the last changes before it returns. If the service cannot be created, says so once
/// and drains.
pub(super) fn run_map_publisher(domain: &Domain, mut map: HeldMap, events: &Receiver<MapEvent>) {
    let mut publisher = match MapUpdatePublisher::create(domain) {
        Ok(p) => p,
        Err(e) => {
            tracing::error!(
                "the map_update service is off: {:#}",
                anyhow::Error::from(e)
            );
            for _ in events {}
            return;
        }
    };
    let per_tick = (MAP_UPDATE_REPLAY_RATE as f64 * TICK.as_secs_f64()).ceil() as usize;
    let mut queue: VecDeque<Outgoing> = VecDeque::new();
    let mut sent = Sent::default();
    let mut last_update: Option<Instant> = None;
    let mut next_tick = Instant::now();
    let mut open = true;
    loop {
        let wait = next_tick.saturating_duration_since(Instant::now());
        if open {
            match events.recv_timeout(wait) {
                Ok(event) => {
                    map.apply(event);
                    if Instant::now() < next_tick {
                        continue;
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    // The run is ending: the last changes go out, a replay would only delay
                    // the exit.
                    open = false;
                    queue.retain(|o| !o.is_replay());
                }
            }
        } else {
            std::thread::sleep(wait);
        }
        next_tick = Instant::now() + TICK;
        match publisher.new_subscribers() {
            Ok(true) if open => {
                // Everything, from the current state: it also covers the changes not yet sent.
                queue.clear();
                queue.push_back(Outgoing::Poses {
                    from: 0,
                    replay: true,
                });
                queue.push_back(Outgoing::Edges { replay: true });
                queue.extend((0..map.poses.len()).map(|index| Outgoing::Cloud {
                    index,
                    replay: true,
                }));
                map.new_from = map.poses.len();
                map.poses_moved = false;
                map.edges_changed = false;
                sent.replays += 1;
            }
            Ok(_) => {}
            Err(e) => tracing::warn!("map_update: cannot connect a subscriber: {e:?}"),
        }
        let due = last_update.is_none_or(|t| t.elapsed() >= UPDATE_PERIOD);
        if map.has_changes() && (due || !open) {
            last_update = Some(Instant::now());
            let from = if map.poses_moved { 0 } else { map.new_from };
            queue.push_back(Outgoing::Poses {
                from,
                replay: false,
            });
            if map.edges_changed {
                queue.push_back(Outgoing::Edges { replay: false });
            }
            queue.extend(
                (map.new_from..map.poses.len()).map(|index| Outgoing::Cloud {
                    index,
                    replay: false,
                }),
            );
            map.new_from = map.poses.len();
            map.poses_moved = false;
            map.edges_changed = false;
        }
        let mut budget = per_tick;
        while budget > 0 {
            let Some(next) = queue.pop_front() else { break };
            match send(&mut publisher, &map, next) {
                Ok(parts) => {
                    sent.parts += parts as u64;
                    budget = budget.saturating_sub(parts);
                }
                Err(e) => {
                    sent.failures += 1;
                    if sent.failures.is_power_of_two() {
                        tracing::warn!(failures = sent.failures, "map_update: {e:#}");
                    }
                }
            }
        }
        if !open && queue.is_empty() {
            break;
        }
    }
    tracing::debug!(
        parts = sent.parts,
        replays = sent.replays,
        failures = sent.failures,
        "map_update service closed"
    );
}

/// Sends one message; the parts it took.
fn send(
    publisher: &mut MapUpdatePublisher,
    map: &HeldMap,
    message: Outgoing,
) -> Result<usize, glint_ipc::MapUpdatePublishError> {
    let header = |replay: bool| MapUpdateHeader {
        sensor_time_ns: map.newest_ns(),
        map_id: map.map_id,
        keyframes: map.poses.len() as u32,
        flags: if replay {
            map.flags.with(MapUpdateFlags::REPLAY)
        } else {
            map.flags
        },
        ..MapUpdateHeader::default()
    };
    match message {
        Outgoing::Poses { from, replay } => {
            publisher.publish(header(replay), &map.poses[from.min(map.poses.len())..])
        }
        Outgoing::Edges { replay } => publisher.publish(header(replay), &map.edges),
        Outgoing::Cloud { index, replay } => {
            let header = MapUpdateHeader {
                keyframe: index as u32,
                sensor_time_ns: map.poses[index].sensor_time_ns,
                ..header(replay)
            };
            publisher.publish(header, &map.clouds[index])
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn changes_are_held_until_queued_and_optimisations_move_every_pose() {
        let mut map = HeldMap::mapping(7);
        for index in 0..3 {
            map.apply(MapEvent::Keyframe {
                index,
                pose: Isometry3::translation(index as f64, 0.0, 0.0),
                time_ns: 100 + index as u64,
                points: vec![MapPoint::default(); index + 1],
            });
        }
        assert!(map.has_changes());
        assert_eq!(map.newest_ns(), 102);
        // A keyframe out of order is refused, not stored under the wrong index.
        map.apply(MapEvent::Keyframe {
            index: 9,
            pose: Isometry3::identity(),
            time_ns: 0,
            points: vec![],
        });
        assert_eq!(map.poses.len(), 3);
        map.apply(MapEvent::Optimised {
            poses: (0..3)
                .map(|i| Isometry3::translation(0.0, i as f64, 0.0))
                .collect(),
            edges: vec![edge(2, 0)],
        });
        assert!(map.poses_moved && map.edges_changed);
        assert_eq!(map.edges, vec![MapEdge { from: 0, to: 2 }]);
        assert_eq!(map.poses[2].position, [0.0, 2.0, 0.0]);
        assert_eq!(map.poses[2].sensor_time_ns, 102);
    }
}

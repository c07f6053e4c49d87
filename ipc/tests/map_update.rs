//! The `map_update` service over real iceoryx2 shared memory, in process: a cloud larger than a
//! sample arrives in parts that join to the records sent; poses and edges arrive field for
//! field; the publisher notices each new subscriber once; a subscriber that never reads does
//! not stop the publisher.

use std::collections::hash_map::RandomState;
use std::hash::BuildHasher;
use std::time::Instant;

use glint_ipc::settings::MAP_UPDATE_SUBSCRIBER_BUFFER_SIZE;
use glint_ipc::{
    Domain, KeyframePose, MapContent, MapEdge, MapPoint, MapUpdateFlags, MapUpdateHeader,
    MapUpdateKind, MapUpdatePublisher, MapUpdateSubscriber,
};

fn unique_domain(tag: &str) -> Domain {
    let random = RandomState::new().hash_one((std::process::id(), tag, Instant::now()));
    Domain::new(&format!("test-{tag}-{random:016x}")).expect("valid test domain")
}

fn header() -> MapUpdateHeader {
    MapUpdateHeader {
        sensor_time_ns: 1_700_000_000_000_000_123,
        map_id: 42,
        keyframe: 5,
        keyframes: 6,
        flags: MapUpdateFlags::SAVED_MAP,
        ..MapUpdateHeader::default()
    }
}

#[test]
fn messages_arrive_whole_across_parts() {
    let domain = unique_domain("map-parts");
    let mut publisher = MapUpdatePublisher::create(&domain).unwrap();
    let subscriber = MapUpdateSubscriber::open(&domain).unwrap();
    assert!(publisher.new_subscribers().unwrap());
    assert!(!publisher.new_subscribers().unwrap(), "noticed once");

    let per_part = MapUpdatePublisher::records_per_part::<MapPoint>();
    let cloud: Vec<MapPoint> = (0..per_part * 2 + 17)
        .map(|i| MapPoint {
            position: [i as f32, -0.5 * i as f32, 0.125],
            intensity: 0.001 * i as f32,
        })
        .collect();
    assert_eq!(publisher.publish(header(), &cloud).unwrap(), 3);
    let poses: Vec<KeyframePose> = (0..4)
        .map(|i| KeyframePose {
            keyframe: i,
            reserved: 0,
            sensor_time_ns: 10 + u64::from(i),
            position: [f64::from(i), 2.0, -1.0],
            orientation: [0.0, 0.0, 0.6, 0.8],
        })
        .collect();
    assert_eq!(publisher.publish(header(), &poses).unwrap(), 1);
    let edges = [MapEdge { from: 0, to: 3 }];
    publisher.publish(header(), &edges).unwrap();
    // An empty message is one part of no records (a keyframe without points).
    assert_eq!(publisher.publish::<MapEdge>(header(), &[]).unwrap(), 1);

    let mut received = Vec::new();
    while let Some(m) = subscriber.try_next().unwrap() {
        received.push(m);
    }
    assert_eq!(received.len(), 6);
    let mut joined = Vec::new();
    for (part, m) in received[..3].iter().enumerate() {
        assert_eq!(m.header.kind, MapUpdateKind::Cloud as u32);
        assert_eq!((m.header.part, m.header.parts), (part as u16, 3));
        assert_eq!(m.header.sequence, part as u64);
        assert_eq!(
            (m.header.map_id, m.header.keyframe, m.header.keyframes),
            (42, 5, 6)
        );
        let MapContent::Cloud(points) = &m.content else {
            panic!("{:?}", m.content)
        };
        assert_eq!(points.len(), m.header.count as usize);
        joined.extend_from_slice(points);
    }
    assert_eq!(joined, cloud);
    assert_eq!(received[3].content, MapContent::KeyframePoses(poses));
    assert_eq!(received[4].content, MapContent::Edges(edges.to_vec()));
    assert_eq!(received[5].content, MapContent::Edges(vec![]));
    assert!(received[5].header.flags.contains(MapUpdateFlags::SAVED_MAP));
}

#[test]
fn later_subscribers_are_noticed_and_a_stalled_one_costs_only_its_own_messages() {
    let domain = unique_domain("map-stalled");
    let mut publisher = MapUpdatePublisher::create(&domain).unwrap();
    assert!(!publisher.new_subscribers().unwrap());
    let stalled = MapUpdateSubscriber::open(&domain).unwrap();
    assert!(publisher.new_subscribers().unwrap());
    let edges = [MapEdge { from: 1, to: 9 }];
    for _ in 0..MAP_UPDATE_SUBSCRIBER_BUFFER_SIZE * 3 {
        publisher.publish(header(), &edges).unwrap();
    }
    let reader = MapUpdateSubscriber::open(&domain).unwrap();
    assert!(publisher.new_subscribers().unwrap());
    assert_eq!(publisher.subscribers(), 2);
    publisher.publish(header(), &edges).unwrap();
    let got = reader
        .try_next()
        .unwrap()
        .expect("the new subscriber reads");
    assert_eq!(got.content, MapContent::Edges(edges.to_vec()));
    // The stalled one kept its newest messages, up to its buffer.
    let mut kept = 0;
    while stalled.try_next().unwrap().is_some() {
        kept += 1;
    }
    assert_eq!(kept, MAP_UPDATE_SUBSCRIBER_BUFFER_SIZE);
    drop(reader);
    assert!(!publisher.new_subscribers().unwrap(), "a subscriber left");
}

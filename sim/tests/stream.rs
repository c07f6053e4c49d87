//! Live UDP: the same packets as the capture, to the data and position ports of a host, at
//! real-time pace. Only loopback is used.

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use glint_sim::{run, PacketKind, RunOptions, Scenario, SimConfig, Simulation, UdpTarget};

#[test]
fn packets_arrive_on_their_ports_byte_for_byte_at_real_time_pace() {
    let data = UdpSocket::bind("127.0.0.1:0").unwrap();
    let position = UdpSocket::bind("127.0.0.1:0").unwrap();
    for s in [&data, &position] {
        s.set_read_timeout(Some(Duration::from_millis(500)))
            .unwrap();
    }
    let target = UdpTarget {
        host: "127.0.0.1".into(),
        data_port: data.local_addr().unwrap().port(),
        position_port: position.local_addr().unwrap().port(),
        // Another address on loopback, as a second simulated sensor would use.
        bind: Some([127, 0, 0, 2].into()),
    };
    let config = SimConfig {
        scenario: Scenario::Warehouse,
        seconds: 0.4,
        ..SimConfig::default()
    };
    let expected: Vec<_> = Simulation::new(&config).unwrap().into_packets().collect();
    let receive = |socket: UdpSocket| {
        std::thread::spawn(move || {
            let mut got = Vec::new();
            let mut buf = [0u8; 2048];
            while let Ok((n, from)) = socket.recv_from(&mut buf) {
                assert_eq!(from.ip(), std::net::Ipv4Addr::new(127, 0, 0, 2));
                got.push(buf[..n].to_vec());
            }
            got
        })
    };
    let (rd, rp) = (receive(data), receive(position));
    let start = Instant::now();
    let summary = run(
        &config,
        &RunOptions {
            udp: Some(&target),
            ..RunOptions::default()
        },
    )
    .unwrap();
    let elapsed = start.elapsed().as_secs_f64();
    let (got_data, got_position) = (rd.join().unwrap(), rp.join().unwrap());
    let want = |kind| {
        expected
            .iter()
            .filter(|p| p.kind == kind)
            .map(|p| p.payload.clone())
            .collect::<Vec<_>>()
    };
    assert_eq!(got_data, want(PacketKind::Data));
    assert_eq!(got_position, want(PacketKind::Position));
    assert_eq!(summary.data_packets as usize, got_data.len());
    // Paced: the packets span 0.4 s of sensor time, so sending them takes about that long.
    assert!(elapsed > 0.37, "sent in {elapsed} s");
}

//! The fleet link end to end, on loopback only: `glintd bridge` forwarding a live replay's poses
//! over Zenoh to subscribers in this process and in Python, through a router that is stopped
//! and restarted, across a bridge restart; maps served and fetched, damaged transfers refused;
//! TLS and mutual TLS with certificates made here. No assertion is on time: the waits only
//! bound how long a broken build may hang.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use glint_ipc::{Domain, Pose, PoseStream, PoseSubscriber};
use zenoh::handlers::FifoChannel;
use zenoh::Wait;

/// The replays here run at real-time pace: one test at a time, so they keep their pace.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn real_time() -> std::sync::MutexGuard<'static, ()> {
    REAL_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn glintd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glintd"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("glint-fleet-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A TCP port free right now on loopback.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A simulated capture of `seconds` in `dir`.
fn capture(dir: &Path, seconds: u32, seed: u32) -> PathBuf {
    let sim = glintd()
        .args(["sim", "warehouse", "--seconds", &seconds.to_string()])
        .args(["--seed", &seed.to_string(), "--out"])
        .arg(dir)
        .output()
        .unwrap();
    assert!(sim.status.success(), "{sim:?}");
    dir.join("scan.pcap")
}

/// A running `glintd bridge` whose log lines arrive on a channel.
struct Bridge {
    child: Child,
    log: mpsc::Receiver<String>,
}

impl Bridge {
    /// Starts a bridge with `args` and waits for its `ready` line.
    fn start(args: &[&str]) -> Self {
        let mut child = glintd()
            .arg("bridge")
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (tx, log) = mpsc::channel();
        let stderr = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let mut bridge = Self { child, log };
        bridge.wait_for("ready");
        bridge
    }

    fn wait_for(&mut self, text: &str) -> String {
        let until = Instant::now() + Duration::from_secs(60);
        let mut seen = Vec::new();
        while Instant::now() < until {
            if let Ok(line) = self.log.recv_timeout(Duration::from_millis(100)) {
                if line.contains(text) {
                    return line;
                }
                seen.push(line);
            }
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!("the bridge exited ({status}): {}", seen.join("\n"));
            }
        }
        panic!("no {text:?} from the bridge: {}", seen.join("\n"));
    }

    /// Stops it with SIGTERM and returns what it printed (its per-stream counts).
    fn stop(mut self) -> String {
        Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .unwrap();
        let mut out = String::new();
        std::io::Read::read_to_string(self.child.stdout.as_mut().unwrap(), &mut out).unwrap();
        assert!(self.child.wait().unwrap().success(), "{out}");
        out
    }

    fn rss_kib(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap();
        status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.split_whitespace().next())
            .unwrap()
            .parse()
            .unwrap()
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A count from the bridge's summary line of `stream`.
fn summary_count(summary: &str, stream: &str, field: &str) -> u64 {
    let line = summary
        .lines()
        .find(|l| l.starts_with(&format!("bridge {stream}:")))
        .unwrap_or_else(|| panic!("no {stream} line in {summary}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    let at = words.iter().position(|w| *w == field).unwrap();
    words[at + 1].parse().unwrap()
}

/// A Zenoh session for a fleet-side consumer in this test.
fn session(mode: &str, connect: &[String], listen: &[String]) -> zenoh::Session {
    let mut config = zenoh::Config::default();
    let json = |v: serde_json::Value| v.to_string();
    config
        .insert_json5("mode", &json(serde_json::json!(mode)))
        .unwrap();
    config
        .insert_json5("connect/endpoints", &json(serde_json::json!(connect)))
        .unwrap();
    config
        .insert_json5("listen/endpoints", &json(serde_json::json!(listen)))
        .unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zenoh::open(config).wait().unwrap()
}

/// Every pose a shared-memory subscriber receives on the odom stream of `domain` until
/// `done` is sent, by sequence.
fn shared_memory_poses(
    domain: &str,
    done: mpsc::Receiver<()>,
) -> std::thread::JoinHandle<BTreeMap<u64, Vec<u8>>> {
    let domain = Domain::new(domain).unwrap();
    std::thread::spawn(move || {
        let until = Instant::now() + Duration::from_secs(60);
        let subscriber = loop {
            match PoseSubscriber::open(&domain, PoseStream::Odom) {
                Ok(s) => break s,
                Err(e) if Instant::now() > until => panic!("{e}"),
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        };
        let mut poses = BTreeMap::new();
        while done.try_recv().is_err() {
            if let Some(p) = subscriber.wait_next(Duration::from_millis(50)).unwrap() {
                poses.insert(p.sequence, p.to_le_bytes().to_vec());
            }
        }
        poses
    })
}

#[test]
fn a_replay_reaches_rust_and_python_fleet_subscribers_byte_for_byte() {
    let _pace = real_time();
    let dir = scratch("peer");
    let pcap = capture(&dir, 10, 31);
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let domain = format!("fleet-peer-{}", std::process::id());
    let bridge = Bridge::start(&[
        "--domain",
        &domain,
        "--site",
        "test",
        "--robot",
        "agv1",
        "--listen",
        &endpoint,
        "--insecure",
    ]);
    let fleet = session("peer", std::slice::from_ref(&endpoint), &[]);
    let odom = fleet
        .declare_subscriber("glint/test/agv1/odom")
        .with(FifoChannel::new(10_000))
        .wait()
        .unwrap();
    let python = glint_testkit::python_imports("zenoh").then(|| {
        let script =
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/python/fleet_monitor.py");
        let mut child = Command::new("python3")
            .arg(script)
            .args(["--site", "test", "--connect", &endpoint, "--insecure"])
            .args(["--idle", "3", "--dump"])
            .arg(dir.join("python.txt"))
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let mut first = String::new();
        BufReader::new(child.stdout.as_mut().unwrap())
            .read_line(&mut first)
            .unwrap();
        assert!(first.starts_with("subscribed"), "{first}");
        child
    });
    if python.is_none() {
        assert!(
            std::env::var("CI").map_or(true, |v| v != "true"),
            "python3 cannot import zenoh: .ci/run installs eclipse-zenoh"
        );
        eprintln!(
            "python part skipped: python3 cannot import zenoh (pip install eclipse-zenoh==1.10.2)"
        );
    }
    // The fleet side is subscribed before the first pose exists, so nothing is dropped unheard.
    let (stop_shm, done) = mpsc::channel();
    let shm = shared_memory_poses(&domain, done);
    let replay = glintd()
        .arg("replay")
        .arg(&pcap)
        .args(["--domain", &domain, "--pace", "realtime"])
        .output()
        .unwrap();
    assert!(replay.status.success(), "{replay:?}");
    // Let the last poses cross before closing the subscribers.
    let mut over_zenoh = BTreeMap::new();
    while let Ok(Some(sample)) = odom.recv_timeout(Duration::from_secs(2)) {
        let attachment = sample.attachment().unwrap().try_to_string().unwrap();
        assert_eq!(attachment, "type=glint::PoseV1;version=1");
        let bytes = sample.payload().to_bytes().into_owned();
        let pose = Pose::from_le_bytes(&bytes).unwrap();
        over_zenoh.insert(pose.sequence, bytes);
    }
    stop_shm.send(()).unwrap();
    let in_shared_memory = shm.join().unwrap();
    assert!(in_shared_memory.len() >= 80, "{}", in_shared_memory.len());
    assert_eq!(over_zenoh, in_shared_memory);
    if let Some(child) = python {
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success(), "{out:?}");
        let dump = std::fs::read_to_string(dir.join("python.txt")).unwrap();
        let from_python: BTreeMap<u64, Vec<u8>> = dump
            .lines()
            .filter(|l| l.starts_with("glint/test/agv1/odom "))
            .map(|l| {
                let w: Vec<&str> = l.split_whitespace().collect();
                let bytes = (0..w[2].len())
                    .step_by(2)
                    .map(|i| u8::from_str_radix(&w[2][i..i + 2], 16).unwrap())
                    .collect();
                (w[1].parse().unwrap(), bytes)
            })
            .collect();
        assert_eq!(from_python, in_shared_memory);
        assert!(dump
            .lines()
            .any(|l| l.starts_with("glint/test/agv1/status ")));
    }
    let summary = bridge.stop();
    assert_eq!(summary_count(&summary, "odom", "dropped_unheard"), 0);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A Zenoh router in this process, listening on `endpoint`.
fn router(endpoint: &str) -> zenoh::Session {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"router\"").unwrap();
    config
        .insert_json5(
            "listen/endpoints",
            &serde_json::json!([endpoint]).to_string(),
        )
        .unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    // A restarted router must get its port back at once.
    let until = Instant::now() + Duration::from_secs(30);
    loop {
        match zenoh::open(config.clone()).wait() {
            Ok(s) => return s,
            Err(e) if Instant::now() > until => panic!("{e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}

/// The next pose from `subscriber` with a sequence above `after`.
fn next_pose_after(
    subscriber: &zenoh::pubsub::Subscriber<
        zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>,
    >,
    after: u64,
) -> u64 {
    let until = Instant::now() + Duration::from_secs(60);
    while Instant::now() < until {
        if let Ok(Some(sample)) = subscriber.recv_timeout(Duration::from_millis(200)) {
            let pose = Pose::from_le_bytes(&sample.payload().to_bytes()).unwrap();
            if pose.sequence > after {
                return pose.sequence;
            }
        }
    }
    panic!("no pose after #{after} within a minute");
}

#[test]
fn the_link_survives_a_router_outage_and_a_bridge_restart_without_holding_the_daemon() {
    let _pace = real_time();
    let dir = scratch("router");
    let pcap = capture(&dir, 30, 32);
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let domain = format!("fleet-router-{}", std::process::id());
    let mut hub = Some(router(&endpoint));
    let bridge_args = [
        "--domain",
        &domain,
        "--site",
        "test",
        "--robot",
        "agv2",
        "--connect",
        &endpoint,
        "--insecure",
    ];
    let bridge = Bridge::start(&bridge_args);
    let fleet = session("client", std::slice::from_ref(&endpoint), &[]);
    let odom = fleet
        .declare_subscriber("glint/test/agv2/odom")
        .with(FifoChannel::new(10_000))
        .wait()
        .unwrap();
    let (stop_shm, done) = mpsc::channel();
    let shm = shared_memory_poses(&domain, done);
    let replay = glintd()
        .arg("replay")
        .arg(&pcap)
        .args(["--domain", &domain, "--pace", "realtime"])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let first = next_pose_after(&odom, 0);
    let rss_before = bridge.rss_kib();
    // The router goes away for 3 s of poses; the bridge keeps only the latest meanwhile.
    hub.take().unwrap().close().wait().unwrap();
    let cut_at = next_pose_while_cut(&domain);
    std::thread::sleep(Duration::from_secs(3));
    hub = Some(router(&endpoint));
    let resumed = next_pose_after(&odom, cut_at + 10);
    let rss_after = bridge.rss_kib();
    let summary = bridge.stop();
    assert!(
        summary_count(&summary, "odom", "dropped_unheard") > 0,
        "{summary}"
    );
    assert!(
        rss_after < rss_before + 8 * 1024,
        "the bridge grew from {rss_before} to {rss_after} KiB during the outage"
    );
    // A new bridge picks up where the daemon is.
    let bridge = Bridge::start(&bridge_args);
    let after_restart = next_pose_after(&odom, resumed);
    let out = replay.wait_with_output().unwrap();
    assert!(out.status.success(), "{out:?}");
    stop_shm.send(()).unwrap();
    // The daemon never waited for the link: its own consumer saw every pose, in order.
    let in_shared_memory = shm.join().unwrap();
    let sequences: Vec<u64> = in_shared_memory.keys().copied().collect();
    assert!(
        sequences.windows(2).all(|w| w[1] == w[0] + 1),
        "{sequences:?}"
    );
    assert!(
        first <= cut_at && cut_at < resumed && resumed < after_restart,
        "{first} {cut_at} {resumed} {after_restart}"
    );
    drop(bridge);
    drop(hub);
    std::fs::remove_dir_all(dir).unwrap();
}

/// The sequence of a pose the daemon publishes now (read from shared memory).
fn next_pose_while_cut(domain: &str) -> u64 {
    let subscriber = PoseSubscriber::open(&Domain::new(domain).unwrap(), PoseStream::Odom).unwrap();
    loop {
        if let Some(p) = subscriber.wait_next(Duration::from_secs(10)).unwrap() {
            return p.sequence;
        }
    }
}

/// A small site map made by a mapping replay.
fn site_map(dir: &Path) -> PathBuf {
    let pcap = capture(dir, 6, 33);
    let map = dir.join("hall.glintmap");
    let replay = glintd()
        .arg("replay")
        .arg(&pcap)
        .args(["--no-publish", "--save-map"])
        .arg(&map)
        .output()
        .unwrap();
    assert!(replay.status.success(), "{replay:?}");
    map
}

fn fetch(name: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    glintd()
        .args([
            "map",
            "fetch",
            name,
            "--site",
            "test",
            "--timeout",
            "5",
            "--out",
        ])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn maps_are_fetched_verified_and_damaged_transfers_refused() {
    let dir = scratch("maps");
    let map = site_map(&dir);
    let served = dir.join("served");
    std::fs::create_dir_all(&served).unwrap();
    let good = std::fs::read(&map).unwrap();
    let mut corrupted = good.clone();
    corrupted[good.len() / 3] ^= 0x01;
    std::fs::write(served.join("hall.glintmap"), &good).unwrap();
    std::fs::write(served.join("corrupt.glintmap"), &corrupted).unwrap();
    std::fs::write(served.join("cut.glintmap"), &good[..good.len() * 2 / 3]).unwrap();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut args = vec![
        "--site".to_string(),
        "test".into(),
        "--robot".into(),
        "mapper".into(),
        "--listen".into(),
        endpoint.clone(),
        "--insecure".into(),
    ];
    for name in ["hall", "corrupt", "cut"] {
        args.push("--serve-map".into());
        args.push(
            served
                .join(format!("{name}.glintmap"))
                .to_string_lossy()
                .into(),
        );
    }
    // The bridge refuses to serve a damaged map of its own…
    let refused = glintd().arg("bridge").args(&args).output().unwrap();
    assert!(!refused.status.success());
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(text.contains("corrupt.glintmap"), "{text}");
    // …so the damaged files are swapped in after it started, as a disk or a copy may damage them.
    std::fs::write(served.join("corrupt.glintmap"), &good).unwrap();
    std::fs::write(served.join("cut.glintmap"), &good).unwrap();
    let arg_refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let bridge = Bridge::start(&arg_refs);
    std::fs::write(served.join("corrupt.glintmap"), &corrupted).unwrap();
    std::fs::write(served.join("cut.glintmap"), &good[..good.len() * 2 / 3]).unwrap();

    let local = dir.join("local.glintmap");
    let old = b"the map this robot had".to_vec();
    let connect = ["--connect", endpoint.as_str(), "--insecure"];
    for name in ["corrupt", "cut"] {
        std::fs::write(&local, &old).unwrap();
        let out = fetch(name, &local, &connect);
        assert!(!out.status.success(), "{out:?}");
        let error = String::from_utf8_lossy(&out.stderr);
        assert!(error.contains("refused"), "{error}");
        assert_eq!(std::fs::read(&local).unwrap(), old, "{name}");
    }
    let missing = fetch("absent", &local, &connect);
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("no peer serves"));
    let out = fetch("hall", &local, &connect);
    assert!(out.status.success(), "{out:?}");
    assert_eq!(std::fs::read(&local).unwrap(), good);
    drop(bridge);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A CA and certificates signed by it, written as PEM files in `dir`.
struct Pki {
    ca: PathBuf,
}

impl Pki {
    fn new(dir: &Path, name: &str, leaves: &[(&str, &str)]) -> Self {
        use rcgen::{
            BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, KeyPair,
            SanType,
        };
        let ca_key = KeyPair::generate().unwrap();
        let mut ca_params = CertificateParams::new(Vec::<String>::new()).unwrap();
        ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        ca_params
            .distinguished_name
            .push(DnType::CommonName, format!("{name} CA"));
        let ca_cert = ca_params.self_signed(&ca_key).unwrap();
        let ca = dir.join(format!("{name}-ca.pem"));
        std::fs::write(&ca, ca_cert.pem()).unwrap();
        for (leaf, common_name) in leaves {
            let key = KeyPair::generate().unwrap();
            let mut params = CertificateParams::new(vec!["localhost".to_string()]).unwrap();
            params
                .subject_alt_names
                .push(SanType::IpAddress([127, 0, 0, 1].into()));
            params
                .distinguished_name
                .push(DnType::CommonName, common_name.to_string());
            params.extended_key_usages = vec![
                ExtendedKeyUsagePurpose::ServerAuth,
                ExtendedKeyUsagePurpose::ClientAuth,
            ];
            let cert = params.signed_by(&key, &ca_cert, &ca_key).unwrap();
            std::fs::write(dir.join(format!("{leaf}.pem")), cert.pem()).unwrap();
            std::fs::write(dir.join(format!("{leaf}.key")), key.serialize_pem()).unwrap();
        }
        Self { ca }
    }
}

/// Zenoh access control letting only peers whose certificate's CN is `fleet-server` ask for
/// and receive maps.
const MAPS_FOR_THE_FLEET_SERVER: &str = r#"
[link.access_control]
enabled = true
default_permission = "deny"
rules = [{ id = "maps", messages = ["query", "reply", "declare_queryable"], flows = ["egress", "ingress"], permission = "allow", key_exprs = ["glint/test/maps/**"] }]
subjects = [{ id = "server", cert_common_names = ["fleet-server"], link_protocols = ["tls"] }]
policies = [{ rules = ["maps"], subjects = ["server"] }]
"#;

/// A bridge or fetch configuration file with a `[link.tls]` table.
fn tls_config(dir: &Path, file: &str, ca: &Path, leaf: Option<&str>, mutual: bool) -> PathBuf {
    let mut text = format!(
        "site = \"test\"\n[link.tls]\nroot_ca = {:?}\nmutual = {mutual}\n",
        ca.to_string_lossy()
    );
    if let Some(leaf) = leaf {
        text.push_str(&format!(
            "certificate = {:?}\nprivate_key = {:?}\n",
            dir.join(format!("{leaf}.pem")).to_string_lossy(),
            dir.join(format!("{leaf}.key")).to_string_lossy()
        ));
    }
    let path = dir.join(file);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn tls_and_mutual_tls_admit_only_the_right_certificates() {
    let dir = scratch("tls");
    let map = site_map(&dir);
    let fleet = Pki::new(
        &dir,
        "fleet",
        &[("robot", "agv3"), ("server", "fleet-server")],
    );
    let other = Pki::new(&dir, "other", &[("intruder", "fleet-server")]);
    let fetched = dir.join("fetched.glintmap");
    let fetch_with = |config: &Path, endpoint: &str| {
        let _ = std::fs::remove_file(&fetched);
        let out = fetch(
            "hall",
            &fetched,
            &["--config", config.to_str().unwrap(), "--connect", endpoint],
        );
        out.status.success() && std::fs::read(&fetched).unwrap() == std::fs::read(&map).unwrap()
    };

    // Without TLS settings the bridge refuses to start unless told --insecure.
    let plain = glintd()
        .args(["bridge", "--robot", "agv3", "--listen", "tcp/127.0.0.1:1"])
        .output()
        .unwrap();
    assert!(!plain.status.success());
    assert!(String::from_utf8_lossy(&plain.stderr).contains("--insecure"));

    // TLS: the server proves itself with a certificate from the fleet's CA.
    // A bridge serving the map over TLS with `config`, and the endpoint clients connect to.
    let tls_bridge = |config: &Path| {
        let port = free_port();
        let bridge = Bridge::start(&[
            "--config",
            config.to_str().unwrap(),
            "--robot",
            "agv3",
            "--listen",
            &format!("tls/127.0.0.1:{port}"),
            "--serve-map",
            map.to_str().unwrap(),
        ]);
        (bridge, port)
    };
    let server = tls_config(&dir, "bridge.toml", &fleet.ca, Some("robot"), false);
    let (bridge, port) = tls_bridge(&server);
    let endpoint = format!("tls/localhost:{port}");
    let trusting = tls_config(&dir, "client.toml", &fleet.ca, None, false);
    let distrusting = tls_config(&dir, "other.toml", &other.ca, None, false);
    assert!(fetch_with(&trusting, &endpoint));
    assert!(!fetch_with(&distrusting, &endpoint));
    // Plain TCP to a TLS-only bridge gets nothing.
    let _ = std::fs::remove_file(&fetched);
    let plain_fetch = fetch(
        "hall",
        &fetched,
        &["--connect", &format!("tcp/127.0.0.1:{port}"), "--insecure"],
    );
    assert!(!plain_fetch.status.success());
    drop(bridge);

    // Mutual TLS: clients must present a certificate from the fleet's CA.
    let server = tls_config(&dir, "bridge-mtls.toml", &fleet.ca, Some("robot"), true);
    let (bridge, port) = tls_bridge(&server);
    let endpoint = format!("tls/localhost:{port}");
    let member = tls_config(&dir, "member.toml", &fleet.ca, Some("server"), true);
    let anonymous = tls_config(&dir, "anonymous.toml", &fleet.ca, None, false);
    let intruder = tls_config(&dir, "intruder.toml", &fleet.ca, Some("intruder"), true);
    assert!(fetch_with(&member, &endpoint));
    assert!(!fetch_with(&anonymous, &endpoint));
    assert!(!fetch_with(&intruder, &endpoint));
    drop(bridge);

    // Access control on top: of two clients with the fleet's certificates, only the one named
    // fleet-server gets the map.
    let guarded = tls_config(&dir, "bridge-acl.toml", &fleet.ca, Some("robot"), true);
    let text = std::fs::read_to_string(&guarded).unwrap();
    std::fs::write(&guarded, text + MAPS_FOR_THE_FLEET_SERVER).unwrap();
    let (bridge, port) = tls_bridge(&guarded);
    let endpoint = format!("tls/localhost:{port}");
    let other_robot = tls_config(&dir, "robot.toml", &fleet.ca, Some("robot"), true);
    assert!(fetch_with(&member, &endpoint));
    assert!(!fetch_with(&other_robot, &endpoint));
    drop(bridge);
    std::fs::remove_dir_all(dir).unwrap();
}

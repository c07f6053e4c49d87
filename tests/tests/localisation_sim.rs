//! End to end in a saved site map: one simulated run maps the warehouse (the tracker, the back
//! end and the site map the daemon saves, in its levelled map frame), later runs of the same
//! scene localise in it (the tracker in localisation mode and the localiser, each keyframe
//! answered at once as a replay does) and are scored against the simulator's ground truth with
//! no alignment: the map frame is anchored to the scene through the mapping run's first pose,
//! as `glintd eval --no-align --anchor` does. A pose published as tracked more than 0.5 m or 5°
//! off is a wrong pose; there must be none, whatever the run. Seeds are chosen here, not tuned
//! on.

use glint_core::backend::config::BackEndConfig;
use glint_core::backend::{BackEnd, SiteMapHeader};
use glint_core::config::OdometryConfig;
use glint_core::extension::MapExtension;
use glint_core::features::SweepFeatures;
use glint_core::front_end::FrontEnd;
use glint_core::localiser::{localisation_keyframes, Localiser, LocaliserConfig, MapState};
use glint_core::metrics::{anchor_map_frame, fixed_frame_errors, FixedFrameReport, Jump};
use glint_core::site_map::SiteMap;
use glint_core::tracker::Tracker;
use glint_core::trajectory::StampedPose;
use glint_sim::{Scenario, SimConfig, Simulation};
use glint_tests::{dense_groundtruth, for_each_scan, sensor_pose};
use nalgebra::Isometry3;

/// A mapped site: the map, and the scene ← map transform from the mapping run's first pose.
struct Site {
    map: SiteMap,
    scene_from_map: Isometry3<f64>,
}

/// Maps `sim_config`'s run as `glintd replay --save-map` does (the mounting is the identity).
fn map_site(sim_config: &SimConfig) -> Site {
    let config = OdometryConfig::default();
    let backend_config = BackEndConfig::default();
    let mut sim = Simulation::new(sim_config).expect("the scenario builds");
    let mut front_end = FrontEnd::new(&config);
    let mut tracker = Tracker::new(&config, Some(&backend_config.keyframes));
    let mut backend = BackEnd::new(&backend_config);
    let mut features = SweepFeatures::default();
    let mut odometry = Vec::new();
    for_each_scan(&mut sim, |scan| {
        front_end.process(scan, &mut features);
        let tracked = tracker.track(&features, None, |_| {});
        odometry.push(StampedPose {
            time_ns: tracked.estimate.time_ns,
            pose: tracked.estimate.pose,
        });
        if let Some(keyframe) = tracked.keyframe {
            backend.add_keyframe(keyframe, |_| {});
        }
    });
    backend.finish();
    let site_from_world = backend.site_from_world(&Isometry3::identity());
    let map = backend.site_map(
        &site_from_world,
        &config.intensity_map,
        SiteMapHeader {
            created_ns: 0,
            sensor_model: "VLP-16".into(),
            base_from_sensor: Isometry3::identity(),
        },
    );
    // The mapping run's trajectory in the map frame, as `--trajectory` writes it.
    let trajectory: Vec<StampedPose> = backend
        .trajectory(&odometry)
        .into_iter()
        .map(|p| StampedPose {
            time_ns: p.time_ns,
            pose: site_from_world * p.pose,
        })
        .collect();
    let groundtruth = dense_groundtruth(&sim, &trajectory);
    let scene_from_map = anchor_map_frame(&trajectory, &groundtruth, &[]).expect("an anchor");
    Site {
        map,
        scene_from_map,
    }
}

/// What a localisation run published.
#[derive(Debug)]
struct Localised {
    sweeps: usize,
    /// The verified poses (sensor → map), as `--trajectory` holds them.
    verified: Vec<StampedPose>,
    /// Each (re)localisation: sensor time of the first verified pose and the time spent
    /// searching since the run started or tracking was lost, s.
    relocalisations: Vec<(u64, f64)>,
    /// The teleports the simulator made.
    kidnaps: Vec<Jump>,
    report: FixedFrameReport,
}

fn localise(site: &Site, sim_config: &SimConfig) -> Localised {
    localise_extending(site, sim_config, None)
}

/// [`localise`], also feeding each keyframe and its outcome to `extension` as the daemon's
/// localiser thread does with `replay --localise MAP --save-map NEW`.
fn localise_extending(
    site: &Site,
    sim_config: &SimConfig,
    mut extension: Option<&mut MapExtension>,
) -> Localised {
    let config = OdometryConfig::default();
    let backend_config = BackEndConfig::default();
    let mut localiser = Localiser::new(
        site.map.clone(),
        &LocaliserConfig::default(),
        &backend_config.scan_context,
    );
    let mut sim = Simulation::new(sim_config).expect("the scenario builds");
    let mut front_end = FrontEnd::new(&config);
    let mut tracker =
        Tracker::localising(&config, &localisation_keyframes(&backend_config.keyframes));
    let mut features = SweepFeatures::default();
    let mut verified = Vec::new();
    let mut all = Vec::new();
    let mut relocalisations = Vec::new();
    let mut searching_since: Option<u64> = None;
    for_each_scan(&mut sim, |scan| {
        front_end.process(scan, &mut features);
        let tracked = tracker.track(&features, None, |_| {});
        let t = tracked.estimate.time_ns;
        if let Some(keyframe) = &tracked.keyframe {
            let (correction, outcome) = localiser.answer(tracker.epoch(), keyframe);
            tracker.apply(&correction);
            if let Some(e) = extension.as_deref_mut() {
                e.add(correction.epoch, keyframe, &outcome);
            }
        }
        all.push(StampedPose {
            time_ns: t,
            pose: tracked.estimate.pose,
        });
        let fix = tracker.map_fix(&tracked.estimate);
        if fix.verified {
            verified.push(StampedPose {
                time_ns: t,
                pose: tracker.correction() * tracked.estimate.pose,
            });
            if fix.relocalised {
                let since = searching_since.take().unwrap_or(t);
                relocalisations.push((t, (t - since) as f64 * 1e-9));
            }
        } else {
            searching_since.get_or_insert(t);
        }
        assert!(
            !(fix.verified && fix.state == MapState::Lost),
            "a lost pose is never verified"
        );
    });
    let kidnaps: Vec<Jump> = sim
        .kidnaps()
        .iter()
        .map(|k| Jump {
            before_ns: k.before_ns,
            after_ns: k.after_ns,
        })
        .collect();
    // Dense ground truth as the simulator writes it: nothing inside a jump, both its ends.
    let mut groundtruth: Vec<StampedPose> = dense_groundtruth(&sim, &all)
        .into_iter()
        .filter(|g| {
            !kidnaps
                .iter()
                .any(|j| j.before_ns < g.time_ns && g.time_ns < j.after_ns)
        })
        .chain(kidnaps.iter().flat_map(|j| {
            [j.before_ns, j.after_ns].map(|t| StampedPose {
                time_ns: t,
                pose: sensor_pose(&sim, t),
            })
        }))
        .collect();
    groundtruth.sort_by_key(|g| g.time_ns);
    let report = fixed_frame_errors(&verified, &groundtruth, &site.scene_from_map, &kidnaps)
        .unwrap_or(FixedFrameReport {
            poses: 0,
            in_jumps: 0,
            position_rmse: 0.0,
            yaw_rmse_deg: 0.0,
            horizontal_rmse: 0.0,
            vertical_rmse: 0.0,
            max_position: 0.0,
            wrong_poses: 0,
        });
    Localised {
        sweeps: all.len(),
        verified,
        relocalisations,
        kidnaps,
        report,
    }
}

fn warehouse(seconds: f64) -> SimConfig {
    SimConfig {
        scenario: Scenario::Warehouse,
        seed: 21,
        path_seed: Some(2),
        seconds,
        ..SimConfig::default()
    }
}

#[test]
fn runs_of_the_mapped_warehouse_localise_in_its_map() {
    // The mapping run: two laps around two double rows of racks.
    let site = map_site(&warehouse(150.0));
    assert!(
        site.map.keyframes.len() > 100,
        "{}",
        site.map.keyframes.len()
    );
    let runs = [
        (
            "reversed, a third of the way round",
            SimConfig {
                reverse: true,
                start_fraction: 0.3,
                ..warehouse(20.0)
            },
        ),
        (
            "another sensor unit",
            SimConfig {
                start_fraction: 0.7,
                unit_seed: Some(5),
                ..warehouse(20.0)
            },
        ),
        (
            "a third of the goods moved",
            SimConfig {
                start_fraction: 0.5,
                change: 0.33,
                change_seed: 2,
                ..warehouse(20.0)
            },
        ),
        (
            "more people and forklifts",
            SimConfig {
                start_fraction: 0.15,
                movers: Some(6),
                ..warehouse(20.0)
            },
        ),
        (
            "a shorter route inside the mapped one",
            SimConfig {
                path_seed: Some(4),
                ..warehouse(20.0)
            },
        ),
        (
            "kidnapped after 10 s",
            SimConfig {
                start_fraction: 0.1,
                kidnap_s: Some(10.0),
                ..warehouse(25.0)
            },
        ),
        // Carried into the look-alike aisle on the other side, turned round: the odometry
        // matches the new place as usual one sweep after the jump.
        (
            "kidnapped into a look-alike aisle",
            SimConfig {
                start_fraction: 0.217,
                kidnap_s: Some(15.6),
                ..warehouse(25.0)
            },
        ),
    ];
    for (name, config) in runs {
        let run = localise(&site, &config);
        let r = &run.report;
        eprintln!(
            "{name}: {} of {} sweeps verified, relocalisations {:?}, position RMSE {:.3} m, heading RMSE {:.3}°, max {:.3} m, {} wrong",
            run.verified.len(),
            run.sweeps,
            run.relocalisations,
            r.position_rmse,
            r.yaw_rmse_deg,
            r.max_position,
            r.wrong_poses
        );
        assert_eq!(r.wrong_poses, 0, "{name}: wrong poses published as tracked");
        let first = run.relocalisations.first().map(|&(_, s)| s);
        assert!(first.is_some_and(|s| s <= 2.0), "{name}: {first:?}");
        assert!(
            run.verified.len() * 10 >= run.sweeps * 8,
            "{name}: {} of {}",
            run.verified.len(),
            run.sweeps
        );
        // No alignment: the error is the map's own relative to its first pose plus the
        // localisation's (measured 0.04–0.07 m and 0.18–0.25° on this scene).
        assert!(
            r.position_rmse <= 0.1 && r.yaw_rmse_deg <= 0.4,
            "{name}: {r:?}"
        );
        for jump in &run.kidnaps {
            // Recovered within 5 s of the jump, and nothing tracked in between was wrong.
            let back = run
                .relocalisations
                .iter()
                .find(|&&(t, _)| t > jump.after_ns)
                .map(|&(t, _)| (t - jump.after_ns) as f64 * 1e-9);
            assert!(back.is_some_and(|s| s <= 5.0), "{name}: {back:?}");
        }
    }
}

#[test]
fn a_corridor_s_look_alike_places_never_give_a_wrong_pose() {
    let corridor = |seconds, path_seed, start_fraction| SimConfig {
        scenario: Scenario::Corridor,
        seed: 4,
        path_seed,
        start_fraction,
        seconds,
        ..SimConfig::default()
    };
    let site = map_site(&corridor(60.0, None, 0.0));
    for (path_seed, start) in [(None, 0.4), (Some(3), 0.0)] {
        let run = localise(&site, &corridor(20.0, path_seed, start));
        eprintln!(
            "corridor {path_seed:?} from {start}: {} of {} sweeps verified, {:?}",
            run.verified.len(),
            run.sweeps,
            run.report
        );
        assert_eq!(run.report.wrong_poses, 0, "{:?}", run.report);
    }
}

#[test]
fn a_map_extended_by_a_run_beyond_it_localises_there() {
    // The site mapped over the first 42 % of the route only; a run from a quarter of the way
    // round drives on past its end and back into it (0.25 → 1.09 of the lap) and extends it;
    // then a run in the part only the extension covers (0.60 → 0.80) localises in both maps.
    let partial = map_site(&warehouse(25.0));
    let mut extension = MapExtension::new(partial.map.clone(), &BackEndConfig::default());
    let extending = localise_extending(
        &partial,
        &SimConfig {
            start_fraction: 0.25,
            ..warehouse(50.0)
        },
        Some(&mut extension),
    );
    assert_eq!(extending.report.wrong_poses, 0, "{:?}", extending.report);
    let header = SiteMapHeader {
        created_ns: 1,
        sensor_model: "VLP-16".into(),
        base_from_sensor: Isometry3::identity(),
    };
    let (map, added) = extension.finish(&header).expect("a valid graph");
    let saved = partial.map.keyframes.len();
    eprintln!("partial map {saved} keyframes, extension {added:?}");
    assert_eq!(map.keyframes[..saved], partial.map.keyframes[..]);
    assert!(added.added >= 20, "{added:?}");
    let extended = Site {
        map,
        scene_from_map: partial.scene_from_map,
    };
    let beyond = SimConfig {
        start_fraction: 0.6,
        ..warehouse(12.0)
    };
    let before = localise(&partial, &beyond);
    let after = localise(&extended, &beyond);
    for (name, run) in [("partial map", &before), ("extended map", &after)] {
        eprintln!(
            "{name}: {} of {} sweeps verified, relocalisations {:?}, {:?}",
            run.verified.len(),
            run.sweeps,
            run.relocalisations,
            run.report
        );
        assert_eq!(run.report.wrong_poses, 0, "{name}: {:?}", run.report);
    }
    let first = after.relocalisations.first().map(|&(_, s)| s);
    assert!(first.is_some_and(|s| s <= 2.0), "{first:?}");
    assert!(
        after.verified.len() * 10 >= after.sweeps * 8,
        "{} of {}",
        after.verified.len(),
        after.sweeps
    );
    assert!(after.verified.len() > before.verified.len());
    // The partial map is 25 s of mapping with no loop to close: localising in it is 6 cm and
    // 0.23° off the scene here, and the aisle added to it inherits its frame at both ends
    // (measured 0.11 m and 0.26° in the added part).
    let r = &after.report;
    let own = &extending.report;
    assert!(r.position_rmse <= 0.15 && r.yaw_rmse_deg <= 0.4, "{r:?}");
    assert!(
        r.position_rmse <= own.position_rmse + 0.07,
        "{r:?} against {own:?}"
    );
}

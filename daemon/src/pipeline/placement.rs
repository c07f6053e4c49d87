//! Where the pipeline's threads run. The odometry thread is pinned to one core and given a
//! real-time priority when configured, so that the navigation stack sharing the robot's computer
//! delays the pose as little as possible; the threads off the pose's path (back end, localiser,
//! map and sweep publishers) run at a lower priority, so that their bursts (a keyframe's loop
//! search, a map sent whole) wait for the pose rather than the pose for them. Whatever the system
//! refuses (no `CAP_SYS_NICE`, systemd's `RestrictRealtime=`, a core that does not exist) is
//! logged and the thread runs as it is.

use thread_priority::{
    set_thread_priority_and_policy, thread_native_id, NormalThreadSchedulePolicy,
    RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
};

/// The priority of the threads off the pose's path, on the 0–99 scale `thread_priority` maps
/// onto Linux's nice values: 22 is nice 10, a tenth of a normal thread's share of a busy core
/// (the kernel's weights fall by 1.25× a nice step), so a loaded computer still closes loops.
const BACKGROUND_PRIORITY: u8 = 22;

/// Moves the calling thread, named `thread` in the log, off the pose's path: `SCHED_BATCH` at
/// nice 10, which also leaves it out of the wake-up preemption that favours interactive
/// threads. A thread started under `SCHED_FIFO` (systemd's `CPUSchedulingPolicy=`, inherited)
/// leaves it. Lowering a priority needs no privilege; a refusal (a seccomp filter) is logged and
/// the thread runs as it is. Returns whether the thread moved.
pub fn run_in_background(thread: &str) -> bool {
    let batch = ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Batch);
    match set_own_policy(BACKGROUND_PRIORITY, batch) {
        Ok(()) => {
            tracing::debug!(thread, "background priority (SCHED_BATCH, nice 10)");
            true
        }
        Err(e) => {
            tracing::info!(
                thread,
                "kept its priority ({e}): it competes with the pose's path"
            );
            false
        }
    }
}

/// Puts the calling thread under `policy` at `priority` (0–99, see [`BACKGROUND_PRIORITY`]).
fn set_own_policy(priority: u8, policy: ThreadSchedulePolicy) -> Result<(), String> {
    let value = ThreadPriorityValue::try_from(priority).map_err(|e| e.to_string())?;
    set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        policy,
    )
    .map_err(|e| format!("{e:?}"))
}

/// A thread's placement (`[pipeline] odometry_cpu`, `odometry_priority`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ThreadPlacement {
    /// Pin to this core (0-based, as `taskset` and `CPUAffinity=` count).
    pub cpu: Option<usize>,
    /// `SCHED_FIFO` at this priority, 1–99.
    pub realtime_priority: Option<u8>,
}

/// What [`ThreadPlacement::apply`] achieved.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Placed {
    /// Pinned to the configured core.
    pub pinned: bool,
    /// Running under `SCHED_FIFO` at the configured priority.
    pub realtime: bool,
}

impl ThreadPlacement {
    /// Places the calling thread, named `thread` in the log.
    pub fn apply(&self, thread: &str) -> Placed {
        let mut placed = Placed::default();
        if let Some(cpu) = self.cpu {
            let core = core_affinity::get_core_ids()
                .unwrap_or_default()
                .into_iter()
                .find(|c| c.id == cpu);
            match core {
                Some(core) if core_affinity::set_for_current(core) => {
                    tracing::info!(thread, cpu, "pinned to a core");
                    placed.pinned = true;
                }
                Some(_) => tracing::warn!(thread, cpu, "could not be pinned to its core"),
                None => tracing::warn!(thread, cpu, "not pinned: no such core here"),
            }
        }
        if let Some(priority) = self.realtime_priority {
            let fifo = ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo);
            match set_own_policy(priority, fifo) {
                Ok(()) => {
                    tracing::info!(thread, priority, "real-time priority (SCHED_FIFO)");
                    placed.realtime = true;
                }
                Err(e) => tracing::warn!(
                    thread,
                    priority,
                    "no real-time priority ({e}): needs CAP_SYS_NICE, or systemd's \
                     CPUSchedulingPolicy= (see systemd/README.md)"
                ),
            }
        }
        placed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The calling thread's line `key:` in /proc/thread-self/status.
    fn status(key: &str) -> Option<String> {
        std::fs::read_to_string("/proc/thread-self/status")
            .ok()?
            .lines()
            .find_map(|l| l.strip_prefix(key).map(|v| v.trim().to_owned()))
    }

    #[test]
    fn a_thread_is_pinned_where_asked_and_told_what_was_refused() {
        std::thread::spawn(|| {
            let placement = ThreadPlacement {
                cpu: Some(0),
                realtime_priority: None,
            };
            let placed = placement.apply("test");
            assert!(placed.pinned);
            assert!(!placed.realtime);
            if let Some(allowed) = status("Cpus_allowed_list:") {
                assert_eq!(allowed, "0");
            }
            let nowhere = ThreadPlacement {
                cpu: Some(100_000),
                realtime_priority: None,
            };
            assert!(!nowhere.apply("test").pinned);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn background_threads_run_batch_at_nice_10() {
        // Nice is per thread on Linux: /proc/thread-self/stat's 19th field.
        let nice = || {
            let stat = std::fs::read_to_string("/proc/thread-self/stat").unwrap();
            let after_name = &stat[stat.rfind(')').unwrap() + 2..];
            after_name
                .split(' ')
                .nth(16)
                .unwrap()
                .parse::<i32>()
                .unwrap()
        };
        std::thread::spawn(move || {
            let was = nice();
            if !run_in_background("test") {
                // Only a thread already lower (the tests run under `nice`) may be refused:
                // going back up needs a privilege.
                assert!(was > 10, "refused at nice {was}");
                assert_eq!(nice(), was);
                return;
            }
            let policy = thread_priority::thread_schedule_policy_param(thread_native_id());
            let batch = ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Batch);
            assert!(matches!(policy, Ok((p, _)) if p == batch), "{policy:?}");
            assert_eq!(nice(), 10);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn a_real_time_priority_is_taken_or_refused_never_half() {
        std::thread::spawn(|| {
            let placement = ThreadPlacement {
                cpu: None,
                realtime_priority: Some(10),
            };
            let placed = placement.apply("test");
            let policy = thread_priority::thread_schedule_policy_param(thread_native_id());
            let fifo = ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo);
            match policy {
                Ok((p, params)) if placed.realtime => {
                    assert_eq!(p, fifo);
                    assert_eq!(params.sched_priority, 10);
                }
                Ok((p, _)) => assert_ne!(p, fifo),
                Err(e) => panic!("{e:?}"),
            }
        })
        .join()
        .unwrap();
    }
}

//! The SERVER thread's real-time budget.
//!
//! At a real-time priority (`--rt-priority`) the thread that receives and
//! verifies datagrams runs ahead of every SCHED_OTHER task. Each datagram
//! costs it an HMAC whether the datagram is the client's or forged, and a
//! flood from the session's own (spoofed) address cannot be told from the
//! client before that HMAC, so no per-source limit applies to it. Left at a
//! real-time priority under such a flood, the thread would hold the CPU, and
//! the kernel's fair server (its guarantee to SCHED_OTHER tasks: by default
//! 50 ms of each second, run at deadline priority, above every real-time
//! task) would then run those tasks ahead of the module's SERVO and CLOCK:
//! missed cycles and, after five, the fail-safe.
//!
//! So the thread measures its own CPU time (`CLOCK_THREAD_CPUTIME_ID`) over
//! windows of [`WINDOW`]: a window in which it used more than its share
//! (`--rt-budget`, percent of one CPU) demotes it to SCHED_OTHER, where it
//! goes on serving at a fair share; the first window within the share
//! restores SCHED_FIFO. The real-time load the bridge can put on the CPU is
//! thus one window at full use, then at most its share; the CLIENT thread
//! (answers, one per servo cycle at most) keeps its priority.
//!
//! [`RtBudget`] is the decision alone (time and CPU time are given to it, so
//! that it is tested on the host without a real-time priority);
//! [`set_policy`] and [`thread_cpu_time`] are the two system calls.

use std::time::{Duration, Instant};

/// Length of a budget window.
pub const WINDOW: Duration = Duration::from_millis(100);

/// The SERVER thread's scheduling policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Policy {
    /// `SCHED_FIFO` at the bridge's real-time priority.
    Fifo,
    /// `SCHED_OTHER`: over budget.
    Other,
}

/// A change of policy decided at the end of a window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Switch {
    pub to: Policy,
    /// CPU time the thread used in the window that ended.
    pub used: Duration,
    /// That window's length.
    pub window: Duration,
}

/// The budget's state: the current policy and the window being measured.
#[derive(Debug)]
pub struct RtBudget {
    percent: u32,
    policy: Policy,
    window_start: Instant,
    cpu_at_start: Duration,
}

impl RtBudget {
    /// A thread at `SCHED_FIFO` that may use `percent` (1..=100; 100: never
    /// demoted) of a CPU; `now` and `cpu` start the first window.
    pub fn new(percent: u32, now: Instant, cpu: Duration) -> RtBudget {
        RtBudget {
            percent: percent.clamp(1, 100),
            policy: Policy::Fifo,
            window_start: now,
            cpu_at_start: cpu,
        }
    }

    pub fn policy(&self) -> Policy {
        self.policy
    }

    /// Has the current window ended at `now`? (Cheap: the caller reads the
    /// thread's CPU time only then.)
    pub fn window_ended(&self, now: Instant) -> bool {
        now.saturating_duration_since(self.window_start) >= WINDOW
    }

    /// End the window at `now` with the thread's CPU time `cpu`; returns the
    /// change of policy to apply, if any. The caller reports whether it was
    /// applied with [`RtBudget::applied`].
    pub fn end_window(&mut self, now: Instant, cpu: Duration) -> Option<Switch> {
        let window = now.saturating_duration_since(self.window_start);
        let used = cpu.saturating_sub(self.cpu_at_start);
        self.window_start = now;
        self.cpu_at_start = cpu;
        // used / window > percent / 100, without division.
        let over = used.as_nanos().saturating_mul(100)
            > window.as_nanos().saturating_mul(u128::from(self.percent));
        let to = match (self.policy, over) {
            (Policy::Fifo, true) if self.percent < 100 => Policy::Other,
            (Policy::Other, false) => Policy::Fifo,
            _ => return None,
        };
        Some(Switch { to, used, window })
    }

    /// The switch was applied (the policy changed).
    pub fn applied(&mut self, s: Switch) {
        self.policy = s.to;
    }
}

/// CPU time the calling thread has used.
pub fn thread_cpu_time() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec for the call's duration.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return Duration::ZERO;
    }
    Duration::new(
        u64::try_from(ts.tv_sec).unwrap_or(0),
        u32::try_from(ts.tv_nsec).unwrap_or(0),
    )
}

/// Set the calling thread's policy: `SCHED_FIFO` at `priority`, or
/// `SCHED_OTHER`. Going back to `SCHED_FIFO` needs CAP_SYS_NICE, which the
/// bridge keeps when it was asked for a real-time priority.
pub fn set_policy(p: Policy, priority: i32) -> std::io::Result<()> {
    let (policy, prio) = match p {
        Policy::Fifo => (libc::SCHED_FIFO, priority),
        Policy::Other => (libc::SCHED_OTHER, 0),
    };
    let param = libc::sched_param {
        sched_priority: prio,
    };
    // SAFETY: `param` is a valid, initialised sched_param that outlives the
    // call; pid 0 is the calling thread (Linux applies the policy per thread).
    let rc = unsafe { libc::sched_setscheduler(0, policy, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// The calling thread's policy as the kernel reports it.
pub fn current_policy() -> std::io::Result<i32> {
    // SAFETY: no pointer argument; pid 0 is the calling thread.
    let rc = unsafe { libc::sched_getscheduler(0) };
    if rc < 0 {
        Err(std::io::Error::last_os_error())
    } else {
        Ok(rc)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn a_window_over_budget_demotes_and_a_window_within_restores() {
        let t0 = Instant::now();
        let mut b = RtBudget::new(25, t0, Duration::ZERO);
        assert!(!b.window_ended(t0 + 99 * MS));
        assert!(b.window_ended(t0 + 100 * MS));
        // 25 ms in 100 ms: within the share.
        assert_eq!(b.end_window(t0 + 100 * MS, 25 * MS), None);
        assert_eq!(b.policy(), Policy::Fifo);
        // 26 ms in the next 100 ms: over.
        let s = b.end_window(t0 + 200 * MS, 51 * MS).expect("demotion");
        assert_eq!(
            s,
            Switch {
                to: Policy::Other,
                used: 26 * MS,
                window: 100 * MS
            }
        );
        // Not applied (the system call failed): still Fifo, and the next
        // window over budget asks again.
        let again = b.end_window(t0 + 300 * MS, 151 * MS).expect("asked again");
        assert_eq!(again.to, Policy::Other);
        b.applied(again);
        assert_eq!(b.policy(), Policy::Other);
        // Still flooded while demoted: stays demoted.
        assert_eq!(b.end_window(t0 + 400 * MS, 240 * MS), None);
        // The flood is over: 2 ms in 100 ms restores SCHED_FIFO.
        let r = b.end_window(t0 + 500 * MS, 242 * MS).expect("restore");
        assert_eq!(r.to, Policy::Fifo);
        b.applied(r);
        assert_eq!(b.policy(), Policy::Fifo);
    }

    #[test]
    fn the_share_is_of_the_window_as_it_was() {
        let t0 = Instant::now();
        let mut b = RtBudget::new(10, t0, Duration::ZERO);
        // A window that lasted 1 s (the thread slept in recv): 90 ms is 9 %.
        assert_eq!(b.end_window(t0 + 1000 * MS, 90 * MS), None);
        // 11 ms in 100 ms is 11 %.
        assert!(b.end_window(t0 + 1100 * MS, 101 * MS).is_some());
    }

    #[test]
    fn at_100_percent_it_is_never_demoted_and_time_going_backwards_is_harmless() {
        let t0 = Instant::now();
        let mut b = RtBudget::new(100, t0, 5 * MS);
        assert_eq!(b.end_window(t0 + 100 * MS, 105 * MS), None);
        assert_eq!(b.end_window(t0 + 200 * MS, 1000 * MS), None);
        // CPU time read as 0 (clock_gettime failed): no underflow, no switch.
        let mut c = RtBudget::new(25, t0, 50 * MS);
        assert_eq!(c.end_window(t0 + 100 * MS, Duration::ZERO), None);
        // Percent out of range is clamped.
        let d = RtBudget::new(0, t0, Duration::ZERO);
        assert_eq!(d.percent, 1);
    }

    #[test]
    fn the_calling_threads_cpu_time_moves() {
        let a = thread_cpu_time();
        let mut x = 0u64;
        let t = Instant::now();
        while t.elapsed() < 20 * MS {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
        }
        std::hint::black_box(x);
        let b = thread_cpu_time();
        assert!(b > a, "{a:?} -> {b:?}");
    }

    #[test]
    fn demotion_to_sched_other_needs_no_privilege_and_is_what_the_kernel_reports() {
        // In a thread of its own: the test harness's threads are left as
        // they were.
        std::thread::spawn(|| {
            set_policy(Policy::Other, 0).expect("SCHED_OTHER is always allowed");
            assert_eq!(current_policy().expect("policy"), libc::SCHED_OTHER);
        })
        .join()
        .expect("thread");
    }
}

//! Real-time set-up of the haptic thread and its clock: SCHED_FIFO and mlockall when the
//! host permits them (a clear warning when not), and sleeping until an absolute deadline
//! on CLOCK_MONOTONIC (never a busy spin: with SCHED_FIFO and the kernel's RT throttling a
//! spinning thread stalls for milliseconds once a second, dependencies.md §9).

// The calls into libc below are the only unsafe code of the server; each is a plain
// system call with arguments built right before it.
#![allow(unsafe_code)]

/// What the real-time set-up got.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RealtimeStatus {
    /// SCHED_FIFO priority in effect (0: normal scheduling).
    pub fifo_priority: i32,
    /// Memory locked.
    pub memory_locked: bool,
    /// Why something asked for was not granted.
    pub warnings: Vec<String>,
}

/// Locks the pages the process has now (call it once the threads and their buffers exist).
/// Not MCL_FUTURE: under a finite RLIMIT_MEMLOCK a later allocation (an incision re-mesh on
/// the simulation thread) would fail, and a failed allocation aborts the process; the
/// haptic loop allocates nothing after start-up, so what it touches is locked.
pub fn lock_memory() -> Result<(), String> {
    // SAFETY: mlockall takes flags only and touches no Rust memory.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT) };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!("mlockall: {}", std::io::Error::last_os_error()))
    }
}

/// Puts the calling thread under SCHED_FIFO at `priority`.
pub fn make_thread_fifo(priority: i32) -> Result<(), String> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pthread_self is the calling thread; `param` lives across the call.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!(
            "SCHED_FIFO {priority}: {}",
            std::io::Error::from_raw_os_error(rc)
        ))
    }
}

/// CPUs this process may run on.
pub fn allowed_cpus() -> Vec<usize> {
    // SAFETY: `set` is a plain bit set that sched_getaffinity fills; its size is passed.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            return Vec::new();
        }
        (0..libc::CPU_SETSIZE as usize)
            .filter(|&c| libc::CPU_ISSET(c, &set))
            .collect()
    }
}

/// Restricts the calling thread to `cpus`.
pub fn pin_thread(cpus: &[usize]) -> Result<(), String> {
    if cpus.is_empty() {
        return Err("no CPU to pin to".into());
    }
    // SAFETY: `set` is a plain bit set built here; pthread_self is the calling thread.
    let rc = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &c in cpus {
            libc::CPU_SET(c, &mut set);
        }
        libc::pthread_setaffinity_np(libc::pthread_self(), size_of::<libc::cpu_set_t>(), &set)
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!(
            "CPU affinity {cpus:?}: {}",
            std::io::Error::from_raw_os_error(rc)
        ))
    }
}

/// Sets the calling thread's nice value (Linux schedules threads, not processes, by it):
/// below 0 needs CAP_SYS_NICE or RLIMIT_NICE, as SCHED_FIFO does.
pub fn set_thread_nice(nice: i32) -> Result<(), String> {
    // SAFETY: gettid and setpriority take plain integers and touch no Rust memory.
    let rc = unsafe {
        let tid = libc::gettid();
        libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, nice)
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!("nice {nice}: {}", std::io::Error::last_os_error()))
    }
}

/// Seconds on CLOCK_MONOTONIC.
pub fn monotonic_s() -> f64 {
    let t = monotonic();
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// Seconds of CPU time the calling thread has used (CLOCK_THREAD_CPUTIME_ID): a tick's
/// own cost, without the time it was kept off the CPU.
pub fn thread_cpu_s() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid timespec for the call to fill.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

fn monotonic() -> libc::timespec {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid timespec for the call to fill.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut t) };
    t
}

/// Sleeps until `deadline_s` on CLOCK_MONOTONIC (returns at once if it has passed).
pub fn sleep_until(deadline_s: f64) {
    let t = libc::timespec {
        tv_sec: deadline_s.floor() as libc::time_t,
        tv_nsec: ((deadline_s - deadline_s.floor()) * 1e9) as libc::c_long,
    };
    loop {
        // SAFETY: `t` is a valid timespec; the remainder pointer may be null with
        // TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &t,
                std::ptr::null_mut(),
            )
        };
        // Interrupted by a signal: sleep again to the same absolute deadline.
        if rc != libc::EINTR {
            return;
        }
    }
}

/// The CPUs other than `cpu` among `cpus` (this process's), when `cpu` can have a CPU of
/// its own: it is one of them and not the only one.
pub fn cpus_besides(cpu: usize, cpus: &[usize]) -> Result<Vec<usize>, String> {
    if cpus.contains(&cpu) && cpus.len() >= 2 {
        Ok(cpus.iter().copied().filter(|&o| o != cpu).collect())
    } else {
        Err(format!(
            "realtime.haptic_cpu {cpu}: not one of this process's CPUs {cpus:?} (or the only one)"
        ))
    }
}

/// The type libc gives resource numbers (glibc has its own).
#[cfg(target_env = "gnu")]
pub type Resource = libc::__rlimit_resource_t;
/// The type libc gives resource numbers.
#[cfg(not(target_env = "gnu"))]
pub type Resource = libc::c_int;

/// The soft limit of `resource` (`Ok(None)` = unlimited).
pub fn soft_limit(resource: Resource) -> std::io::Result<Option<u64>> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `r` is a valid rlimit for getrlimit to fill.
    if unsafe { libc::getrlimit(resource, &mut r) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok((r.rlim_cur != libc::RLIM_INFINITY).then_some(r.rlim_cur))
}

/// Whether mlockall(MCL_CURRENT) is permitted now: locks and unlocks at once (the host
/// check; the server locks for good with [`lock_memory`]).
pub fn try_lock_memory() -> std::io::Result<()> {
    // SAFETY: mlockall/munlockall take flags only and touch no Rust memory.
    if unsafe { libc::mlockall(libc::MCL_CURRENT) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: as above.
    unsafe { libc::munlockall() };
    Ok(())
}

/// Bytes an unprivileged user may still write on the file system holding `path`.
pub fn free_bytes(path: &std::ffi::CStr) -> std::io::Result<u64> {
    // SAFETY: statvfs is plain data, filled by the call; an all-zero value is valid.
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `path` is a valid C string and `s` a valid statvfs for the call to fill.
    if unsafe { libc::statvfs(path.as_ptr(), &mut s) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(s.f_bavail.saturating_mul(s.f_frsize))
}

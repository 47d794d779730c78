//! Real-time scheduling for the loops that talk to a robot's controller (`deploy`, `ur-sim`,
//! `bench rtde` with `--rt-priority N`): the calling thread on SCHED_FIFO at priority N (the
//! threads it starts afterwards inherit it) and the process's memory locked, so neither the
//! scheduler nor a page fault holds a command back — what ur_rtde's `rt_priority` and a
//! controller PC's PREEMPT_RT kernel are for.

/// Puts the calling thread on SCHED_FIFO at `priority` (1–99) and locks the process's memory.
/// An error when the kernel refuses (it needs root or CAP_SYS_NICE); a memory lock that is
/// refused is said on stderr and the run goes on.
pub fn set_rt_priority(priority: i32) -> anyhow::Result<()> {
    anyhow::ensure!((1..=99).contains(&priority), "--rt-priority must be 1 to 99 (SCHED_FIFO), not {priority}");
    #[cfg(target_os = "linux")]
    {
        let param = libc::sched_param { sched_priority: priority };
        // SAFETY: plain system calls on this thread and process with a valid parameter.
        let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
        if rc != 0 {
            anyhow::bail!(
                "--rt-priority {priority}: the kernel refused SCHED_FIFO ({}): it needs root or CAP_SYS_NICE, or an rtprio limit in /etc/security/limits.conf",
                std::io::Error::from_raw_os_error(rc)
            );
        }
        // SAFETY: as above.
        if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
            eprintln!(
                "--rt-priority: memory not locked ({}); page faults may still delay a cycle",
                std::io::Error::last_os_error()
            );
        }
        Ok(())
    }
    #[cfg(not(target_os = "linux"))]
    anyhow::bail!("--rt-priority is implemented for Linux only")
}

//! Resident memory of this process, for the study's per-run peak (Linux `/proc/self`).
//!
//! Runs of a study execute in the study's own process, one after the other. Before each run the
//! peak resident set size (`VmHWM`) is reset to the current resident size by writing `5` to
//! `/proc/self/clear_refs` (Linux >= 4.0); after the run `VmHWM` is the largest resident size the
//! process had *during that run*. It includes what the process held before the run (the
//! binary, the study's own records, memory the allocator kept from earlier runs), which is
//! reported separately as the baseline (`VmRSS` just before the run). Where the reset is not
//! possible, the peak is the process's peak since it started and the study says so.

use std::fs;

/// Resident-set figures of one run, in MiB.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MemoryUse {
    /// `VmRSS` just before the run.
    pub baseline_mib: Option<f64>,
    /// `VmHWM` after the run.
    pub peak_mib: Option<f64>,
    /// Whether the peak was reset before the run (else it is the process's lifetime peak).
    pub peak_is_per_run: bool,
}

/// A `kB` field of `/proc/self/status` (e.g. `VmHWM`), in MiB.
pub fn status_field_mib(status: &str, field: &str) -> Option<f64> {
    let line = status.lines().find(|l| l.starts_with(field))?;
    let rest = line[field.len()..].trim_start_matches(':').trim();
    let kib: f64 = rest.strip_suffix("kB")?.trim().parse().ok()?;
    Some(kib / 1024.0)
}

fn read_status() -> Option<String> {
    fs::read_to_string("/proc/self/status").ok()
}

/// Resets the peak resident size to the current one; returns whether it worked.
pub fn reset_peak() -> bool {
    fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Starts measuring a run: resets the peak, returns the baseline.
pub fn begin_run() -> MemoryUse {
    let peak_is_per_run = reset_peak();
    MemoryUse {
        baseline_mib: read_status().and_then(|s| status_field_mib(&s, "VmRSS")),
        peak_mib: None,
        peak_is_per_run,
    }
}

/// Finishes measuring a run started with [`begin_run`].
pub fn end_run(mut started: MemoryUse) -> MemoryUse {
    started.peak_mib = read_status().and_then(|s| status_field_mib(&s, "VmHWM"));
    started
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_fields_are_parsed_in_mib() {
        let status = "Name:\timpm\nVmHWM:\t   20480 kB\nVmRSS:\t    1024 kB\n";
        assert_eq!(status_field_mib(status, "VmHWM"), Some(20.0));
        assert_eq!(status_field_mib(status, "VmRSS"), Some(1.0));
        assert_eq!(status_field_mib(status, "VmSwap"), None);
    }

    #[test]
    fn a_large_allocation_raises_the_measured_peak() {
        let started = begin_run();
        if started.baseline_mib.is_none() {
            return; // no /proc: nothing to measure on this system
        }
        let block = vec![1u8; 64 << 20];
        std::hint::black_box(&block);
        // Read while the block is held: the process then holds at least its 64 MiB.
        let held = read_status()
            .and_then(|s| status_field_mib(&s, "VmRSS"))
            .unwrap();
        drop(block);
        let used = end_run(started);
        let peak = used.peak_mib.unwrap();
        // Other test threads allocate and free concurrently, so the baseline can fall during the
        // run (a bound against it failed so); what cannot fail is that the block was resident
        // and that the peak saw it, to the kernel's lag in syncing per-thread page counts (a
        // tenth of a MiB seen; 1 MiB allowed).
        assert!(
            held >= 64.0,
            "resident {held} MiB while holding a 64 MiB block"
        );
        assert!(
            peak >= held - 1.0,
            "peak {peak} MiB below the {held} MiB resident during the run"
        );
    }
}

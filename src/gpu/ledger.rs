//! What the stages allocate on the device, counted where it is allocated: every buffer, bind
//! group and pipeline goes through [`super::Gpu`]'s methods, which tell the ledger. Two uses:
//! tests that check resources are made once per reconstruction (the counts must not grow with
//! the number of chunks a stage evaluates), and the per-stage peak of live buffer memory set
//! against the plan's footprints ([`crate::plan`]).
//!
//! The live bytes are the device's own count (wgpu's `counters` feature: the bytes of memory
//! allocated for buffers, freed buffers included only until the device reclaims them). Without
//! that feature, as in release builds and in the browser, wgpu reports 0 and the ledger says
//! the live bytes are unknown rather than zero: [`super::Gpu::live_bytes`] and the peak are `None`.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};

/// Monotonic creation counts and the peak of live buffer memory since the last
/// [`Ledger::begin`].
#[derive(Debug, Default)]
pub struct Ledger {
    buffers: AtomicU64,
    buffer_bytes: AtomicU64,
    retired: AtomicU64,
    bind_groups: AtomicU64,
    pipelines: AtomicU64,
    /// Whether the device counts its live buffer memory (decided once, at the first buffer).
    counted: AtomicBool,
    peak: AtomicU64,
}

/// A snapshot of the ledger.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Allocations {
    /// Buffers created (staging buffers for readback included), and their requested bytes.
    pub buffers: u64,
    pub buffer_bytes: u64,
    /// Buffers destroyed explicitly once their work was submitted ([`super::Gpu::retire`]).
    pub retired: u64,
    pub bind_groups: u64,
    pub pipelines: u64,
    /// The most buffer memory the device held at once since the last [`Ledger::begin`], when
    /// the device counts it.
    pub peak_live_bytes: Option<u64>,
}

impl Allocations {
    /// What was created between `earlier` and `self` (the peak is `self`'s).
    pub fn since(&self, earlier: &Allocations) -> Allocations {
        Allocations {
            buffers: self.buffers - earlier.buffers,
            buffer_bytes: self.buffer_bytes - earlier.buffer_bytes,
            retired: self.retired - earlier.retired,
            bind_groups: self.bind_groups - earlier.bind_groups,
            pipelines: self.pipelines - earlier.pipelines,
            peak_live_bytes: self.peak_live_bytes,
        }
    }
}

impl Ledger {
    /// Called by the device's first buffer: whether the device counts live bytes at all.
    pub(super) fn set_counted(&self, counted: bool) {
        self.counted.store(counted, Relaxed);
    }

    pub(super) fn buffer(&self, bytes: u64, live: i64) {
        self.buffers.fetch_add(1, Relaxed);
        self.buffer_bytes.fetch_add(bytes, Relaxed);
        self.peak.fetch_max(live.max(0) as u64, Relaxed);
    }

    pub(super) fn retired(&self, n: u64) {
        self.retired.fetch_add(n, Relaxed);
    }

    pub(super) fn bind_group(&self) {
        self.bind_groups.fetch_add(1, Relaxed);
    }

    pub(super) fn pipelines(&self, n: usize) {
        self.pipelines.fetch_add(n as u64, Relaxed);
    }

    /// Starts a new peak at the memory held now (`live`, the device's count).
    pub(super) fn begin(&self, live: i64) {
        self.peak.store(live.max(0) as u64, Relaxed);
    }

    pub(super) fn snapshot(&self) -> Allocations {
        Allocations {
            buffers: self.buffers.load(Relaxed),
            buffer_bytes: self.buffer_bytes.load(Relaxed),
            retired: self.retired.load(Relaxed),
            bind_groups: self.bind_groups.load(Relaxed),
            pipelines: self.pipelines.load(Relaxed),
            peak_live_bytes: self.counted.load(Relaxed).then(|| self.peak.load(Relaxed)),
        }
    }

    /// Whether live bytes are counted by this device.
    pub fn counted(&self) -> bool {
        self.counted.load(Relaxed)
    }
}


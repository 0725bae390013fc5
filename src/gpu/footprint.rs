//! What a stage allocates, as the stage itself states it: each stage's module has a function
//! next to the code that allocates (`net::gpu::encode_footprint`, `krr::gpu::objective_footprint`,
//! …), and [`crate::plan`] only adds them up per stage and checks them against the adapter.

/// Bytes one stage (or one part of it) holds at its peak.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Footprint {
    /// GPU memory, all buffers together.
    pub gpu: u64,
    /// The largest single buffer (each must fit the adapter's binding limit).
    pub largest: u64,
    /// Host memory.
    pub host: u64,
}

impl Footprint {
    /// Host memory only.
    pub fn host(bytes: u64) -> Footprint {
        Footprint { host: bytes, ..Default::default() }
    }

    /// Two parts held at the same time.
    pub fn and(self, other: Footprint) -> Footprint {
        Footprint { gpu: self.gpu + other.gpu, largest: self.largest.max(other.largest), host: self.host + other.host }
    }
}

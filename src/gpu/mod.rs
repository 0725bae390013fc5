//! The GPU runtime: one wgpu device and queue used by every stage, native and in the browser.
//!
//! Why a wrapper at all: the stages need the same four things — a device whose limits they can
//! size their work by, upload of typed slices, readback that works both natively (by polling)
//! and on the web (where the browser resolves the map), and dispatches split so no dimension
//! exceeds the device's workgroup-count limit. Keeping those here keeps the stages about math.
//!
//! Shader convention for 1-D work: a kernel launched through [`Gpu::dispatch_linear`] computes
//! its global index as `gid.x + gid.y * (num_workgroups.x * WG)` where `WG` is its workgroup
//! size, and returns early when the index is past the end (`shaders/marching_cubes.wgsl` states it too).
//!
//! Also here, so every stage does them one way: [`specialise`] (sizes pasted into WGSL
//! templates), [`to_u32`] (the 32-bit index check), and [`now`] (the clock stages time
//! themselves with, in [`clock`]).

pub mod clock;
pub mod footprint;
pub mod ledger;

pub use clock::now;
pub use footprint::Footprint;
pub use ledger::{Allocations, Ledger};

use std::collections::HashMap;
use std::fmt;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};

use wgpu::util::DeviceExt;

/// Why the GPU could not be used.
#[derive(Debug)]
pub enum GpuError {
    /// No adapter: no WebGPU in this browser, or no Vulkan/Metal/DX12/GL driver natively.
    NoAdapter(String),
    /// The adapter refused the device (limits or features).
    Device(String),
    /// A buffer could not be mapped for reading.
    Readback(String),
    /// The work does not fit the device (buffer larger than its limits, say).
    TooLarge(String),
    /// A validation or out-of-memory error reported by the device while running a kernel.
    Kernel(String),
}

impl fmt::Display for GpuError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GpuError::NoAdapter(s) => write!(f, "no GPU adapter found: {s}"),
            GpuError::Device(s) => write!(f, "the GPU adapter refused a device: {s}"),
            GpuError::Readback(s) => write!(f, "reading a result back from the GPU failed: {s}"),
            GpuError::TooLarge(s) => write!(f, "the work does not fit this GPU: {s}"),
            GpuError::Kernel(s) => write!(f, "a GPU kernel failed: {s}"),
        }
    }
}

impl std::error::Error for GpuError {}

/// The device, its queue, and what it can do. Cloning is cheap (handles are shared), which
/// lets async work own a handle instead of borrowing its creator across an `await`.
#[derive(Clone)]
pub struct Gpu {
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    /// What has been allocated through this handle and its clones ([`ledger`]).
    pub ledger: Arc<Ledger>,
    /// Compute pipelines already built, by their WGSL source and entry points
    /// ([`Gpu::compute_pipelines`]): a stage built once per tile of a scene compiles its
    /// shaders once per device, not once per tile.
    pipelines: Arc<Mutex<HashMap<(String, Vec<String>), Vec<wgpu::ComputePipeline>>>>,
}

/// The largest buffer a shader may bind under `limits`: both the storage-binding and the
/// buffer-size limit apply.
pub fn binding_limit(limits: &wgpu::Limits) -> u64 {
    limits.max_storage_buffer_binding_size.min(limits.max_buffer_size)
}

impl Gpu {
    /// An instance configured from the environment (`WGPU_BACKEND` etc.), no display needed.
    pub fn instance() -> wgpu::Instance {
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env())
    }

    /// A headless device for compute. Natively this finds lavapipe where no GPU exists.
    pub async fn new() -> Result<Gpu, GpuError> {
        Self::with_instance(&Self::instance(), None).await
    }

    /// A device on `instance`, able to present to `surface` when one is given.
    pub async fn with_instance(
        instance: &wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Gpu, GpuError> {
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: surface,
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        // Ask for everything the adapter offers: the stages size their blocks from these limits,
        // and staying within the WebGPU defaults would cap buffers at 256 MiB for no reason.
        let limits = adapter.limits();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("nkrr"),
                required_features: wgpu::Features::empty(),
                required_limits: limits.clone(),
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::Device(e.to_string()))?;
        let gpu = Gpu { adapter, device, queue, info, limits, ledger: Arc::default(), pipelines: Arc::default() };
        // Whether the device counts its buffer memory (wgpu's `counters` feature, on in the test
        // build): a 4-byte probe either shows up in the count or the count stays 0.
        let probe = gpu.storage::<u32>("ledger probe", 1)?;
        gpu.ledger.set_counted(gpu.device_live_bytes() > 0);
        drop(probe);
        Ok(gpu)
    }

    /// Buffer memory the device holds now, as it counts it (0 when it does not count).
    fn device_live_bytes(&self) -> i64 {
        self.device.get_internal_counters().hal.buffer_memory.read() as i64
    }

    /// Buffer memory the device holds now, when it counts it ([`ledger`]).
    pub fn live_bytes(&self) -> Option<u64> {
        self.ledger.counted().then(|| self.device_live_bytes().max(0) as u64)
    }

    /// What has been created so far, and the peak of live memory since [`Gpu::begin_peak`].
    pub fn allocations(&self) -> Allocations {
        self.ledger.snapshot()
    }

    /// Starts measuring a new peak of live buffer memory from what the device holds now (a
    /// stage boundary). Natively, finished work is reclaimed first, so freed buffers do not
    /// count against the next stage.
    pub fn begin_peak(&self) {
        self.poll_wait();
        self.ledger.begin(self.device_live_bytes());
    }

    fn note_buffer(&self, bytes: u64) {
        self.ledger.buffer(bytes, self.device_live_bytes());
    }

    /// Blocking constructor for native code (CLI, tests).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_blocking() -> Result<Gpu, GpuError> {
        pollster::block_on(Self::new())
    }

    /// A one-paragraph description of the adapter and the limits that size our work.
    pub fn describe(&self) -> String {
        let l = &self.limits;
        format!(
            "{} ({:?}, {:?}{}); max buffer {} MiB, max storage binding {} MiB, \
             {} invocations/workgroup, {} workgroups/dimension, {} storage buffers/stage",
            if self.info.name.is_empty() { "unnamed adapter" } else { &self.info.name },
            self.info.device_type,
            self.info.backend,
            if self.info.driver.is_empty() {
                String::new()
            } else {
                format!(", driver {} {}", self.info.driver, self.info.driver_info)
            },
            l.max_buffer_size >> 20,
            l.max_storage_buffer_binding_size >> 20,
            l.max_compute_invocations_per_workgroup,
            l.max_compute_workgroups_per_dimension,
            l.max_storage_buffers_per_shader_stage,
        )
    }

    /// A storage buffer holding `data`, readable and writable by kernels and copyable out.
    pub fn upload<T: bytemuck::Pod>(&self, label: &str, data: &[T]) -> wgpu::Buffer {
        // Zero-sized buffers are legal but bindings of them are not: keep at least 4 bytes.
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let padded;
        let contents = if bytes.len() < 4 {
            padded = [0u8; 4];
            &padded[..]
        } else {
            bytes
        };
        let buffer = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        });
        self.note_buffer(contents.len() as u64);
        buffer
    }

    /// A uniform buffer holding `value`.
    pub fn uniform<T: bytemuck::Pod>(&self, label: &str, value: &T) -> wgpu::Buffer {
        let buffer = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        self.note_buffer(std::mem::size_of::<T>() as u64);
        buffer
    }

    /// An uninitialised (zeroed) storage buffer of `len` elements of `T`, checked against the
    /// device's limits first so an oversized request is an error, not a device loss.
    pub fn storage<T: bytemuck::Pod>(&self, label: &str, len: usize) -> Result<wgpu::Buffer, GpuError> {
        let size = self.check_binding::<T>(label, len)?;
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.note_buffer(size);
        Ok(buffer)
    }

    /// The byte size of a binding of `len` elements of `T`, or an error naming the limit it
    /// breaks.
    pub fn check_binding<T>(&self, label: &str, len: usize) -> Result<u64, GpuError> {
        let size = (len as u64)
            .checked_mul(std::mem::size_of::<T>() as u64)
            .ok_or_else(|| GpuError::TooLarge(format!("{label}: {len} elements overflow")))?
            .max(4);
        let max = binding_limit(&self.limits);
        if size > max {
            return Err(GpuError::TooLarge(format!(
                "{label} needs {size} bytes; this device binds at most {max}"
            )));
        }
        Ok(size)
    }

    /// Whether the adapter is a software one (lavapipe, SwiftShader: wgpu reports a CPU device).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// How many rows of `row_bytes` fit one storage binding on this device (at least 1).
    /// Stages split their work into blocks of this many rows.
    pub fn rows_per_binding(&self, row_bytes: u64) -> usize {
        (binding_limit(&self.limits) / row_bytes.max(1)).max(1) as usize
    }

    /// A compute pipeline from WGSL source, with its bind group layout inferred.
    pub fn compute_pipeline(&self, label: &str, source: &str, entry: &str) -> wgpu::ComputePipeline {
        self.compute_pipelines(label, source, &[entry]).remove(0)
    }

    /// Pipelines for several entry points of one WGSL module, compiled once (layouts inferred
    /// per entry point). Once per device: a second call with the same source and entry points
    /// returns the same pipelines (a compile error is reported to the first caller's error
    /// scope only; our shaders are fixed text, so the first call is where a bug shows).
    pub fn compute_pipelines(&self, label: &str, source: &str, entries: &[&str]) -> Vec<wgpu::ComputePipeline> {
        let key = (source.to_string(), entries.iter().map(|e| e.to_string()).collect::<Vec<_>>());
        if let Some(built) = self.pipelines.lock().expect("pipeline cache").get(&key) {
            return built.clone();
        }
        let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        self.ledger.pipelines(entries.len());
        let built: Vec<wgpu::ComputePipeline> = entries
            .iter()
            .map(|e| {
                self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(e),
                    layout: None,
                    module: &module,
                    entry_point: Some(e),
                    compilation_options: Default::default(),
                    cache: None,
                })
            })
            .collect();
        self.pipelines.lock().expect("pipeline cache").insert(key, built.clone());
        built
    }

    /// A bind group for group 0 of `pipeline`, binding `buffers` at 0, 1, 2, ….
    pub fn bind(&self, pipeline: &wgpu::ComputePipeline, buffers: &[&wgpu::Buffer]) -> wgpu::BindGroup {
        let entries: Vec<(u32, &wgpu::Buffer)> = buffers.iter().enumerate().map(|(i, b)| (i as u32, *b)).collect();
        self.bind_at(pipeline, &entries)
    }

    /// A bind group for group 0 of `pipeline` with buffers at explicit binding indices (for
    /// shaders whose entry points use different subsets of one module's bindings).
    pub fn bind_at(&self, pipeline: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(i, b)| wgpu::BindGroupEntry { binding: *i, resource: b.as_entire_binding() })
            .collect();
        self.ledger.bind_group();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Workgroup counts covering `n` items with workgroups of `wg` invocations, folded into a
    /// second dimension when one would exceed the device's per-dimension limit.
    pub fn dispatch_linear(&self, n: u64, wg: u32) -> Result<[u32; 3], GpuError> {
        split_groups(n.div_ceil(wg as u64), self.limits.max_compute_workgroups_per_dimension)
    }

    /// Records one compute pass running `pipeline` over `groups`.
    pub fn encode_pass(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        bind_group: &wgpu::BindGroup,
        groups: [u32; 3],
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
    }

    /// A staging buffer for readbacks of up to `bytes` bytes, kept by a stage that reads back
    /// repeatedly (each chunk of a decode, each tuning step) instead of one per read.
    pub fn readback(&self, bytes: u64) -> Readback {
        let size = bytes.max(4).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.note_buffer(size);
        Readback { buffer, capacity: size }
    }

    /// Reads `len` elements of `T` from the start of `buffer` (which needs COPY_SRC), through a
    /// staging buffer made for this one read (and retired after it).
    pub async fn read<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer, len: usize) -> Result<Vec<T>, GpuError> {
        let size = (len * std::mem::size_of::<T>()) as u64;
        if size == 0 {
            return Ok(Vec::new());
        }
        let staging = self.readback(size);
        let out = self.read_via(&staging, buffer, len).await;
        self.retire([staging.buffer]);
        out
    }

    /// Destroys buffers whose work has been submitted and that nothing will bind again: a
    /// stage's scratch, a tile's planes. Natively dropping them would do; in the browser,
    /// wgpu's WebGPU backend only drops the JS handle, and the GPU process keeps the memory
    /// until the worker's garbage collector runs, which GPU memory does not prompt (wgpu issue
    /// 4092): a scene's tiles grew Chromium's GPU process by ~90 MB a minute. Work already
    /// submitted still completes (WebGPU and wgpu-core free a destroyed buffer only after it);
    /// binding one again is a validation error, not a silent one.
    pub fn retire(&self, buffers: impl IntoIterator<Item = wgpu::Buffer>) {
        let mut n = 0;
        for b in buffers {
            b.destroy();
            n += 1;
        }
        self.ledger.retired(n);
    }

    /// Reads `len` elements of `T` from the start of `buffer` through `staging`, which must
    /// hold them.
    pub async fn read_via<T: bytemuck::Pod>(&self, staging: &Readback, buffer: &wgpu::Buffer, len: usize) -> Result<Vec<T>, GpuError> {
        let size = (len * std::mem::size_of::<T>()) as u64;
        if size == 0 {
            return Ok(Vec::new());
        }
        if size > staging.capacity {
            return Err(GpuError::Readback(format!("{size} bytes do not fit a staging buffer of {}", staging.capacity)));
        }
        let staging = &staging.buffer;
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, 0, staging, 0, size);
        self.queue.submit([encoder.finish()]);

        let (signal, wait) = oneshot();
        staging.slice(..size).map_async(wgpu::MapMode::Read, move |r| signal.send(r));
        self.poll_wait();
        wait.await
            .ok_or_else(|| GpuError::Readback("the map callback was dropped".into()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let view = staging
            .slice(..size)
            .get_mapped_range()
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let out = bytemuck::cast_slice::<u8, T>(&view).to_vec();
        drop(view);
        staging.unmap();
        Ok(out)
    }

    /// Blocking readback for native code.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn read_blocking<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer, len: usize) -> Result<Vec<T>, GpuError> {
        pollster::block_on(self.read(buffer, len))
    }

    /// Runs the uploads queued so far and, natively, waits for them, so that the device frees
    /// their staging copies now: an upload's staging copy (as large as the data) otherwise
    /// lives until the next submission completes, on top of what a stage allocates next.
    pub fn flush_uploads(&self) {
        self.queue.submit([]);
        self.poll_wait();
    }

    /// Resolves once the work submitted so far is done: natively by driving the device, in the
    /// browser through the queue's `onSubmittedWorkDone` (nothing may block there). A stage
    /// timed up to here is timed whole: the page's features stage used to end at its last
    /// submission, and the GPU work it had queued (seconds on a software adapter) was counted
    /// in the next stage that read something back.
    pub async fn work_done(&self) {
        let (signal, wait) = oneshot();
        self.queue.on_submitted_work_done(move || signal.send(()));
        self.poll_wait();
        let _ = wait.await;
    }

    /// Natively, drive the device until submitted work is done; on the web the browser does it.
    pub fn poll_wait(&self) {
        #[cfg(not(target_arch = "wasm32"))]
        {
            let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
        }
    }
}

/// Each stage's peak of device memory beyond what was held when the first stage began, named
/// as the plan names its stages; nothing where the device does not count its memory.
pub struct StagePeaks<'a> {
    gpu: &'a Gpu,
    held: Option<u64>,
    pub peaks: Vec<(&'static str, u64)>,
}

impl<'a> StagePeaks<'a> {
    /// Starts the first stage.
    pub fn start(gpu: &'a Gpu) -> StagePeaks<'a> {
        gpu.begin_peak();
        StagePeaks { gpu, held: gpu.live_bytes(), peaks: Vec::new() }
    }

    /// Ends `stage` (and starts the next).
    pub fn end(&mut self, stage: &'static str) {
        if let (Some(held), Some(peak)) = (self.held, self.gpu.allocations().peak_live_bytes) {
            self.peaks.push((stage, peak.saturating_sub(held)));
        }
        self.gpu.begin_peak();
    }
}

/// A staging buffer kept for repeated readbacks ([`Gpu::readback`], [`Gpu::read_via`]).
pub struct Readback {
    buffer: wgpu::Buffer,
    capacity: u64,
}

impl Readback {
    /// Bytes it holds.
    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Its buffer, for [`Gpu::retire`] by the holder that is done with it.
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }
}

/// `v` as a `u32` (kernels index with 32 bits), or an error naming `what`.
pub fn to_u32(what: &str, v: usize) -> Result<u32, GpuError> {
    u32::try_from(v).map_err(|_| GpuError::TooLarge(format!("{what}: {v} does not fit 32 bits")))
}

/// WGSL template substitution: replaces every `{{KEY}}` placeholder of `source` by its value
/// (WGSL private arrays need constant sizes, so sizes known only at run time are pasted in).
pub fn specialise(source: &str, vars: &[(&str, usize)]) -> String {
    let mut s = source.to_string();
    for (k, v) in vars {
        s = s.replace(&format!("{{{{{k}}}}}"), &v.to_string());
    }
    debug_assert!(!s.contains("{{"), "unreplaced placeholder");
    s
}

/// Workgroup counts for `groups` groups with at most `max_per_dim` in one dimension.
pub fn split_groups(groups: u64, max_per_dim: u32) -> Result<[u32; 3], GpuError> {
    let max = max_per_dim.max(1) as u64;
    if groups <= max {
        return Ok([groups.max(1) as u32, 1, 1]);
    }
    let y = groups.div_ceil(max);
    if y > max {
        return Err(GpuError::TooLarge(format!("{groups} workgroups exceed {max}^2")));
    }
    Ok([max as u32, y as u32, 1])
}

// A single-value channel whose receiving end is a future: the map callback fires from
// `device.poll` natively and from the browser's event loop on the web, and either way the
// awaiting code resumes. (No executor-specific channel crate needed.)
struct Slot<T> {
    value: Option<T>,
    closed: bool,
    waker: Option<Waker>,
}

struct Sender<T>(Arc<Mutex<Slot<T>>>);
struct Receiver<T>(Arc<Mutex<Slot<T>>>);

fn oneshot<T>() -> (Sender<T>, Receiver<T>) {
    let slot = Arc::new(Mutex::new(Slot { value: None, closed: false, waker: None }));
    (Sender(slot.clone()), Receiver(slot))
}

impl<T> Sender<T> {
    fn send(self, value: T) {
        let mut s = self.0.lock().unwrap();
        s.value = Some(value);
        if let Some(w) = s.waker.take() {
            w.wake();
        }
    }
}

impl<T> Drop for Sender<T> {
    fn drop(&mut self) {
        let mut s = self.0.lock().unwrap();
        s.closed = true;
        if let Some(w) = s.waker.take() {
            w.wake();
        }
    }
}

impl<T> Future for Receiver<T> {
    type Output = Option<T>;
    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<T>> {
        let mut s = self.0.lock().unwrap();
        if let Some(v) = s.value.take() {
            return Poll::Ready(Some(v));
        }
        if s.closed {
            return Poll::Ready(None);
        }
        s.waker = Some(cx.waker().clone());
        Poll::Pending
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_groups_folds_into_y() {
        assert_eq!(split_groups(10, 65535).unwrap(), [10, 1, 1]);
        assert_eq!(split_groups(0, 65535).unwrap(), [1, 1, 1]);
        assert_eq!(split_groups(65536, 65535).unwrap(), [65535, 2, 1]);
        let g = split_groups(1_000_000, 65535).unwrap();
        assert!(g[0] as u64 * g[1] as u64 >= 1_000_000);
        assert!(split_groups(65535u64 * 65535 + 1, 65535).is_err());
    }
}

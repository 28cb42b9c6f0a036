//! [`GpuEngine`]: buffers, pipelines and the per-frame submission.

use std::borrow::Cow;
use std::time::{Duration, Instant};

use super::device::GpuDevice;
use super::{FLAG_DEBUG_HIST, FrameUniform, STAGES, stage_source};
use crate::likelihood::cpu;
use crate::likelihood::{
    ColourHistogram, ContrastTable, FrameInput, HIST_BINS, LiftedFeature, LikelihoodEngine,
    LikelihoodError, LikelihoodParams, Particle, TERM_COLOUR, TERM_CONTRAST, TERM_FEATURE,
    TERM_GRADIENT, TermLogs,
};

/// Invocations per workgroup of the per-particle and per-line kernels (as in the shaders).
const WG: u32 = 64;
/// Tile of the gradient-image kernel (as in the shader).
const TILE: u32 = 16;
/// Kernels in submission order.
const KERNELS: [&str; 5] = [
    "gradient_image",
    "colour",
    "gradient_lines",
    "feature",
    "combine",
];

/// How [`StageTimes`] were measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimingSource {
    /// Kernel times from GPU timestamp queries at pass boundaries, one submission.
    Timestamps,
    /// Kernel times from the wall clock, one submission and wait per kernel.
    WallClock,
}

/// Where the time of one [`GpuEngine::evaluate_timed`] call went.
#[derive(Debug, Clone, Default)]
pub struct StageTimes {
    /// Host side of the upload: packing the frame and writing frame, particles, features and
    /// uniforms into the queue's staging memory (wall clock).
    pub upload: Duration,
    /// Each kernel: `(name, time)`; a disabled stage is absent.
    pub kernels: Vec<(&'static str, Duration)>,
    /// From the end of the GPU work to the results in host memory: map and copy (wall clock).
    pub readback: Duration,
    /// The whole call (wall clock).
    pub total: Duration,
    /// How kernel times were measured (`None` before any call).
    pub source: Option<TimingSource>,
}

/// Everything the GPU computed for one frame, for tests: terms, histograms and line distances.
#[derive(Debug, Clone, Default)]
pub struct DebugOutput {
    /// Per-particle results, as [`LikelihoodEngine::evaluate`] returns them.
    pub terms: Vec<TermLogs>,
    /// Histogram counts, `HIST_BINS` per particle (empty when the colour term is disabled).
    pub histograms: Vec<u32>,
    /// Per (particle, line) the smallest |t| of an edge, [`super::NO_EDGE`] without one,
    /// [`super::SKIPPED`] for a degenerate particle (empty when the gradient term is disabled).
    pub line_distances: Vec<i32>,
}

/// Calls in a row asking a buffer of the GPU engine for under a quarter of what it holds
/// after which it is made smaller ([`GpuEngine::buffer_bytes`] says what they hold).
pub const SHRINK_AFTER_CALLS: u32 = 64;

/// Below this many bytes a buffer is never made smaller: too little memory to be worth a new
/// allocation and bind group.
const SHRINK_ABOVE_BYTES: u64 = 1 << 20;

/// A storage buffer that grows to the size asked for, and shrinks to it once
/// [`SHRINK_AFTER_CALLS`] calls in a row have asked for under a quarter of what it holds
/// (a million particles evaluated once, then 200 a frame, had kept the million's buffers,
/// about 320 MB on lavapipe, for as long as the engine lived).
struct GrowBuf {
    buf: wgpu::Buffer,
    size: u64,
    usage: wgpu::BufferUsages,
    label: &'static str,
    /// Calls in a row that asked for under a quarter of `size`.
    small_calls: u32,
    /// Whether the buffer may be one wgpu refused ([`Self::forget`]): made afresh next time.
    stale: bool,
}

impl GrowBuf {
    fn new(device: &wgpu::Device, label: &'static str, usage: wgpu::BufferUsages) -> Self {
        let size = 256;
        let buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        });
        Self {
            buf,
            size,
            usage,
            label,
            small_calls: 0,
            stale: false,
        }
    }

    /// The bytes a buffer asked to hold `bytes` is allocated with.
    fn allocated(bytes: u64) -> u64 {
        // Saturating: a size near `u64::MAX` (a count checked against the limits) stays past
        // them instead of wrapping to a small one.
        bytes
            .max(16)
            .checked_next_multiple_of(256)
            .unwrap_or(u64::MAX)
    }

    /// Makes room for `bytes`; true when the buffer was replaced (grown, or shrunk after
    /// [`SHRINK_AFTER_CALLS`] calls in a row asking for under a quarter of it). The size is
    /// recorded before wgpu says whether the allocation worked: a failed one must be
    /// [`Self::forget`]ten.
    fn ensure(&mut self, device: &wgpu::Device, bytes: u64) -> bool {
        let bytes = Self::allocated(bytes);
        if bytes <= self.size && !self.stale {
            if self.size > SHRINK_ABOVE_BYTES && bytes < self.size / 4 {
                self.small_calls += 1;
            } else {
                self.small_calls = 0;
            }
            if self.small_calls < SHRINK_AFTER_CALLS {
                return false;
            }
        }
        self.buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(self.label),
            size: bytes,
            usage: self.usage,
            mapped_at_creation: false,
        });
        self.size = bytes;
        self.small_calls = 0;
        self.stale = false;
        true
    }

    /// Has the next [`Self::ensure`] allocate the buffer afresh, whatever it asks for: after
    /// an error, this buffer may be one wgpu refused to create.
    fn forget(&mut self) {
        self.stale = true;
        self.small_calls = 0;
    }
}

struct Buffers {
    params: wgpu::Buffer,
    frame: wgpu::Buffer,
    pixels: GrowBuf,
    grad: GrowBuf,
    particles: GrowBuf,
    trig: GrowBuf,
    model: wgpu::Buffer,
    features: GrowBuf,
    terms: GrowBuf,
    line_d: GrowBuf,
    hist: GrowBuf,
    staging: GrowBuf,
}

impl Buffers {
    /// Forgets every buffer that grows ([`GrowBuf::forget`]).
    fn forget_grown(&mut self) {
        for b in [
            &mut self.pixels,
            &mut self.grad,
            &mut self.particles,
            &mut self.trig,
            &mut self.features,
            &mut self.terms,
            &mut self.line_d,
            &mut self.hist,
            &mut self.staging,
        ] {
            b.forget();
        }
    }
}

struct Timestamps {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    read: wgpu::Buffer,
}

/// What [`GpuEngine::build`] makes: the bind group layout, the pipelines in [`KERNELS`]
/// order, the buffers and the timestamp queries.
type Built = (
    wgpu::BindGroupLayout,
    Vec<wgpu::ComputePipeline>,
    Buffers,
    Option<Timestamps>,
);

/// The GPU likelihood engine: one device, pipelines and buffers created once.
pub struct GpuEngine {
    gpu: GpuDevice,
    layout: wgpu::BindGroupLayout,
    pipelines: Vec<wgpu::ComputePipeline>,
    bufs: Buffers,
    bind_group: Option<wgpu::BindGroup>,
    has_model: bool,
    /// Whether [`LikelihoodEngine::set_contrast_table`] was called.
    has_contrast: bool,
    q_sum: f32,
    timestamps: Option<Timestamps>,
    pixel_scratch: Vec<u32>,
    trig_scratch: Vec<[f32; 2]>,
}

impl std::fmt::Debug for GpuEngine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuEngine")
            .field("gpu", &self.gpu)
            .field("has_model", &self.has_model)
            .field("has_contrast", &self.has_contrast)
            .finish_non_exhaustive()
    }
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Lays `groups` workgroups out as `(x, y)` with `x, y <= max_dim` (`x * y >= groups`), or
/// `None` when even a square grid cannot hold them.
/// The rows are filled evenly, so fewer than `y` groups are spare: full rows of `max_dim`
/// left 65,534 of the 131,070 groups of 65,536 particles idle, and the colour stage 40 %
/// slower on lavapipe than at 65,535.
pub(crate) fn grid(groups: u32, max_dim: u32) -> Option<(u32, u32)> {
    if groups <= max_dim {
        return Some((groups, 1));
    }
    let y = groups.div_ceil(max_dim);
    (y <= max_dim).then(|| (groups.div_ceil(y), y))
}

/// Packs RGB8 pixels as one `u32` each: `r | g << 8 | b << 16`.
pub(crate) fn pack_pixels(raw: &[u8], out: &mut Vec<u32>) {
    out.clear();
    out.extend(
        raw.chunks_exact(3)
            .map(|p| p[0] as u32 | (p[1] as u32) << 8 | (p[2] as u32) << 16),
    );
}

/// `(sin, cos)` of each particle's `theta0 + rz` in `f32`, as the CPU twin computes them
/// (`EllipseF32::from_particle(..).theta.sin_cos()`).
pub(crate) fn particle_sin_cos(particles: &[Particle], theta0: f32, out: &mut Vec<[f32; 2]>) {
    out.clear();
    out.extend(particles.iter().map(|p| {
        let (s, c) = (theta0 + p.rz).sin_cos();
        [s, c]
    }));
}

impl GpuEngine {
    /// Opens the GPU (see [`GpuDevice::open`]: `PFTRACK_ADAPTER` picks the adapter) and builds
    /// the pipelines.
    pub fn new() -> Result<Self, LikelihoodError> {
        Self::with_device(GpuDevice::open()?)
    }

    /// Builds the engine on an opened device.
    pub fn with_device(gpu: GpuDevice) -> Result<Self, LikelihoodError> {
        if gpu.limits.max_storage_buffers_per_shader_stage < 9 {
            return Err(LikelihoodError::Gpu(format!(
                "the adapter binds {} storage buffers per stage, the engine needs 9",
                gpu.limits.max_storage_buffers_per_shader_stage
            )));
        }
        // Shaders, pipelines and buffers, built inside error scopes: a shader the driver
        // refuses is this call's error.
        let scopes = gpu.push_scopes();
        let built = Self::build(&gpu);
        let (layout, pipelines, bufs, timestamps) = gpu.pop_scopes(scopes, built)?;
        gpu.check()?;
        Ok(Self {
            gpu,
            layout,
            pipelines,
            bufs,
            bind_group: None,
            has_model: false,
            has_contrast: false,
            q_sum: 0.0,
            timestamps,
            pixel_scratch: Vec::new(),
            trig_scratch: Vec::new(),
        })
    }

    /// The engine's bind group layout, pipelines, buffers and timestamp queries.
    fn build(gpu: &GpuDevice) -> Result<Built, LikelihoodError> {
        let device = &gpu.device;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("likelihood"),
            entries: &[
                uniform_entry(0),
                uniform_entry(1),
                storage_entry(2, true),
                storage_entry(3, false),
                storage_entry(4, true),
                storage_entry(5, true),
                storage_entry(6, true),
                storage_entry(7, false),
                storage_entry(8, false),
                storage_entry(9, false),
                storage_entry(10, true),
            ],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("likelihood"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let mut by_entry = Vec::new();
        for (name, src, entries) in STAGES {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(name),
                source: wgpu::ShaderSource::Wgsl(Cow::Owned(stage_source(src))),
            });
            for e in entries {
                let p = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(e),
                    layout: Some(&pl),
                    module: &module,
                    entry_point: Some(e),
                    compilation_options: Default::default(),
                    cache: None,
                });
                by_entry.push((*e, p));
            }
        }
        let mut pipelines = Vec::new();
        for k in KERNELS {
            let i = by_entry
                .iter()
                .position(|(e, _)| *e == k)
                .ok_or_else(|| LikelihoodError::Gpu(format!("no pipeline {k}")))?;
            pipelines.push(by_entry.swap_remove(i).1);
        }
        use wgpu::BufferUsages as U;
        let uniform = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 64,
                usage: U::UNIFORM | U::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let st = U::STORAGE | U::COPY_DST;
        let bufs = Buffers {
            params: uniform("params"),
            frame: uniform("frame"),
            pixels: GrowBuf::new(device, "pixels", st),
            grad: GrowBuf::new(device, "gradient image", st),
            particles: GrowBuf::new(device, "particles", st),
            trig: GrowBuf::new(device, "particle sin cos", st),
            model: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("model"),
                // The colour model, then the contrast table.
                size: (2 * HIST_BINS * 4) as u64,
                usage: st,
                mapped_at_creation: false,
            }),
            features: GrowBuf::new(device, "features", st),
            terms: GrowBuf::new(device, "terms", st | U::COPY_SRC),
            line_d: GrowBuf::new(device, "line distances", st | U::COPY_SRC),
            hist: GrowBuf::new(device, "histograms", st | U::COPY_SRC),
            staging: GrowBuf::new(device, "readback", U::MAP_READ | U::COPY_DST),
        };
        let timestamps = gpu.timestamps.then(|| {
            let count = 2 * KERNELS.len() as u32;
            let bytes = 8 * count as u64;
            Timestamps {
                set: device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("stage timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count,
                }),
                resolve: device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("timestamp resolve"),
                    size: bytes,
                    usage: U::QUERY_RESOLVE | U::COPY_SRC,
                    mapped_at_creation: false,
                }),
                read: device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("timestamp read"),
                    size: bytes,
                    usage: U::MAP_READ | U::COPY_DST,
                    mapped_at_creation: false,
                }),
            }
        });
        Ok((layout, pipelines, bufs, timestamps))
    }

    /// The opened device (adapter description, limits).
    pub fn device(&self) -> &GpuDevice {
        &self.gpu
    }

    /// The bytes of GPU memory the buffers that follow the work's size hold now (the
    /// frame's pixels and gradients, the particles and their results, the features):
    /// they grow with the largest call and shrink again after [`SHRINK_AFTER_CALLS`] calls
    /// in a row that need under a quarter of them. The fixed buffers (uniforms, the colour
    /// model, timestamps) are not counted.
    pub fn buffer_bytes(&self) -> u64 {
        let b = &self.bufs;
        [
            &b.pixels,
            &b.grad,
            &b.particles,
            &b.trig,
            &b.features,
            &b.terms,
            &b.line_d,
            &b.hist,
            &b.staging,
        ]
        .iter()
        .map(|g| g.size)
        .sum()
    }

    /// Whether kernel times come from GPU timestamps.
    pub fn has_timestamps(&self) -> bool {
        self.timestamps.is_some()
    }

    /// Destroys the device, as a driver reset would; every later call returns
    /// [`LikelihoodError::DeviceLost`] (on an application's device, from the first
    /// evaluation on: see [`GpuDevice::destroy`]). For tests of that path.
    pub fn simulate_device_loss(&self) {
        self.gpu.destroy();
    }

    fn max_binding(&self) -> u64 {
        self.gpu
            .limits
            .max_storage_buffer_binding_size
            .min(self.gpu.limits.max_buffer_size)
    }

    /// Whether a `width × height` frame fits the adapter's buffers and dispatch limits, checked
    /// before anything is allocated.
    pub fn check_frame_size(&self, width: u32, height: u32) -> Result<(), LikelihoodError> {
        let limit = self.max_binding();
        // The gradient image (two i32 per pixel) is the largest per-frame buffer, allocated
        // rounded up.
        let bytes = GrowBuf::allocated((width as u64 * height as u64).saturating_mul(8));
        let max_dim = self.gpu.limits.max_compute_workgroups_per_dimension;
        if bytes > limit
            || width.div_ceil(TILE) > max_dim
            || height.div_ceil(TILE) > max_dim
            || width as u64 * height as u64 > u32::MAX as u64
        {
            return Err(LikelihoodError::FrameTooLarge {
                width,
                height,
                bytes,
                limit,
            });
        }
        Ok(())
    }

    fn check_particles(
        &self,
        n: usize,
        num_lines: u32,
        debug: bool,
    ) -> Result<(), LikelihoodError> {
        let limit = self.max_binding();
        let n64 = n as u64;
        // Saturating: a count near `u64::MAX` is refused, not wrapped (or a panic in a
        // debug build).
        let lines = n64.saturating_mul(num_lines as u64);
        let mut bytes = n64
            .saturating_mul(32)
            .max(lines.saturating_mul(4))
            .max(n64.saturating_add(num_lines as u64).saturating_mul(8));
        if debug {
            bytes = bytes.max(n64.saturating_mul(HIST_BINS as u64 * 4));
        }
        let bytes = GrowBuf::allocated(bytes);
        let max_dim = self.gpu.limits.max_compute_workgroups_per_dimension;
        let too_many = bytes > limit
            || lines > u32::MAX as u64 - WG as u64
            || n64 > u32::MAX as u64
            || grid(n as u32, max_dim).is_none()
            || grid((lines as u32).div_ceil(WG), max_dim).is_none();
        if too_many {
            return Err(LikelihoodError::TooManyParticles { n, bytes, limit });
        }
        Ok(())
    }

    fn check_features(&self, n: usize) -> Result<(), LikelihoodError> {
        let limit = self.max_binding();
        let bytes =
            GrowBuf::allocated((n as u64).saturating_mul(size_of::<LiftedFeature>() as u64));
        if bytes > limit || n > u32::MAX as usize {
            return Err(LikelihoodError::TooManyFeatures { n, bytes, limit });
        }
        Ok(())
    }

    /// [`LikelihoodEngine::evaluate`] that also reports where the time went.
    pub fn evaluate_timed(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
    ) -> Result<StageTimes, LikelihoodError> {
        let mut times = StageTimes::default();
        self.run(frame, params, particles, out, None, Some(&mut times))?;
        Ok(times)
    }

    /// Evaluates like [`LikelihoodEngine::evaluate`] and also reads back each particle's
    /// histogram counts and line distances (tests).
    pub fn evaluate_debug(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
    ) -> Result<DebugOutput, LikelihoodError> {
        let mut dbg = DebugOutput::default();
        let mut terms = Vec::new();
        self.run(frame, params, particles, &mut terms, Some(&mut dbg), None)?;
        dbg.terms = terms;
        Ok(dbg)
    }

    /// Evaluates the particles inside the device's error scopes
    /// ([`GpuDevice::push_scopes`]).
    fn run(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
        debug: Option<&mut DebugOutput>,
        timing: Option<&mut StageTimes>,
    ) -> Result<(), LikelihoodError> {
        self.gpu.check()?;
        // Input the engine refuses is refused before any GPU work, and leaves its buffers
        // as they are.
        self.check_input(frame, params, particles.len(), debug.is_some())?;
        let scopes = self.gpu.push_scopes();
        let result = self.run_scoped(frame, params, particles, out, debug, timing);
        let result = self
            .gpu
            .pop_scopes(scopes, result)
            .and_then(|()| self.gpu.check());
        if result.is_err() {
            // A buffer grown in this call may be one wgpu refused (out of memory on a device
            // shared with the application), and the bind group may hold it: both are made
            // afresh on the next call rather than failing every call from now on.
            self.bufs.forget_grown();
            self.bind_group = None;
        }
        result
    }

    /// The checks of the input before any GPU work: the CPU engine's ([`cpu::validate`]),
    /// so the same errors, then the model and table the terms on need, and the sizes the
    /// buffers can hold.
    fn check_input(
        &self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        n: usize,
        debug: bool,
    ) -> Result<(), LikelihoodError> {
        cpu::validate(frame, params)?;
        if params.terms & TERM_COLOUR != 0 && !self.has_model {
            return Err(LikelihoodError::NoModel);
        }
        if params.terms & TERM_CONTRAST != 0 && !self.has_contrast {
            return Err(LikelihoodError::NoContrastTable);
        }
        let (w, h) = frame.image.dimensions();
        self.check_frame_size(w, h)?;
        self.check_particles(n, gradient_lines(params), debug)?;
        if params.terms & TERM_FEATURE != 0 && !frame.features.is_empty() {
            self.check_features(frame.features.len())?;
        }
        Ok(())
    }

    /// One evaluation, inside the error scopes [`Self::run`] opened: the buffers made ready,
    /// the inputs uploaded, the kernels dispatched, the terms read back, and on request each
    /// particle's histogram and line distances and the stages' times.
    fn run_scoped(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
        debug: Option<&mut DebugOutput>,
        timing: Option<&mut StageTimes>,
    ) -> Result<(), LikelihoodError> {
        let t_start = Instant::now();
        out.clear();
        if particles.is_empty() {
            return Ok(());
        }
        let pass = Pass::new(frame, params, particles.len(), debug.is_some());
        self.prepare_buffers(frame, &pass);
        self.upload(frame, params, particles, &pass);
        let t_uploaded = Instant::now();
        let dispatches = self.dispatches(&pass)?;
        let timed = timing.is_some();
        let kernel_wall = self.dispatch(&pass, &dispatches, timed)?;
        let t_gpu_done = Instant::now();
        let terms_bytes = pass.n as u64 * pass.logs;
        read_into(
            &self.gpu.device,
            &self.bufs.staging.buf,
            terms_bytes,
            |bytes| {
                out.extend_from_slice(bytemuck::cast_slice::<u8, TermLogs>(bytes));
            },
        )?;
        let t_read = Instant::now();
        if let Some(dbg) = debug {
            self.read_debug(&pass, dbg)?;
        }
        if let Some(times) = timing {
            times.upload = t_uploaded - t_start;
            times.readback = t_read - t_gpu_done;
            self.read_times(&dispatches, kernel_wall, times)?;
            times.total = t_start.elapsed();
        }
        Ok(())
    }

    /// Grows the buffers `pass` needs (a term that is off leaves its own as they are) and
    /// makes the bind group afresh where one was replaced.
    fn prepare_buffers(&mut self, frame: &FrameInput<'_>, pass: &Pass) {
        let device = &self.gpu.device;
        let b = &mut self.bufs;
        let (px, n64, lines) = (
            u64::from(pass.w) * u64::from(pass.h),
            pass.n as u64,
            u64::from(pass.num_lines),
        );
        let mut changed = false;
        changed |= b.pixels.ensure(device, px * 4);
        changed |= b.grad.ensure(device, px * 8);
        changed |= b.particles.ensure(device, n64 * 32);
        changed |= b.trig.ensure(device, (n64 + lines) * 8);
        // Only a term that reads them grows the features' buffer (unchecked size otherwise);
        // it is still ensured, so a buffer forgotten after a refusal is made afresh.
        let feature_bytes = if pass.feat_on {
            frame.features.len() as u64 * size_of::<LiftedFeature>() as u64
        } else {
            0
        };
        changed |= b.features.ensure(device, feature_bytes);
        changed |= b.terms.ensure(device, n64 * pass.logs);
        changed |= b.line_d.ensure(device, n64 * lines * 4);
        changed |= b.hist.ensure(device, pass.hist_bytes);
        b.staging.ensure(
            device,
            (n64 * pass.logs).max(pass.hist_bytes).max(pass.line_bytes),
        );
        if changed || self.bind_group.is_none() {
            fn entry(binding: u32, buf: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
                wgpu::BindGroupEntry {
                    binding,
                    resource: buf.as_entire_binding(),
                }
            }
            self.bind_group = Some(device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("likelihood"),
                layout: &self.layout,
                entries: &[
                    entry(0, &b.params),
                    entry(1, &b.frame),
                    entry(2, &b.pixels.buf),
                    entry(3, &b.grad.buf),
                    entry(4, &b.particles.buf),
                    entry(5, &b.model),
                    entry(6, &b.features.buf),
                    entry(7, &b.terms.buf),
                    entry(8, &b.line_d.buf),
                    entry(9, &b.hist.buf),
                    entry(10, &b.trig.buf),
                ],
            }));
        }
    }

    /// Uploads the uniforms, the frame's pixels (for the colour and contour terms), the
    /// particles with their orientations' and the normal lines' `(sin, cos)`, and the
    /// features lifted onto the previous estimate's model.
    fn upload(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        pass: &Pass,
    ) {
        let (queue, b) = (&self.gpu.queue, &self.bufs);
        let fu = FrameUniform {
            prev: frame.prev,
            width: pass.w,
            height: pass.h,
            n: pass.n as u32,
            num_features: frame.features.len() as u32,
            theta0: frame.theta0,
            line_h: cpu::gradient::half_samples(params),
            flags: if pass.debug { FLAG_DEBUG_HIST } else { 0 },
            q_sum: self.q_sum,
        };
        queue.write_buffer(&b.params, 0, bytemuck::bytes_of(params));
        queue.write_buffer(&b.frame, 0, bytemuck::bytes_of(&fu));
        if pass.hist_on || pass.grad_on {
            pack_pixels(
                crate::frames::rgb_bytes(frame.image),
                &mut self.pixel_scratch,
            );
            queue.write_buffer(&b.pixels.buf, 0, bytemuck::cast_slice(&self.pixel_scratch));
        }
        queue.write_buffer(&b.particles.buf, 0, bytemuck::cast_slice(particles));
        if pass.hist_on || pass.grad_on {
            particle_sin_cos(particles, frame.theta0, &mut self.trig_scratch);
            // The normal lines' angles, the CPU's own (see common.wgsl).
            self.trig_scratch.extend(
                cpu::gradient::line_angles(pass.num_lines)
                    .into_iter()
                    .map(|(c, s)| [s, c]),
            );
            queue.write_buffer(&b.trig.buf, 0, bytemuck::cast_slice(&self.trig_scratch));
        }
        if pass.feat_on {
            // The lift does not depend on the particle: done once here, as the CPU twin does.
            let lifted = cpu::feature::FeatureFrame::new(
                frame.features,
                frame.depths,
                &frame.prev,
                frame.theta0,
                params,
            )
            .lifted;
            queue.write_buffer(&b.features.buf, 0, bytemuck::cast_slice(&lifted));
        }
    }

    /// Each kernel of [`KERNELS`] with whether it runs and its workgroup grid.
    fn dispatches(&self, pass: &Pass) -> Result<Dispatches, LikelihoodError> {
        let n = pass.n;
        let max_dim = self.gpu.limits.max_compute_workgroups_per_dimension;
        let too_many = || LikelihoodError::TooManyParticles {
            n,
            bytes: 0,
            limit: 0,
        };
        let per_particle = grid((n as u32).div_ceil(WG), max_dim).ok_or_else(too_many)?;
        Ok([
            (pass.grad_on, (pass.w.div_ceil(TILE), pass.h.div_ceil(TILE))),
            (pass.hist_on, grid(n as u32, max_dim).ok_or_else(too_many)?),
            (
                pass.grad_on,
                grid((n as u32 * pass.num_lines).div_ceil(WG), max_dim).ok_or_else(too_many)?,
            ),
            (pass.feat_on, per_particle),
            (true, per_particle),
        ])
    }

    /// Runs the kernels that are on, copies the terms to the staging buffer (and resolves the
    /// timestamps, when `timed` and the device has them), and waits for the GPU. Timed on a
    /// device without timestamps, each kernel is submitted and waited for on its own, and
    /// their wall-clock times are returned.
    fn dispatch(
        &mut self,
        pass: &Pass,
        dispatches: &Dispatches,
        timed: bool,
    ) -> Result<Vec<(&'static str, Duration)>, LikelihoodError> {
        let (device, queue, b) = (&self.gpu.device, &self.gpu.queue, &self.bufs);
        let bind_group = self
            .bind_group
            .as_ref()
            .ok_or_else(|| LikelihoodError::Gpu("no bind group".into()))?;
        let wall_mode = timed && self.timestamps.is_none();
        let ts = if timed {
            self.timestamps.as_ref()
        } else {
            None
        };
        let mut kernel_wall = Vec::new();
        let mut encoder = device.create_command_encoder(&Default::default());
        for (k, (on, (gx, gy))) in dispatches.iter().enumerate() {
            if !on || *gx == 0 || *gy == 0 {
                continue;
            }
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some(KERNELS[k]),
                    timestamp_writes: ts.map(|t| wgpu::ComputePassTimestampWrites {
                        query_set: &t.set,
                        beginning_of_pass_write_index: Some(2 * k as u32),
                        end_of_pass_write_index: Some(2 * k as u32 + 1),
                    }),
                });
                pass.set_pipeline(&self.pipelines[k]);
                pass.set_bind_group(0, bind_group, &[]);
                pass.dispatch_workgroups(*gx, *gy, 1);
            }
            if wall_mode {
                let t0 = Instant::now();
                let done = std::mem::replace(
                    &mut encoder,
                    device.create_command_encoder(&Default::default()),
                );
                queue.submit([done.finish()]);
                wait(device)?;
                kernel_wall.push((KERNELS[k], t0.elapsed()));
            }
        }
        let terms_bytes = pass.n as u64 * pass.logs;
        encoder.copy_buffer_to_buffer(&b.terms.buf, 0, &b.staging.buf, 0, terms_bytes);
        if let Some(t) = ts {
            let count = 2 * KERNELS.len() as u32;
            encoder.resolve_query_set(&t.set, 0..count, &t.resolve, 0);
            encoder.copy_buffer_to_buffer(&t.resolve, 0, &t.read, 0, 8 * count as u64);
        }
        queue.submit([encoder.finish()]);
        wait(device)?;
        Ok(kernel_wall)
    }

    /// Reads back each particle's histogram counts and line distances into `dbg`.
    fn read_debug(&self, pass: &Pass, dbg: &mut DebugOutput) -> Result<(), LikelihoodError> {
        let (device, queue, b) = (&self.gpu.device, &self.gpu.queue, &self.bufs);
        dbg.histograms.clear();
        dbg.line_distances.clear();
        for (on, src, bytes) in [
            (pass.hist_on, 0, pass.hist_bytes),
            (pass.grad_on, 1, pass.line_bytes),
        ] {
            if !on || bytes == 0 {
                continue;
            }
            let from = if src == 0 { &b.hist.buf } else { &b.line_d.buf };
            let mut enc = device.create_command_encoder(&Default::default());
            enc.copy_buffer_to_buffer(from, 0, &b.staging.buf, 0, bytes);
            queue.submit([enc.finish()]);
            wait(device)?;
            read_into(device, &b.staging.buf, bytes, |raw| {
                if src == 0 {
                    dbg.histograms
                        .extend_from_slice(bytemuck::cast_slice::<u8, u32>(raw));
                } else {
                    dbg.line_distances
                        .extend_from_slice(bytemuck::cast_slice::<u8, i32>(raw));
                }
            })?;
        }
        Ok(())
    }

    /// Each kernel's time into `times`: from the device's timestamps where it has them, else
    /// the wall-clock times [`Self::dispatch`] took.
    fn read_times(
        &self,
        dispatches: &Dispatches,
        kernel_wall: Vec<(&'static str, Duration)>,
        times: &mut StageTimes,
    ) -> Result<(), LikelihoodError> {
        times.kernels.clear();
        if let Some(t) = &self.timestamps {
            let count = 2 * KERNELS.len() as u64;
            let period = self.gpu.queue.get_timestamp_period() as f64;
            let mut stamps = Vec::new();
            read_into(&self.gpu.device, &t.read, 8 * count, |raw| {
                stamps.extend_from_slice(bytemuck::cast_slice::<u8, u64>(raw));
            })?;
            for (k, (on, (gx, gy))) in dispatches.iter().enumerate() {
                if *on && *gx > 0 && *gy > 0 {
                    let ns = stamps[2 * k + 1].saturating_sub(stamps[2 * k]) as f64 * period;
                    times
                        .kernels
                        .push((KERNELS[k], Duration::from_nanos(ns as u64)));
                }
            }
            times.source = Some(TimingSource::Timestamps);
        } else {
            times.kernels = kernel_wall;
            times.source = Some(TimingSource::WallClock);
        }
        Ok(())
    }
}

/// Each kernel of [`KERNELS`], in order: whether it runs, and its workgroup grid.
type Dispatches = [(bool, (u32, u32)); 5];

/// What one evaluation runs: the terms that are on, and the sizes that follow from them.
struct Pass {
    /// Particles.
    n: usize,
    /// The frame's size.
    w: u32,
    /// See `w`.
    h: u32,
    /// Normal lines per particle (0: the contour term is off).
    num_lines: u32,
    /// The contour term.
    grad_on: bool,
    /// The feature term, on with features to project.
    feat_on: bool,
    /// The colour kernel, which builds the histogram both the colour and contrast terms read.
    hist_on: bool,
    /// Each particle's histogram and line distances are read back.
    debug: bool,
    /// Bytes of the histograms read back (0 without `debug` or the histogram).
    hist_bytes: u64,
    /// Bytes of the line distances read back (0 without `debug`).
    line_bytes: u64,
    /// Bytes of one particle's terms.
    logs: u64,
}

impl Pass {
    fn new(frame: &FrameInput<'_>, params: &LikelihoodParams, n: usize, debug: bool) -> Self {
        let colour_on = params.terms & TERM_COLOUR != 0;
        let num_lines = gradient_lines(params);
        let contrast_on = params.terms & TERM_CONTRAST != 0;
        let hist_on = colour_on || contrast_on;
        let n64 = n as u64;
        let (w, h) = frame.image.dimensions();
        Self {
            n,
            w,
            h,
            num_lines,
            grad_on: num_lines > 0,
            feat_on: params.terms & TERM_FEATURE != 0 && !frame.features.is_empty(),
            hist_on,
            debug,
            hist_bytes: if debug && hist_on {
                n64 * HIST_BINS as u64 * 4
            } else {
                0
            },
            line_bytes: if debug {
                n64 * u64::from(num_lines) * 4
            } else {
                0
            },
            logs: size_of::<TermLogs>() as u64,
        }
    }
}

/// Waits for all submitted work.
fn wait(device: &wgpu::Device) -> Result<(), LikelihoodError> {
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map(|_| ())
        .map_err(|e| LikelihoodError::DeviceLost(format!("waiting for the GPU: {e}")))
}

/// Maps the first `bytes` of a MAP_READ buffer, hands them to `f`, unmaps.
fn read_into(
    device: &wgpu::Device,
    buf: &wgpu::Buffer,
    bytes: u64,
    f: impl FnOnce(&[u8]),
) -> Result<(), LikelihoodError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buf.map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
        let _ = tx.send(r);
    });
    wait(device)?;
    rx.recv()
        .map_err(|_| LikelihoodError::DeviceLost("mapping callback dropped".into()))?
        .map_err(|e| LikelihoodError::DeviceLost(format!("mapping the readback buffer: {e}")))?;
    {
        let view = buf
            .get_mapped_range(0..bytes)
            .map_err(|e| LikelihoodError::Gpu(format!("reading the readback buffer: {e}")))?;
        f(&view);
    }
    buf.unmap();
    Ok(())
}

impl LikelihoodEngine for GpuEngine {
    fn name(&self) -> String {
        self.gpu.name()
    }

    fn set_colour_model(&mut self, model: &ColourHistogram) -> Result<(), LikelihoodError> {
        self.gpu.check()?;
        // Same checks as the CPU engine, and the same f32 sum in bin order.
        let q_sum = cpu::colour::Model::checked(&model.0)?.q_sum;
        let scopes = self.gpu.push_scopes();
        self.gpu
            .queue
            .write_buffer(&self.bufs.model, 0, bytemuck::cast_slice(&model.0));
        self.gpu.pop_scopes(scopes, Ok(()))?;
        self.q_sum = q_sum;
        self.has_model = true;
        Ok(())
    }

    fn set_contrast_table(&mut self, table: &ContrastTable) -> Result<(), LikelihoodError> {
        self.gpu.check()?;
        table.check()?;
        let scopes = self.gpu.push_scopes();
        self.gpu.queue.write_buffer(
            &self.bufs.model,
            (HIST_BINS * 4) as u64,
            bytemuck::cast_slice(&table.0),
        );
        self.gpu.pop_scopes(scopes, Ok(()))?;
        self.has_contrast = true;
        Ok(())
    }

    fn evaluate(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
    ) -> Result<(), LikelihoodError> {
        self.run(frame, params, particles, out, None, None)
    }

    fn check_capacity(
        &self,
        particles: usize,
        width: u32,
        height: u32,
        params: &LikelihoodParams,
    ) -> Result<(), LikelihoodError> {
        self.check_frame_size(width, height)?;
        self.check_particles(particles, gradient_lines(params), false)
    }
}

/// The normal lines a pass evaluates per particle: `num_lines` with the gradient term on, 0
/// without (what sizes the line buffers and the line grid).
fn gradient_lines(params: &LikelihoodParams) -> u32 {
    if params.terms & TERM_GRADIENT != 0 {
        params.num_lines
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_covers_every_group_within_the_limit() {
        assert_eq!(grid(0, 65535), Some((0, 1)));
        assert_eq!(grid(65535, 65535), Some((65535, 1)));
        let (x, y) = grid(70000, 65535).unwrap();
        assert!(x <= 65535 && y <= 65535 && x as u64 * y as u64 >= 70000);
        assert_eq!((x, y), (35000, 2));
        // Fewer spare groups than rows, at every count past one row.
        for g in [65536, 65537, 131070, 131071, 200_000, 65535 * 65535] {
            let (x, y) = grid(g, 65535).unwrap();
            assert!(x <= 65535 && y <= 65535, "{g}: {x}x{y}");
            let total = x as u64 * y as u64;
            assert!(
                total >= g as u64 && total - (g as u64) < y as u64,
                "{g}: {x}x{y}"
            );
        }
        assert_eq!(grid(u32::MAX, 100), None);
    }

    #[test]
    fn pixels_pack_as_r_g_b_bytes_of_a_word() {
        let mut out = Vec::new();
        pack_pixels(&[1, 2, 3, 255, 0, 128], &mut out);
        assert_eq!(out, vec![0x030201, 0x8000ff]);
    }
}

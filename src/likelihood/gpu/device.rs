//! The wgpu instance, adapter and device of one engine (Vulkan only).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use crate::likelihood::LikelihoodError;

/// Environment variable that picks an adapter by a substring of its name.
pub const ADAPTER_ENV: &str = "PFTRACK_ADAPTER";

/// An opened GPU: adapter, device and queue, with what the adapter offers.
pub struct GpuDevice {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter's description.
    pub info: wgpu::AdapterInfo,
    /// The limits the device was created with (the adapter's own).
    pub limits: wgpu::Limits,
    /// Whether timestamp queries (at pass boundaries) are enabled.
    pub timestamps: bool,
    lost: Arc<Mutex<Option<String>>>,
    uncaptured: Arc<Mutex<Option<String>>>,
    lost_flag: Arc<AtomicBool>,
}

/// wgpu's multi-line error text (`Validation Error`, `Caused by:`, the cause indented) as one
/// line, its lines joined by `: `.
fn one_line(text: &str) -> String {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && *l != "Caused by:")
        .collect::<Vec<_>>()
        .join(": ")
}

/// The error scopes of [`GpuDevice::push_scopes`]. Fields drop in declaration order, the
/// reverse of the pushing, so an unwind that drops them unpopped keeps wgpu's order.
pub(crate) struct Scopes {
    internal: wgpu::ErrorScopeGuard,
    memory: wgpu::ErrorScopeGuard,
    validation: wgpu::ErrorScopeGuard,
}

impl Scopes {
    /// Ends the scopes, in the reverse order of their pushing as wgpu requires: the first
    /// error they caught, if any.
    fn pop(self) -> Option<wgpu::Error> {
        let Scopes {
            internal,
            memory,
            validation,
        } = self;
        [internal.pop(), memory.pop(), validation.pop()]
            .into_iter()
            .find_map(pollster::block_on)
    }
}

impl std::fmt::Debug for GpuDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuDevice")
            .field("adapter", &describe(&self.info))
            .field("timestamps", &self.timestamps)
            .field("lost", &self.is_lost())
            .finish_non_exhaustive()
    }
}

fn vulkan_instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN;
    wgpu::Instance::new(desc)
}

fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type)
}

/// The adapter `PFTRACK_ADAPTER` names (a substring of its name), when set and not empty.
pub fn named_adapter() -> Option<String> {
    std::env::var(ADAPTER_ENV).ok().filter(|s| !s.is_empty())
}

/// Names of the Vulkan adapters on this machine (empty when there is no Vulkan driver).
pub fn adapter_names() -> Vec<String> {
    let instance = vulkan_instance();
    pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN))
        .iter()
        .map(|a| describe(&a.get_info()))
        .collect()
}

/// Picks the adapter: the first whose name contains `wanted` (case-insensitive) when given,
/// else the first discrete GPU, integrated GPU, other, CPU, in that order.
fn pick_adapter(
    adapters: Vec<wgpu::Adapter>,
    wanted: Option<&str>,
) -> Result<wgpu::Adapter, LikelihoodError> {
    if adapters.is_empty() {
        // An adapter asked for by name is missing whether or not others are there: `auto`
        // reports it rather than going on on the CPU, as it does when other adapters exist.
        return Err(match wanted {
            Some(w) => LikelihoodError::AdapterNotFound {
                wanted: w.to_string(),
                available: Vec::new(),
            },
            None => LikelihoodError::NoAdapter,
        });
    }
    if let Some(w) = wanted {
        let lw = w.to_lowercase();
        let names: Vec<String> = adapters.iter().map(|a| describe(&a.get_info())).collect();
        return adapters
            .into_iter()
            .find(|a| a.get_info().name.to_lowercase().contains(&lw))
            .ok_or_else(|| LikelihoodError::AdapterNotFound {
                wanted: w.to_string(),
                available: names,
            });
    }
    let rank = |t: wgpu::DeviceType| match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    adapters
        .into_iter()
        .min_by_key(|a| rank(a.get_info().device_type))
        .ok_or(LikelihoodError::NoAdapter)
}

/// Whether an automatic choice (`hardware`) refuses the picked adapter: it renders on the CPU
/// and the user did not name it.
fn refuses_software(hardware: bool, named: bool, device_type: wgpu::DeviceType) -> bool {
    hardware && !named && device_type == wgpu::DeviceType::Cpu
}

impl GpuDevice {
    /// Opens the adapter chosen by `PFTRACK_ADAPTER` (a substring of its name) or the best
    /// Vulkan adapter, with the adapter's own limits and, when offered, timestamp queries.
    pub fn open() -> Result<Self, LikelihoodError> {
        Self::open_matching(named_adapter().as_deref())
    }

    /// Opens the first Vulkan adapter whose name contains `wanted`, or the best one.
    pub fn open_matching(wanted: Option<&str>) -> Result<Self, LikelihoodError> {
        Self::open_with(wanted, false)
    }

    /// Like [`Self::open_matching`], but without `wanted` a best adapter that renders in
    /// software on the CPU (lavapipe, SwiftShader) is refused with
    /// [`LikelihoodError::SoftwareAdapter`] before any device is created: the CPU engine is
    /// faster than such an adapter (lavapipe trails it 2.4-12 times on the likelihood pass).
    /// A named adapter is opened whatever it is. This is what `--backend auto` opens.
    pub fn open_hardware(wanted: Option<&str>) -> Result<Self, LikelihoodError> {
        Self::open_with(wanted, true)
    }

    fn open_with(wanted: Option<&str>, hardware: bool) -> Result<Self, LikelihoodError> {
        let instance = vulkan_instance();
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN));
        let adapter = pick_adapter(adapters, wanted)?;
        let info = adapter.get_info();
        if refuses_software(hardware, wanted.is_some(), info.device_type) {
            return Err(LikelihoodError::SoftwareAdapter {
                name: describe(&info),
            });
        }
        if info.backend != wgpu::Backend::Vulkan {
            return Err(LikelihoodError::NoAdapter);
        }
        let limits = adapter.limits();
        let offered = adapter.features();
        let timestamps = offered.contains(wgpu::Features::TIMESTAMP_QUERY);
        let mut features = wgpu::Features::empty();
        if timestamps {
            features |= wgpu::Features::TIMESTAMP_QUERY;
            if offered.contains(wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES) {
                features |= wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES;
            }
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("pftrack likelihood"),
            required_features: features,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| LikelihoodError::Gpu(format!("requesting a device: {e}")))?;
        Ok(Self::wrap(device, queue, info, limits, timestamps, true))
    }

    /// Wraps a device the application opened itself (with the `wgpu` this crate re-exports,
    /// [`crate::wgpu`]), so that an engine ([`crate::likelihood::gpu::GpuEngine::with_device`])
    /// runs on it instead of opening its own. The device keeps the limits and features it was
    /// created with (the engine needs 9 storage buffers per shader stage, and uses timestamp
    /// queries when they are on).
    ///
    /// The application's device-lost callback and uncaptured-error handler stay as they were
    /// (wgpu keeps one of each per device): the engine installs neither. It catches the errors
    /// of its own work in wgpu error scopes pushed around each of its calls, on the calling
    /// thread, and returns them as that call's [`LikelihoodError`]; it sees a lost device when
    /// a call's work fails (an upload to a buffer made since the loss, a readback) and the
    /// device, asked, is lost, and returns [`LikelihoodError::DeviceLost`] from then on.
    /// Tested on Vulkan, the one backend this crate builds wgpu with.
    pub fn from_wgpu(device: wgpu::Device, queue: wgpu::Queue) -> Self {
        let info = device.adapter_info();
        let limits = device.limits();
        let timestamps = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        Self::wrap(device, queue, info, limits, timestamps, false)
    }

    /// The device, with the engine's lost-device and error handlers installed when
    /// `install` (a device the engine opened, whose handlers no one else sets).
    fn wrap(
        device: wgpu::Device,
        queue: wgpu::Queue,
        info: wgpu::AdapterInfo,
        limits: wgpu::Limits,
        timestamps: bool,
        install: bool,
    ) -> Self {
        let lost = Arc::new(Mutex::new(None));
        let lost_flag = Arc::new(AtomicBool::new(false));
        let uncaptured = Arc::new(Mutex::new(None));
        if install {
            let lost = lost.clone();
            let flag = lost_flag.clone();
            device.set_device_lost_callback(move |reason, msg| {
                flag.store(true, Ordering::SeqCst);
                if let Ok(mut l) = lost.lock() {
                    *l = Some(if msg.is_empty() {
                        format!("{reason:?}")
                    } else {
                        format!("{reason:?}: {msg}")
                    });
                }
            });
            // Errors outside the engine's error scopes become typed errors of the next call,
            // not panics (wgpu's default handler panics).
            let uncaptured = uncaptured.clone();
            device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
                if let Ok(mut u) = uncaptured.lock() {
                    u.get_or_insert_with(|| e.to_string());
                }
            }));
        }
        Self {
            device,
            queue,
            info,
            limits,
            timestamps,
            lost,
            uncaptured,
            lost_flag,
        }
    }

    /// `adapter name (backend)`, e.g. `llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan)`.
    pub fn name(&self) -> String {
        format!("{} ({:?})", self.info.name, self.info.backend)
    }

    /// An error if the device was lost or an uncaptured wgpu error happened since the last
    /// check (which clears the latter). On a device from [`Self::from_wgpu`] the engine
    /// installs no handlers: there a loss shows once a call's work failed on it, and
    /// uncaptured errors go to the application's handler.
    pub fn check(&self) -> Result<(), LikelihoodError> {
        if self.lost_flag.load(Ordering::SeqCst) {
            let msg = self
                .lost
                .lock()
                .ok()
                .and_then(|l| l.clone())
                .unwrap_or_default();
            return Err(LikelihoodError::DeviceLost(msg));
        }
        if let Some(e) = self.uncaptured.lock().ok().and_then(|mut u| u.take()) {
            return Err(LikelihoodError::Gpu(e));
        }
        Ok(())
    }

    /// Pushes wgpu error scopes for validation, out-of-memory and internal errors on this
    /// thread, around a piece of the engine's work; [`Self::pop_scopes`] ends them. An error of
    /// that work so becomes the typed error of the engine's call and never reaches the device's
    /// uncaptured-error handler (the application's, on a device from [`Self::from_wgpu`]).
    pub(crate) fn push_scopes(&self) -> Scopes {
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let internal = self.device.push_error_scope(wgpu::ErrorFilter::Internal);
        Scopes {
            internal,
            memory,
            validation,
        }
    }

    /// Ends the scopes of [`Self::push_scopes`]: the work's `result`, or the wgpu error they
    /// caught. A [`LikelihoodError::DeviceLost`] marks the device lost, so that every later
    /// [`Self::check`] fails.
    pub(crate) fn pop_scopes<T>(
        &self,
        scopes: Scopes,
        result: Result<T, LikelihoodError>,
    ) -> Result<T, LikelihoodError> {
        let caught = scopes.pop();
        // An error the scopes caught is the cause: a buffer wgpu refused also fails its
        // mapping, which the readback reports as a lost device, and the device is not lost.
        // Unless the device is lost: then a buffer made since is invalid, and writing to it
        // is a validation error the scopes catch (the frame's features, uploaded before any
        // readback), which must read as the lost device a fallback acts on.
        let result = match (result, caught) {
            (_, Some(e)) if self.is_lost() || self.probe_lost() => {
                Err(LikelihoodError::DeviceLost(format!(
                    "{} (the device is lost)",
                    one_line(&e.to_string())
                )))
            }
            (_, Some(wgpu::Error::OutOfMemory { .. })) => Err(LikelihoodError::Gpu(
                "the GPU ran out of memory".to_string(),
            )),
            (_, Some(e)) => Err(LikelihoodError::Gpu(one_line(&e.to_string()))),
            (result, None) => result,
        };
        if let Err(LikelihoodError::DeviceLost(msg)) = &result {
            if let Ok(mut l) = self.lost.lock() {
                l.get_or_insert_with(|| msg.clone());
            }
            self.lost_flag.store(true, Ordering::SeqCst);
        }
        result
    }

    /// Whether the device is lost, asked of the device itself: a small buffer, valid on any
    /// device, made and mapped for reading, which fails only on a lost one (out of memory
    /// aside, which is not a loss). Its own errors go to error scopes of its own, not to the
    /// device's handler. Run where the engine's work failed, never on the way of a call that
    /// succeeds. Where the engine installed the device-lost callback, the poll also runs it.
    fn probe_lost(&self) -> bool {
        let scopes = self.push_scopes();
        let probe = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pftrack lost-device probe"),
            size: 4,
            usage: wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let (tx, rx) = std::sync::mpsc::channel();
        probe.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r.is_ok());
        });
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
        let mapped = rx.try_recv().unwrap_or(false);
        match scopes.pop() {
            // Out of memory is no loss: the device is there, full.
            Some(wgpu::Error::OutOfMemory { .. }) => false,
            Some(_) => true,
            None => !mapped,
        }
    }

    /// Whether the device has been lost.
    pub fn is_lost(&self) -> bool {
        self.lost_flag.load(Ordering::SeqCst)
    }

    /// Destroys the device (as a driver reset would): every later engine call fails with
    /// [`LikelihoodError::DeviceLost`], from the next one on a device the engine opened and
    /// from the first whose work fails on it (an upload, a readback) on one from
    /// [`Self::from_wgpu`], which has no device-lost callback of the engine's. For tests of the
    /// lost-device path.
    pub fn destroy(&self) {
        self.device.destroy();
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_an_automatic_choice_refuses_a_software_adapter() {
        use wgpu::DeviceType as T;
        assert!(refuses_software(true, false, T::Cpu));
        assert!(!refuses_software(true, true, T::Cpu), "named: opened");
        assert!(
            !refuses_software(false, false, T::Cpu),
            "open_matching: opened"
        );
        for t in [T::DiscreteGpu, T::IntegratedGpu, T::VirtualGpu, T::Other] {
            assert!(!refuses_software(true, false, t), "{t:?}");
        }
    }

    #[test]
    fn a_named_adapter_is_missing_even_where_there_is_none() {
        // No adapter at all: an unnamed choice is NoAdapter (auto goes on on the CPU), a
        // named one is the name's error (auto reports it, as it does beside other adapters).
        assert!(matches!(
            pick_adapter(Vec::new(), None),
            Err(LikelihoodError::NoAdapter)
        ));
        match pick_adapter(Vec::new(), Some("nvidia")) {
            Err(e @ LikelihoodError::AdapterNotFound { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains("\"nvidia\"")
                        && msg.ends_with("available: none (no Vulkan driver is installed)"),
                    "{msg}"
                );
            }
            other => panic!("{:?}", other.map(|a| a.get_info())),
        }
    }

    /// A device on any Vulkan adapter (lavapipe in CI), or `None` where there is none and
    /// `PFTRACK_REQUIRE_GPU=1` is not set.
    fn any_device() -> Option<GpuDevice> {
        match GpuDevice::open_matching(None) {
            Ok(d) => Some(d),
            Err(e) if std::env::var("PFTRACK_REQUIRE_GPU").as_deref() == Ok("1") => {
                panic!("PFTRACK_REQUIRE_GPU=1 but no device: {e}")
            }
            Err(_) => None,
        }
    }

    /// A buffer wgpu refuses also fails its mapping, which the readback reports as a lost
    /// device: the scopes' error wins, and the device is not marked lost. A lost-device error
    /// with nothing caught stands, and marks it.
    #[test]
    fn a_caught_error_is_the_cause_not_a_lost_device() {
        let Some(gpu) = any_device() else { return };
        let scopes = gpu.push_scopes();
        let _refused = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("refused"),
            size: gpu.limits.max_buffer_size.saturating_add(1 << 20),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mapping = Err::<(), _>(LikelihoodError::DeviceLost("mapping failed".into()));
        let r = gpu.pop_scopes(scopes, mapping);
        let Err(LikelihoodError::Gpu(msg)) = &r else {
            panic!("{r:?}")
        };
        assert!(msg.contains("refused"), "{msg}");
        assert!(!gpu.is_lost());
        assert!(gpu.check().is_ok());

        let scopes = gpu.push_scopes();
        let lost = Err::<(), _>(LikelihoodError::DeviceLost("gone".into()));
        let r = gpu.pop_scopes(scopes, lost);
        assert!(matches!(r, Err(LikelihoodError::DeviceLost(_))), "{r:?}");
        assert!(gpu.is_lost());
        assert!(matches!(gpu.check(), Err(LikelihoodError::DeviceLost(_))));
    }

    #[test]
    fn wgpu_errors_read_as_one_line() {
        let text = "Validation Error\n\nCaused by:\n  In Device::create_bind_group, label = \
                    'likelihood'\n    Buffer with 'features' label is invalid\n";
        assert_eq!(
            one_line(text),
            "Validation Error: In Device::create_bind_group, label = 'likelihood': Buffer \
             with 'features' label is invalid"
        );
        assert_eq!(one_line("Out of Memory"), "Out of Memory");
    }
}

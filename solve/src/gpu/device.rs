//! Device creation on the adapter [`lightwire_adapter`] chooses, and what
//! a long-running owner (the service's tick thread) needs to notice a
//! device going bad: the device-lost callback and uncaptured errors are
//! recorded in a [`DeviceHealth`], and [`Device::capture`] runs work inside
//! wgpu error scopes.

use std::fmt;
use std::sync::{Arc, Mutex};

use lightwire_adapter::AdapterError;

/// Why the GPU could not be used or a GPU operation failed.
///
/// The messages are meant for the person running `lightwire`: they say what
/// to install or which adapter names exist.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter on any backend: the machine has neither a GPU driver nor
    /// a software rasterizer.
    #[error("{}", lightwire_adapter::NO_ADAPTER)]
    NoAdapter,
    /// `--adapter NAME` matched none of the adapters present.
    #[error("{}", lightwire_adapter::no_matching_adapter(.wanted, .available))]
    NoMatchingAdapter { wanted: String, available: String },
    /// The adapter refused to create a device.
    #[error("{}", lightwire_adapter::request_device_failed(.adapter, .message))]
    RequestDevice { adapter: String, message: String },
    /// Mapping a buffer back to the CPU failed (device lost, ...).
    #[error("reading GPU results back failed: {0}")]
    Readback(String),
    /// The device was lost or reported an error (see [`DeviceHealth`]).
    #[error("{0}")]
    Device(String),
    /// The problem does not fit the device (too many elements, ...).
    #[error("{0}")]
    TooLarge(String),
}

/// A device and queue on the chosen adapter, with what was chosen.
///
/// Solvers clone the (reference-counted) device and queue from here, so one
/// `Device` can serve several solvers.
#[derive(Clone)]
pub struct Device {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// Name, backend and type of the adapter, for logs and benchmarks.
    pub info: wgpu::AdapterInfo,
    /// The limits the device was created with (the adapter's own).
    pub limits: wgpu::Limits,
    /// What went wrong with the device outside any error scope.
    pub health: Arc<DeviceHealth>,
}

/// Failures of a device that no call returned: the device-lost callback
/// and (once [`Device::record_uncaptured_errors`] is on) errors outside
/// every error scope. The first of each is kept.
#[derive(Debug, Default)]
pub struct DeviceHealth {
    lost: Mutex<Option<String>>,
    uncaptured: Mutex<Option<String>>,
}

impl DeviceHealth {
    fn record(slot: &Mutex<Option<String>>, what: String) {
        let mut slot = slot.lock().unwrap_or_else(|p| p.into_inner());
        if slot.is_none() {
            *slot = Some(what);
        }
    }

    /// Why the device is unusable, if it is: lost, or an uncaptured error.
    pub fn failure(&self) -> Option<String> {
        let lost = self.lost.lock().unwrap_or_else(|p| p.into_inner()).clone();
        lost.or_else(|| {
            self.uncaptured
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone()
        })
    }
}

impl fmt::Debug for Device {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Device")
            .field("adapter", &self.info.name)
            .field("backend", &self.info.backend)
            .finish()
    }
}

impl From<AdapterError> for GpuError {
    fn from(e: AdapterError) -> GpuError {
        match e {
            AdapterError::NoAdapter => GpuError::NoAdapter,
            AdapterError::NoMatchingAdapter { wanted, available } => {
                GpuError::NoMatchingAdapter { wanted, available }
            }
            AdapterError::RequestDevice { adapter, message } => {
                GpuError::RequestDevice { adapter, message }
            }
        }
    }
}

impl Device {
    /// Picks an adapter and creates a device with the adapter's limits, by
    /// the rule of [`lightwire_adapter`] that the client's renderer shares.
    ///
    /// `name` (case-insensitive substring of the adapter name, e.g. from
    /// `--adapter`) chooses among the adapters; without it a discrete GPU is
    /// preferred, then integrated, virtual, and software ones (lavapipe),
    /// and native backends over GL.
    pub fn new(name: Option<&str>) -> Result<Device, GpuError> {
        pollster::block_on(Self::new_async(name))
    }

    async fn new_async(name: Option<&str>) -> Result<Device, GpuError> {
        let adapter = lightwire_adapter::choose(name).await?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        // Where the adapter has them: timestamp queries, for profiling
        // (`gpu::profile`; nothing else changes with or without them), and
        // clip distances, which let a hemicube pass be one draw
        // (`hemicube::Draws`; without them, a draw per face).
        let optional = wgpu::Features::TIMESTAMP_QUERY
            | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS
            | wgpu::Features::CLIP_DISTANCES;
        let (device, queue) =
            lightwire_adapter::request_device_with(&adapter, "lightwire", optional).await?;
        let health = Arc::new(DeviceHealth::default());
        let lost = health.clone();
        device.set_device_lost_callback(move |reason, message| {
            let what = if message.is_empty() {
                format!("GPU device lost ({reason:?})")
            } else {
                format!("GPU device lost ({reason:?}): {message}")
            };
            DeviceHealth::record(&lost.lost, what);
        });
        Ok(Device {
            device,
            queue,
            info,
            limits,
            health,
        })
    }

    /// Records errors raised outside every error scope in [`Self::health`]
    /// instead of panicking (wgpu's default). For an owner that checks
    /// [`DeviceHealth::failure`] after its work, as the service does; a
    /// command-line tool keeps the default, which stops it at the error.
    pub fn record_uncaptured_errors(&self) {
        let health = self.health.clone();
        self.device
            .on_uncaptured_error(Arc::new(move |error: wgpu::Error| {
                DeviceHealth::record(&health.uncaptured, format!("GPU error: {error}"));
            }));
    }

    /// Runs `work` inside error scopes for validation, out-of-memory and
    /// internal errors (on this thread: wgpu's scopes are thread-local) and
    /// returns what it returned with the first error the scopes caught.
    pub fn capture<T>(&self, work: impl FnOnce() -> T) -> (T, Option<String>) {
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let internal = self.device.push_error_scope(wgpu::ErrorFilter::Internal);
        let out = work();
        // Scopes pop in reverse order; on native wgpu the futures are ready
        // at once.
        let errors = [
            pollster::block_on(internal.pop()),
            pollster::block_on(memory.pop()),
            pollster::block_on(validation.pop()),
        ];
        let first = errors
            .into_iter()
            .flatten()
            .next()
            .map(|e| format!("GPU error: {e}"));
        (out, first)
    }

    /// Why the device is unusable, if it is (see [`DeviceHealth`]).
    pub fn failure(&self) -> Option<String> {
        self.health.failure()
    }

    /// Whether the device has clip distances, with which a hemicube pass is
    /// one draw (`hemicube::Draws`).
    pub fn has_clip_distances(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::CLIP_DISTANCES)
    }

    /// "NAME (BACKEND)", for logs.
    pub fn describe(&self) -> String {
        lightwire_adapter::describe(&self.info)
    }
}

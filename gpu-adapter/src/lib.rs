//! Which GPU adapter Lightwire runs on, and a device on it: the one rule
//! that the server's solvers (`lightwire_solve::gpu::Device`) and the thin
//! client's renderer (`lightwire_client::render`) both follow.
//!
//! The rule:
//!
//! - ask every backend wgpu has (Vulkan, Metal, DX12, GL), as the
//!   environment lets it: wgpu's own variables such as `WGPU_BACKEND`
//!   narrow the instance ([`wgpu::InstanceDescriptor::with_env`]);
//! - with a name (`--adapter NAME`), keep only the adapters whose name
//!   contains it, case-insensitively, and say which names exist when none
//!   does;
//! - otherwise prefer a discrete GPU, then integrated, virtual, and
//!   software ones last (lavapipe, the fallback on a machine without a
//!   GPU), and among equals a native backend over GL ([`rank`]); ties keep
//!   wgpu's enumeration order;
//! - no adapter at all is an error that says what to install.
//!
//! The device is created with the adapter's own limits (large atlases and
//! images need more than wgpu's defaults) and no optional features.
//!
//! Both also draw alike, with depth, into 2D targets: [`texture_2d`],
//! [`depth_test`], [`REVERSED_DEPTH`] and [`begin_render_pass`] are what they share of that.
//!
//! This crate depends on nothing of ours, only on wgpu (and thiserror): the
//! client may not link the server, and `lightwire-protocol` knows no wgpu.

/// Why no adapter or no device could be had. The messages are meant for
/// the person running the command: they say what to install or which
/// adapter names exist.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AdapterError {
    /// No adapter on any backend: the machine has neither a GPU driver nor
    /// a software rasterizer.
    #[error("{}", NO_ADAPTER)]
    NoAdapter,
    /// The wanted name matched none of the adapters present.
    #[error("{}", no_matching_adapter(.wanted, .available))]
    NoMatchingAdapter {
        /// The name asked for.
        wanted: String,
        /// Every adapter present, as `"NAME" (BACKEND)`, comma-separated.
        available: String,
    },
    /// The adapter refused to create a device.
    #[error("{}", request_device_failed(.adapter, .message))]
    RequestDevice {
        /// The adapter's name.
        adapter: String,
        /// wgpu's reason.
        message: String,
    },
}

/// The message of [`AdapterError::NoAdapter`] (the solver's `GpuError`
/// still keeps a variant of its own for each of these).
pub const NO_ADAPTER: &str = "no GPU adapter found on any backend (Vulkan, GL, Metal, DX12). \
     Install a Vulkan driver; without a GPU, the software driver lavapipe works: \
     `apt-get install mesa-vulkan-drivers` (Debian/Ubuntu) or \
     `dnf install mesa-vulkan-drivers` (Fedora)";

/// The message of [`AdapterError::NoMatchingAdapter`].
pub fn no_matching_adapter(wanted: &str, available: &str) -> String {
    format!("no GPU adapter name contains \"{wanted}\"; available: {available}")
}

/// The message of [`AdapterError::RequestDevice`].
pub fn request_device_failed(adapter: &str, message: &str) -> String {
    format!("could not create a device on {adapter}: {message}")
}

/// Preference order among adapters, smallest first: by type (discrete,
/// integrated, virtual, software, other), then native backends (Vulkan,
/// Metal, DX12) before the rest (GL).
pub fn rank(info: &wgpu::AdapterInfo) -> (u8, u8) {
    let kind = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    };
    let backend = match info.backend {
        wgpu::Backend::Vulkan | wgpu::Backend::Metal | wgpu::Backend::Dx12 => 0,
        _ => 1,
    };
    (kind, backend)
}

/// The rule on a list of adapters (see the crate doc): the index of the
/// one to use among `adapters`, in wgpu's enumeration order.
pub fn pick(adapters: &[wgpu::AdapterInfo], name: Option<&str>) -> Result<usize, AdapterError> {
    if adapters.is_empty() {
        return Err(AdapterError::NoAdapter);
    }
    let needle = name.map(str::to_lowercase);
    let matches = |info: &wgpu::AdapterInfo| {
        needle
            .as_ref()
            .is_none_or(|n| info.name.to_lowercase().contains(n))
    };
    adapters
        .iter()
        .enumerate()
        .filter(|(_, info)| matches(info))
        // The first of the best: ties keep the enumeration order.
        .min_by_key(|(_, info)| rank(info))
        .map(|(i, _)| i)
        .ok_or_else(|| AdapterError::NoMatchingAdapter {
            wanted: name.unwrap_or_default().to_string(),
            available: adapters
                .iter()
                .map(|i| format!("\"{}\" ({:?})", i.name, i.backend))
                .collect::<Vec<_>>()
                .join(", "),
        })
}

/// Turns off Mesa's Vulkan device-selection layer
/// (`VK_LAYER_MESA_device_select`) where it can only print an error: the
/// layer asks the display server which GPU drives the screen, and without
/// a login session (`XDG_RUNTIME_DIR` unset, as on a server, in a
/// container or in CI) libwayland prints `error: XDG_RUNTIME_DIR is invalid
/// or not set in the environment.` at every Vulkan instance, though
/// nothing is wrong. Lightwire ranks adapters itself ([`pick`]), so it
/// loses nothing: the layer's own switch, `NODEVICE_SELECT=1`, is set
/// unless the variable is already set (then the user's choice stands).
/// Returns whether it set it. The workspace's `.cargo/config.toml` does the
/// same for processes Cargo runs (tests).
///
/// # Safety
/// Sets an environment variable: call it before any other thread of the
/// process may read or write the environment (first thing in `main`).
pub unsafe fn quiet_device_select() -> bool {
    let session =
        std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|dir| std::path::Path::new(&dir).is_dir());
    if session || std::env::var_os("NODEVICE_SELECT").is_some() {
        return false;
    }
    // SAFETY: the caller guarantees that no other thread touches the
    // environment meanwhile.
    unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    true
}

/// Enumerates the adapters of every backend the environment allows and
/// returns the one [`pick`] chooses.
pub async fn choose(name: Option<&str>) -> Result<wgpu::Adapter, AdapterError> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let mut adapters = instance.enumerate_adapters(wgpu::Backends::all()).await;
    let infos = adapters.iter().map(|a| a.get_info()).collect::<Vec<_>>();
    let chosen = pick(&infos, name)?;
    Ok(adapters.swap_remove(chosen))
}

/// The adapter [`choose`] picks for `name`, and a device and its queue on
/// it ([`request_device`]): all a renderer or a solver needs to start.
pub async fn open(
    name: Option<&str>,
    label: &str,
) -> Result<(wgpu::Adapter, wgpu::Device, wgpu::Queue), AdapterError> {
    open_with(name, label, wgpu::Features::empty()).await
}

/// [`open`] with those of the optional `features` that the adapter has
/// ([`request_device_with`]).
pub async fn open_with(
    name: Option<&str>,
    label: &str,
    features: wgpu::Features,
) -> Result<(wgpu::Adapter, wgpu::Device, wgpu::Queue), AdapterError> {
    let adapter = choose(name).await?;
    let (device, queue) = request_device_with(&adapter, label, features).await?;
    Ok((adapter, device, queue))
}

/// Creates a device and its queue on `adapter` with the adapter's own
/// limits, no optional features and memory hints for performance;
/// `label` names it in wgpu's messages.
pub async fn request_device(
    adapter: &wgpu::Adapter,
    label: &str,
) -> Result<(wgpu::Device, wgpu::Queue), AdapterError> {
    request_device_with(adapter, label, wgpu::Features::empty()).await
}

/// [`request_device`] with those of the optional `features` that the
/// adapter has (the others are left out, never an error).
pub async fn request_device_with(
    adapter: &wgpu::Adapter,
    label: &str,
    features: wgpu::Features,
) -> Result<(wgpu::Device, wgpu::Queue), AdapterError> {
    adapter
        .request_device(&wgpu::DeviceDescriptor {
            label: Some(label),
            required_features: features & adapter.features(),
            required_limits: adapter.limits(),
            memory_hints: wgpu::MemoryHints::Performance,
            ..Default::default()
        })
        .await
        .map_err(|e| AdapterError::RequestDevice {
            adapter: adapter.get_info().name,
            message: e.to_string(),
        })
}

/// "NAME (BACKEND)" of an adapter, for logs and benchmark reports.
pub fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?})", info.name, info.backend)
}

/// A 2D texture of one mip level with `samples` samples per texel: the
/// render targets of the solvers' hemicubes and of the client's view.
pub fn texture_2d(
    device: &wgpu::Device,
    label: &str,
    (width, height): (u32, u32),
    format: wgpu::TextureFormat,
    samples: u32,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: samples,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// Depth written in `format` and tested by `compare`, no stencil.
pub fn depth_test(
    format: wgpu::TextureFormat,
    compare: wgpu::CompareFunction,
) -> wgpu::DepthStencilState {
    wgpu::DepthStencilState {
        format,
        depth_write_enabled: Some(true),
        depth_compare: Some(compare),
        stencil: Default::default(),
        bias: Default::default(),
    }
}

/// How a reversed depth buffer (0 is infinitely far, nearer is larger)
/// is used for one pass: cleared to 0 and not kept after it.
pub const REVERSED_DEPTH: wgpu::Operations<f32> = wgpu::Operations {
    load: wgpu::LoadOp::Clear(0.0),
    store: wgpu::StoreOp::Discard,
};

/// Begins a render pass `label` with one colour attachment, `color`
/// (`view`, the view it resolves to if any, and how it is loaded and
/// stored), and the depth attachment `depth` (no stencil), without
/// queries.
pub fn begin_render_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    label: &str,
    color: (
        &wgpu::TextureView,
        Option<&wgpu::TextureView>,
        wgpu::Operations<wgpu::Color>,
    ),
    depth: (&wgpu::TextureView, wgpu::Operations<f32>),
) -> wgpu::RenderPass<'e> {
    let (view, resolve_target, ops) = color;
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target,
            ops,
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth.0,
            depth_ops: Some(depth.1),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use wgpu::{AdapterInfo, Backend, DeviceType};

    fn adapter(name: &str, kind: DeviceType, backend: Backend) -> AdapterInfo {
        AdapterInfo {
            name: name.to_string(),
            ..AdapterInfo::new(kind, backend)
        }
    }

    /// What a machine with a GPU and Mesa's drivers typically lists.
    fn machine() -> Vec<AdapterInfo> {
        vec![
            adapter(
                "llvmpipe (LLVM 19.1.7, 256 bits)",
                DeviceType::Cpu,
                Backend::Vulkan,
            ),
            adapter(
                "Intel(R) UHD Graphics",
                DeviceType::IntegratedGpu,
                Backend::Gl,
            ),
            adapter(
                "Intel(R) UHD Graphics",
                DeviceType::IntegratedGpu,
                Backend::Vulkan,
            ),
            adapter(
                "NVIDIA GeForce RTX 3060",
                DeviceType::DiscreteGpu,
                Backend::Vulkan,
            ),
        ]
    }

    #[test]
    fn a_discrete_gpu_before_integrated_before_software() {
        assert_eq!(pick(&machine(), None), Ok(3));
        assert_eq!(pick(&machine()[..3], None), Ok(2), "integrated on Vulkan");
        assert_eq!(
            pick(&machine()[..1], None),
            Ok(0),
            "lavapipe as the fallback"
        );
    }

    #[test]
    fn a_native_backend_before_gl_and_ties_in_enumeration_order() {
        let gl_first = machine()[1..3].to_vec();
        assert_eq!(pick(&gl_first, None), Ok(1));
        let twins = vec![
            adapter("first", DeviceType::Cpu, Backend::Vulkan),
            adapter("second", DeviceType::Cpu, Backend::Vulkan),
        ];
        assert_eq!(pick(&twins, None), Ok(0));
    }

    #[test]
    fn a_name_chooses_by_case_insensitive_substring_then_by_rank() {
        assert_eq!(pick(&machine(), Some("LLVMPIPE")), Ok(0));
        assert_eq!(pick(&machine(), Some("intel")), Ok(2));
    }

    #[test]
    fn no_match_names_every_adapter_present() {
        let err = pick(&machine()[..2], Some("radeon")).unwrap_err();
        assert_eq!(
            err,
            AdapterError::NoMatchingAdapter {
                wanted: "radeon".into(),
                available: "\"llvmpipe (LLVM 19.1.7, 256 bits)\" (Vulkan), \
                            \"Intel(R) UHD Graphics\" (Gl)"
                    .into(),
            }
        );
        assert_eq!(
            err.to_string(),
            "no GPU adapter name contains \"radeon\"; available: \
             \"llvmpipe (LLVM 19.1.7, 256 bits)\" (Vulkan), \"Intel(R) UHD Graphics\" (Gl)"
        );
    }

    #[test]
    fn no_adapter_says_what_to_install() {
        assert_eq!(pick(&[], None), Err(AdapterError::NoAdapter));
        assert_eq!(pick(&[], Some("any")), Err(AdapterError::NoAdapter));
        let message = AdapterError::NoAdapter.to_string();
        assert!(
            message.contains("apt-get install mesa-vulkan-drivers"),
            "{message}"
        );
        assert!(message.contains("lavapipe"), "{message}");
    }

    #[test]
    fn described_as_name_and_backend() {
        assert_eq!(describe(&machine()[3]), "NVIDIA GeForce RTX 3060 (Vulkan)");
    }
}

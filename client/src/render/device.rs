//! Choosing an adapter and creating a device.
//!
//! The same preference as the server's `gpu/device.rs` (the client may not
//! depend on the server, and the rule is ten lines): a discrete GPU, then
//! integrated, virtual and software ones (lavapipe), native backends before
//! GL; `--adapter NAME` picks by a case-insensitive substring of the name.

use super::RenderError;

/// Preference order among adapter types: discrete first, software last.
fn rank(info: &wgpu::AdapterInfo) -> (u8, u8) {
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

/// Picks an adapter (see the module doc) and opens a device with its
/// limits (large images and atlases need more than the defaults).
pub(super) async fn open(
    name: Option<&str>,
) -> Result<(wgpu::Adapter, wgpu::Device, wgpu::Queue), RenderError> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let mut adapters = instance.enumerate_adapters(wgpu::Backends::all()).await;
    if adapters.is_empty() {
        return Err(RenderError::NoAdapter);
    }
    if let Some(wanted) = name {
        let needle = wanted.to_lowercase();
        let available = adapters
            .iter()
            .map(|a| {
                let i = a.get_info();
                format!("\"{}\" ({:?})", i.name, i.backend)
            })
            .collect::<Vec<_>>()
            .join(", ");
        adapters.retain(|a| a.get_info().name.to_lowercase().contains(&needle));
        if adapters.is_empty() {
            return Err(RenderError::NoMatchingAdapter {
                wanted: wanted.to_string(),
                available,
            });
        }
    }
    adapters.sort_by_key(|a| rank(&a.get_info()));
    let adapter = adapters.swap_remove(0);
    let info = adapter.get_info();
    let (device, queue) = adapter
        .request_device(&wgpu::DeviceDescriptor {
            label: Some("lightwire-client view"),
            required_features: wgpu::Features::empty(),
            required_limits: adapter.limits(),
            memory_hints: wgpu::MemoryHints::Performance,
            ..Default::default()
        })
        .await
        .map_err(|e| RenderError::RequestDevice {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;
    Ok((adapter, device, queue))
}

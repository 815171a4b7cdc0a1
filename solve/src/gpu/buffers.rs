//! Helpers every GPU solver shares: packing vectors for WGSL, padding
//! what buffers start with, creating render targets, dispatching a compute
//! pass, and reading buffers back.

use bytemuck::Zeroable;
use glam::Vec3;

use super::device::GpuError;

/// Workgroup size of the per-element and per-shooter compute shaders
/// (`WG` in elements.wgsl).
pub(super) const WORKGROUP: u32 = 64;

/// A `vec4<f32>` of WGSL: `v` and `w`.
pub(super) fn v4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}

/// A vector padded with one zero entry when empty (buffers may not be).
pub(super) fn non_empty<T: Zeroable + Clone>(mut v: Vec<T>) -> Vec<T> {
    if v.is_empty() {
        v.push(T::zeroed());
    }
    v
}

/// A 2D texture of one mip level ([`lightwire_adapter::texture_2d`]) and
/// its default view.
pub(super) fn texture(
    device: &wgpu::Device,
    label: &str,
    size: (u32, u32),
    format: wgpu::TextureFormat,
    samples: u32,
    usage: wgpu::TextureUsages,
) -> wgpu::TextureView {
    lightwire_adapter::texture_2d(device, label, size, format, samples, usage)
        .create_view(&Default::default())
}

/// A compute pass of one pipeline over `workgroups` workgroups (at least
/// one).
pub(super) fn encode_compute(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &(wgpu::ComputePipeline, wgpu::BindGroup),
    workgroups: u32,
) {
    encode_compute_grid(encoder, pipeline, (workgroups, 1));
}

/// [`encode_compute`] over a grid of `x` by `y` workgroups.
pub(super) fn encode_compute_grid(
    encoder: &mut wgpu::CommandEncoder,
    (pipeline, group): &(wgpu::ComputePipeline, wgpu::BindGroup),
    (x, y): (u32, u32),
) {
    let mut pass = encoder.begin_compute_pass(&Default::default());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups(x.max(1), y.max(1), 1);
}

/// Copies the first `count` entries of a vec4 buffer (one per element)
/// back to the CPU through a staging buffer.
pub(super) fn read_vec4(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
    count: u32,
) -> Result<Vec<[f32; 4]>, GpuError> {
    let size = u64::from(count.max(1)) * 16;
    let bytes = read_back(device, queue, ("readback", size), buffer, |_| {})?;
    let mut values: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&bytes);
    values.truncate(count as usize);
    Ok(values)
}

/// Copies the first `size` bytes of `source` back to the CPU through a
/// staging buffer `label`, in one submission after the commands `first`
/// encodes (which may fill `source`).
pub(super) fn read_back(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    (label, size): (&str, u64),
    source: &wgpu::Buffer,
    first: impl FnOnce(&mut wgpu::CommandEncoder),
) -> Result<Vec<u8>, GpuError> {
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    first(&mut encoder);
    encoder.copy_buffer_to_buffer(source, 0, &staging, 0, size);
    queue.submit([encoder.finish()]);
    map_read(device, &staging)
}

/// Waits for the GPU and copies a mappable buffer's contents out.
pub(super) fn map_read(device: &wgpu::Device, buffer: &wgpu::Buffer) -> Result<Vec<u8>, GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |result| {
        // The receiver outlives the poll below; a send error cannot happen.
        let _ = tx.send(result);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    rx.recv()
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    let bytes = buffer
        .get_mapped_range(..)
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .to_vec();
    buffer.unmap();
    Ok(bytes)
}

/// Power that arrived at the elements, `Σ A_i H_i`, and the part of it they
/// absorbed, `Σ A_i (1 - ρ_i) H_i` (W, channels summed), from the
/// irradiance `h` read back per element.
pub(super) fn received_and_absorbed(h: &[[f32; 4]], areas: &[f32], albedo: &[Vec3]) -> (f64, f64) {
    let (mut received, mut absorbed) = (0.0f64, 0.0f64);
    for ((hv, a), rho) in h.iter().zip(areas).zip(albedo) {
        let hv = Vec3::new(hv[0], hv[1], hv[2]);
        received += f64::from(*a) * f64::from(hv.element_sum());
        absorbed += f64::from(*a) * f64::from(((Vec3::ONE - *rho) * hv).element_sum());
    }
    (received, absorbed)
}

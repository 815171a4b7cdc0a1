//! The GPU side: device, pipeline, buffers, the render pass and the
//! readback. See the module doc of [`super`] for the data flow.

use glam::Mat4;
use lightwire_protocol::lightmap::{Lightmap, quantize_into};
use lightwire_protocol::{PixelFormat, Pose, SceneInfo};

use super::RenderError;
use super::camera::Camera;
use super::geometry::{self, Vertex};

/// The clear colour, 8-bit sRGB: the dashboard's background
/// (`view3d.js` BACKGROUND = 0.07, 0.08, 0.1). Pixels that show no surface
/// have exactly this value.
pub const BACKGROUND: [u8; 3] = [18, 20, 26];

/// The format of the rendered image: tone mapping and sRGB encoding happen
/// in the shader, as in `bake`, so the target stores the final bytes.
const TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// MSAA sample count when the adapter supports it (every Vulkan device
/// does for these formats): smooth silhouettes. Interior pixels are shaded
/// once at the pixel centre either way, so MSAA does not change them.
const SAMPLES: u32 = 4;
/// The near plane as a fraction of the scene's bounding-box diagonal. With
/// reversed-Z floating-point depth a small near plane costs no precision.
const NEAR_FRACTION: f32 = 1e-4;

/// What to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Radiosity is multiplied by this before the tone curve; see
    /// [`super::tonemap::auto_exposure`] for the `bake` default.
    pub exposure: f32,
}

/// A lightmap as the renderer takes it.
#[derive(Clone, Copy, Debug)]
pub enum LightmapTexels<'a> {
    /// Texels as they came off the wire ([`Lightmap::texels`]): uploaded
    /// as they are, RGB9E5 as `Rgb9e5Ufloat`, RGBA16F as `Rgba16Float`.
    Wire {
        width: u32,
        height: u32,
        format: PixelFormat,
        bytes: &'a [u8],
    },
    /// Linear RGB, row-major (e.g. a decoded EXR snapshot): converted to
    /// RGBA16F. Every RGB9E5 value has at most 9 significant bits, is a
    /// multiple of 2^-24 and at most 65408, so binary16 holds it exactly:
    /// RGB decoded from the wire renders exactly like the wire texels.
    Rgb {
        width: u32,
        height: u32,
        texels: &'a [[f32; 3]],
    },
}

impl<'a> From<&'a Lightmap> for LightmapTexels<'a> {
    fn from(map: &'a Lightmap) -> Self {
        LightmapTexels::Wire {
            width: map.width,
            height: map.height,
            format: map.format,
            bytes: &map.texels,
        }
    }
}

impl LightmapTexels<'_> {
    fn size(&self) -> (u32, u32) {
        match *self {
            LightmapTexels::Wire { width, height, .. }
            | LightmapTexels::Rgb { width, height, .. } => (width, height),
        }
    }
}

/// The scene's geometry on the GPU, with the description it was built
/// from (to notice a different scene).
struct SceneBuffers {
    info: SceneInfo,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
    /// One model matrix per object (at least one slot: empty storage
    /// buffers cannot be bound).
    models: wgpu::Buffer,
}

struct LightmapTexture {
    width: u32,
    height: u32,
    format: wgpu::TextureFormat,
    texture: wgpu::Texture,
    view: wgpu::TextureView,
}

/// Render targets and the readback buffer for one image size.
struct Targets {
    width: u32,
    height: u32,
    /// Multisampled colour (None without MSAA: render into `resolve`).
    color: Option<wgpu::TextureView>,
    resolve: wgpu::Texture,
    resolve_view: wgpu::TextureView,
    depth: wgpu::TextureView,
    /// `height` rows of `padded_row` bytes (copies need 256-byte rows).
    readback: wgpu::Buffer,
    padded_row: u32,
}

/// Frame uniforms, laid out as `Frame` in `view.wgsl` (80 bytes).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameUniform {
    view_proj: [[f32; 4]; 4],
    exposure: f32,
    _pad: [f32; 3],
}

/// A device, the compiled pipeline, and what the last frame uploaded.
pub struct Renderer {
    info: wgpu::AdapterInfo,
    device: wgpu::Device,
    queue: wgpu::Queue,
    max_dimension: u32,
    samples: u32,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    frame: wgpu::Buffer,
    scene: Option<SceneBuffers>,
    lightmap: Option<LightmapTexture>,
    targets: Option<Targets>,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("adapter", &self.adapter())
            .field("samples", &self.samples)
            .finish()
    }
}

impl Renderer {
    /// Opens a device on the preferred adapter, or on the one whose name
    /// contains `adapter` (case-insensitive), and compiles the pipeline.
    pub fn new(adapter: Option<&str>) -> Result<Renderer, RenderError> {
        pollster::block_on(Self::new_async(adapter))
    }

    async fn new_async(adapter: Option<&str>) -> Result<Renderer, RenderError> {
        // The adapter by the rule the server's solvers follow too, and a
        // device with its limits (large images and atlases need more than
        // wgpu's defaults).
        let (adapter, device, queue) =
            lightwire_adapter::open(adapter, "lightwire-client view").await?;
        let info = adapter.get_info();
        let max_dimension = device.limits().max_texture_dimension_2d;
        let msaa = |format| {
            adapter
                .get_texture_format_features(format)
                .flags
                .sample_count_supported(SAMPLES)
        };
        let samples = if msaa(TARGET_FORMAT) && msaa(DEPTH_FORMAT) {
            SAMPLES
        } else {
            1
        };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("view.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("view.wgsl").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("view"),
            entries: &[
                buffer_entry(
                    0,
                    wgpu::ShaderStages::VERTEX_FRAGMENT,
                    wgpu::BufferBindingType::Uniform,
                    std::mem::size_of::<FrameUniform>() as u64,
                ),
                buffer_entry(
                    1,
                    wgpu::ShaderStages::VERTEX,
                    wgpu::BufferBindingType::Storage { read_only: true },
                    64,
                ),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("view"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("view"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<Vertex>() as u64,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![
                        0 => Float32x3, 1 => Float32x2, 2 => Uint32
                    ],
                })],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                // Corners wind counter-clockwise seen from the side u x v
                // points to, the lit side; the back of a one-sided surface
                // carries no light and is not drawn.
                front_face: wgpu::FrontFace::Ccw,
                cull_mode: Some(wgpu::Face::Back),
                ..Default::default()
            },
            // Reversed-Z: nearer is larger.
            depth_stencil: Some(lightwire_adapter::depth_test(
                DEPTH_FORMAT,
                wgpu::CompareFunction::Greater,
            )),
            multisample: wgpu::MultisampleState {
                count: samples,
                ..Default::default()
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: TARGET_FORMAT,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("lightmap"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Nearest,
            ..Default::default()
        });
        let frame = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame"),
            size: std::mem::size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Renderer {
            info,
            device,
            queue,
            max_dimension,
            samples,
            pipeline,
            layout,
            sampler,
            frame,
            scene: None,
            lightmap: None,
            targets: None,
        })
    }

    /// "NAME (BACKEND)" of the adapter in use, for logs.
    pub fn adapter(&self) -> String {
        lightwire_adapter::describe(&self.info)
    }

    /// Renders `scene` with its objects at `poses` (one per object), lit by
    /// `lightmap` (the scene's atlas), seen by `camera`.
    ///
    /// Every input is checked first, and an error names what does not fit;
    /// GPU errors that still occur (out of memory) are returned, not
    /// panicked on.
    pub fn render(
        &mut self,
        scene: &SceneInfo,
        poses: &[Pose],
        lightmap: LightmapTexels<'_>,
        camera: &Camera,
        settings: &Settings,
    ) -> Result<image::RgbaImage, RenderError> {
        let Settings {
            width,
            height,
            exposure,
        } = *settings;
        if width == 0 || height == 0 || width > self.max_dimension || height > self.max_dimension {
            return Err(RenderError::Size(format!(
                "{width}x{height}: width and height must be between 1 and {} on {}",
                self.max_dimension,
                self.adapter()
            )));
        }
        if !(exposure.is_finite() && exposure > 0.0) {
            return Err(RenderError::Exposure(exposure));
        }
        camera.check()?;
        geometry::check_poses(scene, poses)?;
        check_lightmap(scene, &lightmap)?;

        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        self.upload_scene(scene)?;
        self.upload_poses(poses);
        self.upload_lightmap(&lightmap);
        self.ensure_targets(width, height);
        let near = geometry::world_bounds(scene, poses)
            .map(|(lo, hi)| (hi - lo).length() * NEAR_FRACTION)
            .unwrap_or(1e-3)
            .max(1e-6);
        let aspect = width as f32 / height as f32;
        let view_proj: Mat4 = camera.projection(aspect, near) * camera.view();
        self.queue.write_buffer(
            &self.frame,
            0,
            bytemuck::bytes_of(&FrameUniform {
                view_proj: view_proj.to_cols_array_2d(),
                exposure,
                _pad: [0.0; 3],
            }),
        );
        self.draw();
        let oom = pollster::block_on(memory.pop());
        let invalid = pollster::block_on(validation.pop());
        if let Some(e) = oom.or(invalid) {
            return Err(RenderError::Gpu(e.to_string()));
        }
        self.read_back()
    }

    fn upload_scene(&mut self, scene: &SceneInfo) -> Result<(), RenderError> {
        // The lights' states are not drawn: only another scene needs new
        // geometry.
        if self
            .scene
            .as_ref()
            .is_some_and(|s| s.info.same_description(scene))
        {
            return Ok(());
        }
        let mesh = geometry::mesh(scene)?;
        let buffer = |label, contents: &[u8], usage| {
            let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                // Zero-sized buffers cannot be bound; keep one element.
                size: (contents.len() as u64).max(64).next_multiple_of(4),
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            self.queue.write_buffer(&buffer, 0, contents);
            buffer
        };
        let vertices = buffer(
            "vertices",
            bytemuck::cast_slice(&mesh.vertices),
            wgpu::BufferUsages::VERTEX,
        );
        let indices = buffer(
            "indices",
            bytemuck::cast_slice(&mesh.indices),
            wgpu::BufferUsages::INDEX,
        );
        let models = buffer(
            "models",
            &vec![0u8; 64 * scene.objects.len().max(1)],
            wgpu::BufferUsages::STORAGE,
        );
        self.scene = Some(SceneBuffers {
            info: scene.clone(),
            vertices,
            indices,
            index_count: mesh.indices.len() as u32,
            models,
        });
        Ok(())
    }

    fn upload_poses(&mut self, poses: &[Pose]) {
        let scene = self.scene.as_ref().expect("uploaded scene");
        if poses.is_empty() {
            return;
        }
        let models: Vec<[[f32; 4]; 4]> = poses
            .iter()
            .map(|p| geometry::pose_matrix(p).to_cols_array_2d())
            .collect();
        self.queue
            .write_buffer(&scene.models, 0, bytemuck::cast_slice(&models));
    }

    fn upload_lightmap(&mut self, lightmap: &LightmapTexels<'_>) {
        let (width, height) = lightmap.size();
        let (format, bytes_per_texel, converted);
        let bytes: &[u8] = match *lightmap {
            LightmapTexels::Wire {
                format: f, bytes, ..
            } => {
                format = match f {
                    PixelFormat::Rgb9e5 => wgpu::TextureFormat::Rgb9e5Ufloat,
                    PixelFormat::Rgba16f => wgpu::TextureFormat::Rgba16Float,
                };
                bytes_per_texel = f.bytes_per_texel() as u32;
                bytes
            }
            LightmapTexels::Rgb { texels, .. } => {
                format = wgpu::TextureFormat::Rgba16Float;
                bytes_per_texel = PixelFormat::Rgba16f.bytes_per_texel() as u32;
                let mut out = vec![0u8; texels.len() * bytes_per_texel as usize];
                for (rgb, chunk) in texels.iter().zip(out.chunks_exact_mut(8)) {
                    quantize_into(PixelFormat::Rgba16f, *rgb, chunk);
                }
                converted = out;
                &converted
            }
        };
        let reuse = self
            .lightmap
            .as_ref()
            .is_some_and(|l| (l.width, l.height, l.format) == (width, height, format));
        if !reuse {
            let texture = self.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("lightmap"),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            let view = texture.create_view(&Default::default());
            self.lightmap = Some(LightmapTexture {
                width,
                height,
                format,
                texture,
                view,
            });
        }
        let target = self.lightmap.as_ref().expect("lightmap texture");
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &target.texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(width * bytes_per_texel),
                rows_per_image: Some(height),
            },
            wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
        );
    }

    fn ensure_targets(&mut self, width: u32, height: u32) {
        if self
            .targets
            .as_ref()
            .is_some_and(|t| (t.width, t.height) == (width, height))
        {
            return;
        }
        let texture = |label, format, samples, usage| {
            lightwire_adapter::texture_2d(
                &self.device,
                label,
                (width, height),
                format,
                samples,
                usage,
            )
        };
        let attachment = wgpu::TextureUsages::RENDER_ATTACHMENT;
        let resolve = texture(
            "image",
            TARGET_FORMAT,
            1,
            attachment | wgpu::TextureUsages::COPY_SRC,
        );
        let color = (self.samples > 1).then(|| {
            texture("image (msaa)", TARGET_FORMAT, self.samples, attachment)
                .create_view(&Default::default())
        });
        let depth = texture("depth", DEPTH_FORMAT, self.samples, attachment)
            .create_view(&Default::default());
        let padded_row = (width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded_row) * u64::from(height),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.targets = Some(Targets {
            width,
            height,
            color,
            resolve_view: resolve.create_view(&Default::default()),
            resolve,
            depth,
            readback,
            padded_row,
        });
    }

    fn draw(&self) {
        let scene = self.scene.as_ref().expect("uploaded scene");
        let lightmap = self.lightmap.as_ref().expect("uploaded lightmap");
        let targets = self.targets.as_ref().expect("targets");
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("view"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.frame.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: scene.models.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&lightmap.view),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
            ],
        });
        let [r, g, b] = BACKGROUND.map(|c| f64::from(c) / 255.0);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let (view, resolve_target) = match &targets.color {
                Some(msaa) => (msaa, Some(&targets.resolve_view)),
                None => (&targets.resolve_view, None),
            };
            let color = wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color { r, g, b, a: 1.0 }),
                store: if resolve_target.is_some() {
                    wgpu::StoreOp::Discard
                } else {
                    wgpu::StoreOp::Store
                },
            };
            let mut pass = lightwire_adapter::begin_render_pass(
                &mut encoder,
                "view",
                (view, resolve_target, color),
                (&targets.depth, lightwire_adapter::REVERSED_DEPTH),
            );
            if scene.index_count > 0 {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &group, &[]);
                pass.set_vertex_buffer(0, scene.vertices.slice(..));
                pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(0..scene.index_count, 0, 0..1);
            }
        }
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &targets.resolve,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &targets.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(targets.padded_row),
                    rows_per_image: Some(targets.height),
                },
            },
            wgpu::Extent3d {
                width: targets.width,
                height: targets.height,
                depth_or_array_layers: 1,
            },
        );
        self.queue.submit([encoder.finish()]);
    }

    /// Waits for the frame and copies it out of the padded readback rows.
    fn read_back(&self) -> Result<image::RgbaImage, RenderError> {
        let targets = self.targets.as_ref().expect("targets");
        let buffer = &targets.readback;
        let (tx, rx) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |result| {
            // The receiver outlives the poll below.
            let _ = tx.send(result);
        });
        let gpu =
            |e: &dyn std::fmt::Display| RenderError::Gpu(format!("reading the image back: {e}"));
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| gpu(&e))?;
        rx.recv().map_err(|e| gpu(&e))?.map_err(|e| gpu(&e))?;
        let row = targets.width as usize * 4;
        let mut pixels = Vec::with_capacity(row * targets.height as usize);
        {
            let mapped = buffer.get_mapped_range(..).map_err(|e| gpu(&e))?;
            for line in mapped.chunks_exact(targets.padded_row as usize) {
                pixels.extend_from_slice(&line[..row]);
            }
        }
        buffer.unmap();
        Ok(
            image::RgbaImage::from_raw(targets.width, targets.height, pixels)
                .expect("width * height * 4 bytes"),
        )
    }
}

/// Checks that a lightmap fits the scene's atlas and holds all its texels.
/// A bind group layout entry of a buffer `ty` at `binding`, seen by the
/// stages `visibility`, of at least `min_size` bytes.
fn buffer_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
    ty: wgpu::BufferBindingType,
    min_size: u64,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: wgpu::BufferSize::new(min_size),
        },
        count: None,
    }
}

fn check_lightmap(scene: &SceneInfo, lightmap: &LightmapTexels<'_>) -> Result<(), RenderError> {
    let (width, height) = lightmap.size();
    if (width, height) != (scene.atlas_width, scene.atlas_height) {
        return Err(RenderError::Lightmap(format!(
            "{width}x{height} texels, but the scene's atlas is {}x{}",
            scene.atlas_width, scene.atlas_height
        )));
    }
    let texels = width as usize * height as usize;
    let (have, want) = match *lightmap {
        LightmapTexels::Wire { format, bytes, .. } => {
            (bytes.len(), texels * format.bytes_per_texel())
        }
        LightmapTexels::Rgb { texels: t, .. } => (t.len(), texels),
    };
    if have != want {
        return Err(RenderError::Lightmap(format!(
            "{have} texel values for a {width}x{height} atlas, expected {want}"
        )));
    }
    Ok(())
}

//! Hemicubes rasterized at shooters (thesis §4.3.2): one large target
//! holds a row of five face viewports per shooter slot, all drawn in one
//! render pass from the patches' triangles, which live in object space and
//! are placed by the poses in the vertex shader (hemicube.wgsl).
//!
//! Three kinds of target come from the same geometry: item buffers of patch
//! ids (`vs_main`/`fs_main`, R32Uint), which decide visibility in
//! progressive refinement and redistribution; element ids
//! (`vs_rad`/`fs_element`, R32Uint), from which cross redistribution's
//! moving tiles gather what each element shows; and element ids with the
//! distance from the eye (`vs_rad`/`fs_back`, Rg32Uint), which cross
//! redistribution shades with shot radiosity and projects (thesis §4.5.2).
//! The gather solver's radiosity hemicubes use [`render_pipeline`] too.

use bytemuck::{Pod, Zeroable};

use super::binding::{Kind, Pass, Slot};
use super::buffers::v4;
use lightwire_scene::PatchShape;
use lightwire_scene::atlas::ChartMap;

/// Hemicube faces per shooter: top and four sides.
pub(super) const FACES: u32 = 5;

/// One patch corner for the hemicube rasterizer (`Vertex` in hemicube.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct GpuVertex {
    pos: [f32; 4],
    st: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuVertex>() == 32);

/// The bindings of hemicube.wgsl.
pub(super) mod slot {
    use super::{Kind, Slot};

    pub(in crate::gpu) const VERTICES: Slot = Slot::new("vertices", 0, Kind::StorageRead);
    pub(in crate::gpu) const SHOOTERS: Slot = Slot::new("shooters", 1, Kind::Uniform);
    pub(in crate::gpu) const BATCH: Slot = Slot::new("batch", 2, Kind::Uniform);
    pub(in crate::gpu) const POSES: Slot = Slot::new("poses", 3, Kind::StorageRead);
    pub(in crate::gpu) const PATCHES: Slot = Slot::new("patches", 6, Kind::StorageRead);
}

/// Clearing the slots an item-buffer pass draws to "no patch" (no
/// bindings).
pub(super) const CLEAR_ITEMS: Pass = Pass {
    entries: &["vs_clear", "fs_clear_items"],
    slots: &[],
};

/// Clearing the slots a back hemicube pass draws to "no element" at
/// distance 0 (no bindings).
pub(super) const CLEAR_BACK: Pass = Pass {
    entries: &["vs_clear", "fs_clear_back"],
    slots: &[],
};

/// Item buffers: the nearest patch id per pixel.
pub(super) const ITEM_BUFFERS: Pass = Pass {
    entries: &["vs_main", "fs_main"],
    slots: &[slot::VERTICES, slot::SHOOTERS, slot::BATCH, slot::POSES],
};

/// What the passes that draw the element seen per pixel (`vs_rad`) bind:
/// the patches' charts besides the geometry.
const ELEMENT_SLOTS: &[Slot] = &[
    slot::VERTICES,
    slot::SHOOTERS,
    slot::BATCH,
    slot::POSES,
    slot::PATCHES,
];

/// The element seen per pixel and its distance from the eye (Rg32Uint):
/// cross redistribution's back hemicubes, which redistribute.wgsl shades
/// with shot radiosity `B - B^u` (thesis Alg. 4.4-4.5) after drawing, so
/// that a drawing at a tile's new pose serves again at its old pose in the
/// next move.
pub(super) const BACK_ELEMENTS: Pass = Pass {
    entries: &["vs_rad", "fs_back"],
    slots: ELEMENT_SLOTS,
};

/// The element seen per pixel (R32Uint): a moving tile's gathering
/// hemicubes, whose light redistribute.wgsl reads per pixel from the shown
/// textures, so that the gathers in and after a move share one drawing.
pub(super) const ELEMENT_IDS: Pass = Pass {
    entries: &["vs_rad", "fs_element"],
    slots: ELEMENT_SLOTS,
};

/// The triangles of every patch in object space (a quad's two, a triangle
/// patch's one), with the patch id, the patch parameters of each corner and
/// the object id; `triangle_vertices` is the count to draw (the buffer is
/// padded to one vertex when there is none).
///
/// A triangle on its mesh's own lightmap UVs (`maps[p]`, `atlas/uv.rs`)
/// carries its corners' chart coordinates instead of patch parameters, for
/// `element_at` (common.wgsl).
pub(super) fn patch_vertices(
    shapes: &[PatchShape],
    objects: &[u32],
    maps: &[Option<ChartMap>],
) -> (Vec<GpuVertex>, u32) {
    let mut vertices: Vec<GpuVertex> = Vec::with_capacity(shapes.len() * 6);
    for (p, shape) in shapes.iter().enumerate() {
        let map = maps.get(p).copied().flatten();
        let (origin, u, v) = shape.frame();
        let corners = [
            (origin, [0.0, 0.0]),
            (origin + u, [1.0, 0.0]),
            (origin + u + v, [1.0, 1.0]),
            (origin + v, [0.0, 1.0]),
        ];
        let object = f32::from_bits(objects[p]);
        for &i in corner_order(shape.is_triangle()) {
            let (c, st) = corners[i];
            let st = map.map_or(st, |m| m.to_chart(glam::Vec2::from(st)).to_array());
            vertices.push(GpuVertex {
                pos: v4(c, f32::from_bits(p as u32)),
                st: [st[0], st[1], object, 0.0],
            });
        }
    }
    let count = vertices.len() as u32;
    if vertices.is_empty() {
        vertices.push(GpuVertex::zeroed());
    }
    (vertices, count)
}

/// Which corners (origin, `+u`, `+u+v`, `+v`) make a patch's triangles: a
/// quad is cut along its diagonal from the origin; a triangle patch is the
/// first of those two (its corners have patch parameters (0, 0), (1, 0),
/// (1, 1), so the texel lookup of a fragment stays at `t <= s`).
pub(super) fn corner_order(triangle: bool) -> &'static [usize] {
    if triangle {
        &[0, 1, 2]
    } else {
        &[0, 1, 2, 0, 2, 3]
    }
}

/// How a hemicube pass is split into draws. Both rasterize the same
/// triangles into the same pixels of a target that holds a row of five
/// face cells per shooter slot (`one_draw_and_per_face_draws_agree` in the
/// progressive solver's tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Draws {
    /// A draw per face of every slot, each with its face's viewport and
    /// scissor (hemicube_faces.wgsl): works on every device.
    PerFace,
    /// One instanced draw for every face of every slot over a viewport
    /// `rows` slots high; each triangle is clipped to its face's cell by
    /// clip distances (hemicube_rows.wgsl). A draw has a fixed cost, on
    /// lavapipe tens of microseconds, which five draws per slot turn into
    /// most of a small scene's hemicube time.
    One { rows: u32 },
}

impl Draws {
    /// One draw where the device has clip distances and `allowed`, else
    /// per face; `rows` is the slot capacity of the pass's targets.
    pub(super) fn choose(device: &wgpu::Device, rows: u32, allowed: bool) -> Self {
        if allowed && device.features().contains(wgpu::Features::CLIP_DISTANCES) {
            Self::One { rows }
        } else {
            Self::PerFace
        }
    }

    /// The hemicube shader module with this layout's vertex entry points.
    pub(super) fn module(self, device: &wgpu::Device, label: &str) -> wgpu::ShaderModule {
        device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(
                super::shaders::hemicube(matches!(self, Self::One { .. })).into(),
            ),
        })
    }

    /// The pipeline constants of this layout's module (hemicube_rows.wgsl's
    /// `ROWS`).
    pub(super) fn constants(self) -> Vec<(&'static str, f64)> {
        match self {
            Self::PerFace => Vec::new(),
            Self::One { rows } => vec![("ROWS", f64::from(rows))],
        }
    }
}

/// A hemicube pass's pipelines: the one that draws the patches (`draw`,
/// nearer depth wins) and the one that first clears the slots it draws
/// (`clear`), both for one target format and sample count.
pub(super) struct Pipelines {
    draw: wgpu::RenderPipeline,
    clear: wgpu::RenderPipeline,
}

impl Pipelines {
    /// The pipelines of `pass` (`ITEM_BUFFERS` or `ELEMENT_IDS` into
    /// R32Uint, or `BACK_ELEMENTS` into Rg32Uint) with `module`, a module of
    /// `draws`' layout.
    pub(super) fn new(
        device: &wgpu::Device,
        (module, draws): (&wgpu::ShaderModule, Draws),
        pass: &Pass,
        layout: &wgpu::BindGroupLayout,
    ) -> Self {
        let (format, clear) = if pass.entries == BACK_ELEMENTS.entries {
            (wgpu::TextureFormat::Rg32Uint, &CLEAR_BACK)
        } else {
            (wgpu::TextureFormat::R32Uint, &CLEAR_ITEMS)
        };
        let draw = render_pipeline(
            device,
            module,
            &draws.constants(),
            pass,
            layout,
            format,
            1,
            wgpu::CompareFunction::Less,
        );
        let empty = clear.layout(device);
        let clear = render_pipeline(
            device,
            module,
            &[],
            clear,
            &empty,
            format,
            1,
            wgpu::CompareFunction::Always,
        );
        Self { draw, clear }
    }
}

/// A hemicube render pipeline of `pass` with its explicit layout: no
/// culling (surfaces are opaque from both sides), a 32-bit depth buffer
/// compared with `depth_compare`, one colour target of `format`, `samples`
/// samples; `constants` are the module's pipeline-overridable constants.
#[allow(clippy::too_many_arguments)]
pub(super) fn render_pipeline(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    constants: &[(&str, f64)],
    pass: &Pass,
    layout: &wgpu::BindGroupLayout,
    format: wgpu::TextureFormat,
    samples: u32,
    depth_compare: wgpu::CompareFunction,
) -> wgpu::RenderPipeline {
    let label = pass.entries.join("/");
    let compilation_options = wgpu::PipelineCompilationOptions {
        constants,
        ..Default::default()
    };
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(&label),
        layout: Some(&pass.pipeline_layout(device, layout)),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(pass.entries[0]),
            compilation_options: compilation_options.clone(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            // Surfaces are opaque from both sides.
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(lightwire_adapter::depth_test(
            wgpu::TextureFormat::Depth32Float,
            depth_compare,
        )),
        multisample: wgpu::MultisampleState {
            count: samples,
            ..Default::default()
        },
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some(pass.entries[1]),
            compilation_options,
            targets: &[Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// Rows of face `face`'s cell (`res` square) that a hemicube uses: all of
/// the top face, the upper half of a side face (its lower half looks below
/// the horizon). Nothing is drawn in the rest, which keeps the clear
/// colour.
pub(super) fn face_height(face: u32, res: u32) -> u32 {
    if face == 0 { res } else { res.div_ceil(2) }
}

/// Where one hemicube render pass draws.
pub(super) struct Target<'a> {
    pub(super) view: &'a wgpu::TextureView,
    pub(super) depth: &'a wgpu::TextureView,
    /// Top-face resolution in pixels.
    pub(super) resolution: u32,
}

/// Rasterizes hemicube slots `0..slots` of the bound shooters into
/// `target` (thesis §4.3.2: one large target, a viewport per face per
/// shooter, all in one render pass); `triangle_vertices` of the patch
/// triangles are drawn once per face, in draws as `draws` says (the
/// pipelines' module must be that layout's).
///
/// The pass loads the targets and clears only the rows of `0..slots` with
/// a draw (`vs_clear`): a clear at the start of the pass would clear every
/// slot the target holds, and on lavapipe that cost as much as the
/// drawing (cornell-low's cross passes 2-2.5x slower, BENCHMARKS.md). The
/// rows outside keep stale values that nothing reads.
pub(super) fn encode(
    encoder: &mut wgpu::CommandEncoder,
    (pipelines, group): (&Pipelines, &wgpu::BindGroup),
    target: &Target<'_>,
    slots: u32,
    triangle_vertices: u32,
    draws: Draws,
) {
    fn keep<V>() -> wgpu::Operations<V> {
        wgpu::Operations {
            load: wgpu::LoadOp::Load,
            store: wgpu::StoreOp::Store,
        }
    }
    let mut pass = lightwire_adapter::begin_render_pass(
        encoder,
        "hemicubes",
        (target.view, None, keep()),
        (target.depth, keep()),
    );
    let res = target.resolution;
    if slots == 0 {
        return;
    }
    let width = FACES * res;
    // A viewport over the first `rows` rows of face cells.
    let rows_viewport = |pass: &mut wgpu::RenderPass<'_>, rows: u32| {
        pass.set_viewport(0.0, 0.0, width as f32, (rows * res) as f32, 0.0, 1.0);
    };
    rows_viewport(&mut pass, slots);
    pass.set_scissor_rect(0, 0, width, slots * res);
    pass.set_pipeline(&pipelines.clear);
    pass.draw(0..3, 0..1);
    pass.set_pipeline(&pipelines.draw);
    pass.set_bind_group(0, group, &[]);
    if let Draws::One { rows } = draws {
        debug_assert!(slots <= rows, "{slots} slots in a target of {rows}");
        // The viewport spans every row the target holds (the shader places
        // by it); the clear's scissor still keeps to the slots drawn.
        rows_viewport(&mut pass, rows);
        pass.draw(0..triangle_vertices, 0..slots * FACES);
        return;
    }
    for slot in 0..slots {
        for face in 0..FACES {
            let (x, y) = (face * res, slot * res);
            pass.set_viewport(x as f32, y as f32, res as f32, res as f32, 0.0, 1.0);
            pass.set_scissor_rect(x, y, res, face_height(face, res));
            let instance = slot * FACES + face;
            pass.draw(0..triangle_vertices, instance..instance + 1);
        }
    }
}

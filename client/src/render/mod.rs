//! A headless wgpu renderer: the scene's quads, lit by a lightmap, to an
//! RGBA8 image.
//!
//! Data flow. A thin client knows three things: the scene's geometry (the
//! `SceneInfo` of the server's `Welcome`: quads in object space, each with a
//! rectangle of the lightmap atlas), the poses of its objects, and a
//! complete lightmap version. [`geometry`] turns every quad into four
//! vertices in object space with atlas UVs and the index of its object,
//! once per scene. Each frame, the poses become one model matrix per object
//! (a storage buffer, so the whole scene is one draw call), the lightmap is
//! uploaded as it came off the wire (RGB9E5 or RGBA16F texels are native,
//! filterable GPU formats, so nothing is converted) and the vertex shader
//! places the quads with the [`Camera`]. The fragment shader samples the
//! lightmap bilinearly and tone-maps radiosity exactly as `lightwire bake`
//! and the dashboard do ([`tonemap`]); the frame is rendered with 4x MSAA,
//! resolved, copied to a buffer and read back as an [`image::RgbaImage`].
//!
//! Shared edge texels. The atlas puts the outermost texel centres of a
//! chart *on* the quad's edges (server `atlas.rs`, thesis §4.1), so two
//! quads meeting at an edge hold samples at the same points along it. A
//! quad's corners therefore map to the centres of its chart's corner texels
//! (`SurfaceInfo::corner_uvs`, the same mapping as the dashboard's
//! `view3d.js`): bilinear filtering inside the quad reads only its own
//! chart, never the gutter, and light is continuous across seams.
//!
//! Surfaces are one-sided (scenes/README.md): a quad seen from behind is
//! culled, because the lightmap holds the light leaving its front only.
//!
//! [`reference`] is an independent CPU ray caster of the same picture,
//! for tests.
//!
//! The renderer is built once ([`Renderer::new`]) and reused across frames:
//! geometry is re-uploaded only when the scene changes, the lightmap
//! texture and the render targets only when their sizes change.

pub mod camera;
pub mod geometry;
pub mod reference;
mod renderer;
pub mod tonemap;

pub use camera::{Camera, CameraError, CameraSpec};
pub use lightwire_adapter::AdapterError;
pub use renderer::{BACKGROUND, LightmapTexels, Renderer, Settings};

/// Why a frame could not be rendered. Messages name the input at fault.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No adapter, none matching `--adapter NAME`, or no device on it: the
    /// rule and its messages are [`lightwire_adapter`]'s, which the
    /// server's solvers share.
    #[error(transparent)]
    Adapter(#[from] AdapterError),
    /// The scene description cannot be drawn (a surface naming a missing
    /// object, a rectangle outside the atlas, non-finite corners, ...).
    #[error("scene: {0}")]
    Scene(String),
    /// The poses do not fit the scene.
    #[error("poses: {0}")]
    Poses(String),
    /// The lightmap does not fit the scene's atlas.
    #[error("lightmap: {0}")]
    Lightmap(String),
    /// The requested image cannot be rendered (zero or too large).
    #[error("image size: {0}")]
    Size(String),
    /// The camera does not form a view.
    #[error(transparent)]
    Camera(#[from] CameraError),
    /// The exposure is not a positive finite number.
    #[error("exposure {0} is not a positive finite number")]
    Exposure(f32),
    /// The GPU reported an error while rendering or reading back.
    #[error("GPU: {0}")]
    Gpu(String),
}

/// Renders one frame on a fresh [`Renderer`] (default adapter). Reuse a
/// [`Renderer`] to render several frames: building one creates a device
/// and compiles the pipeline.
pub fn render(
    scene: &lightwire_protocol::SceneInfo,
    poses: &[lightwire_protocol::Pose],
    lightmap: LightmapTexels<'_>,
    camera: &Camera,
    settings: &Settings,
) -> Result<image::RgbaImage, RenderError> {
    Renderer::new(None)?.render(scene, poses, lightmap, camera, settings)
}

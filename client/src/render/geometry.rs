//! From `SceneInfo` to vertices: quads in object space with atlas UVs, and
//! poses to model matrices.
//!
//! Everything here checks what arrives off the wire before the GPU sees it:
//! a surface must name an existing object, its rectangle must lie inside the
//! atlas and its corners must be finite. A server that sends anything else
//! gets a [`RenderError::Scene`] naming the surface, not a GPU validation
//! panic.

use glam::{Mat4, Quat, Vec3};
use lightwire_protocol::{Pose, SceneInfo};

use super::RenderError;

/// One vertex: a quad corner in its object's space, its atlas UV, and the
/// object whose model matrix places it.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub uv: [f32; 2],
    pub object: u32,
}

/// The whole scene as one indexed triangle list.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Four per surface, in corner order.
    pub vertices: Vec<Vertex>,
    /// Six per surface: triangles (0, 1, 2) and (0, 2, 3) of its corners.
    pub indices: Vec<u32>,
}

/// Checks a scene description and builds its mesh.
pub fn mesh(scene: &SceneInfo) -> Result<Mesh, RenderError> {
    if scene.atlas_width == 0 || scene.atlas_height == 0 {
        return Err(RenderError::Scene(format!(
            "the atlas is {}x{} texels",
            scene.atlas_width, scene.atlas_height
        )));
    }
    let mut mesh = Mesh::default();
    for (i, s) in scene.surfaces.iter().enumerate() {
        let name = || format!("surface {i} (\"{}\")", s.name);
        if s.object as usize >= scene.objects.len() {
            return Err(RenderError::Scene(format!(
                "{} names object {}, but the scene has {} objects",
                name(),
                s.object,
                scene.objects.len()
            )));
        }
        let [x, y, w, h] = s.rect.map(u64::from);
        if w == 0
            || h == 0
            || x + w > u64::from(scene.atlas_width)
            || y + h > u64::from(scene.atlas_height)
        {
            return Err(RenderError::Scene(format!(
                "{} has atlas rectangle {:?} (x, y, width, height), outside the {}x{} atlas",
                name(),
                s.rect,
                scene.atlas_width,
                scene.atlas_height
            )));
        }
        if !s.corners.iter().flatten().all(|c| c.is_finite()) {
            return Err(RenderError::Scene(format!(
                "{} has a non-finite corner",
                name()
            )));
        }
        let base = mesh.vertices.len() as u32;
        if !(s.uvs.is_empty()
            || s.uvs.len() == 4 && s.uvs.iter().flatten().all(|x| (0.0..=1.0).contains(x)))
        {
            return Err(RenderError::Scene(format!(
                "{} has {} lightmap coordinates: give none or four, each in [0, 1]",
                name(),
                s.uvs.len()
            )));
        }
        // PROTOCOL.md §3: the rectangle's corner texel centres, or `uvs`.
        let uvs = s.corner_uvs(scene.atlas_width, scene.atlas_height);
        for (corner, uv) in s.corners.iter().zip(uvs) {
            mesh.vertices.push(Vertex {
                position: *corner,
                uv,
                object: s.object,
            });
        }
        mesh.indices.extend([0, 1, 2, 0, 2, 3].map(|k| base + k));
    }
    Ok(mesh)
}

/// The model matrix of a pose: `p' = translation + rotation * (scale * p)`
/// (PROTOCOL.md `Pose`). The quaternion is normalised, so a pose within the
/// protocol's tolerance of unit length does not shear.
pub fn pose_matrix(pose: &Pose) -> Mat4 {
    Mat4::from_scale_rotation_translation(
        Vec3::splat(pose.scale),
        Quat::from_array(pose.rotation).normalize(),
        Vec3::from_array(pose.translation),
    )
}

/// Checks that there is one valid pose per object.
pub fn check_poses(scene: &SceneInfo, poses: &[Pose]) -> Result<(), RenderError> {
    if poses.len() != scene.objects.len() {
        return Err(RenderError::Poses(format!(
            "{} poses for {} objects",
            poses.len(),
            scene.objects.len()
        )));
    }
    for (i, (pose, object)) in poses.iter().zip(&scene.objects).enumerate() {
        pose.validate().map_err(|why| {
            RenderError::Poses(format!("object {i} (\"{}\"): {why}", object.name))
        })?;
    }
    Ok(())
}

/// The world-space bounding box of every surface at `poses`, or `None`
/// for a scene without surfaces. `poses` must have one pose per object.
pub fn world_bounds(scene: &SceneInfo, poses: &[Pose]) -> Option<(Vec3, Vec3)> {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for s in &scene.surfaces {
        let model = pose_matrix(poses.get(s.object as usize)?);
        for c in &s.corners {
            let p = model.transform_point3(Vec3::from_array(*c));
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    (lo.x <= hi.x && lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

/// The poses a scene description starts with (the `Welcome`'s).
pub fn initial_poses(scene: &SceneInfo) -> Vec<Pose> {
    scene.objects.iter().map(|o| o.pose).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightwire_protocol::{ObjectInfo, PixelFormat, SurfaceInfo};

    fn scene(surfaces: Vec<SurfaceInfo>) -> SceneInfo {
        SceneInfo {
            id: "t".into(),
            atlas_width: 64,
            atlas_height: 16,
            tile_size: 8,
            format: PixelFormat::Rgb9e5,
            objects: vec![ObjectInfo {
                name: "static".into(),
                dynamic: false,
                pose: Pose::IDENTITY,
            }],
            materials: vec![],
            surfaces,
            lights: Vec::new(),
        }
    }

    fn quad(name: &str, rect: [u32; 4]) -> SurfaceInfo {
        SurfaceInfo {
            name: name.into(),
            object: 0,
            material: 0,
            corners: [
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            rect,
            uvs: Vec::new(),
        }
    }

    #[test]
    fn corners_map_to_corner_texel_centres() {
        // A 5x3 chart at (10, 4) of a 64x16 atlas: corner texels are
        // columns 10 and 14, rows 4 and 6; their centres +0.5.
        let mut s = quad("q", [10, 4, 5, 3]);
        let uv = s.corner_uvs(64, 16);
        assert_eq!(uv[0], [10.5 / 64.0, 4.5 / 16.0]);
        assert_eq!(uv[1], [14.5 / 64.0, 4.5 / 16.0]);
        assert_eq!(uv[2], [14.5 / 64.0, 6.5 / 16.0]);
        assert_eq!(uv[3], [10.5 / 64.0, 6.5 / 16.0]);
        // A surface on its mesh's own lightmap UVs carries them.
        s.uvs = vec![[0.1, 0.2], [0.3, 0.2], [0.3, 0.4], [0.3, 0.4]];
        assert_eq!(s.corner_uvs(64, 16)[2], [0.3, 0.4]);
        let vertices = mesh(&scene(vec![s.clone()])).expect("valid").vertices;
        assert_eq!(vertices[1].uv, [0.3, 0.2]);
        s.uvs.pop();
        let err = mesh(&scene(vec![s])).expect_err("three uvs");
        assert!(err.to_string().contains("3 lightmap coordinates"), "{err}");
    }

    #[test]
    fn bad_surfaces_are_named() {
        let err = mesh(&scene(vec![
            quad("ok", [0, 0, 2, 2]),
            quad("wide", [60, 0, 5, 2]),
        ]))
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("surface 1 (\"wide\")") && err.contains("outside the 64x16 atlas"),
            "{err}"
        );
        let mut orphan = scene(vec![quad("orphan", [0, 0, 2, 2])]);
        orphan.surfaces[0].object = 3;
        let err = mesh(&orphan).unwrap_err().to_string();
        assert!(
            err.contains("names object 3, but the scene has 1 objects"),
            "{err}"
        );
        let mut nan = scene(vec![quad("nan", [0, 0, 2, 2])]);
        nan.surfaces[0].corners[2][1] = f32::NAN;
        assert!(mesh(&nan).unwrap_err().to_string().contains("non-finite"));
    }

    #[test]
    fn a_mesh_has_two_triangles_per_quad() {
        let m = mesh(&scene(vec![
            quad("a", [0, 0, 2, 2]),
            quad("b", [3, 0, 2, 2]),
        ]))
        .unwrap();
        assert_eq!(m.vertices.len(), 8);
        assert_eq!(m.indices, [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7]);
    }

    #[test]
    fn poses_place_and_bound_the_scene() {
        let mut s = scene(vec![quad("a", [0, 0, 2, 2])]);
        let pose = Pose {
            translation: [10.0, 0.0, 0.0],
            rotation: [
                0.0,
                0.0,
                std::f32::consts::FRAC_1_SQRT_2,
                std::f32::consts::FRAC_1_SQRT_2,
            ],
            scale: 2.0,
        };
        s.objects[0].pose = pose;
        // 90 degrees about z: (1, 0, 0) -> (0, 1, 0), (0, 1, 0) -> (-1, 0, 0).
        let (lo, hi) = world_bounds(&s, &initial_poses(&s)).unwrap();
        assert!(lo.abs_diff_eq(Vec3::new(8.0, 0.0, 0.0), 1e-5), "{lo}");
        assert!(hi.abs_diff_eq(Vec3::new(10.0, 2.0, 0.0), 1e-5), "{hi}");
        assert!(
            check_poses(&s, &[])
                .unwrap_err()
                .to_string()
                .contains("0 poses for 1 objects")
        );
        let bad = Pose { scale: 0.0, ..pose };
        let err = check_poses(&s, &[bad]).unwrap_err().to_string();
        assert!(
            err.contains("object 0 (\"static\"): scale is not positive"),
            "{err}"
        );
    }
}

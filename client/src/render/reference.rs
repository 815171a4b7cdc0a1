//! A CPU reference for the renderer: one ray per pixel centre, exact
//! parallelogram intersection, bilinear lookup in f64.
//!
//! It exists so that tests can check the GPU image against something that
//! shares none of its machinery: no rasterizer, no projection matrix, no
//! texture unit, no UV mapping (`SurfaceInfo::corner_uvs` is not used). A
//! hit on surface `k` at patch parameters `(s, t)` reads the chart's texel
//! coordinates `(x + s (w - 1), y + t (h - 1))` directly, with texel
//! centres at integer coordinates (texel `(a, b)` of a chart sits at `(a /
//! (w - 1), b / (h - 1))`, server `atlas.rs`); a surface on its mesh's own
//! lightmap UVs (`SurfaceInfo::uvs`) reads the atlas at the coordinates
//! they give, affine over it. It is slow (every ray
//! tests every surface) and meant for small images.

use glam::{DVec3, Vec3};
use lightwire_protocol::{Pose, SceneInfo};

use super::camera::Camera;
use super::geometry::pose_matrix;

/// What the ray through one pixel centre sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Index into `SceneInfo::surfaces`.
    pub surface: usize,
    /// Patch parameters: the hit is at `origin + s u + t v`.
    pub s: f64,
    pub t: f64,
    /// Distance from the eye along the ray.
    pub distance: f64,
    /// Bilinearly interpolated radiosity (linear RGB).
    pub radiosity: [f64; 3],
}

/// The unit ray direction through the centre of pixel `(px, py)` of a
/// `width x height` image (rows top to bottom), built from the camera's
/// basis and field of view.
pub fn pixel_ray(camera: &Camera, width: u32, height: u32, px: u32, py: u32) -> DVec3 {
    let eye = camera.eye.as_dvec3();
    let forward = (camera.target.as_dvec3() - eye).normalize();
    let right = forward.cross(camera.up.as_dvec3()).normalize();
    let up = right.cross(forward);
    let tan_y = (f64::from(camera.fov_degrees).to_radians() * 0.5).tan();
    let tan_x = tan_y * f64::from(width) / f64::from(height);
    let x = 2.0 * (f64::from(px) + 0.5) / f64::from(width) - 1.0;
    let y = 1.0 - 2.0 * (f64::from(py) + 0.5) / f64::from(height);
    (forward + right * (x * tan_x) + up * (y * tan_y)).normalize()
}

/// Where a world point lands in the image, in pixel coordinates (x right,
/// y down, pixel centres at `.5`), or `None` behind the eye.
pub fn project(camera: &Camera, width: u32, height: u32, point: Vec3) -> Option<(f64, f64)> {
    let eye = camera.eye.as_dvec3();
    let forward = (camera.target.as_dvec3() - eye).normalize();
    let right = forward.cross(camera.up.as_dvec3()).normalize();
    let up = right.cross(forward);
    let rel = point.as_dvec3() - eye;
    let depth = rel.dot(forward);
    if depth <= 0.0 {
        return None;
    }
    let tan_y = (f64::from(camera.fov_degrees).to_radians() * 0.5).tan();
    let tan_x = tan_y * f64::from(width) / f64::from(height);
    let x = rel.dot(right) / (depth * tan_x);
    let y = rel.dot(up) / (depth * tan_y);
    Some((
        (x + 1.0) * 0.5 * f64::from(width),
        (1.0 - y) * 0.5 * f64::from(height),
    ))
}

/// Bilinear radiosity of surface `surface` at patch parameters `(s, t)`,
/// from a row-major RGB lightmap of the scene's atlas size.
pub fn sample(
    scene: &SceneInfo,
    lightmap: &[[f32; 3]],
    surface: usize,
    s: f64,
    t: f64,
) -> [f64; 3] {
    let info = &scene.surfaces[surface];
    let [x, y, w, h] = info.rect;
    let texel = |a: u32, b: u32| {
        lightmap[(b as usize) * scene.atlas_width as usize + a as usize].map(f64::from)
    };
    if let [u0, u1, _, u3] = info.uvs[..] {
        // On its mesh's own lightmap UVs: the atlas's texel coordinates at
        // (s, t), affine over the surface, read between any texels.
        let at = |k: usize| {
            f64::from(u0[k]) + s * f64::from(u1[k] - u0[k]) + t * f64::from(u3[k] - u0[k])
        };
        let size = [f64::from(scene.atlas_width), f64::from(scene.atlas_height)];
        let (fx, fy) = (
            (at(0) * size[0] - 0.5).clamp(0.0, size[0] - 1.0),
            (at(1) * size[1] - 0.5).clamp(0.0, size[1] - 1.0),
        );
        let (a0, b0) = (fx.floor() as u32, fy.floor() as u32);
        let (a1, b1) = (
            (a0 + 1).min(scene.atlas_width - 1),
            (b0 + 1).min(scene.atlas_height - 1),
        );
        let (wa, wb) = (fx - f64::from(a0), fy - f64::from(b0));
        let (t00, t10, t01, t11) = (texel(a0, b0), texel(a1, b0), texel(a0, b1), texel(a1, b1));
        return std::array::from_fn(|c| {
            (t00[c] * (1.0 - wa) + t10[c] * wa) * (1.0 - wb)
                + (t01[c] * (1.0 - wa) + t11[c] * wa) * wb
        });
    }
    // Chart texel coordinates: centres at integers, edges on the quad's edges.
    let fa = s.clamp(0.0, 1.0) * f64::from(w - 1);
    let fb = t.clamp(0.0, 1.0) * f64::from(h - 1);
    let (a0, b0) = (fa.floor() as u32, fb.floor() as u32);
    let (a1, b1) = ((a0 + 1).min(w - 1), (b0 + 1).min(h - 1));
    let (wa, wb) = (fa - f64::from(a0), fb - f64::from(b0));
    let (t00, t10, t01, t11) = (
        texel(x + a0, y + b0),
        texel(x + a1, y + b0),
        texel(x + a0, y + b1),
        texel(x + a1, y + b1),
    );
    std::array::from_fn(|c| {
        (t00[c] * (1.0 - wa) + t10[c] * wa) * (1.0 - wb) + (t01[c] * (1.0 - wa) + t11[c] * wa) * wb
    })
}

/// Casts one ray per pixel centre and returns what each sees, row-major.
/// Only front faces are hit (surfaces are one-sided, as in the GPU
/// renderer). `poses` has one pose per object; `lightmap` covers the atlas.
pub fn trace(
    scene: &SceneInfo,
    poses: &[Pose],
    lightmap: &[[f32; 3]],
    camera: &Camera,
    width: u32,
    height: u32,
) -> Vec<Option<Hit>> {
    // World-space parallelograms: origin, u, v, normal.
    let quads: Vec<[DVec3; 4]> = scene
        .surfaces
        .iter()
        .map(|s| {
            let m = pose_matrix(&poses[s.object as usize]);
            let [o, a, _, b] = s
                .corners
                .map(|c| m.transform_point3(Vec3::from_array(c)).as_dvec3());
            let (u, v) = (a - o, b - o);
            [o, u, v, u.cross(v)]
        })
        .collect();
    let eye = camera.eye.as_dvec3();
    let mut out = Vec::with_capacity(width as usize * height as usize);
    for py in 0..height {
        for px in 0..width {
            let dir = pixel_ray(camera, width, height, px, py);
            let mut best: Option<(usize, f64, f64, f64)> = None;
            for (k, [o, u, v, n]) in quads.iter().enumerate() {
                let facing = dir.dot(*n);
                if facing >= 0.0 {
                    continue; // back face or edge-on
                }
                let distance = (*o - eye).dot(*n) / facing;
                if distance <= 0.0 || best.is_some_and(|b| b.3 <= distance) {
                    continue;
                }
                // Solve p - o = s u + t v in the plane (Cramer's rule on
                // the Gram matrix).
                let d = eye + dir * distance - *o;
                let (uu, uv, vv) = (u.dot(*u), u.dot(*v), v.dot(*v));
                let (du, dv) = (d.dot(*u), d.dot(*v));
                let det = uu * vv - uv * uv;
                let s = (du * vv - dv * uv) / det;
                let t = (dv * uu - du * uv) / det;
                if (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t) {
                    best = Some((k, s, t, distance));
                }
            }
            out.push(best.map(|(surface, s, t, distance)| Hit {
                surface,
                s,
                t,
                distance,
                radiosity: sample(scene, lightmap, surface, s, t),
            }));
        }
    }
    out
}

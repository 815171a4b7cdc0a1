//! The `view` renderer's contract, on whatever adapter exists (lavapipe in
//! CI; with no adapter at all these fail with the message that says what
//! to install). Each test draws a small synthetic scene and compares the
//! GPU image with the CPU reference (`render::reference`: one ray per pixel
//! centre, exact intersection, bilinear lookup in f64), pixel by pixel.
//!
//! Tolerance: 2 levels of 8-bit sRGB on pixels whose 3x3 neighbourhood the
//! reference sees as covered (so that silhouette pixels, which MSAA blends
//! with the background, are left out). Where it comes from: the GPU
//! interpolates UVs in f32 and quantizes bilinear weights to its sub-texel
//! precision (8 bits on lavapipe, so at most 1/512 of the step between two
//! texels), evaluates `exp`/`pow` approximately, and rounds to 8 bits once;
//! the reference rounds once too. 1 level is rounding, the other is slack
//! for the approximations.

use glam::Vec3;
use lightwire_client::render::reference::{self, Hit};
use lightwire_client::render::tonemap::tone_map;
use lightwire_client::render::{
    AdapterError, BACKGROUND, Camera, CameraSpec, LightmapTexels, RenderError, Renderer, Settings,
};
use lightwire_protocol::lightmap::{Lightmap, quantize_into};
use lightwire_protocol::{ObjectInfo, PixelFormat, Pose, SceneInfo, SurfaceInfo};

const TOLERANCE: u8 = 2;
/// A gutter value far brighter than any chart texel: a pixel that reads
/// outside its chart shows it.
const POISON: [f32; 3] = [40.0, 0.0, 40.0];

fn object(name: &str, pose: Pose) -> ObjectInfo {
    ObjectInfo {
        name: name.into(),
        dynamic: false,
        pose,
    }
}

/// A quad `origin, origin + u, origin + u + v, origin + v`.
fn quad(name: &str, object: u32, origin: Vec3, u: Vec3, v: Vec3, rect: [u32; 4]) -> SurfaceInfo {
    SurfaceInfo {
        name: name.into(),
        object,
        material: 0,
        corners: [origin, origin + u, origin + u + v, origin + v].map(|c| c.to_array()),
        rect,
        uvs: Vec::new(),
    }
}

fn scene(atlas: (u32, u32), objects: Vec<ObjectInfo>, surfaces: Vec<SurfaceInfo>) -> SceneInfo {
    SceneInfo {
        id: "synthetic".into(),
        atlas_width: atlas.0,
        atlas_height: atlas.1,
        tile_size: 8,
        format: PixelFormat::Rgb9e5,
        objects,
        materials: vec![],
        surfaces,
        lights: Vec::new(),
    }
}

/// A 2 x 2 m wall centred on the origin in the plane z = 0, its corners
/// `-1, -1, 0` plus `u` and `v` (so its lit side faces `u x v`), alone in a
/// 16 x 8 atlas with its chart at `rect`.
fn wall_spanned(u: Vec3, v: Vec3, rect: [u32; 4]) -> SceneInfo {
    scene(
        (16, 8),
        vec![object("wall", Pose::IDENTITY)],
        vec![quad("wall", 0, Vec3::new(-1.0, -1.0, 0.0), u, v, rect)],
    )
}

/// [`wall_spanned`] facing +z.
fn wall(rect: [u32; 4]) -> SceneInfo {
    wall_spanned(Vec3::X * 2.0, Vec3::Y * 2.0, rect)
}

/// A lightmap full of [`POISON`], with `f(a, b)` written into the chart of
/// each surface (a, b: texel column and row inside the chart).
fn lightmap(scene: &SceneInfo, f: impl Fn(usize, u32, u32) -> [f32; 3]) -> Vec<[f32; 3]> {
    let mut texels = vec![POISON; (scene.atlas_width * scene.atlas_height) as usize];
    for (k, s) in scene.surfaces.iter().enumerate() {
        let [x, y, w, h] = s.rect;
        for b in 0..h {
            for a in 0..w {
                texels[((y + b) * scene.atlas_width + x + a) as usize] = f(k, a, b);
            }
        }
    }
    texels
}

/// The same texels as the wire would carry them.
fn wire(scene: &SceneInfo, texels: &[[f32; 3]], format: PixelFormat) -> Lightmap {
    let mut map = Lightmap::new(scene.atlas_width, scene.atlas_height, 8, format);
    let bpt = format.bytes_per_texel();
    for (rgb, out) in texels.iter().zip(map.texels.chunks_exact_mut(bpt)) {
        quantize_into(format, *rgb, out);
    }
    map
}

fn camera(text: &str) -> Camera {
    text.parse::<CameraSpec>()
        .unwrap()
        .resolve(None, 1.0)
        .unwrap()
}

fn poses(scene: &SceneInfo) -> Vec<Pose> {
    scene.objects.iter().map(|o| o.pose).collect()
}

/// Renders and compares with the reference; returns (pixels compared,
/// largest difference in levels, the reference hits).
fn compare(
    renderer: &mut Renderer,
    scene: &SceneInfo,
    texels: &[[f32; 3]],
    camera: &Camera,
    (width, height): (u32, u32),
    exposure: f32,
) -> (usize, u8, Vec<Option<Hit>>, image::RgbaImage) {
    let poses = poses(scene);
    let map = wire(scene, texels, scene.format);
    let settings = Settings {
        width,
        height,
        exposure,
    };
    let image = renderer
        .render(scene, &poses, LightmapTexels::from(&map), camera, &settings)
        .unwrap();
    // The reference reads the quantized texels, as the GPU does.
    let quantized = map.to_rgb();
    let hits = reference::trace(scene, &poses, &quantized, camera, width, height);
    let at = |x: i64, y: i64| {
        (x >= 0 && y >= 0 && x < width as i64 && y < height as i64)
            .then(|| hits[(y * width as i64 + x) as usize])
            .flatten()
    };
    let (mut compared, mut worst) = (0, 0u8);
    for y in 0..height as i64 {
        for x in 0..width as i64 {
            let covered = (-1..=1).all(|dy| (-1..=1).all(|dx| at(x + dx, y + dy).is_some()));
            let empty = (-1..=1).all(|dy| (-1..=1).all(|dx| at(x + dx, y + dy).is_none()));
            let got = image.get_pixel(x as u32, y as u32).0;
            if empty {
                assert_eq!(
                    got,
                    [BACKGROUND[0], BACKGROUND[1], BACKGROUND[2], 255],
                    "({x}, {y}) shows no surface"
                );
            }
            if !covered {
                continue;
            }
            let hit = at(x, y).unwrap();
            let want = tone_map(hit.radiosity.map(|c| c as f32), exposure);
            let diff = (0..3).map(|c| got[c].abs_diff(want[c])).max().unwrap();
            assert!(
                diff <= TOLERANCE,
                "pixel ({x}, {y}) on surface {} at (s, t) = ({:.4}, {:.4}): GPU {got:?}, reference {want:?}",
                hit.surface,
                hit.s,
                hit.t
            );
            compared += 1;
            worst = worst.max(diff);
        }
    }
    (compared, worst, hits, image)
}

/// [`compare`] at 96 x 72 pixels for a quad that fills much of the frame;
/// prints the largest difference under `what`.
fn compare_large_quad(
    renderer: &mut Renderer,
    scene: &SceneInfo,
    texels: &[[f32; 3]],
    camera: &Camera,
    exposure: f32,
    what: &str,
) {
    let (compared, worst, _, _) = compare(renderer, scene, texels, camera, (96, 72), exposure);
    assert!(
        compared > 1000,
        "the quad is large in the frame: {compared}"
    );
    eprintln!("{what}: {compared} pixels, max difference {worst} levels");
}

#[test]
fn a_wall_of_constant_radiosity_renders_as_one_colour() {
    let mut renderer = Renderer::new(None).unwrap_or_else(|e| panic!("{e}"));
    // A 2 x 2 m wall facing +z; its 5 x 4 chart sits inside a poisoned
    // atlas, so a UV that strays outside the chart changes the colour.
    let s = wall([3, 2, 5, 4]);
    let c = [0.5, 0.25, 0.125];
    let texels = lightmap(&s, |_, _, _| c);
    let cam = camera("eye=0.3,-0.2,3;target=0,0,0;fov=60");
    let (compared, worst, hits, _) = compare(&mut renderer, &s, &texels, &cam, (64, 48), 2.0);
    let wall_pixels = hits.iter().filter(|h| h.is_some()).count();
    assert!(
        compared > 500 && wall_pixels < 64 * 48 / 2,
        "the wall fills part of the frame: {compared} compared, {wall_pixels} hit"
    );
    assert!(
        worst <= 1,
        "a constant wall differs by at most rounding: {worst}"
    );
}

#[test]
fn radiosity_interpolates_bilinearly_between_texels_on_a_posed_quad() {
    let mut renderer = Renderer::new(None).unwrap();
    // A 4 x 3 chart of distinct values on a quad of a rotated, scaled and
    // translated object, seen obliquely (perspective-correct interpolation
    // matters).
    let turn = glam::Quat::from_rotation_y(0.35) * glam::Quat::from_rotation_x(-0.2);
    let pose = Pose {
        translation: [0.2, 0.1, -0.5],
        rotation: turn.to_array(),
        scale: 1.5,
    };
    let s = scene(
        (16, 8),
        vec![object("static", Pose::IDENTITY), object("posed", pose)],
        vec![quad(
            "q",
            1,
            Vec3::new(-0.5, -0.4, 0.0),
            Vec3::X,
            Vec3::Y * 0.8,
            [6, 3, 4, 3],
        )],
    );
    let values = [
        0.05, 0.9, 0.3, 0.6, 1.4, 0.1, 0.7, 0.2, 0.45, 1.1, 0.02, 0.8,
    ];
    let texels = lightmap(&s, |_, a, b| {
        let v = values[(b * 4 + a) as usize];
        [v, 0.5 * v + 0.1, 1.2 - v.min(1.2)]
    });
    let cam = camera("eye=0.8,0.6,2.2;target=0.1,0,-0.4;fov=50");
    compare_large_quad(&mut renderer, &s, &texels, &cam, 1.5, "bilinear");
}

#[test]
fn adjacent_quads_share_their_edge_texels_without_cracks_or_bleeding() {
    let mut renderer = Renderer::new(None).unwrap();
    // Two coplanar quads meeting at x = 0, charts far apart in a poisoned
    // atlas. As the server's atlas does, both charts hold the same values
    // in the texels on the shared edge (the right column of the left chart,
    // the left column of the right one): radiosity is a smooth function of
    // position sampled at each chart's texel positions.
    let s = scene(
        (32, 16),
        vec![object("walls", Pose::IDENTITY)],
        vec![
            quad(
                "left",
                0,
                Vec3::new(-1.0, -0.75, 0.0),
                Vec3::X,
                Vec3::Y * 1.5,
                [1, 1, 4, 5],
            ),
            quad(
                "right",
                0,
                Vec3::new(0.0, -0.75, 0.0),
                Vec3::X,
                Vec3::Y * 1.5,
                [20, 9, 6, 5],
            ),
        ],
    );
    let field = |x: f32, y: f32| {
        let v = 0.4 + 0.3 * (2.0 * x).sin() + 0.2 * y * y;
        [v, 0.8 * v, 0.3]
    };
    let texels = lightmap(&s, |k, a, b| {
        let [_, _, w, h] = s.surfaces[k].rect;
        let x0 = if k == 0 { -1.0 } else { 0.0 };
        field(
            x0 + a as f32 / (w - 1) as f32,
            -0.75 + 1.5 * b as f32 / (h - 1) as f32,
        )
    });
    let cam = camera("eye=0,0,2.2;target=0,0,0;fov=55");
    let (width, height) = (96, 64);
    let (compared, worst, hits, image) =
        compare(&mut renderer, &s, &texels, &cam, (width, height), 1.5);
    // The seam: pixels whose neighbours lie on the other quad. Each was
    // compared above (their 3x3 neighbourhood is covered), so none is
    // background (a crack) or poisoned (bleeding across the gutter).
    let seam: Vec<(u32, u32)> = (0..height)
        .flat_map(|y| (1..width).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let (a, b) = (
                hits[(y * width + x - 1) as usize],
                hits[(y * width + x) as usize],
            );
            matches!((a, b), (Some(a), Some(b)) if a.surface != b.surface)
        })
        .collect();
    assert!(
        seam.len() > 30,
        "the seam crosses the frame: {} rows",
        seam.len()
    );
    for &(x, y) in &seam {
        for px in [x - 1, x] {
            let p = image.get_pixel(px, y).0;
            assert!(
                p[0] < 250 && p[1] > 60,
                "seam pixel ({px}, {y}) is {p:?}: poison or a crack"
            );
        }
    }
    eprintln!(
        "seam: {compared} pixels, {} seam rows, max difference {worst} levels",
        seam.len()
    );
}

#[test]
fn wire_texels_and_decoded_rgb_render_identically() {
    // The RGB path (a decoded EXR snapshot) converts to RGBA16F; every
    // RGB9E5 value is exact there, so both paths give the same bytes.
    let mut renderer = Renderer::new(None).unwrap();
    let s = wall([0, 0, 7, 6]);
    let texels = lightmap(&s, |_, a, b| {
        [
            0.013 * (a * a) as f32,
            3.7 / (1 + b) as f32,
            1e-5 * a as f32,
        ]
    });
    let cam = camera("eye=0.2,0.1,2.5;target=0,0,0;fov=60");
    let settings = Settings {
        width: 48,
        height: 40,
        exposure: 0.7,
    };
    let poses = poses(&s);
    let map = wire(&s, &texels, PixelFormat::Rgb9e5);
    let a = renderer
        .render(&s, &poses, LightmapTexels::from(&map), &cam, &settings)
        .unwrap();
    let rgb = map.to_rgb();
    let b = renderer
        .render(
            &s,
            &poses,
            LightmapTexels::Rgb {
                width: 16,
                height: 8,
                texels: &rgb,
            },
            &cam,
            &settings,
        )
        .unwrap();
    assert!(
        a == b,
        "RGB9E5 texels and their decoded RGB render the same image"
    );
    // A scene announced as RGBA16F uploads its texels as `Rgba16Float`:
    // checked against the reference like the RGB9E5 path.
    let half = SceneInfo {
        format: PixelFormat::Rgba16f,
        ..s
    };
    let (compared, _, _, _) = compare(&mut renderer, &half, &texels, &cam, (48, 40), 0.7);
    assert!(compared > 300, "{compared}");
}

#[test]
fn the_back_of_a_one_sided_surface_is_not_drawn() {
    let mut renderer = Renderer::new(None).unwrap();
    // The wall faces -z (u = y, v = x); the eye is on its +z side.
    let s = wall_spanned(Vec3::Y * 2.0, Vec3::X * 2.0, [0, 0, 3, 3]);
    let texels = lightmap(&s, |_, _, _| [1.0; 3]);
    let map = wire(&s, &texels, PixelFormat::Rgb9e5);
    let settings = Settings {
        width: 32,
        height: 32,
        exposure: 1.0,
    };
    let mut seen_from = |eye: &str| {
        renderer
            .render(&s, &poses(&s), (&map).into(), &camera(eye), &settings)
            .unwrap()
    };
    let image = seen_from("eye=0,0,3;target=0,0,0");
    assert!(
        image.pixels().all(|p| p.0[..3] == BACKGROUND),
        "only background"
    );
    // From the lit side, the same wall covers the middle of the frame.
    let front = seen_from("eye=0,0,-3;target=0,0,0");
    assert_eq!(front.get_pixel(16, 16).0[..3], tone_map([1.0; 3], 1.0));
}

#[test]
fn bad_input_is_refused_with_a_reason() {
    let mut renderer = Renderer::new(None).unwrap();
    let s = wall([0, 0, 3, 3]);
    let map = wire(&s, &lightmap(&s, |_, _, _| [1.0; 3]), PixelFormat::Rgb9e5);
    let cam = camera("eye=0,0,3;target=0,0,0");
    let ok = Settings {
        width: 8,
        height: 8,
        exposure: 1.0,
    };
    let mut render = |s: &SceneInfo, map: &Lightmap, settings: Settings| {
        renderer
            .render(s, &poses(s), map.into(), &cam, &settings)
            .unwrap_err()
            .to_string()
    };
    let err = render(&s, &map, Settings { width: 0, ..ok });
    assert!(err.contains("image size: 0x8"), "{err}");
    let err = render(
        &s,
        &map,
        Settings {
            width: 1 << 20,
            ..ok
        },
    );
    assert!(err.contains("must be between 1 and"), "{err}");
    let err = render(
        &s,
        &map,
        Settings {
            exposure: f32::NAN,
            ..ok
        },
    );
    assert!(
        err.contains("exposure NaN is not a positive finite number"),
        "{err}"
    );
    let small = Lightmap::new(8, 8, 8, PixelFormat::Rgb9e5);
    let err = render(&s, &small, ok);
    assert!(
        err.contains("8x8 texels, but the scene's atlas is 16x8"),
        "{err}"
    );
    let mut outside = s.clone();
    outside.surfaces[0].rect = [14, 0, 3, 3];
    let err = render(&outside, &map, ok);
    assert!(
        err.contains("surface 0 (\"wall\")") && err.contains("outside the 16x8 atlas"),
        "{err}"
    );

    let err = Renderer::new(Some("no-such-adapter-name")).unwrap_err();
    assert!(matches!(
        err,
        RenderError::Adapter(AdapterError::NoMatchingAdapter { .. })
    ));
    assert!(err.to_string().contains("available: \""), "{err}");
}

/// Protocol 3: a surface with `uvs` is drawn with them, not with its
/// `rect`. A quad whose lightmap coordinates are its chart turned a
/// quarter and sheared (an affine map, as a mesh's own lightmap UVs are
/// over each of its triangles) over a poisoned atlas: the GPU image matches
/// the reference, which reads the atlas at the coordinates `uvs` give.
#[test]
fn a_surface_with_its_own_lightmap_coordinates_is_drawn_with_them() {
    let mut renderer = Renderer::new(None).unwrap();
    let (aw, ah) = (16u32, 16u32);
    let mut surface = quad(
        "q",
        0,
        Vec3::new(-0.6, -0.5, 0.0),
        Vec3::X * 1.2,
        Vec3::Y,
        [2, 2, 10, 10],
    );
    // Texel coordinates of the corners (centres at +0.5), then normalized:
    // u runs down the atlas, v runs right and a little down.
    let corners = [[3.5, 3.5], [3.5, 10.5], [9.5, 12.5], [9.5, 5.5]];
    surface.uvs = corners
        .iter()
        .map(|[x, y]: &[f32; 2]| [x / aw as f32, y / ah as f32])
        .collect();
    let s = scene(
        (aw, ah),
        vec![object("static", Pose::IDENTITY)],
        vec![surface],
    );
    let mut texels = vec![POISON; (aw * ah) as usize];
    for y in 2..14 {
        for x in 2..12 {
            let v = 0.05 + 0.07 * x as f32 + 0.011 * (y * y) as f32;
            texels[(y * aw + x) as usize] = [v, 0.3 + 0.02 * y as f32, 1.0 / v];
        }
    }
    let cam = camera("eye=0.4,0.3,2;target=0,0,0;fov=50");
    compare_large_quad(
        &mut renderer,
        &s,
        &texels,
        &cam,
        1.0,
        "own lightmap coordinates",
    );
}

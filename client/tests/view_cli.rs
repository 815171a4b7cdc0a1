//! `lightwire-client view` against a real `lightwire serve` process.
//!
//! The contract (issue "Thin client library and CLI", must show): `view`
//! renders an image whose lightmapped pixels match a render of the server's
//! snapshot within a stated tolerance.
//!
//! How: the server serves cornell-low on the CPU reference solver, which
//! publishes exactly one (converged) version and then nothing until a
//! driver moves something, so the client's version and the snapshot's are
//! the same. `view` runs as a user runs it (default camera, automatic
//! exposure) and prints the camera, the exposure and the version it drew.
//! The test then fetches, over plain HTTP and without the client library,
//! the scene description (`GET /api/scenes/{id}`) and the snapshot
//! (`GET /api/scenes/{id}/lightmap.exr`, f32 RGB, with its version in
//! `x-lightwire-version`), and renders the same camera with the CPU
//! reference (`render::reference`: a ray per pixel centre, exact
//! intersection, bilinear lookup in f64, no GPU).
//!
//! Tolerance: at most 2 levels of 8-bit sRGB per channel, on every pixel
//! whose 3x3 neighbourhood the reference sees on one surface. Why that is
//! enough and not too much:
//! - Quantization contributes nothing: the snapshot EXR is the server's
//!   published RGB9E5 state decoded to f32 (exactly representable), and the
//!   server's published state is bit for bit what a client holds after
//!   applying the same frames (PROTOCOL.md §5), so both renders read the
//!   same texel values once the versions are equal — which is asserted.
//! - Rasterization differences are excluded by the mask: silhouettes and
//!   creases, where MSAA blends two surfaces or the background, are the
//!   pixels with another surface in their 3x3 neighbourhood.
//! - What remains is the GPU's arithmetic: f32 perspective-correct UVs,
//!   bilinear weights at the device's sub-texel precision (8 bits on
//!   lavapipe: at most 1/512 of a texel step), approximate `exp`/`pow`, and
//!   one rounding to 8 bits on each side: 1 level of rounding plus 1 of
//!   slack. (Measured on lavapipe: 0.)
//!
//! The server binary: Cargo hands a test the paths of its own package's
//! binaries only, so, as `load.rs` does, the test has Cargo make sure the
//! workspace's binaries are built (`cargo test --workspace --no-run` with
//! this profile and target directory: a no-op under `make test`, a build
//! when run alone, never a stale binary) and runs `target/<profile>/lightwire`
//! (`lightwire_testkit::Lightwire::built` says why not `cargo build -p`).

use std::path::PathBuf;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use glam::Vec3;
use lightwire_client::render::reference::{self, Hit};
use lightwire_client::render::tonemap::{auto_exposure, tone_map};
use lightwire_client::render::{BACKGROUND, Camera, CameraSpec};
use lightwire_protocol::{Pose, SceneInfo};
use lightwire_testkit::process::Proc;
use lightwire_testkit::{Lightwire, SCENE, repo, scene_file};

const TOLERANCE: u8 = 2;
const WIDTH: u32 = 320;
const HEIGHT: u32 = 240;

/// cornell-low at half density on the reference solver: one converged
/// version in well under a second, then no more (nothing moves).
fn start_server() -> Proc {
    let server = Lightwire::built().dev_solver();
    server.wait_ready();
    server
}

fn view(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lightwire-client"))
        .arg("view")
        .args(args)
        .output()
        .expect("lightwire-client runs")
}

fn text(output: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

/// `key "value"` or `key value` from view's first output line.
fn field<'a>(line: &'a str, key: &str) -> &'a str {
    let rest = line
        .split_once(&format!("{key} "))
        .unwrap_or_else(|| panic!("no {key} in {line:?}"))
        .1;
    match rest.strip_prefix('"') {
        Some(quoted) => quoted.split('"').next().unwrap(),
        None => rest.split([' ', ',']).next().unwrap(),
    }
}

fn out_dir(name: &str) -> PathBuf {
    let dir = repo().join("target/view-artifacts").join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("artifact directory");
    dir
}

#[test]
fn view_renders_the_streamed_lightmap_like_the_servers_snapshot() {
    let server = start_server();
    let dir = out_dir("snapshot");
    let png = dir.join("frame.png");
    let started = Instant::now();
    let output = view(&[
        &server.url(""),
        "--scene",
        SCENE,
        "--width",
        &WIDTH.to_string(),
        "--height",
        &HEIGHT.to_string(),
        "--out",
        png.to_str().unwrap(),
    ]);
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "view failed:\n{stdout}\n{stderr}");
    eprintln!("view took {:?}:\n{stdout}", started.elapsed());
    let mut lines = stdout.lines();
    let header = lines.next().expect("a line describing the view");
    let camera: Camera = field(header, "camera")
        .parse::<CameraSpec>()
        .unwrap()
        .resolve(None, 1.0)
        .unwrap();
    let exposure: f32 = field(header, "exposure").parse().unwrap();
    let wrote = lines.next().expect("a line per frame");
    let version: u64 = field(wrote, "version").parse().unwrap();

    // The snapshot of the version view drew, and the scene, over HTTP.
    let snapshot = server.get(&scene_file("lightmap.exr"));
    assert_eq!(snapshot.status, 200);
    assert_eq!(
        snapshot.version(),
        Some(version),
        "view drew the snapshot's version"
    );
    let snapshot = snapshot.exr();
    let described = server.get(&format!("/api/scenes/{SCENE}"));
    assert_eq!(described.status, 200);
    let scene: SceneInfo = serde_json::from_slice(&described.body).expect("scene JSON");
    assert_eq!(
        snapshot.dimensions(),
        (scene.atlas_width, scene.atlas_height)
    );
    let texels: Vec<[f32; 3]> = snapshot.pixels().map(|p| p.0).collect();

    // The exposure and the curve are `bake`'s: view's automatic exposure is
    // 1 / white point of this lightmap, and tone-mapping each texel with it
    // gives the server's own lightmap.png byte for byte.
    assert_eq!(exposure, auto_exposure(&texels), "automatic exposure");
    let png_snapshot = server.get(&scene_file("lightmap.png"));
    assert_eq!(png_snapshot.status, 200);
    let baked = image::load_from_memory(&png_snapshot.body)
        .unwrap()
        .into_rgb8();
    for (texel, baked) in texels.iter().zip(baked.pixels()) {
        assert_eq!(tone_map(*texel, exposure), baked.0, "texel {texel:?}");
    }

    // The CPU reference of the same camera, scene and snapshot.
    let poses: Vec<Pose> = scene.objects.iter().map(|o| o.pose).collect();
    let hits = reference::trace(&scene, &poses, &texels, &camera, WIDTH, HEIGHT);
    let image = image::open(&png).expect("view wrote a PNG").into_rgb8();
    assert_eq!(image.dimensions(), (WIDTH, HEIGHT));
    let hit = |x: i64, y: i64| -> Option<Hit> {
        if x < 0 || y < 0 || x >= WIDTH as i64 || y >= HEIGHT as i64 {
            return None;
        }
        hits[(y * WIDTH as i64 + x) as usize]
    };
    let (mut compared, mut worst, mut total) = (0usize, 0u8, 0u64);
    let mut per_surface = vec![(0usize, [0u64; 3]); scene.surfaces.len()];
    for y in 0..HEIGHT as i64 {
        for x in 0..WIDTH as i64 {
            let Some(centre) = hit(x, y) else { continue };
            let interior = (-1..=1).all(|dy| {
                (-1..=1).all(|dx| hit(x + dx, y + dy).is_some_and(|h| h.surface == centre.surface))
            });
            if !interior {
                continue;
            }
            let got = image.get_pixel(x as u32, y as u32).0;
            let want = tone_map(centre.radiosity.map(|c| c as f32), exposure);
            let diff = (0..3).map(|c| got[c].abs_diff(want[c])).max().unwrap();
            assert!(
                diff <= TOLERANCE,
                "pixel ({x}, {y}) on {:?} at (s, t) = ({:.3}, {:.3}): view {got:?}, reference {want:?}",
                scene.surfaces[centre.surface].name,
                centre.s,
                centre.t
            );
            compared += 1;
            worst = worst.max(diff);
            total += u64::from(diff);
            let (n, sum) = &mut per_surface[centre.surface];
            *n += 1;
            for c in 0..3 {
                sum[c] += u64::from(got[c]);
            }
        }
    }
    eprintln!(
        "{compared} lightmapped pixels compared, max difference {worst} levels, mean {:.4}",
        total as f64 / compared as f64
    );

    // Not blank, and the room is where it should be: the default camera
    // frames the open box with background around it (more than half of the
    // frame is surfaces, not all of it), and where the reference sees
    // nothing, view shows background (up to the silhouette's pixels).
    let covered = hits.iter().filter(|h| h.is_some()).count();
    let background = image.pixels().filter(|p| p.0 == BACKGROUND).count();
    let pixels = (WIDTH * HEIGHT) as usize;
    assert!(
        compared > pixels * 4 / 10,
        "{compared} of {pixels} pixels are interior"
    );
    assert!(
        covered > pixels / 2 && covered < pixels * 95 / 100,
        "{covered} of {pixels} pixels hit a surface"
    );
    let outline = (2 * (WIDTH + HEIGHT)) as usize;
    assert!(
        background.abs_diff(pixels - covered) <= outline,
        "background pixels: view {background}, reference {}",
        pixels - covered
    );

    // What a person looks for: red left wall, green right wall, a white
    // light, a shaded box (its faces differ in brightness).
    let mean = |name: &str| {
        let k = scene.surfaces.iter().position(|s| s.name == name).unwrap();
        let (n, sum) = per_surface[k];
        assert!(n > 20, "{name} is visible: {n} pixels");
        sum.map(|s| s as f64 / n as f64)
    };
    let left = mean("left");
    assert!(
        left[0] > 1.5 * left[1] && left[0] > 1.5 * left[2],
        "the left wall is red: {left:?}"
    );
    let right = mean("right");
    assert!(
        right[1] > 1.3 * right[0] && right[1] > 1.3 * right[2],
        "the right wall is green: {right:?}"
    );
    // The light is neutral and the brightest surface (automatic exposure
    // puts the 95th percentile, here the light, at 1 - 1/e: sRGB 208).
    let light = mean("light");
    assert!(
        light
            .iter()
            .all(|&c| (c - light[0]).abs() < 2.0 && c > 200.0),
        "the light is white: {light:?}"
    );
    for (k, (n, sum)) in per_surface.iter().enumerate() {
        let level = sum.iter().sum::<u64>() as f64 / (*n).max(1) as f64 / 3.0;
        assert!(
            scene.surfaces[k].name == "light" || level < light[1],
            "{} is brighter than the light",
            scene.surfaces[k].name
        );
    }
    let box_faces: Vec<f64> = scene
        .surfaces
        .iter()
        .enumerate()
        .filter(|(k, s)| scene.objects[s.object as usize].dynamic && per_surface[*k].0 > 20)
        .map(|(k, _)| per_surface[k].1.iter().sum::<u64>() as f64 / per_surface[k].0 as f64 / 3.0)
        .collect();
    assert!(
        box_faces.len() >= 2,
        "at least two faces of the box are visible"
    );
    let (lo, hi) = box_faces
        .iter()
        .fold((f64::MAX, 0.0f64), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    assert!(
        hi - lo > 10.0,
        "the box's faces are shaded differently: {box_faces:?}"
    );

    // Named points: where the CPU puts a known surface point in the image,
    // view shows that surface's bilinear radiosity.
    for (name, s, t) in [
        ("back", 0.5, 0.5),
        ("floor", 0.8, 0.2),
        ("left", 0.4, 0.6),
        ("right", 0.3, 0.5),
    ] {
        let k = scene.surfaces.iter().position(|x| x.name == name).unwrap();
        let c = scene.surfaces[k].corners.map(Vec3::from_array);
        let point = c[0] + (c[1] - c[0]) * s + (c[3] - c[0]) * t;
        let (px, py) = reference::project(&camera, WIDTH, HEIGHT, point).expect("in front");
        let (x, y) = (px as u32, py as u32);
        let h = hit(x as i64, y as i64).expect("the point is visible");
        assert_eq!(
            scene.surfaces[h.surface].name, name,
            "({x}, {y}) shows {name}"
        );
        let want = tone_map(
            reference::sample(&scene, &texels, k, h.s, h.t).map(|v| v as f32),
            exposure,
        );
        let got = image.get_pixel(x, y).0;
        let diff = (0..3).map(|c| got[c].abs_diff(want[c])).max().unwrap();
        assert!(
            diff <= TOLERANCE,
            "{name} at ({s}, {t}) -> pixel ({x}, {y}): view {got:?}, CPU {want:?}"
        );
    }
}

#[test]
fn view_writes_numbered_frames_on_a_cadence() {
    let server = start_server();
    let dir = out_dir("frames");
    let started = Instant::now();
    let output = view(&[
        &server.ws_url(),
        "--camera",
        "eye=2.78,2.74,9;target=2.78,2.74,0;fov=40",
        "--width",
        "64",
        "--height",
        "48",
        "--exposure",
        "0.5",
        "--frames",
        "3",
        "--every",
        "300",
        "--out",
        dir.join("shot.png").to_str().unwrap(),
    ]);
    let elapsed = started.elapsed();
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "view failed:\n{stdout}\n{stderr}");
    assert!(
        stdout.contains("camera \"eye=2.78,2.74,9;target=2.78,2.74,0;up=0,1,0;fov=40\""),
        "{stdout}"
    );
    assert!(stdout.contains("exposure 0.5 (given)"), "{stdout}");
    let images: Vec<_> = (0..3)
        .map(|i| {
            let path = dir.join(format!("shot-000{i}.png"));
            assert!(
                stdout.contains(&format!("wrote {}: version 1", path.display())),
                "{stdout}"
            );
            image::open(&path).unwrap().into_rgb8()
        })
        .collect();
    assert!(
        elapsed >= Duration::from_millis(600),
        "frames 300 ms apart: {elapsed:?}"
    );
    assert!(!dir.join("shot-0003.png").exists());
    // Nothing moves: the same version, the same picture.
    assert!(images[0] == images[1] && images[1] == images[2]);
    assert!(images[0].pixels().any(|p| p.0 != BACKGROUND));
}

#[test]
fn bad_view_input_is_refused_with_a_reason() {
    let fails = |args: &[&str], expected: &[&str]| {
        let output = view(args);
        let (stdout, stderr) = text(&output);
        assert!(!output.status.success(), "{args:?} should fail:\n{stdout}");
        for e in expected {
            assert!(stderr.contains(e), "{args:?}: {e:?} not in:\n{stderr}");
        }
    };
    fails(
        &["127.0.0.1:9", "--scene", "x", "--camera", "eye=1,2"],
        &["camera \"eye=1,2\"", "has 2 numbers, expected three"],
    );
    fails(
        &["127.0.0.1:9", "--scene", "x", "--width", "0"],
        &["--width"],
    );
    fails(
        &[
            "127.0.0.1:9",
            "--scene",
            "x",
            "--out",
            "/nonexistent-dir/f.png",
        ],
        &["directory /nonexistent-dir does not exist"],
    );
    fails(
        &["127.0.0.1:9", "--scene", "x", "--pose", "box:spin=1"],
        &["unknown key \"spin\""],
    );
    // A port nothing listens on (bound, then released): the error names
    // the address.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .unwrap()
        .port();
    fails(
        &[
            &format!("http://127.0.0.1:{port}"),
            "--scene",
            "cornell-low",
            "--timeout",
            "5",
        ],
        &[
            &format!("ws://127.0.0.1:{port}/ws/scenes/cornell-low"),
            "cannot connect",
        ],
    );
}

/// A floor lit by a bulb, for [`view_goes_on_when_a_reconnect_finds_a_light_switched_off`].
fn lit_floor(on: bool) -> SceneInfo {
    use lightwire_protocol::{
        LightInfo, LightState, LightType, MaterialInfo, ObjectInfo, PixelFormat, SurfaceInfo,
    };
    SceneInfo {
        id: "floor".into(),
        atlas_width: 8,
        atlas_height: 8,
        tile_size: 4,
        format: PixelFormat::Rgb9e5,
        objects: vec![ObjectInfo {
            name: "room".into(),
            dynamic: false,
            pose: Pose::IDENTITY,
        }],
        materials: vec![MaterialInfo {
            name: "white".into(),
            albedo: [0.5; 3],
            emission: [0.0; 3],
        }],
        surfaces: vec![SurfaceInfo {
            name: "floor".into(),
            object: 0,
            material: 0,
            corners: [
                [-1.0, 0.0, 1.0],
                [1.0, 0.0, 1.0],
                [1.0, 0.0, -1.0],
                [-1.0, 0.0, -1.0],
            ],
            rect: [0, 0, 8, 8],
            uvs: Vec::new(),
        }],
        lights: vec![LightInfo {
            name: "bulb".into(),
            kind: LightType::Point,
            range: None,
            cone: [0.0; 2],
            angular_radius: 0.0,
            state: LightState {
                on,
                color: [1.0; 3],
                intensity: 8.0,
                position: [0.0, 1.0, 0.0],
                direction: [0.0, -1.0, 0.0],
            },
        }],
    }
}

/// A driver switched the bulb off while `view`'s connection was down: the
/// reconnect's `Welcome` tells the bulb off (PROTOCOL.md §3), the rest of
/// the scene as before. That is the same scene, so `view` goes on drawing
/// the new versions instead of stopping because the scene changed. The
/// server is the testkit's scripted fake.
#[tokio::test(flavor = "multi_thread")]
async fn view_goes_on_when_a_reconnect_finds_a_light_switched_off() {
    use lightwire_protocol::lightmap::Encoder;
    use lightwire_protocol::{
        CAP_LIGHTS, CAP_POSES, PROTOCOL_VERSION, PixelFormat, Role, ServerMessage,
    };
    use lightwire_testkit::fake::{FakeServer, keyframe, send};

    let fake = FakeServer::bind().await;
    let url = fake.ws_url("floor");
    let dir = out_dir("relit");
    let shot = dir.join("shot.png");
    let args = [
        url.clone(),
        "--camera".into(),
        "eye=0,2,3;target=0,0,0".into(),
        "--width".into(),
        "32".into(),
        "--height".into(),
        "24".into(),
        "--exposure".into(),
        "0.5".into(),
        "--frames".into(),
        "4".into(),
        "--every".into(),
        "500".into(),
        "--out".into(),
        shot.to_str().expect("utf-8 path").into(),
    ];
    let viewing = tokio::task::spawn_blocking(move || {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        view(&args)
    });
    let welcome = |scene| ServerMessage::Welcome {
        protocol_version: PROTOCOL_VERSION,
        server: "fake".into(),
        role: Role::Viewer,
        capabilities: CAP_POSES | CAP_LIGHTS,
        scene,
    };
    let lit = |value: f32| vec![[value, value, value]; 64];
    let mut enc = Encoder::new(8, 8, 4, PixelFormat::Rgb9e5, 0.0);
    enc.publish(&lit(1.0), vec![]);
    let (mut ws, _) = fake.accept().await;
    send(&mut ws, &welcome(lit_floor(true))).await;
    keyframe(&mut ws, enc.keyframe()).await;
    // The first frame is drawn; then the connection drops.
    tokio::time::sleep(Duration::from_millis(100)).await;
    drop(ws);
    let (mut ws, _) = fake.accept().await;
    send(&mut ws, &welcome(lit_floor(false))).await;
    enc.publish(&lit(0.0), vec![]);
    keyframe(&mut ws, enc.keyframe()).await;
    let output = viewing.await.expect("view ran");
    drop(ws);
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "view failed:\n{stdout}\n{stderr}");
    assert!(!stderr.contains("changed"), "{stderr}");
    let last = dir.join("shot-0003.png");
    assert!(
        stdout.contains(&format!("wrote {}: version 2", last.display())),
        "the last frame draws the version lit with the bulb off:\n{stdout}"
    );
}

//! `lightwire-client view`: render what a thin client sees to PNG.
//!
//! Data flow: the arguments are checked and the GPU renderer is opened
//! first (a typo or a machine without an adapter fails before any network
//! traffic); then a [`Client`] connects as a viewer and the command waits
//! for the first complete lightmap version in its front buffer. The camera
//! is resolved against the scene's bounding box (at the poses drawn), the
//! exposure against the first lightmap (unless given), and each frame the
//! newest front buffer is rendered by [`render::Renderer`] and written as an
//! RGB PNG. With `--frames N --every MS`, frames are taken on a fixed
//! cadence (`start + k * MS`, so rendering time does not accumulate) from
//! whatever version is in front then; the exposure stays the first frame's,
//! so that brightness changes between frames are changes of light.
//!
//! Poses: the client asks for `Poses` (PROTOCOL.md §3), so each frame
//! carries the dynamic objects' poses its lightmap was lit for
//! ([`Frame::poses`]); `view` draws them there, the rest at the pose of
//! the `Welcome` (the scene file's), and `--pose` overrides either. From a
//! server that sends no poses, a box a driver has moved is lit where it is
//! but drawn at the scene file's pose; give it with `--pose` then.
//!
//! Every line of output is on stdout: one line describing the view (camera
//! in `--camera` syntax, exposure, adapter), then one per written frame
//! (`wrote PATH: version V, ...`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use glam::{Quat, Vec3};
use lightwire_protocol::{Pose, SceneInfo};

use crate::endpoint::ServerArgs;
use crate::render::camera::parse_vec3;
use crate::render::{self, CameraSpec, LightmapTexels, Renderer, Settings, geometry, tonemap};
use crate::{Client, Frame, Options};

/// Arguments of `lightwire-client view`.
#[derive(clap::Args, Debug, Clone)]
pub struct ViewArgs {
    /// The server, the scene and the token, as the other subcommands take
    /// them.
    #[command(flatten)]
    pub server: ServerArgs,
    /// Camera as "eye=x,y,z;target=x,y,z;up=x,y,z;fov=deg" (fov vertical,
    /// degrees). Every key is optional: target defaults to the centre of
    /// the scene's bounding box, up to +y, fov to 45, and eye to a view
    /// from +z, slightly above, that frames the whole scene. The resolved
    /// camera is printed, ready to paste back.
    #[arg(long, value_parser = parse_camera)]
    pub camera: Option<CameraSpec>,
    /// Eye position x,y,z (overrides --camera's eye).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub eye: Option<Vec3>,
    /// Point at the image centre x,y,z (overrides --camera's target).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub target: Option<Vec3>,
    /// Up direction x,y,z (overrides --camera's up).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub up: Option<Vec3>,
    /// Vertical field of view in degrees (overrides --camera's fov).
    #[arg(long)]
    pub fov: Option<f32>,
    /// Image width in pixels.
    #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub height: u32,
    /// Radiosity is multiplied by this before the tone curve 1 - exp(-x)
    /// and sRGB. Default: 1 / the 95th percentile of the luminance of the
    /// first lightmap's lit texels, as `lightwire bake`'s PNGs.
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Where to write the PNG. With --frames N > 1, frames are numbered
    /// before the extension: frame-0000.png, frame-0001.png, ...
    #[arg(long, default_value = "frame.png")]
    pub out: PathBuf,
    /// How many frames to write.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    /// Milliseconds between frames (with --frames).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    pub every: u64,
    /// Draw an object at another pose than the scene's:
    /// "NAME:translation=x,y,z;rotation=x,y,z,w;scale=s" (quaternion x, y,
    /// z, w; keys optional, the rest from the scene). Repeatable.
    #[arg(long = "pose", value_parser = parse_pose)]
    pub poses: Vec<PoseArg>,
    /// Use the GPU adapter whose name contains this (case-insensitive);
    /// default: prefer a discrete GPU, then integrated, then software
    /// (lavapipe).
    #[arg(long)]
    pub adapter: Option<String>,
    /// Seconds to wait for the connection, and again for the first
    /// complete lightmap.
    #[arg(long, default_value_t = 30.0)]
    pub timeout: f64,
}

/// One `--pose`: an object's name and the keys given for it.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseArg {
    pub object: String,
    pub translation: Option<Vec3>,
    /// x, y, z, w.
    pub rotation: Option<Quat>,
    pub scale: Option<f32>,
}

fn parse_camera(text: &str) -> Result<CameraSpec, String> {
    text.parse().map_err(|e: render::CameraError| e.to_string())
}

/// Parses `NAME:translation=x,y,z;rotation=x,y,z,w;scale=s`.
pub fn parse_pose(text: &str) -> Result<PoseArg, String> {
    let fail = |why: String| {
        format!(
            "pose \"{text}\": {why} (expected e.g. \"box:translation=2.78,0.85,2.8;rotation=0,0.38268,0,0.92388;scale=1\")"
        )
    };
    let (object, keys) = text
        .split_once(':')
        .ok_or_else(|| fail("no \"NAME:\" in front".into()))?;
    let object = object.trim();
    if object.is_empty() {
        return Err(fail("the object name is empty".into()));
    }
    let mut pose = PoseArg {
        object: object.to_string(),
        translation: None,
        rotation: None,
        scale: None,
    };
    for item in keys.split(';').map(str::trim).filter(|s| !s.is_empty()) {
        let (key, value) = item
            .split_once('=')
            .ok_or_else(|| fail(format!("\"{item}\" is not key=value")))?;
        let (key, value) = (key.trim(), value.trim());
        let twice = || fail(format!("\"{key}\" is given twice"));
        match key {
            "translation" => {
                let v = parse_vec3(value).map_err(|e| fail(format!("translation: {e}")))?;
                if pose.translation.replace(v).is_some() {
                    return Err(twice());
                }
            }
            "rotation" => {
                let parts: Vec<f32> = value
                    .split(',')
                    .map(|p| p.trim().parse::<f32>().ok().filter(|x| x.is_finite()))
                    .collect::<Option<_>>()
                    .filter(|v: &Vec<f32>| v.len() == 4)
                    .ok_or_else(|| {
                        fail(format!(
                            "rotation \"{value}\" is not four finite numbers x,y,z,w"
                        ))
                    })?;
                let q = Quat::from_xyzw(parts[0], parts[1], parts[2], parts[3]);
                if pose.rotation.replace(q).is_some() {
                    return Err(twice());
                }
            }
            "scale" => {
                let s = value
                    .parse::<f32>()
                    .map_err(|_| fail(format!("scale \"{value}\" is not a number")))?;
                if pose.scale.replace(s).is_some() {
                    return Err(twice());
                }
            }
            _ => {
                return Err(fail(format!(
                    "unknown key \"{key}\" (keys: translation, rotation, scale)"
                )));
            }
        }
    }
    Ok(pose)
}

/// The scene's poses, with those the server sent for the frame (`served`,
/// [`Frame::poses`]) and then the `--pose` overrides applied; unknown
/// object names and invalid poses are errors naming the object.
pub fn resolve_poses(
    scene: &SceneInfo,
    served: &BTreeMap<u32, Pose>,
    overrides: &[PoseArg],
) -> Result<Vec<Pose>> {
    let mut poses = geometry::initial_poses(scene);
    for (&object, pose) in served {
        if let Some(p) = poses.get_mut(object as usize) {
            *p = *pose;
        }
    }
    for o in overrides {
        let Some(index) = scene.objects.iter().position(|x| x.name == o.object) else {
            let names: Vec<&str> = scene.objects.iter().map(|x| x.name.as_str()).collect();
            bail!(
                "--pose: scene \"{}\" has no object \"{}\"; its objects: {}",
                scene.id,
                o.object,
                names.join(", ")
            );
        };
        let pose = &mut poses[index];
        if let Some(t) = o.translation {
            pose.translation = t.to_array();
        }
        if let Some(r) = o.rotation {
            pose.rotation = r.to_array();
        }
        if let Some(s) = o.scale {
            pose.scale = s;
        }
        pose.validate()
            .map_err(|why| anyhow::anyhow!("--pose for \"{}\": {why}", o.object))?;
    }
    Ok(poses)
}

/// The file frame `index` of `count` is written to: `out` itself for a
/// single frame, else `stem-NNNN.ext`.
pub fn frame_path(out: &Path, index: u32, count: u32) -> PathBuf {
    if count <= 1 {
        return out.to_path_buf();
    }
    let digits = (count - 1).to_string().len().max(4);
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy())
        .unwrap_or_default();
    let name = match out.extension() {
        Some(ext) => format!("{stem}-{index:0digits$}.{}", ext.to_string_lossy()),
        None => format!("{stem}-{index:0digits$}"),
    };
    out.with_file_name(name)
}

/// Checks what can be checked before connecting.
fn check_args(args: &ViewArgs) -> Result<()> {
    if let Some(e) = args.exposure {
        if !(e.is_finite() && e > 0.0) {
            bail!("--exposure {e}: must be a positive number");
        }
    }
    if !(args.timeout.is_finite() && args.timeout > 0.0) {
        bail!(
            "--timeout {}: must be a positive number of seconds",
            args.timeout
        );
    }
    let dir = match args.out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!(
            "--out {}: directory {} does not exist",
            args.out.display(),
            dir.display()
        );
    }
    // The camera's syntax was checked by clap; its geometry needs the scene.
    Ok(())
}

/// Runs `view`: connect, wait for a complete version, render, write PNGs.
/// Synchronous: it starts its own tokio runtime for the connection.
pub fn run(args: ViewArgs) -> Result<()> {
    check_args(&args)?;
    let mut renderer = Renderer::new(args.adapter.as_deref()).context("opening the GPU")?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        // One worker keeps the socket served while this thread renders.
        .worker_threads(1)
        .enable_all()
        .build()
        .context("starting the network runtime")?;
    let timeout = Duration::from_secs_f64(args.timeout);
    let endpoint = args.server.endpoint()?;
    let options = Options {
        connect_timeout: timeout,
        ..args.server.options("view")
    };
    let client = runtime.block_on(Client::connect_with(endpoint, options))?;
    let first = runtime.block_on(client.wait_for_version(1, timeout))?;
    let result = render_frames(&args, &runtime, &client, &mut renderer, first);
    runtime.block_on(client.close());
    result
}

fn render_frames(
    args: &ViewArgs,
    runtime: &tokio::runtime::Runtime,
    client: &Client,
    renderer: &mut Renderer,
    first: Arc<Frame>,
) -> Result<()> {
    let scene = first.scene.clone();
    let poses = resolve_poses(&scene, &first.poses, &args.poses)?;
    let spec = args.camera.unwrap_or_default().overridden_by(CameraSpec {
        eye: args.eye,
        target: args.target,
        up: args.up,
        fov: args.fov,
    });
    let camera = spec
        .resolve(
            geometry::world_bounds(&scene, &poses),
            args.width as f32 / args.height as f32,
        )
        .with_context(|| format!("scene \"{}\"", scene.id))?;
    let (exposure, how) = match args.exposure {
        Some(e) => (e, "given"),
        None => (tonemap::auto_exposure(&first.lightmap.to_rgb()), "auto"),
    };
    println!(
        "view of scene \"{}\": camera \"{camera}\", exposure {exposure} ({how}), {}x{}, adapter {}",
        scene.id,
        args.width,
        args.height,
        renderer.adapter()
    );
    let settings = Settings {
        width: args.width,
        height: args.height,
        exposure,
    };
    let start = Instant::now();
    for index in 0..args.frames {
        if index > 0 {
            let due = start + Duration::from_millis(args.every) * index;
            runtime.block_on(async { tokio::time::sleep_until(due.into()).await });
        }
        let frame = client.frame().unwrap_or_else(|| first.clone());
        // Lights a driver changed meanwhile are the same scene.
        if !frame.scene.same_description(&scene) {
            bail!(
                "scene \"{}\" changed on the server (it was reloaded); run view again",
                scene.id
            );
        }
        let poses = resolve_poses(&scene, &frame.poses, &args.poses)?;
        let image = renderer.render(
            &frame.scene,
            &poses,
            LightmapTexels::from(&frame.lightmap),
            &camera,
            &settings,
        )?;
        let path = frame_path(&args.out, index, args.frames);
        image::DynamicImage::ImageRgba8(image)
            .into_rgb8()
            .save_with_format(&path, image::ImageFormat::Png)
            .with_context(|| format!("writing {}", path.display()))?;
        let unshot = client
            .stats()
            .map(|s| format!(", unshot {:.3}%", 100.0 * s.unshot_fraction))
            .unwrap_or_default();
        println!(
            "wrote {}: version {}{unshot}",
            path.display(),
            frame.version()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightwire_protocol::{ObjectInfo, PixelFormat};

    #[test]
    fn poses_parse_and_override_the_scene() {
        let p = parse_pose("box: translation=1,2,3; rotation=0,0.7071068,0,0.7071068").unwrap();
        assert_eq!(p.object, "box");
        assert_eq!(p.translation, Some(Vec3::new(1.0, 2.0, 3.0)));
        assert_eq!(p.scale, None);
        let scene = SceneInfo {
            id: "s".into(),
            atlas_width: 8,
            atlas_height: 8,
            tile_size: 8,
            format: PixelFormat::Rgb9e5,
            objects: vec![ObjectInfo {
                name: "box".into(),
                dynamic: true,
                pose: Pose {
                    scale: 2.0,
                    ..Pose::IDENTITY
                },
            }],
            materials: vec![],
            surfaces: vec![],
            lights: Vec::new(),
        };
        let poses = resolve_poses(&scene, &BTreeMap::new(), &[p]).unwrap();
        assert_eq!(poses[0].translation, [1.0, 2.0, 3.0]);
        assert_eq!(poses[0].scale, 2.0, "keys not given keep the scene's value");
        let refused = |pose: &str| {
            let pose = parse_pose(pose).unwrap();
            resolve_poses(&scene, &BTreeMap::new(), &[pose])
                .unwrap_err()
                .to_string()
        };
        let err = refused("ball:scale=2");
        assert!(
            err.contains("has no object \"ball\"; its objects: box"),
            "{err}"
        );
        let err = refused("box:scale=0");
        assert!(
            err.contains("--pose for \"box\": scale is not positive"),
            "{err}"
        );
    }

    #[test]
    fn bad_poses_say_what_is_wrong() {
        for (text, expected) in [
            ("box", "no \"NAME:\" in front"),
            (":scale=1", "the object name is empty"),
            ("box:rotation=0,0,1", "not four finite numbers"),
            ("box:spin=1", "unknown key \"spin\""),
            ("box:scale=1;scale=2", "\"scale\" is given twice"),
            ("box:translation=1,2", "expected three"),
        ] {
            let err = parse_pose(text).unwrap_err();
            assert!(
                err.contains(expected) && err.contains(text),
                "{text}: {err}"
            );
        }
    }

    #[test]
    fn frames_are_numbered_before_the_extension() {
        let out = Path::new("out/frame.png");
        assert_eq!(frame_path(out, 0, 1), out);
        assert_eq!(frame_path(out, 3, 10), Path::new("out/frame-0003.png"));
        assert_eq!(frame_path(out, 7, 12345), Path::new("out/frame-00007.png"));
        assert_eq!(frame_path(Path::new("shot"), 1, 2), Path::new("shot-0001"));
    }
}

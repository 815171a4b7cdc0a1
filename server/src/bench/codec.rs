//! `lightwire bench codec`: what the lightmap stream costs a viewer, per
//! codec, on recorded version sequences.
//!
//! **Recording.** Per scene and transform script, the GPU solver follows
//! the script sampled at `rate` poses per second (30: one version per
//! pose, as a viewer at 30 versions/s would receive them) exactly as
//! `lightwire serve` follows transforms: [`GpuLive`], stepped until idle
//! after every pose, its lightmap (invalid texels dilated) taken as the
//! atlas image the server would publish. Recordings are cached under
//! `<out>/recordings/` (the solver is the slow part), keyed by everything
//! that changes them.
//!
//! **Codecs**, run over the same recording side by side:
//!
//! - `v1`: protocol version 1, the codec before residuals: a tile is sent
//!   whole (its new texels, zstd) when any texel changed by more than
//!   `epsilon` (its default was 1/256);
//! - `v2`: residuals of the changed tiles in one zstd frame, and the error
//!   budget (PROTOCOL.md §5), at each `epsilon`.
//!
//! Per version: the bytes of the `Delta` frame as it goes on the wire,
//! the encoder's time (publish and frame encoding) and a receiver's time
//! (frame decoding and applying), and the deviation of what the receiver
//! holds from the solver's quantized lightmap (the budget measure,
//! `|target - held| / max(held, target, floor)` per channel: its maximum
//! and RMS over every texel and version). Every version the receiver is
//! checked bit for bit against the encoder's state, and after the
//! sequence one more publish of the last lightmap (the server's settle)
//! must leave it equal to the solver's lightmap: a codec that got either
//! wrong fails the benchmark instead of reporting a number.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use lightwire_protocol::lightmap::{Encoder, Lightmap, budget_measure, dequantize, quantize_into};
use lightwire_protocol::script::Script;
use lightwire_protocol::{
    Keyframe, PixelFormat, ServerMessage, Tile, decode_server, encode_server,
};
use serde::Serialize;

use crate::service::live::{GpuLive, LiveSolver};
use crate::service::wire::from_wire;
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{LoadOptions, Scene};
use lightwire_solve::gpu::{Device, Redistribution};
use lightwire_solve::load::load_scene;

/// What to run.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Versions recorded after the starting pose.
    pub versions: u32,
    /// Script samples (versions) per second.
    pub rate: f64,
    /// How the solver follows the moves.
    pub method: Redistribution,
    pub density_scale: f32,
    /// Error budgets of the v2 codec.
    pub epsilons: Vec<f32>,
    /// The v1 codec's epsilon.
    pub v1_epsilon: f32,
    /// Tile sizes (texels per side).
    pub tile_sizes: Vec<u16>,
    /// zstd levels.
    pub levels: Vec<i32>,
    /// Where recordings are cached.
    pub out: PathBuf,
}

/// One scene under one script: the solver's lightmap per version.
pub struct Recording {
    pub scene: String,
    pub script: String,
    pub width: u32,
    pub height: u32,
    /// `frames[0]` is the starting pose's converged lightmap.
    pub frames: Vec<Vec<[f32; 3]>>,
}

/// One codec configuration on one recording, in the `--json` shape.
#[derive(Debug, Serialize)]
pub struct CodecResult {
    pub scene: String,
    pub script: String,
    pub codec: String,
    pub epsilon: f32,
    pub tile_size: u16,
    pub zstd_level: i32,
    pub versions: usize,
    /// The keyframe a joining viewer gets.
    pub keyframe_bytes: usize,
    pub bytes_mean: f64,
    pub bytes_p50: usize,
    pub bytes_p95: usize,
    pub bytes_max: usize,
    /// `bytes_mean` at 30 versions per second.
    pub mbit_s_at_30: f64,
    pub encode_us_median: f64,
    pub encode_us_p95: f64,
    pub decode_us_median: f64,
    pub decode_us_p95: f64,
    /// Largest budget measure over every texel and version.
    pub max_deviation: f64,
    /// RMS of the budget measure over every texel channel and version.
    pub rms_deviation: f64,
    /// The settle publish after the sequence (v2 only; 0 for v1).
    pub settle_bytes: usize,
}

/// The script file for `name` in `scene`: `scenes/scripts/<scene>/<name>.json`
/// when the scene has its own, else `scenes/scripts/<name>.json`.
pub fn script_path(scripts: &Path, scene: &str, name: &str) -> PathBuf {
    let own = scripts.join(scene).join(format!("{name}.json"));
    if own.is_file() {
        own
    } else {
        scripts.join(format!("{name}.json"))
    }
}

fn cache_name(scene: &Scene, script: &str, settings: &Settings) -> String {
    format!(
        "{}-{}-{}v-{}hz-{}-d{}.lwrec",
        scene.name,
        script,
        settings.versions,
        settings.rate,
        settings.method.name(),
        settings.density_scale
    )
}

const MAGIC: &[u8; 8] = b"LWREC01\n";

fn save(path: &Path, rec: &Recording) -> Result<()> {
    let mut raw = Vec::with_capacity(rec.frames.len() * rec.frames[0].len() * 12 + 20);
    raw.extend_from_slice(MAGIC);
    for v in [rec.width, rec.height, rec.frames.len() as u32] {
        raw.extend_from_slice(&v.to_le_bytes());
    }
    for frame in &rec.frames {
        for c in frame.iter().flatten() {
            raw.extend_from_slice(&c.to_le_bytes());
        }
    }
    let packed = zstd::bulk::compress(&raw, 3).context("compressing the recording")?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::write(path, packed).with_context(|| format!("writing {}", path.display()))
}

fn load(path: &Path, scene: &str, script: &str) -> Result<Recording> {
    let packed = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let raw = zstd::stream::decode_all(&packed[..])
        .with_context(|| format!("{}: not a zstd recording", path.display()))?;
    let bad = || anyhow::anyhow!("{}: not a recording this version wrote", path.display());
    if raw.len() < 20 || &raw[..8] != MAGIC {
        return Err(bad());
    }
    let word = |i: usize| u32::from_le_bytes([raw[i], raw[i + 1], raw[i + 2], raw[i + 3]]);
    let (width, height, count) = (word(8), word(12), word(16) as usize);
    let texels = width as usize * height as usize;
    if raw.len() != 20 + count * texels * 12 {
        return Err(bad());
    }
    let floats: Vec<f32> = raw[20..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let frames = floats
        .chunks_exact(texels * 3)
        .map(|f| f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        .collect();
    Ok(Recording {
        scene: scene.into(),
        script: script.into(),
        width,
        height,
        frames,
    })
}

/// Runs `live` until it is idle; its latest complete lightmap as an image.
fn settle(live: &mut GpuLive<u32>, atlas: &Atlas) -> Result<Vec<[f32; 3]>> {
    let started = Instant::now();
    while !live.is_idle() {
        live.step(Duration::from_millis(100))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if started.elapsed() > Duration::from_secs(600) {
            bail!("the solver did not go idle within 10 minutes");
        }
    }
    let mut radiosity = live.radiosity().to_vec();
    Ok(crate::publish::lightmap(
        atlas,
        live.validity(),
        &mut radiosity,
    ))
}

/// Records (or loads the cached recording of) `scene_path` under the script
/// `script_name` at `script_path`.
pub fn record(
    gpu: &Device,
    scene_path: &Path,
    script_name: &str,
    script_path: &Path,
    settings: &Settings,
) -> Result<Recording> {
    let (scene, atlas) = load_scene(scene_path, LoadOptions::scaled(settings.density_scale))?;
    let cache = settings
        .out
        .join("recordings")
        .join(cache_name(&scene, script_name, settings));
    if cache.is_file() {
        eprintln!(
            "{} / {script_name}: cached recording {}",
            scene.name,
            cache.display()
        );
        return load(&cache, &scene.name, script_name);
    }
    let script = Script::load(script_path)?;
    let object =
        match &script.object {
            Some(name) => scene
                .objects
                .iter()
                .position(|o| &o.name == name)
                .with_context(|| {
                    format!(
                        "{} drives object {name:?}, which {} does not have",
                        script_path.display(),
                        scene_path.display()
                    )
                })?,
            None => scene.dynamic_objects().next().with_context(|| {
                format!("{} has no dynamic object to move", scene_path.display())
            })? as usize,
        };
    let mut poses = scene.initial_poses();
    let pose_at = |k: u32| from_wire(&script.pose_at(f64::from(k) / settings.rate));
    poses[object] = pose_at(0);
    let started = Instant::now();
    let mut live = GpuLive::new(gpu.clone(), &scene, &atlas, &poses, 0, settings.method)?;
    let mut frames = vec![settle(&mut live, &atlas)?];
    eprintln!(
        "{} / {script_name}: {} elements, start converged in {:.1} s; recording {} versions at {} Hz",
        scene.name,
        atlas.elements.len(),
        started.elapsed().as_secs_f64(),
        settings.versions,
        settings.rate
    );
    let started = Instant::now();
    for k in 1..=settings.versions {
        poses[object] = pose_at(k);
        live.set_poses(&poses, k);
        frames.push(settle(&mut live, &atlas)?);
        if k % 10 == 0 {
            eprintln!(
                "  {k}/{} versions ({:.0} ms per version)",
                settings.versions,
                started.elapsed().as_secs_f64() * 1e3 / f64::from(k)
            );
        }
    }
    let rec = Recording {
        scene: scene.name.clone(),
        script: script_name.into(),
        width: atlas.width,
        height: atlas.height,
        frames,
    };
    save(&cache, &rec)?;
    Ok(rec)
}

/// Which codec.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    V1,
    V2,
}

/// One codec configuration.
#[derive(Debug, Clone, Copy)]
pub struct Config {
    pub codec: Codec,
    pub epsilon: f32,
    pub tile_size: u16,
    pub level: i32,
}

/// Every configuration of `settings`: per tile size and level, v1 then v2
/// at each epsilon.
pub fn configs(settings: &Settings) -> Vec<Config> {
    let mut out = Vec::new();
    for &tile_size in &settings.tile_sizes {
        for &level in &settings.levels {
            out.push(Config {
                codec: Codec::V1,
                epsilon: settings.v1_epsilon,
                tile_size,
                level,
            });
            for &epsilon in &settings.epsilons {
                out.push(Config {
                    codec: Codec::V2,
                    epsilon,
                    tile_size,
                    level,
                });
            }
        }
    }
    out
}

const FORMAT: PixelFormat = PixelFormat::Rgb9e5;

fn quantize(rgb: &[[f32; 3]]) -> Vec<u8> {
    let mut out = vec![0u8; rgb.len() * 4];
    for (c, t) in rgb.iter().zip(out.chunks_exact_mut(4)) {
        quantize_into(FORMAT, *c, t);
    }
    out
}

/// The budget measure of one channel pair, in f64 for the sums.
fn measure(a: f32, b: f32, floor: f32) -> f64 {
    f64::from(budget_measure(a, b, floor))
}

/// Protocol version 1's encoder, which this codec replaced: a tile is sent
/// whole, as its new texels, when any texel changed by more than
/// `epsilon` (the same rule and floor); otherwise it keeps its old texels.
/// Its frames are a `Delta` with a list of `Tile`s: `base_version`, then
/// exactly the fields of a `Keyframe` (version, reflected, tiles), so they
/// are encoded and decoded here as that keyframe behind the base's varint.
struct V1 {
    held: Lightmap,
    epsilon: f32,
    floor: f32,
    compressor: zstd::bulk::Compressor<'static>,
}

impl V1 {
    fn new(w: u32, h: u32, tile_size: u16, epsilon: f32, level: i32) -> Result<Self> {
        Ok(V1 {
            held: Lightmap::new(w, h, tile_size, FORMAT),
            epsilon,
            floor: lightwire_protocol::lightmap::DEFAULT_EPSILON_FLOOR,
            compressor: zstd::bulk::Compressor::new(level)?,
        })
    }

    /// The frame taking the held state to `target` (quantized), and the
    /// new held state.
    fn publish(&mut self, target: &[u8]) -> Result<Vec<u8>> {
        let w = self.held.width as usize;
        let mut tiles = Vec::new();
        for index in 0..self.held.tile_count() {
            let rect = self.held.tile_rect(index).expect("in range");
            let row = |y: u32| {
                let start = (y as usize * w + rect.x as usize) * 4;
                start..start + rect.width as usize * 4
            };
            let changed = (rect.y..rect.y + rect.height).any(|y| {
                let r = row(y);
                self.held.texels[r.clone()]
                    .chunks_exact(4)
                    .zip(target[r].chunks_exact(4))
                    .any(|(a, b)| {
                        let (a, b) = (dequantize(FORMAT, a), dequantize(FORMAT, b));
                        (0..3).any(|c| measure(a[c], b[c], self.floor) > f64::from(self.epsilon))
                    })
            });
            if changed {
                let mut texels = Vec::new();
                for y in rect.y..rect.y + rect.height {
                    let r = row(y);
                    texels.extend_from_slice(&target[r.clone()]);
                    self.held.texels[r.clone()].copy_from_slice(&target[r]);
                }
                tiles.push(Tile {
                    index,
                    data: self.compressor.compress(&texels)?,
                });
            }
        }
        let base = self.held.version;
        self.held.version += 1;
        let body = encode_server(&ServerMessage::Keyframe(Keyframe {
            version: self.held.version,
            reflected: vec![],
            tiles,
        }));
        // Discriminant 2 (Delta), base_version, then the keyframe's fields.
        let mut frame = vec![2u8];
        frame.extend_from_slice(&varint(base));
        frame.extend_from_slice(&body[1..]);
        Ok(frame)
    }
}

/// bincode's varint (PROTOCOL.md §2).
fn varint(v: u64) -> Vec<u8> {
    match v {
        0..=250 => vec![v as u8],
        251..=0xFFFF => [vec![0xFB], (v as u16).to_le_bytes().to_vec()].concat(),
        0x1_0000..=0xFFFF_FFFF => [vec![0xFC], (v as u32).to_le_bytes().to_vec()].concat(),
        _ => [vec![0xFD], v.to_le_bytes().to_vec()].concat(),
    }
}

/// Applies a version 1 frame (see [`V1`]) to `map`.
fn apply_v1(map: &mut Lightmap, frame: &[u8]) -> Result<()> {
    let skip = varint(map.version).len();
    let mut keyframe_form = vec![1u8];
    keyframe_form.extend_from_slice(&frame[1 + skip..]);
    let ServerMessage::Keyframe(k) = decode_server(&keyframe_form)? else {
        bail!("not a version 1 delta");
    };
    for t in &k.tiles {
        let rect = map
            .tile_rect(t.index)
            .with_context(|| format!("tile {} out of range", t.index))?;
        let row = rect.width as usize * 4;
        let texels = zstd::bulk::decompress(&t.data, row * rect.height as usize)
            .with_context(|| format!("tile {}", t.index))?;
        for r in 0..rect.height as usize {
            let start = ((rect.y as usize + r) * map.width as usize + rect.x as usize) * 4;
            map.texels[start..start + row].copy_from_slice(&texels[r * row..(r + 1) * row]);
        }
    }
    map.version = k.version;
    Ok(())
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Runs one codec configuration over a recording.
pub fn run(rec: &Recording, config: Config) -> Result<CodecResult> {
    let (w, h) = (rec.width, rec.height);
    let fail = |what: String| anyhow::anyhow!("{} / {} {config:?}: {what}", rec.scene, rec.script);
    let mut encoder =
        Encoder::new(w, h, config.tile_size, FORMAT, config.epsilon).with_zstd_level(config.level);
    let mut v1 = V1::new(w, h, config.tile_size, config.epsilon, config.level)?;
    let floor = encoder.floor();
    // Both start from the keyframe of the starting pose.
    let start = quantize(&rec.frames[0]);
    encoder.publish(&rec.frames[0], vec![]);
    let keyframe = encoder.keyframe();
    let keyframe_bytes = encode_server(&ServerMessage::Keyframe(keyframe.clone())).len();
    let mut receiver = Lightmap::new(w, h, config.tile_size, FORMAT);
    receiver.apply_keyframe(&keyframe)?;
    v1.held.texels.clone_from(&start);
    v1.held.version = 1;
    let (mut bytes, mut encode_us, mut decode_us) = (Vec::new(), Vec::new(), Vec::new());
    let (mut worst, mut squares, mut count) = (0.0f64, 0.0f64, 0usize);
    let mut settle_bytes = 0;
    let last = rec.frames.len() - 1;
    // The frames, then (v2) the last one again: the server's settle.
    let extra = usize::from(config.codec == Codec::V2);
    let frames = rec.frames[1..]
        .iter()
        .chain(rec.frames[last..].iter().take(extra));
    for (i, frame) in frames.enumerate() {
        let target = quantize(frame);
        let started = Instant::now();
        let wire = match config.codec {
            Codec::V2 => encode_server(&ServerMessage::Delta(encoder.publish(frame, vec![]))),
            Codec::V1 => v1.publish(&quantize(frame))?,
        };
        let encoded = started.elapsed();
        let started = Instant::now();
        match config.codec {
            Codec::V2 => {
                let ServerMessage::Delta(received) = decode_server(&wire)? else {
                    bail!("the encoder's frame is not a Delta");
                };
                receiver.apply_delta(&received)?;
            }
            Codec::V1 => apply_v1(&mut receiver, &wire)?,
        }
        let decoded = started.elapsed();
        let server = match config.codec {
            Codec::V2 => encoder.state(),
            Codec::V1 => &v1.held,
        };
        if receiver.texels != server.texels {
            return Err(fail(format!(
                "the receiver differs from the encoder at version {}",
                receiver.version
            )));
        }
        if i == last {
            settle_bytes = wire.len();
            if receiver.texels != target {
                return Err(fail(
                    "after the settle publish the receiver does not hold the solver's lightmap"
                        .into(),
                ));
            }
            continue;
        }
        bytes.push(wire.len());
        encode_us.push(encoded.as_secs_f64() * 1e6);
        decode_us.push(decoded.as_secs_f64() * 1e6);
        for (held, goal) in receiver.texels.chunks_exact(4).zip(target.chunks_exact(4)) {
            let (a, b) = (dequantize(FORMAT, held), dequantize(FORMAT, goal));
            for c in 0..3 {
                let m = measure(a[c], b[c], floor);
                worst = worst.max(m);
                squares += m * m;
                count += 1;
            }
        }
    }
    if worst > f64::from(config.epsilon) {
        return Err(fail(format!(
            "a receiver deviated by {worst}, over the budget {}",
            config.epsilon
        )));
    }
    let n = bytes.len();
    let mean = bytes.iter().sum::<usize>() as f64 / n.max(1) as f64;
    let mut sorted_bytes: Vec<f64> = bytes.iter().map(|&b| b as f64).collect();
    sorted_bytes.sort_by(f64::total_cmp);
    encode_us.sort_by(f64::total_cmp);
    decode_us.sort_by(f64::total_cmp);
    Ok(CodecResult {
        scene: rec.scene.clone(),
        script: rec.script.clone(),
        codec: match config.codec {
            Codec::V1 => "v1".into(),
            Codec::V2 => "v2".into(),
        },
        epsilon: config.epsilon,
        tile_size: config.tile_size,
        zstd_level: config.level,
        versions: n,
        keyframe_bytes,
        bytes_mean: mean,
        bytes_p50: percentile(&sorted_bytes, 0.5) as usize,
        bytes_p95: percentile(&sorted_bytes, 0.95) as usize,
        bytes_max: sorted_bytes.last().copied().unwrap_or(0.0) as usize,
        mbit_s_at_30: mean * 8.0 * 30.0 / 1e6,
        encode_us_median: percentile(&encode_us, 0.5),
        encode_us_p95: percentile(&encode_us, 0.95),
        decode_us_median: percentile(&decode_us, 0.5),
        decode_us_p95: percentile(&decode_us, 0.95),
        max_deviation: worst,
        rms_deviation: (squares / count.max(1) as f64).sqrt(),
        settle_bytes,
    })
}

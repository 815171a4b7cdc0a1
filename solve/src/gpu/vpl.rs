//! A fast first answer for a light that moves: bounces of instant
//! radiosity with imperfect shadow maps, on the GPU (issue 60 item 3).
//!
//! When a light moves, the session adds the change of its direct light,
//! reflected, to the radiosity `B` and the unshot radiosity `U`
//! ([`super::ProgressiveSolver::set_light`]); refinement then shoots `U`
//! until converged, which takes a few hundred milliseconds and more. What
//! `B` lacks meanwhile is every bounce of `U`. [`FirstBounce`] estimates
//! them in a few GPU passes, so that a state `B + bounces(U)` can be
//! published at once. Each bounce (two by default,
//! [`BounceOptions::bounces`]) is:
//!
//! 1. **Virtual point lights** (ism §4.1): Keller's instant radiosity
//!    places lights where light lands; here they are placed on the
//!    elements whose unshot light is the change, by systematic sampling
//!    of `|U| A` (a stratified walk through its cumulative sum), so the
//!    new lit patch sends light and the old one takes its light back
//!    (negative power). Sampling the change rather than the light keeps
//!    every bounce of what did not change exact.
//! 2. **Imperfect shadow maps** (ism §4.11, Ritschel et al. 2008): each
//!    virtual light gets a 32 x 32 paraboloid depth map of its hemisphere,
//!    splatted from its own subset of the scene's points (the elements,
//!    every `stride`-th from an offset of its own, so the maps together see
//!    all of them), one texel per point, the nearest kept (`atomicMax` on
//!    the complemented bits); the holes between points are filled by
//!    pull-push (Marroquim et al. 2007, as the seed's §8.3.6 does).
//! 3. **Gather**: every element sums `Φ cos θ_v cos θ_r / (π r² + A)` over
//!    the lights its maps say it sees (the disc form factor of thesis eq.
//!    2.2.7-2.2.8, which keeps a light's reach bounded near its own
//!    surface) and reflects it.
//!
//! The next bounce's lights sit on the light the one before left (Keller's
//! walk, ism §4.1, eq. 4.2), and the bounces after the last are added as a
//! geometric series measured on the last two ([`BounceOptions::tail`]).
//! What the first answer misses is what that series gets wrong and what
//! the coarse maps get wrong; it is replaced by the refined state as soon
//! as that is complete (`DynamicSolver`). (The type keeps the name of its
//! first pass.)

use std::time::{Duration, Instant};

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use wgpu::util::DeviceExt;

use super::binding::{Kind, Pass, Resources, Slot};
use super::buffers::{encode_compute, encode_compute_grid, read_back, v4};
use super::{Device, GpuError};
use lightwire_scene::Pose;
use lightwire_scene::atlas::Atlas;

/// Side of one imperfect shadow map (`SIDE` in vpl.wgsl).
pub const ISM_SIDE: u32 = 32;
/// Texels of one map.
const MAP: u64 = (ISM_SIDE * ISM_SIDE) as u64;

/// How many bounces, virtual lights and shadow-map points a first answer
/// uses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BounceOptions {
    /// Virtual point lights (the seed's Fig. 9.8 varies them from 4 to
    /// 1,024: hundreds are needed).
    pub vpls: u32,
    /// Points splatted into each light's map (at most every element; the
    /// seed's Fig. 9.9 varies the scene's points from 10³ to 10⁶, shared
    /// out among the maps).
    pub points: u32,
    /// Relative depth tolerance of the visibility test: a receiver is seen
    /// when its distance is within `1 + bias` of the map's depth.
    pub bias: f32,
    /// Bounces gathered, each from virtual lights on the light the one
    /// before left (0: none, the change's direct light alone).
    pub bounces: u32,
    /// Add the bounces after the last as a geometric series: the last
    /// bounce times `r / (1 - r)`, `r` the share of the bounce before
    /// that the last kept.
    pub tail: bool,
}

/// The largest share of a bounce the next may keep in the tail's series
/// (a room of white walls keeps about 0.7).
const MAX_SHARE: f32 = 0.9;

impl Default for BounceOptions {
    fn default() -> Self {
        // Measured on cornell-point (`lightwire bench lights`, the table
        // of first states by lights and points).
        Self {
            vpls: 256,
            points: 2048,
            bias: 0.1,
            bounces: 2,
            tail: true,
        }
    }
}

/// What a first answer's bounces placed, and where their time went.
#[derive(Debug, Clone, Copy, Default)]
pub struct BounceReport {
    /// Virtual lights placed (at most [`BounceOptions::vpls`]: an element
    /// drawn more than once is one light).
    pub placed: usize,
    /// Placing the virtual lights on the CPU and uploading them and the
    /// receivers.
    pub vpls: Duration,
    /// Splatting the points and pull-push: the imperfect shadow maps.
    pub maps: Duration,
    /// Every receiver gathering from every light, and the read-back.
    pub gather: Duration,
}

impl BounceReport {
    pub fn total(&self) -> Duration {
        self.vpls + self.maps + self.gather
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct BounceParams {
    vpls: u32,
    points: u32,
    receivers: u32,
    stride: u32,
    bias: f32,
    row: u32,
    pad: [u32; 2],
}

/// An element as the bounce sees it (`BounceReceiver` in vpl.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug, PartialEq)]
pub(super) struct BounceReceiver {
    position: [f32; 4],
    normal: [f32; 4],
    albedo: [f32; 4],
}

/// A virtual point light (`GpuVpl` in vpl.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Debug, PartialEq)]
pub(super) struct GpuVpl {
    position: [f32; 4],
    normal: [f32; 4],
    power: [f32; 4],
}

mod slot {
    use super::{Kind, Slot};
    pub(super) const PARAMS: Slot = Slot::new("params", 0, Kind::Uniform);
    pub(super) const RECEIVERS: Slot = Slot::new("receivers", 1, Kind::StorageRead);
    pub(super) const VPLS: Slot = Slot::new("vpls", 2, Kind::StorageRead);
    pub(super) const SPLATS: Slot = Slot::new("splats", 3, Kind::Storage);
    pub(super) const DEPTHS: Slot = Slot::new("depths", 4, Kind::Storage);
    pub(super) const BOUNCE: Slot = Slot::new("bounce", 5, Kind::Storage);
}
use slot::*;

const SPLAT: Pass = Pass {
    entries: &["splat"],
    slots: &[PARAMS, RECEIVERS, VPLS, SPLATS],
};
const PULL_PUSH: Pass = Pass {
    entries: &["pull_push"],
    slots: &[PARAMS, SPLATS, DEPTHS],
};
const GATHER: Pass = Pass {
    entries: &["gather"],
    slots: &[PARAMS, RECEIVERS, VPLS, DEPTHS, BOUNCE],
};
/// Every pass of vpl.wgsl (for the binding tests of `shaders.rs`).
#[cfg(test)]
pub(super) const ALL_PASSES: [Pass; 3] = [SPLAT, PULL_PUSH, GATHER];

/// Every element of `atlas` at `poses` as a receiver: its sample, its
/// normal, `albedo`; receiving where `receives(i)`.
pub(super) fn receivers(
    atlas: &Atlas,
    poses: &[Pose],
    albedo: &[Vec3],
    receives: impl Fn(usize) -> bool,
) -> Vec<BounceReceiver> {
    atlas
        .elements
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let pose = poses.get(e.object as usize).copied().unwrap_or_default();
            let n = pose.transform_normal(e.normal);
            let x = pose.transform_point(e.position);
            let on = receives(i) && e.covers_surface();
            BounceReceiver {
                position: v4(x, if on { 1.0 } else { 0.0 }),
                normal: v4(n, 0.0),
                albedo: v4(albedo.get(i).copied().unwrap_or(Vec3::ZERO), 0.0),
            }
        })
        .collect()
}

/// At most `count` virtual lights for the unshot radiosity `source` (W/m²
/// per channel, signed) of elements of world areas `areas`, placed by
/// systematic sampling of `|U| A` (channels summed): element `j` gets as
/// many of the `count` evenly spaced points of the cumulative sum as fall
/// in its share, merged into one light of `U_j A_j c / (count p_j)` W (an
/// unbiased estimate of its power, `p_j` its share), standing for the area
/// `A_j max(1, 1 / (count p_j))`. Elements that do not receive send nothing.
pub(super) fn place_vpls(
    source: &[Vec3],
    areas: &[f32],
    receivers: &[BounceReceiver],
    count: u32,
) -> Vec<GpuVpl> {
    let weight = |j: usize| -> f64 {
        let on = receivers.get(j).is_some_and(|r| r.position[3] > 0.0);
        if !on {
            return 0.0;
        }
        let u = source[j];
        f64::from(u.x.abs() + u.y.abs() + u.z.abs())
            * f64::from(areas.get(j).copied().unwrap_or(0.0))
    };
    let total: f64 = (0..source.len()).map(weight).sum();
    if total.is_nan() || total <= 0.0 || count == 0 {
        return Vec::new();
    }
    let step = total / f64::from(count);
    let mut lights = Vec::new();
    let (mut before, mut next) = (0.0f64, 0.5 * step);
    for j in 0..source.len() {
        let w = weight(j);
        if w <= 0.0 {
            continue;
        }
        let after = before + w;
        let mut hits = 0u32;
        while next < after {
            hits += 1;
            next += step;
        }
        before = after;
        if hits == 0 {
            continue;
        }
        let share = w / total;
        let expected = f64::from(count) * share;
        let area = f64::from(areas[j]);
        let power = source[j] * (area * f64::from(hits) / expected) as f32;
        let r = &receivers[j];
        lights.push(GpuVpl {
            position: [
                r.position[0],
                r.position[1],
                r.position[2],
                (area * (1.0 / expected).max(1.0)) as f32,
            ],
            normal: r.normal,
            power: v4(power, 0.0),
        });
    }
    lights
}

/// The GPU side of the bounces: pipelines and buffers for a scene of a
/// given element count and [`BounceOptions`].
pub struct FirstBounce {
    options: BounceOptions,
    count: u32,
    params: wgpu::Buffer,
    receivers: wgpu::Buffer,
    vpls: wgpu::Buffer,
    splats: wgpu::Buffer,
    bounce: wgpu::Buffer,
    splat: (wgpu::ComputePipeline, wgpu::BindGroup),
    pull_push: (wgpu::ComputePipeline, wgpu::BindGroup),
    gather: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// Workgroups along x of the splat and pull-push grids.
    row: u32,
}

impl FirstBounce {
    /// Pipelines and buffers for `count` elements.
    pub fn new(gpu: &Device, count: usize, options: BounceOptions) -> Self {
        let device = &gpu.device;
        let count = count.max(1) as u32;
        let options = BounceOptions {
            points: options.points.clamp(1, count),
            ..options
        };
        let storage = |label: &str, size: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16),
                usage: wgpu::BufferUsages::STORAGE | usage,
                mapped_at_creation: false,
            })
        };
        let copy_dst = wgpu::BufferUsages::COPY_DST;
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bounce params"),
            contents: bytemuck::bytes_of(&BounceParams::zeroed()),
            usage: wgpu::BufferUsages::UNIFORM | copy_dst,
        });
        let n = u64::from(count);
        let lights = u64::from(options.vpls.max(1));
        let receivers = storage(
            "bounce receivers",
            n * std::mem::size_of::<BounceReceiver>() as u64,
            copy_dst,
        );
        let vpls = storage(
            "bounce vpls",
            lights * std::mem::size_of::<GpuVpl>() as u64,
            copy_dst,
        );
        let splats = storage("bounce splats", lights * MAP * 4, copy_dst);
        let depths = storage(
            "bounce depths",
            lights * MAP * 4,
            wgpu::BufferUsages::empty(),
        );
        let bounce = storage("bounce", n * 16, wgpu::BufferUsages::COPY_SRC);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("vpl.wgsl"),
            source: wgpu::ShaderSource::Wgsl(super::shaders::vpl().into()),
        });
        let bound = Resources::new()
            .buffer(PARAMS, &params)
            .buffer(RECEIVERS, &receivers)
            .buffer(VPLS, &vpls)
            .buffer(SPLATS, &splats)
            .buffer(DEPTHS, &depths)
            .buffer(BOUNCE, &bounce);
        let splat = SPLAT.compute(device, &module, &[], |s| bound.get(s));
        let pull_push = PULL_PUSH.compute(device, &module, &[], |s| bound.get(s));
        let gather = GATHER.compute(device, &module, &[], |s| bound.get(s));
        let row = gpu
            .limits
            .max_compute_workgroups_per_dimension
            .clamp(1, 65535);
        Self {
            options,
            count,
            params,
            receivers,
            vpls,
            splats,
            bounce,
            splat,
            pull_push,
            gather,
            row,
        }
    }

    pub fn options(&self) -> BounceOptions {
        self.options
    }

    /// The reflected light (W/m² per channel) the unshot radiosity
    /// `source` adds at every receiver: [`BounceOptions::bounces`]
    /// bounces, each of virtual lights placed on the light the one before
    /// left (Keller's walk, ism §4.1, with the light carried rather than
    /// absorbed at random), then the geometric tail of the rest
    /// ([`BounceOptions::tail`]); and what was placed and where the time
    /// went. `areas` are the elements' world areas.
    ///
    /// # Panics
    /// If the slices do not hold one entry per element of the count the
    /// bounce was made for.
    pub(super) fn run(
        &self,
        gpu: &Device,
        receivers: &[BounceReceiver],
        source: &[Vec3],
        areas: &[f32],
    ) -> Result<(Vec<Vec3>, BounceReport), GpuError> {
        let count = self.count as usize;
        assert!(
            receivers.len() == count && source.len() == count && areas.len() == count,
            "one receiver, source and area per element"
        );
        let mut report = BounceReport::default();
        let started = Instant::now();
        gpu.queue
            .write_buffer(&self.receivers, 0, bytemuck::cast_slice(receivers));
        report.vpls += started.elapsed();
        let mut total = vec![Vec3::ZERO; count];
        let mut before = source.to_vec();
        let mut last: Option<Vec<Vec3>> = None;
        for _ in 0..self.options.bounces {
            let from = last.as_deref().unwrap_or(source);
            let Some(light) = self.bounce(gpu, receivers, from, areas, &mut report)? else {
                break;
            };
            for (t, l) in total.iter_mut().zip(&light) {
                *t += *l;
            }
            if let Some(previous) = last.replace(light) {
                before = previous;
            }
        }
        if let (true, Some(last)) = (self.options.tail, &last) {
            // Each bounce keeps about the same share of the one before
            // (the room's reflectance, less what escapes): the rest is
            // the last bounce times r / (1 - r), r that share per channel
            // measured on the last two (absolute power, so that a change
            // whose gains and losses cancel as they spread keeps less).
            let power = |b: &[Vec3]| -> Vec3 {
                b.iter()
                    .zip(areas)
                    .map(|(v, a)| v.abs() * *a)
                    .fold(Vec3::ZERO, |s, v| s + v)
            };
            let (now, then) = (power(last), power(&before));
            let r = Vec3::select(
                then.cmpgt(Vec3::ZERO),
                now / then.max(Vec3::splat(1e-30)),
                Vec3::ZERO,
            )
            .clamp(Vec3::ZERO, Vec3::splat(MAX_SHARE));
            let rest = r / (Vec3::ONE - r);
            for (t, l) in total.iter_mut().zip(last) {
                *t += *l * rest;
            }
        }
        Ok((total, report))
    }

    /// One bounce of `source`: its virtual lights, their maps, the
    /// gather; none when there is no light to place.
    fn bounce(
        &self,
        gpu: &Device,
        receivers: &[BounceReceiver],
        source: &[Vec3],
        areas: &[f32],
        report: &mut BounceReport,
    ) -> Result<Option<Vec<Vec3>>, GpuError> {
        let (device, queue) = (&gpu.device, &gpu.queue);
        let started = Instant::now();
        let lights = place_vpls(source, areas, receivers, self.options.vpls);
        if lights.is_empty() {
            report.vpls += started.elapsed();
            return Ok(None);
        }
        report.placed += lights.len();
        let used = lights.len() as u32;
        let points = self.options.points;
        let stride = self.count.div_ceil(points).max(1);
        let splat_groups = (u64::from(used) * u64::from(points)).div_ceil(64);
        let row = self.row;
        let grid = (
            splat_groups.min(u64::from(row)) as u32,
            splat_groups.div_ceil(u64::from(row)) as u32,
        );
        let params = BounceParams {
            vpls: used,
            points,
            receivers: self.count,
            stride,
            bias: self.options.bias,
            row: grid.0,
            pad: [0; 2],
        };
        queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        queue.write_buffer(&self.vpls, 0, bytemuck::cast_slice(&lights));
        report.vpls += started.elapsed();

        let started = Instant::now();
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.clear_buffer(&self.splats, 0, Some(u64::from(used) * MAP * 4));
        encode_compute_grid(&mut encoder, &self.splat, grid);
        encode_compute_grid(
            &mut encoder,
            &self.pull_push,
            (used.min(65535), used.div_ceil(65535)),
        );
        queue.submit([encoder.finish()]);
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        report.maps += started.elapsed();

        let started = Instant::now();
        let bytes = read_back(
            device,
            queue,
            ("bounce readback", u64::from(self.count) * 16),
            &self.bounce,
            |encoder| encode_compute(encoder, &self.gather, self.count.div_ceil(64)),
        )?;
        let values: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&bytes);
        report.gather += started.elapsed();
        Ok(Some(
            values.iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect(),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An element at `at` facing `normal`, of albedo 0.5, receiving.
    fn element(at: Vec3, normal: Vec3) -> BounceReceiver {
        BounceReceiver {
            position: v4(at, 1.0),
            normal: v4(normal, 0.0),
            albedo: [0.5; 4],
        }
    }

    /// One bounce from a 1 m² source sending 1 W per channel up from the
    /// origin: what a receiver 2 m above it gets (facing down) is the disc
    /// form factor's `ρ Φ cos cos / (π r² + A)`, and nothing with a
    /// 2 x 2 m plate of elements between them, which the imperfect shadow
    /// maps see; a receiver off to the side, past the plate's edge, is lit
    /// either way.
    #[test]
    fn imperfect_shadow_maps_hide_what_a_plate_hides() {
        let gpu = Device::new(None).unwrap_or_else(|e| panic!("{e}"));
        let up = Vec3::Y;
        let above = Vec3::new(0.0, 2.0, 0.0);
        let aside = Vec3::new(3.0, 2.0, 0.0);
        let expected = |at: Vec3| {
            let d = at.length();
            let cos = at.y / d;
            0.5 * cos * cos / (std::f32::consts::PI * d * d + 1.0)
        };
        for plate in [false, true] {
            let mut elements = vec![
                element(Vec3::ZERO, up),
                element(above, -up),
                element(aside, -up),
            ];
            if plate {
                for a in 0..41 {
                    for b in 0..41 {
                        let (x, z) = (a as f32 / 20.0 - 1.0, b as f32 / 20.0 - 1.0);
                        elements.push(element(Vec3::new(x, 1.0, z), -up));
                    }
                }
            }
            let n = elements.len();
            let mut source = vec![Vec3::ZERO; n];
            source[0] = Vec3::ONE;
            let areas = vec![1.0; n];
            let options = BounceOptions {
                vpls: 4,
                points: n as u32,
                bounces: 1,
                tail: false,
                ..BounceOptions::default()
            };
            let bounce = FirstBounce::new(&gpu, n, options);
            let (light, report) = bounce
                .run(&gpu, &elements, &source, &areas)
                .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(report.placed, 1, "one light on the one source");
            let got_above = light[1].x;
            let got_aside = light[2].x;
            let rel = |got: f32, want: f32| (got - want).abs() / want;
            assert!(
                rel(got_aside, expected(aside)) < 1e-3,
                "plate {plate}: aside {got_aside}, expected {}",
                expected(aside)
            );
            if plate {
                assert!(
                    got_above < 0.01 * expected(above),
                    "the plate must hide the source: {got_above}"
                );
            } else {
                assert!(
                    rel(got_above, expected(above)) < 1e-3,
                    "above {got_above}, expected {}",
                    expected(above)
                );
            }
        }
    }

    fn receiver(x: f32, on: bool) -> BounceReceiver {
        BounceReceiver {
            position: [x, 0.0, 0.0, if on { 1.0 } else { 0.0 }],
            normal: [0.0, 1.0, 0.0, 0.0],
            albedo: [0.5; 4],
        }
    }

    /// The lights carry the sources' power: their absolute power is the
    /// sources' exactly, whatever their count (every one of the evenly
    /// spaced points lands), their signed power the sources' to within
    /// one light's share; an element that does not receive gets none.
    #[test]
    fn virtual_lights_carry_the_unshot_power() {
        let source = [
            Vec3::splat(2.0),
            Vec3::splat(-1.0),
            Vec3::ZERO,
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::splat(100.0),
        ];
        let areas = [1.0, 2.0, 1.0, 0.5, 1.0];
        let receivers: Vec<_> = (0..5).map(|k| receiver(k as f32, k != 4)).collect();
        let absolute = 6.0 + 6.0 + 0.25;
        let signed = Vec3::new(0.25, 0.0, 0.0);
        for count in [1, 3, 7, 64, 1000] {
            let lights = place_vpls(&source, &areas, &receivers, count);
            assert!(lights.len() as u32 <= count, "{count}: {}", lights.len());
            assert!(lights.iter().all(|l| l.position[0] != 4.0), "{count}");
            let power = |l: &GpuVpl| Vec3::new(l.power[0], l.power[1], l.power[2]);
            let sum: f32 = lights.iter().map(|l| power(l).abs().element_sum()).sum();
            assert!((sum - absolute).abs() < 1e-4, "{count}: {sum}");
            let share = absolute / count as f32;
            let net: Vec3 = lights.iter().map(power).sum();
            assert!(
                (net - signed).abs().max_element() <= share,
                "{count}: {net}"
            );
        }
        assert!(place_vpls(&[Vec3::ZERO; 2], &[1.0; 2], &receivers[..2], 8).is_empty());
    }
}

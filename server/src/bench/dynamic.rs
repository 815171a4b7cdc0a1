//! `lightwire bench dynamic`: what following a moving object costs, per
//! method, and how close each method stays to a converged solution — thesis
//! Tables 5.1 (NRMSE) and 5.2 (milliseconds per frame) on this machine.
//!
//! Per scene, the dynamic object (the box) rotates about its own y axis by
//! a fixed angle per frame. Each method starts converged at frame 0 (not
//! timed) and then follows the frames one by one; a frame's time runs from
//! handing the solver the new pose until the solver is idle again (the
//! state is complete and refined as far as the method refines it):
//!
//! - `gather` (thesis §4.2): a from-scratch GPU gather solve per frame;
//! - `progressive`: full recompute, progressive refinement from scratch;
//! - `incremental` (thesis §4.4): incremental radiosity with reshooting
//!   (every 10th move re-anchors with a full recompute; the median hides it);
//! - `cross` (thesis §4.5): cross redistribution radiosity.
//!
//! Every method's last frame is compared with a high-quality reference at
//! the same pose — the CPU reference solver where its dense matrix fits,
//! the ray solver to 1e-4 on a level (where hemicube corrections are too
//! slow), else the progressive solver at 4x the hemicube resolution
//! converged to 1e-5 and corrected — by [`lightwire_solve::accuracy::accuracy`] (NRMSE and p95 relative error
//! over the non-emitting elements), and written as an atlas PNG with a x5 difference image (thesis
//! Fig. 5.2.1(f)), all at the reference's exposure.
//!
//! That NRMSE is mostly texels the motion leaves alone, so the NRMSE over
//! the static texels whose reference light the motion changed by more
//! than [`CHANGED`] (a second reference solve, at the start pose) is
//! reported too: the shadows and light the move casts on the scene. At
//! the default 2° a frame the few texels that change lie next to the box,
//! where every move regathers (`gpu/progressive/regather.rs`), and cross
//! redistribution without its projection read the same; at 10° a frame it
//! read 3.31% there against 1.55% (cornell-low, BENCHMARKS.md).
//!
//! With `--profile` (issue 19) each redistribution method's frames are also
//! broken down by unit and stage ([`lightwire_solve::gpu::profile`]): after each
//! frame the state is published as the service publishes a version (read
//! back, invalid texels filled, `Encoder::publish`'s delta), which the
//! breakdown counts as the publication unit; the milliseconds per frame
//! above stay the solver's alone. Profiling adds no work to the solver and
//! changes nothing it computes, so NRMSE and p95 are those of an
//! unprofiled run.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use glam::{Quat, Vec3};
use serde::Serialize;

use crate::bake::{white_point, write_png_with};
use lightwire_protocol::lightmap::Encoder;
use lightwire_protocol::{DEFAULT_TILE_SIZE, PixelFormat};
use lightwire_scene::atlas::Atlas;
use lightwire_scene::{Charts, LoadOptions, Pose, Scene, SolverHints};
use lightwire_solve::accuracy::accuracy_where;
use lightwire_solve::gpu::profile::{Clock, FrameProfile, Profiler, Stage, Unit};
use lightwire_solve::gpu::{
    Correction, Device, DynamicOptions, DynamicSolver, GatherOptions, GatherSolver,
    ProgressiveOptions, ProgressiveSolver, Redistribution,
};
use lightwire_solve::load::load_scene;
use lightwire_solve::rays::{self, RaySolver};
use lightwire_solve::reference::{MAX_ELEMENTS, ReferenceSolver, Silent, SolveOptions};
use lightwire_solve::solver::DEFAULT_CORRECTIONS;
use lightwire_solve::validity::Validity;

/// A method the benchmark compares (thesis Table 5.2's rows).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Gather radiosity from scratch per frame.
    Gather,
    /// Full progressive refinement from scratch per frame.
    Progressive,
    /// Incremental radiosity with reshooting.
    Incremental,
    /// Cross redistribution radiosity.
    Cross,
}

impl Method {
    /// Every method, in the order of the report.
    pub const ALL: [Method; 4] = [
        Self::Gather,
        Self::Progressive,
        Self::Incremental,
        Self::Cross,
    ];

    /// The name in reports and file names.
    pub fn name(self) -> &'static str {
        match self {
            Self::Gather => "gather",
            Self::Progressive => "progressive",
            Self::Incremental => "incremental",
            Self::Cross => "cross",
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What to run.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Frames each redistribution method follows.
    pub frames: u32,
    /// Frames the gather solver follows (it solves from scratch each time).
    pub gather_frames: u32,
    /// Rotation of the box per frame, degrees.
    pub degrees_per_frame: f32,
    /// The methods to run.
    pub methods: Vec<Method>,
    pub density_scale: f32,
    /// How a mesh's triangles get charts (`LoadOptions`).
    pub charts: Charts,
    /// The solver's options; a scene's measured settings (`Scene::solver`)
    /// replace theirs unless `stated` states them too.
    pub progressive: ProgressiveOptions,
    /// The settings the command line states (in `progressive` already):
    /// they win over a scene's.
    pub stated: SolverHints,
    pub gather: GatherOptions,
    /// Gathered correction rounds of a cross session's first solve
    /// (`DynamicOptions::corrections`).
    pub corrections: u32,
    /// Where the images go (one directory per scene inside).
    pub out: PathBuf,
    /// Break each redistribution method's frames down by stage with this
    /// clock (GPU timestamps fall back to CPU timing where the adapter has
    /// none); `None`: no breakdown.
    pub profile: Option<Clock>,
}

/// One scene's results, in the `--json` shape the issue asks for.
#[derive(Debug, Serialize)]
pub struct SceneResult {
    pub scene: String,
    pub adapter: String,
    pub elements: usize,
    pub dynamic_elements: usize,
    /// What the NRMSE is measured against: "reference" (CPU) or
    /// "progressive-hq+corr" (the progressive solver at four times the
    /// hemicube resolution, with the bake's gathered corrections), for
    /// scenes too large for the reference.
    pub reference: String,
    /// The scene file's solver settings this run used (those the command
    /// line did not override), e.g. "cross_grid 3, back_resolution 16", or
    /// "none".
    pub scene_settings: String,
    /// Static non-emitting texels (valid at the last pose) whose reference
    /// light the motion changed by more than [`CHANGED`] of their value:
    /// where the move casts its shadows and light. `nrmse_changed` is
    /// measured over them.
    pub changed_texels: usize,
    pub methods: Vec<MethodResult>,
}

/// A texel counts as changed by the motion when its reference radiosity
/// at the last pose differs from the one at the start by more than this
/// share of it (RGB vector lengths).
pub const CHANGED: f32 = 0.05;

/// One method on one scene.
#[derive(Debug, Serialize)]
pub struct MethodResult {
    /// gather | progressive | incremental | cross
    pub name: String,
    /// Median milliseconds per frame: from the new poses until the
    /// session is idle (for cross and incremental, refinement included).
    pub ms_per_frame: f64,
    pub ms_min: f64,
    pub ms_max: f64,
    /// Median milliseconds from the new poses to the first complete state
    /// that reflects them, the one a viewer waits for (publication not
    /// included); for gather, the frame.
    pub ms_to_state: f64,
    pub frames: usize,
    /// NRMSE of the last frame against the reference: area-weighted, over
    /// the non-emitting elements ([`lightwire_solve::accuracy::accuracy`]).
    pub nrmse: f64,
    /// 95th percentile of the last frame's per-element relative error
    /// against the reference (same elements).
    pub p95_rel: f64,
    /// NRMSE over the static texels the motion changed
    /// ([`SceneResult::changed_texels`]; see the module doc). NaN for a
    /// method compared at another pose (gather with fewer frames) or when
    /// nothing changed.
    pub nrmse_changed: f64,
    /// Milliseconds from the last frame's settled state until its
    /// gathered corrections have run (the scene holding still,
    /// `DynamicOptions::corrections`); 0 without corrections, NaN for
    /// gather.
    pub ms_to_corrected: f64,
    /// NRMSE of the last frame against the reference once corrected (as
    /// [`MethodResult::nrmse`]).
    pub nrmse_corrected: f64,
    /// With `--profile`: where the frames' time went.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub profile: Option<MethodProfile>,
}

/// A method's frames broken down by unit and stage (`--profile`).
#[derive(Debug, Serialize)]
pub struct MethodProfile {
    /// "gpu" (timestamp queries) or "cpu" (submit and wait per stage).
    pub clock: Clock,
    pub frames: usize,
    /// Median wall milliseconds per frame, the publication included.
    pub frame_ms: f64,
    /// Every unit and stage that ran in some frame, in report order.
    pub stages: Vec<StageProfile>,
    /// Medians over the frames of the per-frame sums of the GPU stages and
    /// of the CPU stages. With the GPU clock the two overlap in time.
    pub gpu_stages_ms: f64,
    pub cpu_stages_ms: f64,
}

/// One unit's stage of a [`MethodProfile`].
#[derive(Debug, Serialize)]
pub struct StageProfile {
    pub unit: &'static str,
    pub stage: &'static str,
    /// "gpu" when timed by GPU timestamps, else "cpu".
    pub clock: &'static str,
    /// Median over the frames (a frame without it counts 0).
    pub ms: f64,
    /// `ms` over the median frame.
    pub share: f64,
    /// Median times per frame the stage was timed (batches, passes).
    pub count: f64,
}

impl MethodProfile {
    fn new(clock: Clock, frames: &[FrameProfile]) -> Self {
        let median = |mut v: Vec<f64>| -> f64 {
            v.sort_by(f64::total_cmp);
            let n = v.len();
            match n {
                0 => 0.0,
                _ if n % 2 == 1 => v[n / 2],
                _ => (v[n / 2 - 1] + v[n / 2]) / 2.0,
            }
        };
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let frame_ms = median(frames.iter().map(|f| ms(f.wall)).collect());
        let on_gpu = |s: Stage| s.is_gpu() && clock == Clock::Gpu;
        let mut stages = Vec::new();
        for unit in Unit::ALL {
            for stage in Stage::ALL {
                if !frames.iter().any(|f| f.stages.contains_key(&(unit, stage))) {
                    continue;
                }
                let each = frames
                    .iter()
                    .map(|f| f.stages.get(&(unit, stage)).map_or(0.0, |d| ms(*d)))
                    .collect();
                let value = median(each);
                let count = median(
                    frames
                        .iter()
                        .map(|f| f.counts.get(&(unit, stage)).map_or(0.0, |n| f64::from(*n)))
                        .collect(),
                );
                stages.push(StageProfile {
                    unit: unit.name(),
                    stage: stage.name(),
                    clock: if on_gpu(stage) { "gpu" } else { "cpu" },
                    ms: value,
                    share: if frame_ms > 0.0 {
                        value / frame_ms
                    } else {
                        0.0
                    },
                    count,
                });
            }
        }
        Self {
            clock,
            frames: frames.len(),
            frame_ms,
            stages,
            gpu_stages_ms: median(frames.iter().map(|f| ms(f.sum(on_gpu))).collect()),
            cpu_stages_ms: median(frames.iter().map(|f| ms(f.sum(|s| !on_gpu(s)))).collect()),
        }
    }
}

/// The `--profile` tables of one scene, as Markdown.
pub fn profile_table(result: &SceneResult) -> String {
    let mut out = String::new();
    for m in &result.methods {
        let Some(p) = &m.profile else { continue };
        out += &format!(
            "\n{} {} ({}, {} frames): {:.1} ms per frame with publication; GPU stages {:.1} ms, CPU stages {:.1} ms\n\n",
            result.scene,
            m.name,
            p.clock.name(),
            p.frames,
            p.frame_ms,
            p.gpu_stages_ms,
            p.cpu_stages_ms
        );
        out += "| unit | stage | clock | ms/frame (median) | share | times/frame |\n| --- | --- | --- | --- | --- | --- |\n";
        for s in &p.stages {
            out += &format!(
                "| {} | {} | {} | {:.2} | {:.1}% | {} |\n",
                s.unit,
                s.stage,
                s.clock,
                s.ms,
                s.share * 100.0,
                s.count
            );
        }
    }
    out
}

/// What the service does with each completed state, for the profile's
/// publication unit: read back, fill invalid texels, encode the delta.
struct Publication {
    encoder: Encoder,
}

impl Publication {
    fn new(atlas: &Atlas) -> Self {
        Self {
            // The service's lightmap format and tile size, and
            // `lightwire serve`'s default error budget.
            encoder: Encoder::new(
                atlas.width,
                atlas.height,
                DEFAULT_TILE_SIZE,
                PixelFormat::Rgb9e5,
                1.0 / 64.0,
            ),
        }
    }

    fn publish(
        &mut self,
        session: &DynamicSolver<u32>,
        atlas: &Atlas,
        profile: &Profiler,
    ) -> Result<()> {
        profile.set_unit(Unit::Publication);
        profile.sync();
        let readback = profile.start();
        let mut values = session.radiosity()?;
        profile.stop(readback, Stage::Readback);
        let encode = profile.start();
        let image = crate::publish::lightmap(atlas, session.progressive().validity(), &mut values);
        std::hint::black_box(self.encoder.publish(&image, Vec::new()));
        profile.stop(encode, Stage::Encode);
        Ok(())
    }
}

fn median_ms(times: &mut [Duration]) -> (f64, f64, f64) {
    times.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let n = times.len();
    let median = if n % 2 == 1 {
        ms(times[n / 2])
    } else {
        (ms(times[n / 2 - 1]) + ms(times[n / 2])) / 2.0
    };
    (median, ms(times[0]), ms(times[n - 1]))
}

/// Runs the benchmark on one scene file.
pub fn dynamic_scene(gpu: &Device, path: &Path, settings: &Settings) -> Result<SceneResult> {
    let bench = SceneBench::new(gpu, path, settings)?;
    let mut methods = Vec::new();
    if settings.methods.contains(&Method::Gather) {
        methods.push(bench.gather()?);
    }
    for (which, method) in [
        (Method::Progressive, Redistribution::Full),
        (Method::Incremental, Redistribution::Incremental),
        (Method::Cross, Redistribution::Cross),
    ] {
        if settings.methods.contains(&which) {
            methods.push(bench.redistribution(which, method)?);
        }
    }
    Ok(SceneResult {
        scene: bench.scene.name.clone(),
        adapter: gpu.describe(),
        elements: bench.atlas.elements.len(),
        dynamic_elements: bench.atlas.dynamic_element_count(&bench.scene),
        reference: bench.reference_name,
        scene_settings: bench.used.to_string(),
        changed_texels: bench.changed.iter().filter(|&&c| c).count(),
        methods,
    })
}

/// One scene's benchmark: the scene, its references at the start and at
/// the last frame, and what every method is judged by.
struct SceneBench<'a> {
    gpu: &'a Device,
    settings: &'a Settings,
    scene: Scene,
    atlas: Atlas,
    /// The moving object.
    object: usize,
    start: Vec<Pose>,
    /// The scene file's solver settings that the command line left alone.
    used: SolverHints,
    progressive: ProgressiveOptions,
    /// Frames the redistribution methods follow.
    frames: u32,
    last: Vec<Pose>,
    gather_last: Vec<Pose>,
    reference_name: String,
    /// The reference at `last`.
    expected: Vec<Vec3>,
    /// Texels inside or under geometry at the compared poses are left out
    /// (lightwire_solve::validity).
    visible_last: Validity,
    visible_gather: Validity,
    /// Where the motion changes the light (between the references at the
    /// start and at `last`).
    changed: Vec<bool>,
    dir: PathBuf,
    /// The reference's white point, which scales every image.
    white: f32,
}

impl<'a> SceneBench<'a> {
    /// Loads the scene, solves its references and writes `reference.png`.
    fn new(gpu: &'a Device, path: &Path, settings: &'a Settings) -> Result<Self> {
        let (scene, atlas) = load_scene(
            path,
            LoadOptions {
                density_scale: settings.density_scale,
                charts: settings.charts,
            },
        )?;
        let object = scene.dynamic_objects().next().with_context(|| {
            format!(
                "{} has no dynamic object to move (add one under \"objects\")",
                path.display()
            )
        })? as usize;
        let start = scene.initial_poses();
        let used = SolverHints {
            cross_grid: scene
                .solver
                .cross_grid
                .filter(|_| settings.stated.cross_grid.is_none()),
            back_resolution: scene
                .solver
                .back_resolution
                .filter(|_| settings.stated.back_resolution.is_none()),
            cross_coarse_below: scene
                .solver
                .cross_coarse_below
                .filter(|_| settings.stated.cross_coarse_below.is_none()),
        };
        let progressive = settings.progressive.with_hints(&used);
        let frames = settings.frames.max(1);
        let mut bench = Self {
            gpu,
            settings,
            object,
            used,
            progressive,
            frames,
            last: Vec::new(),
            gather_last: Vec::new(),
            reference_name: String::new(),
            expected: Vec::new(),
            visible_last: Validity::all_valid(&atlas),
            visible_gather: Validity::all_valid(&atlas),
            changed: Vec::new(),
            dir: settings.out.join(&scene.name),
            white: 1.0,
            start,
            scene,
            atlas,
        };
        bench.last = bench.pose_at(frames);
        bench.gather_last = bench.pose_at(settings.gather_frames.max(1));
        eprintln!(
            "{}: {} elements, reference solve at frame {frames}, the scene file's solver settings: {used}",
            bench.scene.name,
            bench.atlas.elements.len()
        );
        let (reference_name, expected) = bench.reference(&bench.last)?;
        // Where the motion changes the light: the reference at the start too.
        let (_, expected_start) = bench.reference(&bench.start)?;
        let (scene, atlas) = (&bench.scene, &bench.atlas);
        let visible_last = Validity::compute(scene, atlas, &bench.last);
        bench.visible_gather = Validity::compute(scene, atlas, &bench.gather_last);
        bench.changed = expected
            .iter()
            .zip(&expected_start)
            .enumerate()
            .map(|(i, (end, begin))| {
                !visible_last.is_invalid(i)
                    && !scene.objects[atlas.elements[i].object as usize].dynamic
                    && atlas.elements[i].emission.max_element() <= 0.0
                    && atlas.elements[i].covers_surface()
                    && (*end - *begin).length() > CHANGED * end.length()
            })
            .collect();
        bench.visible_last = visible_last;

        let dir = &bench.dir;
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        // The reference as solved (its white point scales every image).
        let expected_image = atlas.to_image(&expected);
        bench.white = white_point(&expected_image);
        write_png_with(
            &dir.join("reference.png"),
            atlas.width,
            atlas.height,
            &expected_image,
            bench.white,
        )?;
        bench.reference_name = reference_name;
        bench.expected = expected;
        Ok(bench)
    }

    /// The poses at `frame`: the object turned about y by the frames'
    /// degrees.
    fn pose_at(&self, frame: u32) -> Vec<Pose> {
        let mut poses = self.start.clone();
        let angle = (self.settings.degrees_per_frame * frame as f32).to_radians();
        let object = self.object;
        poses[object].rotation = Quat::from_rotation_y(angle) * poses[object].rotation;
        poses
    }

    /// The reference at `poses`, and what it is: the CPU reference where
    /// the scene is small enough for it; on a level, where a hemicube
    /// correction sweep is too slow, the ray solver converged to 1e-4
    /// (`lightwire_solve::rays`, within 2% of the CPU reference on the
    /// Cornell scenes); else a high-quality corrected progressive solve.
    fn reference(&self, poses: &[Pose]) -> Result<(String, Vec<Vec3>)> {
        let (gpu, scene, atlas) = (self.gpu, &self.scene, &self.atlas);
        if atlas.elements.len() <= MAX_ELEMENTS {
            let solver = ReferenceSolver::new(scene, atlas, poses, &Silent)?;
            return Ok((
                "reference".into(),
                solver.solve(SolveOptions::default(), &Silent).radiosity,
            ));
        }
        if !lightwire_solve::gpu::corrections_affordable(scene, atlas) {
            let mut solver = RaySolver::new(
                scene,
                atlas,
                poses,
                (rays::SIDE, lightwire_solve::direct::GRID),
                &|_, _| {},
            );
            solver.solve(atlas, 1e-4, None, &|_, _| {});
            return Ok(("rays".into(), solver.radiosity().to_vec()));
        }
        let options = ProgressiveOptions {
            hemicube_resolution: self.progressive.hemicube_resolution * 4,
            ..self.progressive
        };
        let mut solver = ProgressiveSolver::new(gpu, scene, atlas, poses, options)?;
        solver.solve(1e-5)?;
        // Progressive refinement alone is biased (its one eye per
        // shooter, yes-or-no visibility) at any resolution, and a
        // session that is nearer the truth would read as further off
        // it: corrected by gathering, as a bake is.
        let mut correction = Correction::new(gpu, scene, atlas, poses, GatherOptions::default())?;
        for _ in 0..DEFAULT_CORRECTIONS {
            correction.round(&mut solver, 1e-5)?;
        }
        Ok(("progressive-hq+corr".into(), solver.radiosity()?))
    }

    /// `NAME.png` and `NAME-diff5.png` (five times the difference from
    /// `against`): what a client would see ([`crate::publish`]).
    fn write_images(&self, name: &str, values: &[Vec3], against: &[Vec3]) -> Result<()> {
        let atlas = &self.atlas;
        let (mut values, mut against) = (values.to_vec(), against.to_vec());
        let image = crate::publish::lightmap(atlas, &self.visible_last, &mut values);
        // The difference is taken between two published states.
        crate::publish::lightmap(atlas, &self.visible_last, &mut against);
        write_png_with(
            &self.dir.join(format!("{name}.png")),
            atlas.width,
            atlas.height,
            &image,
            self.white,
        )?;
        let diff: Vec<Vec3> = values
            .iter()
            .zip(&against)
            .map(|(a, b)| (*a - *b).abs() * 5.0)
            .collect();
        write_png_with(
            &self.dir.join(format!("{name}-diff5.png")),
            atlas.width,
            atlas.height,
            &atlas.to_image(&diff),
            self.white,
        )
    }

    /// NRMSE and p95 of `values` against `against` over the `visible`
    /// texels; NaN (JSON null) when there is nothing to compare.
    fn judge(&self, values: &[Vec3], against: &[Vec3], visible: &Validity) -> (f64, f64) {
        accuracy_where(&self.atlas, values, against, visible.keep())
            .map_or((f64::NAN, f64::NAN), |a| (a.nrmse, a.p95_rel))
    }

    /// NRMSE against the reference where the motion changes the light.
    fn judge_changed(&self, values: &[Vec3]) -> f64 {
        accuracy_where(&self.atlas, values, &self.expected, |i| self.changed[i])
            .map_or(f64::NAN, |a| a.nrmse)
    }

    /// Gather: a from-scratch solve per frame, to the level the others
    /// refine to (power changed per bounce below 0.1% of emitted).
    fn gather(&self) -> Result<MethodResult> {
        let (gpu, scene, atlas, settings) = (self.gpu, &self.scene, &self.atlas, self.settings);
        let mut times = Vec::new();
        let mut values = Vec::new();
        for frame in 1..=settings.gather_frames.max(1) {
            let started = Instant::now();
            let mut solver =
                GatherSolver::new(gpu, scene, atlas, &self.pose_at(frame), settings.gather)?;
            solver.solve(1e-3)?;
            values = solver.radiosity()?;
            times.push(started.elapsed());
            eprintln!("  gather frame {frame}: {:?}", times[times.len() - 1]);
        }
        let at_last = settings.gather_frames.max(1) == self.frames;
        let against = if at_last {
            self.expected.clone()
        } else {
            self.reference(&self.gather_last)?.1
        };
        let (median, min, max) = median_ms(&mut times);
        let visible = if at_last {
            &self.visible_last
        } else {
            &self.visible_gather
        };
        let (nrmse, p95_rel) = self.judge(&values, &against, visible);
        let nrmse_changed = if at_last {
            self.judge_changed(&values)
        } else {
            f64::NAN
        };
        self.write_images("gather", &values, &against)?;
        Ok(MethodResult {
            name: "gather".into(),
            ms_per_frame: median,
            ms_min: min,
            ms_max: max,
            ms_to_state: median,
            frames: times.len(),
            nrmse,
            p95_rel,
            nrmse_changed,
            ms_to_corrected: f64::NAN,
            nrmse_corrected: nrmse,
            profile: None,
        })
    }

    /// A session that follows the frames by `method`, timed per frame and
    /// judged at the last one, then once more after its corrections.
    fn redistribution(&self, which: Method, method: Redistribution) -> Result<MethodResult> {
        let (gpu, atlas) = (self.gpu, &self.atlas);
        let name = which.name();
        let options = DynamicOptions {
            method,
            progressive: self.progressive,
            corrections: self.settings.corrections,
            ..DynamicOptions::default()
        };
        let mut session = DynamicSolver::new(gpu, &self.scene, atlas, &self.start, 0, options)?;
        settle(&mut session, true)?;
        let profiler = self
            .settings
            .profile
            .map_or_else(Profiler::disabled, |clock| Profiler::new(gpu, clock));
        session.set_profiler(profiler.clone());
        let mut publication = profiler.is_enabled().then(|| Publication::new(atlas));
        if let Some(p) = &mut publication {
            // The converged start, so that frames encode deltas.
            p.publish(&session, atlas, &Profiler::disabled())?;
        }
        let mut times = Vec::new();
        let mut to_state = Vec::new();
        let mut profiles = Vec::new();
        for frame in 1..=self.frames {
            profiler.begin_frame();
            let started = Instant::now();
            session.set_poses(&self.pose_at(frame), frame);
            let first = settle(&mut session, false)?;
            times.push(started.elapsed());
            to_state.push(first.unwrap_or_else(|| started.elapsed()));
            if let Some(p) = &mut publication {
                p.publish(&session, atlas, &profiler)?;
            }
            profiles.extend(profiler.end_frame()?);
        }
        let profile = profiler
            .clock()
            .map(|clock| MethodProfile::new(clock, &profiles));
        let values = session.radiosity()?;
        let (median, min, max) = median_ms(&mut times);
        let (state_median, _, _) = median_ms(&mut to_state);
        eprintln!(
            "  {name}: median {median:.1} ms per frame, {state_median:.1} ms to the first state"
        );
        let (nrmse, p95_rel) = self.judge(&values, &self.expected, &self.visible_last);
        // The scene now holds still: its corrections run.
        let started = Instant::now();
        settle(&mut session, true)?;
        let ms_to_corrected = started.elapsed().as_secs_f64() * 1e3;
        let corrected = session.radiosity()?;
        let (nrmse_corrected, _) = self.judge(&corrected, &self.expected, &self.visible_last);
        eprintln!(
            "  {name}: {ms_to_corrected:.0} ms from the last frame to its corrected state, NRMSE {:.2}% -> {:.2}%",
            nrmse * 100.0,
            nrmse_corrected * 100.0
        );
        self.write_images(name, &values, &self.expected)?;
        Ok(MethodResult {
            name: name.into(),
            ms_per_frame: median,
            ms_min: min,
            ms_max: max,
            ms_to_state: state_median,
            frames: times.len(),
            nrmse,
            p95_rel,
            nrmse_changed: self.judge_changed(&values),
            ms_to_corrected,
            nrmse_corrected,
            profile,
        })
    }
}

/// Runs the session until it is settled (a frame: the move's states are
/// complete and refined) or, with `corrected`, idle (its gathered
/// corrections run too); returns how long it took to the first completed
/// state, if there was one.
fn settle(session: &mut DynamicSolver<u32>, corrected: bool) -> Result<Option<Duration>> {
    let started = Instant::now();
    let mut first = None;
    while !(if corrected {
        session.is_idle()
    } else {
        session.is_settled()
    }) {
        if session.step(Duration::from_millis(100))?.completed && first.is_none() {
            first = Some(started.elapsed());
        }
    }
    Ok(first)
}

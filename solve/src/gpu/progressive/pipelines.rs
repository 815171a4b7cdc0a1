//! The compute passes of progressive.wgsl and redistribute.wgsl (two
//! modules, `shaders::progressive` and `shaders::redistribute`, that share
//! one binding table), their bindings by name, and the pipelines a
//! progressive batch runs.

use super::resources::Buffers;
use crate::gpu::binding::Pass;
use crate::gpu::hemicube::{self, Draws};
use crate::gpu::shaders;

use super::slot::*;

/// GENERATESHOOTINGPATCHES: each shooter's unshot power into `energy` (a
/// cluster shooter's from its member patches).
pub(in crate::gpu) const SHOOTER_ENERGY: Pass = Pass {
    entries: &["shooter_energy"],
    slots: &[ELEMENTS, UNSHOT, PATCHES, SHOOTERS, ENERGY, MEMBERS],
};

/// RECONSTRUCTIONSHADER: every element gathers from the batch's shooters.
pub(in crate::gpu) const RECONSTRUCT: Pass = Pass {
    entries: &["reconstruct"],
    slots: &[
        ELEMENTS,
        RADIOSITY,
        UNSHOT,
        IRRADIANCE,
        PATCHES,
        SHOOTERS,
        ENERGY,
        BATCH,
        ITEM,
        OBJECT_FLAGS,
        POSES,
        LOCAL_ELEMENTS,
        PATCH_FRAMES,
    ],
};

/// Unshot power per patch.
pub(in crate::gpu) const PATCH_POWER_PASS: Pass = Pass {
    entries: &["patch_power_main"],
    slots: &[ELEMENTS, UNSHOT, PATCHES, PATCH_POWER, OBJECT_FLAGS],
};

/// FINDSHOOTINGQUAD: the arg-max and the total of the patch powers.
pub(in crate::gpu) const SELECT_SHOOTER: Pass = Pass {
    entries: &["select_shooter"],
    slots: &[PATCH_POWER, SELECTION],
};

/// Elements placed at the current poses.
pub(in crate::gpu) const PLACE_ELEMENTS: Pass = Pass {
    entries: &["place_elements"],
    slots: &[POSES, LOCAL_ELEMENTS, PLACED],
};

/// Redistribution: moving elements back to their emission.
pub(in crate::gpu) const RESET_MOVING: Pass = Pass {
    entries: &["reset_moving"],
    slots: &[
        ELEMENTS,
        RADIOSITY,
        UNSHOT,
        BATCH,
        OBJECT_FLAGS,
        EMISSION,
        OLD_SHOT,
        GATHERED,
        REGATHERED,
        SMOOTHED,
    ],
};

/// Redistribution: what each shooter of a job shoots.
pub(in crate::gpu) const SHOOTER_ENERGY_DYN: Pass = Pass {
    entries: &["shooter_energy_dyn"],
    slots: &[
        ELEMENTS, RADIOSITY, UNSHOT, SHOOTERS, ENERGY, BATCH, OLD_SHOT,
    ],
};

/// Cross redistribution: moving tiles gather the static scene's light.
pub(in crate::gpu) const GATHER_MOVING: Pass = Pass {
    entries: &["gather_moving"],
    slots: &[
        ELEMENTS,
        RADIOSITY,
        UNSHOT,
        SHOOTERS,
        ENERGY,
        BATCH,
        LOCAL_ELEMENTS,
        OLD_SHOT,
        FRONT_IDS,
        SHOWN_FRONT,
        GATHERED,
        MOVING_DIRECT,
    ],
};

/// Cross redistribution: moving tiles gather again, from the total
/// radiosity, once a move's batches have run.
pub(in crate::gpu) const REGATHER_MOVING: Pass = Pass {
    entries: &["regather_moving"],
    slots: &[SHOOTERS, FRONT_IDS, SHOWN_FRONT, REGATHERED],
};

/// Cross redistribution: what the static set shows a batch's front and back
/// hemicubes, one texel per element (`shade_back` and the moving tiles'
/// gathers read them).
pub(in crate::gpu) const SHADE_STATIC: Pass = Pass {
    entries: &["shade_static"],
    slots: &[
        ELEMENTS,
        RADIOSITY,
        UNSHOT,
        BATCH,
        OBJECT_FLAGS,
        EMISSION,
        HELD,
        SHOWN_BACK_OUT,
        SHOWN_FRONT_OUT,
    ],
};

/// Cross redistribution: what the static set shows the regathering's front
/// hemicubes (its total radiosity).
pub(in crate::gpu) const SHADE_TOTAL: Pass = Pass {
    entries: &["shade_total"],
    slots: &[
        ELEMENTS,
        RADIOSITY,
        UNSHOT,
        BATCH,
        OBJECT_FLAGS,
        EMISSION,
        HELD,
        SHOWN_FRONT_OUT,
    ],
};

/// Cross redistribution: the back hemicubes' element ids and distances
/// shaded into shot radiosity and distance for the cross projection.
pub(in crate::gpu) const SHADE_BACK: Pass = Pass {
    entries: &["shade_back"],
    slots: &[BACK, BACK_IDS, SHOWN_BACK, BACK_RAD_OUT],
};

/// Cross redistribution: a moving face's light read between tile centres.
pub(in crate::gpu) const SMOOTH_MOVING: Pass = Pass {
    entries: &["smooth_moving"],
    slots: &[
        ELEMENTS,
        RADIOSITY,
        PATCHES,
        BATCH,
        OBJECT_FLAGS,
        GATHERED,
        REGATHERED,
        SMOOTHED,
        MOVING_DIRECT,
    ],
};

/// Redistribution: every element takes what a job's shooters change.
pub(in crate::gpu) const RECONSTRUCT_DYN: Pass = Pass {
    entries: &["reconstruct_dyn"],
    slots: &[
        ELEMENTS,
        RADIOSITY,
        UNSHOT,
        PATCHES,
        SHOOTERS,
        ENERGY,
        BATCH,
        ITEM,
        OBJECT_FLAGS,
        POSES,
        LOCAL_ELEMENTS,
        BACK_RAD,
        BACK_SAMPLER,
        BACK_SHOOTERS,
        BACK,
        MARKS,
        PATCH_FRAMES,
    ],
};

/// Every pass of the progressive module, for the naga check in shaders.rs.
#[cfg(test)]
pub(in crate::gpu) const PROGRESSIVE_PASSES: [Pass; 5] = [
    SHOOTER_ENERGY,
    RECONSTRUCT,
    PATCH_POWER_PASS,
    SELECT_SHOOTER,
    PLACE_ELEMENTS,
];

/// Every pass of the redistribution module, for the naga check in
/// shaders.rs.
#[cfg(test)]
pub(in crate::gpu) const REDISTRIBUTION_PASSES: [Pass; 9] = [
    RESET_MOVING,
    SHOOTER_ENERGY_DYN,
    SHADE_STATIC,
    SHADE_BACK,
    SHADE_TOTAL,
    GATHER_MOVING,
    REGATHER_MOVING,
    SMOOTH_MOVING,
    RECONSTRUCT_DYN,
];

/// The pipelines of a progressive batch, each with its bind group.
pub(super) struct Pipelines {
    pub(super) shooter_energy: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) reconstruct: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) patch_power: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) select: (wgpu::ComputePipeline, wgpu::BindGroup),
    pub(super) place: (wgpu::ComputePipeline, wgpu::BindGroup),
    /// Item buffers of patch ids (hemicube.wgsl).
    pub(super) item_buffers: (hemicube::Pipelines, wgpu::BindGroup),
}

/// The compute modules' `CUT_SHOOTERS` (common.wgsl): only a scene with
/// triangle patches has shooters cut by a triangle's diagonal.
pub(super) fn cut_constants(triangles: bool) -> [(&'static str, f64); 1] {
    [("CUT_SHOOTERS", if triangles { 1.0 } else { 0.0 })]
}

impl Pipelines {
    /// `triangles`: whether the scene has triangle patches
    /// ([`cut_constants`]).
    pub(super) fn new(
        device: &wgpu::Device,
        buffers: &Buffers,
        draws: Draws,
        triangles: bool,
    ) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("progressive.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::progressive().into()),
        });
        let hemicube_module = draws.module(device, "hemicube.wgsl");
        let resources = buffers.resources();
        let cuts = cut_constants(triangles);
        let compute = |pass: Pass| pass.compute(device, &module, &cuts, |s| resources.get(s));
        let item_layout = hemicube::ITEM_BUFFERS.layout(device);
        let item_pipeline = hemicube::Pipelines::new(
            device,
            (&hemicube_module, draws),
            &hemicube::ITEM_BUFFERS,
            &item_layout,
        );
        let item_group = hemicube::ITEM_BUFFERS.bind(device, &item_layout, |s| resources.get(s));
        Self {
            shooter_energy: compute(SHOOTER_ENERGY),
            reconstruct: compute(RECONSTRUCT),
            patch_power: compute(PATCH_POWER_PASS),
            select: compute(SELECT_SHOOTER),
            place: compute(PLACE_ELEMENTS),
            item_buffers: (item_pipeline, item_group),
        }
    }
}

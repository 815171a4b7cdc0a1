//! The bindings of the two compute modules: elements.wgsl declares 0, 1,
//! 2, 4, 11 and 13 and receive.wgsl 7-10, 12 and 34 for both;
//! progressive.wgsl adds 3, 5, 6, 14 and 27, redistribute.wgsl 15-26 and
//! 28-33 and 35.
//!
//! Its own file so that the pipelines (which name the slots a pass binds)
//! and the resources (which bind a buffer to each slot) both import it and
//! neither the other.

use crate::gpu::binding::{Kind, Slot};

pub(in crate::gpu) const ELEMENTS: Slot = Slot::new("elements", 0, Kind::StorageRead);
pub(in crate::gpu) const RADIOSITY: Slot = Slot::new("radiosity", 1, Kind::Storage);
pub(in crate::gpu) const UNSHOT: Slot = Slot::new("unshot", 2, Kind::Storage);
pub(in crate::gpu) const IRRADIANCE: Slot = Slot::new("irradiance", 3, Kind::Storage);
pub(in crate::gpu) const PATCHES: Slot = Slot::new("patches", 4, Kind::StorageRead);
pub(in crate::gpu) const PATCH_POWER: Slot = Slot::new("patch_power", 5, Kind::Storage);
pub(in crate::gpu) const SELECTION: Slot = Slot::new("selection", 6, Kind::Storage);
pub(in crate::gpu) const SHOOTERS: Slot = Slot::new("shooters", 7, Kind::Uniform);
pub(in crate::gpu) const ENERGY: Slot = Slot::new("energy", 8, Kind::Storage);
pub(in crate::gpu) const BATCH: Slot = Slot::new("batch", 9, Kind::Uniform);
pub(in crate::gpu) const ITEM: Slot = Slot::new("item", 10, Kind::UintTexture);
pub(in crate::gpu) const OBJECT_FLAGS: Slot = Slot::new("object_flags", 11, Kind::StorageRead);
pub(in crate::gpu) const POSES: Slot = Slot::new("poses", 12, Kind::StorageRead);
pub(in crate::gpu) const LOCAL_ELEMENTS: Slot = Slot::new("local_elements", 13, Kind::StorageRead);
pub(in crate::gpu) const PLACED: Slot = Slot::new("placed", 14, Kind::Storage);
pub(in crate::gpu) const EMISSION: Slot = Slot::new("emission", 15, Kind::StorageRead);
pub(in crate::gpu) const OLD_SHOT: Slot = Slot::new("old_shot", 16, Kind::Storage);
pub(in crate::gpu) const FRONT_IDS: Slot = Slot::new("front_ids", 17, Kind::UintTexture);
pub(in crate::gpu) const BACK_RAD: Slot =
    Slot::new("back_rad", 18, Kind::FloatTexture { filterable: true });
pub(in crate::gpu) const BACK_SAMPLER: Slot = Slot::new("back_sampler", 19, Kind::Sampler);
pub(in crate::gpu) const BACK_SHOOTERS: Slot = Slot::new("back_shooters", 20, Kind::Uniform);
pub(in crate::gpu) const BACK: Slot = Slot::new("back", 21, Kind::Uniform);
pub(in crate::gpu) const GATHERED: Slot = Slot::new("gathered", 22, Kind::Storage);
pub(in crate::gpu) const SMOOTHED: Slot = Slot::new("smoothed", 23, Kind::Storage);
pub(in crate::gpu) const REGATHERED: Slot = Slot::new("regathered", 25, Kind::Storage);
pub(in crate::gpu) const MOVING_DIRECT: Slot = Slot::new("moving_direct", 26, Kind::StorageRead);
pub(in crate::gpu) const MEMBERS: Slot = Slot::new("members", 27, Kind::StorageRead);
pub(in crate::gpu) const SHOWN_BACK_OUT: Slot = Slot::new(
    "shown_back_out",
    28,
    Kind::StorageTextureWrite(wgpu::TextureFormat::Rgba32Float),
);
pub(in crate::gpu) const SHOWN_FRONT_OUT: Slot = Slot::new(
    "shown_front_out",
    29,
    Kind::StorageTextureWrite(wgpu::TextureFormat::Rgba32Float),
);
pub(in crate::gpu) const SHOWN_FRONT: Slot =
    Slot::new("shown_front", 30, Kind::FloatTexture { filterable: false });
pub(in crate::gpu) const BACK_IDS: Slot = Slot::new("back_ids", 24, Kind::UintTexture);
pub(in crate::gpu) const BACK_RAD_OUT: Slot = Slot::new(
    "back_rad_out",
    31,
    Kind::StorageTextureWrite(wgpu::TextureFormat::Rgba16Float),
);
pub(in crate::gpu) const SHOWN_BACK: Slot =
    Slot::new("shown_back", 32, Kind::FloatTexture { filterable: false });
pub(in crate::gpu) const MARKS: Slot = Slot::new("marks", 33, Kind::Storage);
pub(in crate::gpu) const PATCH_FRAMES: Slot = Slot::new("patch_frames", 34, Kind::StorageRead);
pub(in crate::gpu) const HELD: Slot = Slot::new("held", 35, Kind::StorageRead);

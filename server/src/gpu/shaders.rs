//! The WGSL modules the GPU solvers compile, assembled in one place.
//!
//! The sources live in `shaders/` at the repository root and are compiled
//! into the binary with `include_str!`. A module is its files concatenated
//! in a fixed order; `common.wgsl` (the shooter record, the batch
//! constants, patch ranges and the hemicube face projection) comes first
//! in every module, so a file may use what it defines. The tests below
//! parse and validate every assembled module with naga (no device needed)
//! and check that each struct shared with Rust has the same size on both
//! sides.

const COMMON: &str = include_str!("../../../shaders/common.wgsl");
const HEMICUBE: &str = include_str!("../../../shaders/hemicube.wgsl");
const PROGRESSIVE: &str = include_str!("../../../shaders/progressive.wgsl");
const REDISTRIBUTE: &str = include_str!("../../../shaders/redistribute.wgsl");
const GATHER: &str = include_str!("../../../shaders/gather.wgsl");

/// The compute passes of progressive refinement and redistribution:
/// common, progressive, redistribute.
pub(super) fn compute() -> String {
    format!("{COMMON}\n{PROGRESSIVE}\n{REDISTRIBUTE}")
}

/// The hemicube rasterizer (item buffers of patch ids, and radiosity
/// hemicubes for cross redistribution): common, hemicube.
pub(super) fn hemicube() -> String {
    format!("{COMMON}\n{HEMICUBE}")
}

/// The gather solver's hemicubes and integration: common, gather.
pub(super) fn gather() -> String {
    format!("{COMMON}\n{GATHER}")
}

#[cfg(test)]
mod tests {
    use super::super::binding::{Pass, check};
    use super::super::gather::{self, GatherElement, GatherParams, GatherVertex};
    use super::super::hemicube::{self, GpuVertex};
    use super::super::placement::{ELEMENT_BYTES, LocalElement};
    use super::super::progressive::{self, BatchUniform, GpuShooter, Selection};
    use super::*;

    /// Every module the solvers build, by the label they give it.
    fn modules() -> [(&'static str, String); 3] {
        [
            ("compute", compute()),
            ("hemicube", hemicube()),
            ("gather", gather()),
        ]
    }

    fn parse(label: &str, source: &str) -> (naga::Module, naga::valid::ModuleInfo) {
        let module = naga::front::wgsl::parse_str(source)
            .unwrap_or_else(|e| panic!("{label}: {}", e.emit_to_string(source)));
        let info = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::default(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{label}: {}", e.emit_to_string(source)));
        (module, info)
    }

    /// Every assembled module parses and passes naga's validation, as the
    /// device would check it at pipeline creation.
    #[test]
    fn every_shader_module_parses_and_validates() {
        for (label, source) in modules() {
            let (module, _) = parse(label, &source);
            assert!(
                module.entry_points.len() >= 2,
                "{label}: {} entry points",
                module.entry_points.len()
            );
        }
    }

    /// Each WGSL struct that a Rust buffer fills has the Rust struct's size
    /// in every module that declares it: a field added on one side only
    /// fails here, not as garbage on the GPU.
    #[test]
    fn structs_shared_with_rust_have_the_same_size_on_both_sides() {
        use std::mem::size_of;
        let shared: [(&str, usize); 10] = [
            ("Shooter", size_of::<GpuShooter>()),
            ("Batch", size_of::<BatchUniform>()),
            ("PatchRange", size_of::<[u32; 4]>()),
            ("Element", ELEMENT_BYTES as usize),
            ("LocalElement", size_of::<LocalElement>()),
            ("Selection", size_of::<Selection>()),
            ("Vertex", size_of::<GpuVertex>()),
            ("GatherVertex", size_of::<GatherVertex>()),
            ("GatherParams", size_of::<GatherParams>()),
            ("GatherElement", size_of::<GatherElement>()),
        ];
        let mut found = vec![0; shared.len()];
        for (label, source) in modules() {
            let (module, _) = parse(label, &source);
            for (_, ty) in module.types.iter() {
                let Some(name) = ty.name.as_deref() else {
                    continue;
                };
                let Some(k) = shared.iter().position(|(n, _)| *n == name) else {
                    continue;
                };
                let wgsl = ty.inner.size(module.to_ctx()) as usize;
                assert_eq!(
                    wgsl, shared[k].1,
                    "{label}: WGSL struct {name} is {wgsl} bytes, its Rust mirror {}",
                    shared[k].1
                );
                found[k] += 1;
            }
        }
        for ((name, _), count) in shared.iter().zip(found) {
            assert!(count > 0, "no module declares {name}");
        }
    }

    /// Every pipeline's explicit bind group layout lists exactly the
    /// bindings its entry points use, at the indices and of the kinds the
    /// WGSL declares: a binding changed on one side only fails here.
    #[test]
    fn every_pass_binds_what_its_shader_declares() {
        let passes: [(&str, String, Vec<Pass>); 3] = [
            ("compute", compute(), progressive::ALL_PASSES.to_vec()),
            (
                "hemicube",
                hemicube(),
                vec![hemicube::ITEM_BUFFERS, hemicube::SHOT_RADIOSITY],
            ),
            ("gather", gather(), gather::ALL_PASSES.to_vec()),
        ];
        for (label, source, list) in passes {
            let (module, info) = parse(label, &source);
            for pass in &list {
                check::pass_matches(label, &module, &info, pass);
            }
        }
    }
}

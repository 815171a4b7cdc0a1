//! The WGSL modules the GPU solvers compile, assembled in one place.
//!
//! Each source lives beside the Rust that binds it (`gpu/*.wgsl` for the
//! shared declarations and the hemicube; `gpu/progressive/` for
//! progressive refinement, `gpu/progressive/redistribute/` for
//! redistribution, `gpu/gather/` for gather radiosity) and is compiled
//! into the binary with `include_str!`. Every file is standalone: it
//! declares each binding, struct and function it uses, or names the file
//! that does in its first line, the one documented way WGSL is shared:
//!
//! ```text
//! // requires: common.wgsl, elements.wgsl, receive.wgsl
//! ```
//!
//! The module built from a file is the files of that line, in its order,
//! then the file itself; each file once; `enable` directives, which WGSL
//! wants first, are moved to the top. The list is complete, not
//! transitive: it names every file the module is made of, those that a
//! listed file requires before it, so the first line of a file says all
//! the WGSL its module holds. A file without the line requires nothing.
//!
//! Library files (no entry points):
//!
//! - `common.wgsl`: the shooter record, the batch constants, patch ranges,
//!   object flags and the hemicube face projection (every other file
//!   requires it);
//! - `elements.wgsl`: the element records and the element, patch and
//!   object buffers of the compute passes (their bindings 0, 1, 2, 4, 11
//!   and 13), `absent`, `is_invalid`;
//! - `receive.wgsl`: what an element receives from a batch of shooters:
//!   the batch's bindings (7-10, 12), visibility through the item buffers
//!   and the form factor.
//!
//! - `hemicube.wgsl`: the hemicube rasterizer's bindings, projection and
//!   fragment entry points.
//!
//! Entry-point files, one module each: `hemicube_faces.wgsl` and
//! `hemicube_rows.wgsl` (the hemicube rasterizer's vertex entry points in
//! its two draw layouts: a draw per face, or all faces in one draw with
//! clip distances), `progressive.wgsl` (progressive refinement),
//! `redistribute.wgsl` (redistribution after moves, on what
//! `redistribute_bindings.wgsl` declares), `gather.wgsl` (gather
//! radiosity). The progressive and redistribution modules share the
//! bindings of `elements.wgsl` and `receive.wgsl` at the same indices, so
//! one slot table serves both (`progressive/pipelines.rs`).
//!
//! The tests below assemble every file with exactly what its first line
//! names and validate it with naga (no device needed), so a file that uses
//! something it does not declare or require fails; they check that each
//! struct shared with Rust has the same size on both sides, and that every
//! pipeline binds what its entry points use.

/// Every `.wgsl` file under `gpu/`, by name.
const FILES: [(&str, &str); 11] = [
    ("common.wgsl", include_str!("common.wgsl")),
    ("elements.wgsl", include_str!("elements.wgsl")),
    ("receive.wgsl", include_str!("receive.wgsl")),
    ("hemicube.wgsl", include_str!("hemicube.wgsl")),
    ("hemicube_faces.wgsl", include_str!("hemicube_faces.wgsl")),
    ("hemicube_rows.wgsl", include_str!("hemicube_rows.wgsl")),
    (
        "progressive.wgsl",
        include_str!("progressive/progressive.wgsl"),
    ),
    (
        "redistribute_bindings.wgsl",
        include_str!("progressive/redistribute/redistribute_bindings.wgsl"),
    ),
    (
        "redistribute.wgsl",
        include_str!("progressive/redistribute/redistribute.wgsl"),
    ),
    ("gather.wgsl", include_str!("gather/gather.wgsl")),
    ("vpl.wgsl", include_str!("vpl.wgsl")),
];

/// The first line of a file that lists what it requires.
const REQUIRES: &str = "// requires:";

/// The text of file `name`.
///
/// # Panics
///
/// If `name` is not in [`FILES`]: the names are fixed in the code and in
/// the compiled-in files, so that is a bug, and the tests assemble every
/// file.
fn source(name: &str) -> &'static str {
    FILES
        .iter()
        .find(|(file, _)| *file == name)
        .map(|(_, text)| *text)
        .unwrap_or_else(|| panic!("{name} is not in shaders.rs's FILES"))
}

/// The files `text` requires, in order: the names on its first line if
/// that line is a `// requires:` line, else none.
fn requires(text: &str) -> Vec<&str> {
    text.lines()
        .next()
        .and_then(|line| line.strip_prefix(REQUIRES))
        .map(|list| {
            list.split(',')
                .map(str::trim)
                .filter(|name| !name.is_empty())
                .collect()
        })
        .unwrap_or_default()
}

/// The module built from file `name`: the files it requires, then itself,
/// with every `enable` directive of those files moved to the top (WGSL
/// wants directives before any declaration; a file states the extensions
/// it uses where it uses them).
fn assemble(name: &str) -> String {
    let text = source(name);
    let mut parts: Vec<&str> = requires(text).into_iter().map(source).collect();
    parts.push(text);
    let is_directive = |line: &&str| line.starts_with("enable ");
    let lines = || parts.iter().flat_map(|part| part.lines());
    let mut module: Vec<&str> = lines().filter(is_directive).collect();
    module.extend(lines().filter(|line| !is_directive(line)));
    module.join("\n")
}

/// The compute passes of progressive refinement (progressive.wgsl).
pub(super) fn progressive() -> String {
    assemble("progressive.wgsl")
}

/// The compute passes of redistribution (redistribute.wgsl).
pub(super) fn redistribute() -> String {
    assemble("redistribute.wgsl")
}

/// The hemicube rasterizer (item buffers of patch ids, and radiosity
/// hemicubes for cross redistribution; hemicube.wgsl) with the vertex
/// entry points of one draw layout (`hemicube::Draws`): every face in one
/// draw (`rows`, hemicube_rows.wgsl, needs clip distances) or a draw per
/// face (hemicube_faces.wgsl).
pub(super) fn hemicube(rows: bool) -> String {
    assemble(if rows {
        "hemicube_rows.wgsl"
    } else {
        "hemicube_faces.wgsl"
    })
}

/// The gather solver's hemicubes and integration (gather.wgsl).
pub(super) fn gather() -> String {
    assemble("gather.wgsl")
}

/// One bounce of instant radiosity with imperfect shadow maps (vpl.wgsl).
pub(super) fn vpl() -> String {
    assemble("vpl.wgsl")
}

#[cfg(test)]
mod tests {
    use super::super::binding::{Pass, check};
    use super::super::gather::{self, GatherElement, GatherParams, GatherVertex};
    use super::super::hemicube::{self, GpuVertex};
    use super::super::placement::{ELEMENT_BYTES, LocalElement, PatchFrame, PatchRange};
    use super::super::progressive::{self, BatchUniform, GpuShooter, Selection};
    use super::super::vpl;
    use super::*;

    /// Every module the solvers build, by the label they give it.
    fn modules() -> [(&'static str, String); 6] {
        [
            ("progressive", progressive()),
            ("redistribute", redistribute()),
            ("hemicube (faces)", hemicube(false)),
            ("hemicube (rows)", hemicube(true)),
            ("gather", gather()),
            ("vpl", vpl()),
        ]
    }

    fn parse(label: &str, source: &str) -> (naga::Module, naga::valid::ModuleInfo) {
        let module = naga::front::wgsl::parse_str(source)
            .unwrap_or_else(|e| panic!("{label}: {}", e.emit_to_string(source)));
        // Clip distances: the one optional capability a module uses
        // (hemicube_rows.wgsl; its pipelines exist only where the device
        // has the feature).
        let info = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::default() | naga::valid::Capabilities::CLIP_DISTANCES,
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{label}: {}", e.emit_to_string(source)));
        (module, info)
    }

    /// Every `.wgsl` file under `gpu/` is standalone: assembled with exactly the
    /// files its first line requires, it parses and validates, so it uses
    /// nothing it neither declares nor requires. Its list is complete
    /// (what a listed file requires comes before that file, each file
    /// once), and every `.wgsl` file under `src/gpu/` is in [`FILES`].
    #[test]
    fn every_shader_file_validates_with_only_what_it_requires() {
        fn wgsl_under(dir: &std::path::Path, found: &mut Vec<String>) {
            let entries =
                std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
            for entry in entries {
                let path = entry
                    .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
                    .path();
                if path.is_dir() {
                    wgsl_under(&path, found);
                } else if path.extension().is_some_and(|e| e == "wgsl") {
                    let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
                    found.extend(name);
                }
            }
        }
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/gpu");
        let mut on_disk = Vec::new();
        wgsl_under(&dir, &mut on_disk);
        on_disk.sort();
        let mut listed: Vec<String> = FILES.iter().map(|(name, _)| name.to_string()).collect();
        listed.sort();
        assert_eq!(
            on_disk, listed,
            "the .wgsl files under src/gpu/ and shaders.rs's FILES differ"
        );

        for (name, text) in FILES {
            let required = requires(text);
            for (k, dependency) in required.iter().enumerate() {
                assert!(
                    FILES.iter().any(|(file, _)| file == dependency),
                    "{name} requires {dependency}, which is not in FILES"
                );
                assert_ne!(*dependency, name, "{name} requires itself");
                assert!(
                    !required[..k].contains(dependency),
                    "{name} requires {dependency} twice"
                );
                for inner in requires(source(dependency)) {
                    assert!(
                        required[..k].contains(&inner),
                        "{name} requires {dependency}, which requires {inner}: \
                         {name} must list {inner} before {dependency}"
                    );
                }
            }
            parse(name, &assemble(name));
        }
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
        let shared: [(&str, usize); 14] = [
            ("Shooter", size_of::<GpuShooter>()),
            ("Batch", size_of::<BatchUniform>()),
            ("PatchRange", size_of::<PatchRange>()),
            ("PatchFrame", size_of::<PatchFrame>()),
            ("Element", ELEMENT_BYTES as usize),
            ("LocalElement", size_of::<LocalElement>()),
            ("Selection", size_of::<Selection>()),
            ("Vertex", size_of::<GpuVertex>()),
            ("GatherVertex", size_of::<GatherVertex>()),
            ("GatherParams", size_of::<GatherParams>()),
            ("GatherElement", size_of::<GatherElement>()),
            ("BounceParams", size_of::<vpl::BounceParams>()),
            ("BounceReceiver", size_of::<vpl::BounceReceiver>()),
            ("GpuVpl", size_of::<vpl::GpuVpl>()),
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

    /// The uniform arrays of shooters hold as many as a batch may
    /// (`MAX_BATCH` on both sides): a longer batch would be cut off
    /// silently, a shorter array wastes no binding but reads past nothing.
    #[test]
    fn uniform_shooter_arrays_hold_a_full_batch() {
        let mut seen = 0;
        for (label, source) in modules() {
            let (module, _) = parse(label, &source);
            for (_, var) in module.global_variables.iter() {
                if var.space != naga::AddressSpace::Uniform {
                    continue;
                }
                let naga::TypeInner::Array { base, size, .. } = module.types[var.ty].inner else {
                    continue;
                };
                if module.types[base].name.as_deref() != Some("Shooter") {
                    continue;
                }
                let naga::ArraySize::Constant(n) = size else {
                    panic!("{label}: {:?} is not a fixed-size array", var.name);
                };
                assert_eq!(
                    n.get(),
                    crate::gpu::progressive::MAX_BATCH,
                    "{label}: {:?}",
                    var.name
                );
                seen += 1;
            }
        }
        assert!(
            seen >= 2,
            "shooters and back_shooters: {seen} uniform arrays found"
        );
    }

    /// Every pipeline's explicit bind group layout lists exactly the
    /// bindings its entry points use, at the indices and of the kinds the
    /// WGSL declares: a binding changed on one side only fails here.
    #[test]
    fn every_pass_binds_what_its_shader_declares() {
        let hemicube_passes = vec![
            hemicube::ITEM_BUFFERS,
            hemicube::ELEMENT_IDS,
            hemicube::BACK_ELEMENTS,
            hemicube::CLEAR_ITEMS,
            hemicube::CLEAR_BACK,
        ];
        let passes: [(&str, String, Vec<Pass>); 6] = [
            (
                "progressive",
                progressive(),
                progressive::PROGRESSIVE_PASSES.to_vec(),
            ),
            (
                "redistribute",
                redistribute(),
                progressive::REDISTRIBUTION_PASSES.to_vec(),
            ),
            ("hemicube (faces)", hemicube(false), hemicube_passes.clone()),
            ("hemicube (rows)", hemicube(true), hemicube_passes),
            ("gather", gather(), gather::ALL_PASSES.to_vec()),
            ("vpl", vpl(), vpl::ALL_PASSES.to_vec()),
        ];
        for (label, source, list) in passes {
            let (module, info) = parse(label, &source);
            for pass in &list {
                check::pass_matches(label, &module, &info, pass);
            }
        }
    }
}

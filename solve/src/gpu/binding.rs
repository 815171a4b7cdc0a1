//! Explicit bind group layouts, declared once per shader binding.
//!
//! Every `@group(0) @binding(N) var ...` of a WGSL module has one [`Slot`]
//! constant on the Rust side that names it: the WGSL variable's name, its
//! index and what kind of resource it is. A [`Pass`] lists the slots one
//! pipeline uses; from it come the pipeline's bind group layout (no layout
//! is derived from the shader at run time) and its bind group, whose
//! resources a caller supplies slot by slot by name. The tests of
//! `shaders.rs` check every pass against the assembled WGSL with naga: the
//! slots a pass lists are exactly the globals its entry points use, at the
//! same indices, of the same kinds, so that changing a binding on one side
//! only fails a test instead of binding the wrong buffer on the GPU.

use std::collections::BTreeMap;

/// What a binding holds, as the WGSL declaration says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// `var<storage, read>`.
    StorageRead,
    /// `var<storage, read_write>`.
    Storage,
    /// `var<uniform>`.
    Uniform,
    /// `texture_2d<u32>`, read with `textureLoad`.
    UintTexture,
    /// `texture_2d<f32>`; `filterable` when a filtering sampler reads it.
    FloatTexture { filterable: bool },
    /// `sampler` (filtering).
    Sampler,
    /// `texture_storage_2d<F, write>` of format `F`: rgba32float or
    /// rgba16float.
    StorageTextureWrite(wgpu::TextureFormat),
}

/// One binding of group 0 of a shader module.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Slot {
    /// The WGSL variable's name.
    pub(super) name: &'static str,
    /// `@binding(index)`.
    pub(super) index: u32,
    pub(super) kind: Kind,
}

impl Slot {
    pub(super) const fn new(name: &'static str, index: u32, kind: Kind) -> Self {
        Self { name, index, kind }
    }
}

/// A pipeline of a shader module: its entry points (one compute entry, or
/// a vertex and a fragment entry) and the slots they use.
#[derive(Debug, Clone, Copy)]
pub(super) struct Pass {
    pub(super) entries: &'static [&'static str],
    pub(super) slots: &'static [Slot],
}

impl Pass {
    /// The pipeline's label: its entry points.
    fn label(&self) -> String {
        self.entries.join("/")
    }

    /// The bind group layout of this pass. Compute passes bind for the
    /// compute stage; render passes bind read-only resources for both
    /// stages and writable ones for the fragment stage only (vertex shaders
    /// may not write storage).
    pub(super) fn layout(&self, device: &wgpu::Device) -> wgpu::BindGroupLayout {
        let render = self.entries.len() > 1;
        let entries: Vec<wgpu::BindGroupLayoutEntry> = self
            .slots
            .iter()
            .map(|slot| {
                let visibility = match (render, slot.kind) {
                    (false, _) => wgpu::ShaderStages::COMPUTE,
                    (true, Kind::Storage) => wgpu::ShaderStages::FRAGMENT,
                    (true, _) => wgpu::ShaderStages::VERTEX_FRAGMENT,
                };
                let ty = match slot.kind {
                    Kind::StorageRead | Kind::Storage => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage {
                            read_only: slot.kind == Kind::StorageRead,
                        },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Kind::Uniform => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Kind::UintTexture => wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    Kind::FloatTexture { filterable } => wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    Kind::Sampler => {
                        wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering)
                    }
                    Kind::StorageTextureWrite(format) => wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                };
                wgpu::BindGroupLayoutEntry {
                    binding: slot.index,
                    visibility,
                    ty,
                    count: None,
                }
            })
            .collect();
        device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(&self.label()),
            entries: &entries,
        })
    }

    /// The pipeline layout of this pass: one bind group, or none when the
    /// pass has no slots (then nothing needs to be bound to draw with it).
    pub(super) fn pipeline_layout(
        &self,
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
    ) -> wgpu::PipelineLayout {
        let groups = if self.slots.is_empty() {
            &[][..]
        } else {
            &[Some(layout)][..]
        };
        device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(&self.label()),
            bind_group_layouts: groups,
            immediate_size: 0,
        })
    }

    /// A bind group for this pass: `resource` gives what to bind at each of
    /// its slots, by the slot's name.
    ///
    /// # Panics
    ///
    /// If `resource` has nothing for one of the pass's slots: the passes
    /// and their resources are fixed in the code, so that is a bug, and
    /// every solver's construction in the tests would hit it.
    pub(super) fn bind<'a>(
        &self,
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        resource: impl Fn(&Slot) -> Option<wgpu::BindingResource<'a>>,
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry<'a>> = self
            .slots
            .iter()
            .map(|slot| wgpu::BindGroupEntry {
                binding: slot.index,
                resource: resource(slot).unwrap_or_else(|| {
                    panic!("{}: nothing to bind at `{}`", self.label(), slot.name)
                }),
            })
            .collect();
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(&self.label()),
            layout,
            entries: &entries,
        })
    }

    /// The compute pipeline of this pass and its bind group, with
    /// pipeline-overridable `constants`.
    pub(super) fn compute<'a>(
        &self,
        device: &wgpu::Device,
        module: &wgpu::ShaderModule,
        constants: &[(&str, f64)],
        resource: impl Fn(&Slot) -> Option<wgpu::BindingResource<'a>>,
    ) -> (wgpu::ComputePipeline, wgpu::BindGroup) {
        let layout = self.layout(device);
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(&self.label()),
            layout: Some(&self.pipeline_layout(device, &layout)),
            module,
            entry_point: Some(self.entries[0]),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants,
                ..Default::default()
            },
            cache: None,
        });
        let group = self.bind(device, &layout, resource);
        (pipeline, group)
    }
}

/// Buffers by slot name, for [`Pass::bind`] and [`Pass::compute`].
pub(super) struct Resources<'a>(BTreeMap<&'static str, wgpu::BindingResource<'a>>);

impl<'a> Resources<'a> {
    pub(super) fn new() -> Self {
        Self(BTreeMap::new())
    }

    /// Binds `buffer` (whole) at the slot named like `slot`.
    pub(super) fn buffer(mut self, slot: Slot, buffer: &'a wgpu::Buffer) -> Self {
        self.0.insert(slot.name, buffer.as_entire_binding());
        self
    }

    /// Binds a texture view at the slot named like `slot`.
    pub(super) fn view(mut self, slot: Slot, view: &'a wgpu::TextureView) -> Self {
        self.0
            .insert(slot.name, wgpu::BindingResource::TextureView(view));
        self
    }

    /// Binds a sampler at the slot named like `slot`.
    pub(super) fn sampler(mut self, slot: Slot, sampler: &'a wgpu::Sampler) -> Self {
        self.0
            .insert(slot.name, wgpu::BindingResource::Sampler(sampler));
        self
    }

    /// What is bound at `slot`, if anything.
    pub(super) fn get(&self, slot: &Slot) -> Option<wgpu::BindingResource<'a>> {
        self.0.get(slot.name).cloned()
    }
}

#[cfg(test)]
pub(super) mod check {
    //! The naga side of [`Pass`]: what a module's entry points really bind.

    use super::{Kind, Pass};

    /// Asserts that `pass` lists exactly the group-0 globals its entry
    /// points use in `module`, by name, index and kind.
    pub(in crate::gpu) fn pass_matches(
        label: &str,
        module: &naga::Module,
        info: &naga::valid::ModuleInfo,
        pass: &Pass,
    ) {
        let mut used = std::collections::BTreeMap::new();
        for entry in pass.entries {
            let index = module
                .entry_points
                .iter()
                .position(|e| e.name == *entry)
                .unwrap_or_else(|| panic!("{label}: no entry point `{entry}`"));
            let ep = info.get_entry_point(index);
            for (handle, var) in module.global_variables.iter() {
                let Some(binding) = &var.binding else {
                    continue;
                };
                if ep[handle].is_empty() {
                    continue;
                }
                assert_eq!(binding.group, 0, "{label}: `{:?}` not in group 0", var.name);
                let name = var.name.clone().unwrap_or_default();
                used.insert(name.clone(), (binding.binding, kind_of(module, var)));
            }
        }
        let listed: std::collections::BTreeMap<String, (u32, Kind)> = pass
            .slots
            .iter()
            .map(|s| (s.name.to_string(), (s.index, s.kind)))
            .collect();
        for (name, (index, kind)) in &used {
            let Some((li, lk)) = listed.get(name) else {
                panic!(
                    "{label} {:?}: the shader uses `{name}` (binding {index}) but the pass does not list it",
                    pass.entries
                );
            };
            assert_eq!(
                li, index,
                "{label} {:?}: `{name}` is binding {index} in WGSL, {li} in Rust",
                pass.entries
            );
            let same = match (kind, lk) {
                (Kind::FloatTexture { .. }, Kind::FloatTexture { .. }) => true,
                (a, b) => a == b,
            };
            assert!(
                same,
                "{label} {:?}: `{name}` is {kind:?} in WGSL, {lk:?} in Rust",
                pass.entries
            );
        }
        for name in listed.keys() {
            assert!(
                used.contains_key(name),
                "{label} {:?}: the pass lists `{name}`, which its entry points do not use",
                pass.entries
            );
        }
    }

    /// The [`Kind`] a WGSL global declares (float textures as not
    /// filterable: WGSL does not say).
    fn kind_of(module: &naga::Module, var: &naga::GlobalVariable) -> Kind {
        match var.space {
            naga::AddressSpace::Uniform => Kind::Uniform,
            naga::AddressSpace::Storage { access } => {
                if access.contains(naga::StorageAccess::STORE) {
                    Kind::Storage
                } else {
                    Kind::StorageRead
                }
            }
            naga::AddressSpace::Handle => match &module.types[var.ty].inner {
                naga::TypeInner::Image {
                    class: naga::ImageClass::Sampled { kind, .. },
                    ..
                } => match kind {
                    naga::ScalarKind::Uint => Kind::UintTexture,
                    _ => Kind::FloatTexture { filterable: false },
                },
                naga::TypeInner::Sampler { .. } => Kind::Sampler,
                naga::TypeInner::Image {
                    class: naga::ImageClass::Storage { format, access },
                    ..
                } if !access.contains(naga::StorageAccess::LOAD) => {
                    Kind::StorageTextureWrite(match format {
                        naga::StorageFormat::Rgba32Float => wgpu::TextureFormat::Rgba32Float,
                        naga::StorageFormat::Rgba16Float => wgpu::TextureFormat::Rgba16Float,
                        other => panic!("unexpected storage texture format {other:?}"),
                    })
                }
                other => panic!("unexpected handle type {other:?}"),
            },
            other => panic!("unexpected address space {other:?}"),
        }
    }
}

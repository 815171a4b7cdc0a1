//! The lights' and the sky's direct light after a move (issue 59).
//!
//! The solver starts each element with `ρ D` of the lights and the sky as
//! reflected light (`crate::lights::element_irradiance`). A moved object
//! changes `D` where it now casts a shadow or no longer does, and on its
//! own faces. Neither is light a patch shot, so neither redistribution
//! method sees it: incremental reshooting and cross projection move what
//! surfaces send, not what a point light or the sun sends. So when a move
//! ends, the change `ρ ΔD` of every static element whose shadow rays pass
//! through the moved objects' bounds before or after
//! (`crate::lights::irradiance_change`: only those rays are cast again,
//! every other texel is left to the bit) is added to its radiosity and
//! its unshot radiosity, as any change of `B` is (thesis §2.2.5);
//! refinement then carries its bounces. Cross relights the moved faces
//! itself (their direct light per texel includes the lights,
//! `crate::direct::element_direct_light`); incremental resets them to
//! their emission, so they get `ρ D` at the new pose here as unshot light.
//!
//! A light that changes (issue 60: switched, dimmed, recoloured, moved or
//! turned) is followed the same way ([`ProgressiveSolver::set_light`]):
//! radiosity is linear in what the sources send, so the signed change
//! `ρ (D_new − D_old)` of that light alone, added as unshot radiosity and
//! shot like any other, takes the converged solution to the one of the
//! new light, with no memory kept per light (a change costs one light's
//! shadow rays over the texels and the refinement that carries it).

use glam::Vec3;
use lightwire_scene::Light;
use rayon::prelude::*;

use super::{Move, Redistribution};
use crate::gpu::GpuError;
use crate::gpu::progressive::ProgressiveSolver;
use crate::raycast::{CosineGrid, Raycaster};

impl ProgressiveSolver {
    /// Adds what `mv` changed of the lights' and the sky's direct light,
    /// reflected, as unshot radiosity (see the module documentation).
    /// Nothing for a scene without lights or a move of nothing.
    pub(super) fn relight(&mut self, mv: &Move) -> Result<(), GpuError> {
        if !crate::lights::any(&self.scene) || mv.is_empty_move() {
            return Ok(());
        }
        let scene = &self.scene;
        let mut boxes = Vec::new();
        for (o, _) in mv.moving.iter().enumerate().filter(|(_, m)| **m) {
            let placed = [
                (&mv.old_poses[o], mv.old_absent[o]),
                (&self.poses[o], self.absent[o]),
            ];
            for (pose, absent) in placed {
                if let (false, Some((lo, hi))) =
                    (absent, crate::validity::bounds(scene, o as u32, pose))
                {
                    let pad = 1e-4 * f64::from((hi - lo).length()).max(1e-6);
                    boxes.push((lo.as_dvec3() - pad, hi.as_dvec3() + pad));
                }
            }
        }
        if boxes.is_empty() {
            return Ok(());
        }
        let old = Raycaster::with_absent(scene, &mv.old_poses, &mv.old_absent);
        let new = Raycaster::with_absent(scene, &self.poses, &self.absent);
        let sky = CosineGrid::new(crate::lights::SKY_SIDE);
        let moving = |i: usize| {
            mv.moving
                .get(self.element_objects[i] as usize)
                .copied()
                .unwrap_or(false)
        };
        let reset_moving = mv.method == Redistribution::Incremental;
        let placed = (&self.atlas, self.poses.as_slice());
        let delta: Vec<Vec3> = (0..self.element_count as usize)
            .into_par_iter()
            .map(|i| {
                let e = &self.atlas.elements[i];
                if !e.covers_surface() {
                    return Vec3::ZERO;
                }
                let object = self.element_objects[i] as usize;
                let at = crate::raycast::sample_point(scene, &new, &self.atlas, &self.poses, i);
                if mv.flipped.binary_search(&i).is_ok() && !moving(i) {
                    // An invalid texel holds none of the lights' light
                    // (the solver starts it dark): one M covers gives
                    // back what it had, one M uncovers takes all of it.
                    // (Cross then zeroes the one and gathers the other
                    // anew, `regather.rs`.)
                    return if self.validity.is_invalid(i) {
                        -e.albedo
                            * crate::lights::element_direct_at(scene, &old, placed, (i, at), &sky)
                    } else {
                        e.albedo
                            * crate::lights::element_direct_at(scene, &new, placed, (i, at), &sky)
                    };
                }
                if self.validity.is_invalid(i) {
                    return Vec3::ZERO;
                }
                if !moving(i) {
                    e.albedo
                        * crate::lights::irradiance_change(
                            scene,
                            (&old, &new),
                            placed,
                            (i, at),
                            (&boxes, &sky),
                        )
                } else if reset_moving && !self.absent[object] {
                    e.albedo * crate::lights::element_direct_at(scene, &new, placed, (i, at), &sky)
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        if delta.iter().all(|d| *d == Vec3::ZERO) {
            return Ok(());
        }
        // As `add_unshot`, and a covered texel's radiosity too (it shoots
        // nothing).
        let mut b = self.read_vec4(&self.buffers.radiosity)?;
        let mut u = self.read_vec4(&self.buffers.unshot)?;
        for (i, d) in delta.iter().enumerate() {
            if *d == Vec3::ZERO {
                continue;
            }
            for c in 0..3 {
                b[i][c] += d[c];
                if !self.validity.is_invalid(i) {
                    u[i][c] += d[c];
                }
            }
        }
        self.queue
            .write_buffer(&self.buffers.radiosity, 0, bytemuck::cast_slice(&b));
        self.queue
            .write_buffer(&self.buffers.unshot, 0, bytemuck::cast_slice(&u));
        self.reselect()
    }

    /// Makes light `k` of the scene `light` (its intensity, colour, on or
    /// off, position or direction): the change of its direct light at
    /// every valid element, reflected, is added to the radiosity and the
    /// unshot radiosity (see the module documentation), and refinement
    /// carries it on. Returns the change added per element (`ρ ΔD`, atlas
    /// order), or none when nothing changed (`k` beyond the scene's lights
    /// or the same light).
    pub fn set_light(&mut self, k: usize, light: Light) -> Result<Option<Vec<Vec3>>, GpuError> {
        let Some(old) = self.scene.lights.get(k).cloned() else {
            return Ok(None);
        };
        if old == light {
            return Ok(None);
        }
        let caster = Raycaster::with_absent(&self.scene, &self.poses, &self.absent);
        let (scene, atlas, poses) = (&self.scene, &self.atlas, self.poses.as_slice());
        let validity = &self.validity;
        // ΔD per element, and ρ ΔD.
        let change: Vec<Vec3> = (0..self.element_count as usize)
            .into_par_iter()
            .map(|i| {
                let e = &atlas.elements[i];
                if !e.covers_surface() || validity.is_invalid(i) {
                    return Vec3::ZERO;
                }
                let at = crate::raycast::sample_point(scene, &caster, atlas, poses, i);
                crate::lights::light_change(scene, &caster, (atlas, poses), (i, at), (&old, &light))
            })
            .collect();
        let delta: Vec<Vec3> = change
            .iter()
            .zip(&self.albedo)
            .map(|(d, rho)| *rho * *d)
            .collect();
        // The source the unshot fraction is measured against, and the
        // power the lights deliver (`stats.json`), follow the light.
        let (mut reflected, mut onto, mut taken) = (0.0, 0.0, 0.0);
        for ((d, rho), a) in change.iter().zip(&self.albedo).zip(&self.areas) {
            let a = f64::from(*a);
            reflected += a * f64::from((*rho * *d).element_sum());
            onto += a * f64::from(d.element_sum());
            taken += a * f64::from(((Vec3::ONE - *rho) * *d).element_sum());
        }
        self.emitted = (self.emitted + reflected).max(0.0);
        self.delivered = (self.delivered.0 + onto, self.delivered.1 + taken);
        if let Some(direct) = &mut self.direct {
            for (b, d) in direct.iter_mut().zip(&delta) {
                *b += *d;
            }
        }
        self.scene.lights[k] = light;
        self.add_unshot(&delta)?;
        Ok(Some(delta))
    }

    /// What a first bounce of the unshot light starts from (`gpu::vpl`):
    /// per element, its unshot radiosity where refinement would shoot it,
    /// zero on invalid elements and those of absent or passive objects.
    pub(in crate::gpu) fn unshot_light(&self) -> Result<Vec<Vec3>, GpuError> {
        let u = self.read_vec4(&self.buffers.unshot)?;
        Ok(u.iter()
            .enumerate()
            .map(|(i, v)| {
                let o = self.element_objects[i] as usize;
                let out = self.absent.get(o).copied().unwrap_or(false)
                    || self.passive.get(o).copied().unwrap_or(false);
                if out || self.validity.is_invalid(i) {
                    Vec3::ZERO
                } else {
                    Vec3::new(v[0], v[1], v[2])
                }
            })
            .collect())
    }

    /// Whether element `i`'s object is passive (its unshot light is not
    /// refinement's, [`ProgressiveSolver::set_passive`]).
    pub(in crate::gpu) fn is_passive_element(&self, i: usize) -> bool {
        let o = self.element_objects.get(i).copied().unwrap_or(0) as usize;
        self.passive.get(o).copied().unwrap_or(false)
    }

    /// The elements' world areas and albedos at the current poses.
    pub(in crate::gpu) fn areas_and_albedo(&self) -> (&[f32], &[Vec3]) {
        (&self.areas, &self.albedo)
    }
}

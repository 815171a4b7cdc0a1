//! The static elements next to a moved object gather their light again
//! when a cross move completes (issue 15, item 4: a box put down on the
//! floor, then moved away).
//!
//! Two things go wrong there without it. While an element is invalid
//! (inside or under geometry, `crate::validity`) it receives nothing, and
//! cross redistribution carries only the change the moved set makes to
//! light that was already shot (thesis §3.3): the floor a box stood on
//! stays black once the box moves away (the dark wedges at a box's base),
//! and the removal of the box's old light even takes from it light it never
//! got (measured -2 to -6 W/m² on cornell-low's floor, where the light is
//! about 1). And the texels at a contact receive the largest, most
//! sensitive part of the moved object's light (their form factor to its
//! bottom row is large), so what one move gives and the next takes back
//! there does not cancel: a floor texel beside the box grew from 1.0 to 4.8
//! in 100 small moves (expected 1.4).
//!
//! So when a cross move completes, every static element whose validity was
//! re-tested (those within a texel of the moved objects' bounds, before
//! and after the move) and that is valid gathers: `B = E + ρ H`, `H`
//! estimated on the CPU from the current radiosity ([`gather`]). The
//! change of `B` is added to the element's unshot radiosity as well, as
//! every change of `B` is in progressive refinement (thesis §2.2.5): what
//! the element passes on always matches what it holds, whatever the moves
//! handed it before.
//!
//! Every re-tested static element that is invalid goes to `B = 0` with
//! nothing left to shoot, and *holds* its shot radiosity `B - U` (`held`,
//! a GPU buffer the cross projection reads): a texel a box lands on shot
//! that light into the room before, and the box now blocks all of it. The
//! move's cross projection takes back what the box's faces block of it
//! (R_x(C, C) through their back hemicubes), as it does for every static
//! shooter, and the next move off it gives that back; the held shot
//! radiosity is what both see. When the texel is uncovered it gathers like
//! any other and shoots its new light less what it held (the room holds
//! that already). Without the zeroing, the cross projection's shadows
//! left the texels under a box at about -2.9 where the floor beside it
//! reads +2.5 (a texel under the box is behind it for light from either
//! side), and refinement shot that as negative light.
//!
//! Issue 57. Before, a covered texel's change went to its unshot
//! radiosity like any other: refinement took its light back a second time
//! (from beside the box, the projection having taken its part), and
//! uncovered it shot all of its light again. On cornell-low (full density)
//! a box jumping about the room (`teleport-stress.json`, 19 jumps, nine
//! landings) and put back left the room 5.3% darker than a fresh session,
//! its ceiling 15.6%. Covered texels that kept nothing (neither shot nor
//! held) made the room gain about half a percent per landing and leaving
//! instead (the projection takes back only part of what a texel under a
//! box shot; 1,000 moves with ten jumps: +2.5% at move 499). Holding the
//! shot radiosity makes the two directions the same operator.
//!
//! The texels next to a moving object are mostly the same from one move to
//! the next, and most of their rays meet the static world, whose hits do not
//! change: those are kept ([`StaticHits`]) and only the dynamic objects are
//! ray cast again (the same values to the bit).

use glam::Vec3;

use super::super::device::GpuError;
use super::super::profile::Stage;
use super::ProgressiveSolver;
use crate::direct::{Lookup, StaticHits, at_contact, gather, gather_cached};

/// Cosine-distributed rays per gathering element, as a `SIDE` x `SIDE`
/// stratified grid (`raycast::CosineGrid`).
const SIDE: usize = 16;
/// Samples per emitting patch for next-event estimation, `GRID` x `GRID`.
const GRID: usize = 8;
/// Elements whose rays' hits on the static world are kept between moves:
/// the texels next to a moving object are mostly the same from one move to
/// the next. 16 bytes a ray, 8 MiB at most.
const KEPT_ELEMENTS: usize = 2048;

/// The cache of static hits the regathering keeps.
pub(super) fn static_hits() -> StaticHits {
    StaticHits::new(SIDE, KEPT_ELEMENTS)
}

/// The moved texels at a contact that gather on their own
/// ([`ProgressiveSolver::gather_contacts`]), and the radiosity they read
/// (the static set as just relit, invalid texels filled).
pub(super) struct Contacts {
    elements: Vec<usize>,
    radiosity: Vec<[f32; 4]>,
}

impl ProgressiveSolver {
    /// Gathers the light of the valid elements re-tested since the last
    /// cross move completed and zeroes the invalid ones (see the module
    /// documentation), except those
    /// of the objects flagged in `moving`: cross redistribution relights
    /// those itself and keeps its own account of what they shot. With
    /// `contacts`, the elements of `moving` that stand at a contact
    /// ([`at_contact`]) are returned, to gather from the static set as just
    /// relit with [`Self::gather_contacts`] (which the caller may run while
    /// the GPU works), and what they gather goes to `moving_direct` for
    /// `smooth_moving` to show. Call while no batch is pending, before the
    /// next shooter is selected.
    pub(super) fn regather(
        &mut self,
        moving: &[bool],
        contacts: bool,
    ) -> Result<Option<Contacts>, GpuError> {
        let mut elements = std::mem::take(&mut self.regather);
        elements.sort_unstable();
        elements.dedup();
        elements.retain(|&i| {
            !moving
                .get(self.element_objects[i] as usize)
                .copied()
                .unwrap_or(false)
        });
        // Invalid elements hold no light and have none to shoot: what they
        // shot, the cross projection took back (see the module
        // documentation).
        let (covered, elements): (Vec<usize>, Vec<usize>) = elements
            .into_iter()
            .partition(|&i| self.validity.is_invalid(i));
        let gathering = self.profile.start();
        let contacts = if contacts {
            self.moving_contacts(moving)
        } else {
            Vec::new()
        };
        self.profile.stop(gathering, Stage::Regather);
        if elements.is_empty() && covered.is_empty() && contacts.is_empty() {
            return Ok(None);
        }
        self.profile.sync();
        let readback = self.profile.start();
        let radiosity = self.read_vec4(&self.buffers.radiosity)?;
        let (unshot, mut held) = if elements.is_empty() && covered.is_empty() {
            (Vec::new(), Vec::new())
        } else {
            let d = self.dynamic.as_ref().expect("built in begin_move");
            (
                self.read_vec4(&self.buffers.unshot)?,
                self.read_vec4(&d.held)?,
            )
        };
        self.profile.stop(readback, Stage::RegatherReadback);
        let gathering = self.profile.start();
        // What a ray sees where it lands, as published and as a client
        // reads it (bilinearly): negative light (what a move took before
        // refinement gives it back) reads as none, and invalid texels
        // (under or inside geometry), which hold no light of their own and
        // would give the floor beside a box the texels under it, are
        // filled from their valid neighbours.
        let mut seen: Vec<Vec3> = radiosity
            .iter()
            .map(|b| Vec3::new(b[0], b[1], b[2]).max(Vec3::ZERO))
            .collect();
        self.validity.dilate(&self.atlas, &mut seen);
        let mut seen: Vec<[f32; 4]> = seen.iter().map(|b| [b.x, b.y, b.z, 0.0]).collect();
        let lit = gather_cached(
            &self.scene,
            &self.atlas,
            (&self.poses, &self.absent),
            &seen,
            &elements,
            GRID,
            Lookup::Bilinear,
            &mut self.static_hits,
        );
        let (mut radiosity, mut unshot) = (radiosity, unshot);
        let mut changed: Vec<usize> = Vec::with_capacity(elements.len() + covered.len());
        // A valid element shoots the change of its light, less what it
        // held while covered: the room still holds that (see the module
        // doc), and the move's cross projection gave back what the box
        // had blocked of it.
        for (&i, b) in elements.iter().zip(lit) {
            let (old, u, h) = (radiosity[i], unshot[i], held[i]);
            let delta = b - Vec3::new(old[0], old[1], old[2]) - Vec3::new(h[0], h[1], h[2]);
            seen[i] = [b.x, b.y, b.z, 0.0];
            radiosity[i] = [b.x, b.y, b.z, old[3]];
            unshot[i] = [u[0] + delta.x, u[1] + delta.y, u[2] + delta.z, u[3]];
            held[i] = [0.0; 4];
            changed.push(i);
        }
        // A covered element shows and shoots nothing and holds its shot
        // radiosity (see the module doc).
        for &i in &covered {
            let (old, u, h) = (radiosity[i], unshot[i], held[i]);
            seen[i] = [0.0; 4];
            radiosity[i] = [0.0, 0.0, 0.0, old[3]];
            unshot[i] = [0.0, 0.0, 0.0, u[3]];
            held[i] = [
                h[0] + old[0] - u[0],
                h[1] + old[1] - u[1],
                h[2] + old[2] - u[2],
                0.0,
            ];
            changed.push(i);
        }
        self.write_changed(changed, &radiosity, &unshot, &held);
        self.profile.stop(gathering, Stage::Regather);
        Ok((!contacts.is_empty()).then_some(Contacts {
            elements: contacts,
            radiosity: seen,
        }))
    }

    /// Writes the `changed` elements' radiosity, unshot radiosity and
    /// held shot radiosity to the GPU, one write per run of consecutive
    /// elements (a chart's row along the moved object), not two per
    /// element.
    fn write_changed(
        &self,
        mut changed: Vec<usize>,
        radiosity: &[[f32; 4]],
        unshot: &[[f32; 4]],
        held: &[[f32; 4]],
    ) {
        changed.sort_unstable();
        let mut k = 0;
        while k < changed.len() {
            let start = changed[k];
            let mut end = start + 1;
            while k + 1 < changed.len() && changed[k + 1] == end {
                k += 1;
                end += 1;
            }
            k += 1;
            let offset = start as u64 * 16;
            let d = self.dynamic.as_ref().expect("built in begin_move");
            for (buffer, values) in [
                (&self.buffers.radiosity, radiosity),
                (&self.buffers.unshot, unshot),
                (&d.held, held),
            ] {
                self.queue
                    .write_buffer(buffer, offset, bytemuck::cast_slice(&values[start..end]));
            }
        }
    }

    /// The valid elements of the present objects flagged in `moving` that
    /// stand at a contact ([`at_contact`]).
    fn moving_contacts(&self, moving: &[bool]) -> Vec<usize> {
        let candidates = self.present_moving_elements(moving);
        if candidates.is_empty() {
            return candidates;
        }
        at_contact(
            &self.scene,
            &self.atlas,
            (&self.poses, &self.absent),
            &candidates,
        )
    }

    /// A moved texel at a contact sees, within its own footprint, the
    /// surface it touches darken towards the contact (the floor beside a
    /// box's base): the tiles' gathers, read between tile centres, gave the
    /// contact row of a moved box what the row above it gets, 30-80% more
    /// than a from-scratch solve and the path tracer on cornell-large
    /// (BENCHMARKS.md). Each such texel gathers on its own, `B = E + ρ H`
    /// from `radiosity`, and the result is written to its `moving_direct`
    /// with w = 1; `smooth_moving` then shows the lesser of that and the
    /// tiles' value. The lesser, because the gather reads the touching
    /// surface's lightmap, whose texels are larger than the darkening at
    /// the contact: on cornell-low at a third of its density (a box face
    /// of 3 x 3 texels) the gather read the contact row 1.5-2.5 times the
    /// path tracer, brighter than the row above, which a contact, taking
    /// part of what the row above sees, cannot be. The direct light in
    /// `moving_direct` has served by then: every batch of the move has
    /// shot, and the next move writes it again.
    pub(super) fn gather_contacts(&self, contacts: &Contacts) {
        let gathering = self.profile.start();
        let Contacts {
            elements: contacts,
            radiosity,
        } = contacts;
        let lit = gather(
            &self.scene,
            &self.atlas,
            (&self.poses, &self.absent),
            radiosity,
            contacts,
            SIDE,
            GRID,
            Lookup::Bilinear,
        );
        let d = self.dynamic.as_ref().expect("built in begin_move");
        for (&i, b) in contacts.iter().zip(lit) {
            self.queue.write_buffer(
                &d.moving_direct,
                i as u64 * 16,
                bytemuck::bytes_of(&[b.x, b.y, b.z, 1.0f32]),
            );
        }
        self.profile.stop(gathering, Stage::Regather);
    }
}

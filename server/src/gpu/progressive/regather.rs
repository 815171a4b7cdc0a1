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

use glam::Vec3;

use super::super::device::GpuError;
use super::super::profile::Stage;
use super::ProgressiveSolver;
use crate::direct::gather;

/// Cosine-distributed rays per gathering element, as a `SIDE` x `SIDE`
/// stratified grid (`raycast::cosine_grid`).
const SIDE: usize = 16;
/// Samples per emitting patch for next-event estimation, `GRID` x `GRID`.
const GRID: usize = 8;

impl ProgressiveSolver {
    /// Gathers the light of the valid elements re-tested since the last
    /// cross move completed (see the module documentation), except those
    /// of the objects flagged in `moving`: cross redistribution relights
    /// those itself and keeps its own account of what they shot. Call
    /// while no batch is pending, before the next shooter is selected.
    pub(super) fn regather(&mut self, moving: &[bool]) -> Result<(), GpuError> {
        let mut elements = std::mem::take(&mut self.regather);
        elements.sort_unstable();
        elements.dedup();
        elements.retain(|&i| {
            let object = self.element_objects[i] as usize;
            !self.validity.is_invalid(i) && !moving.get(object).copied().unwrap_or(false)
        });
        if elements.is_empty() {
            return Ok(());
        }
        self.profile.sync();
        let readback = self.profile.start();
        let radiosity = self.read_vec4(&self.buffers.radiosity)?;
        let unshot = self.read_vec4(&self.buffers.unshot)?;
        self.profile.stop(readback, Stage::RegatherReadback);
        let gathering = self.profile.start();
        let lit = gather(
            &self.scene,
            &self.atlas,
            (&self.poses, &self.absent),
            &radiosity,
            &elements,
            SIDE,
            GRID,
        );
        for (&i, b) in elements.iter().zip(lit) {
            let (old, u) = (radiosity[i], unshot[i]);
            let delta = b - Vec3::new(old[0], old[1], old[2]);
            let offset = i as u64 * 16;
            self.queue.write_buffer(
                &self.buffers.radiosity,
                offset,
                bytemuck::bytes_of(&[b.x, b.y, b.z, old[3]]),
            );
            self.queue.write_buffer(
                &self.buffers.unshot,
                offset,
                bytemuck::bytes_of(&[u[0] + delta.x, u[1] + delta.y, u[2] + delta.z, u[3]]),
            );
        }
        self.profile.stop(gathering, Stage::Regather);
        Ok(())
    }
}

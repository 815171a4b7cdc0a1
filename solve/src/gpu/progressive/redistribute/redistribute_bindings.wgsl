// requires: common.wgsl, elements.wgsl, receive.wgsl
// What every redistribution pass binds and shares (redistribute.wgsl has
// the passes): the bindings of thesis ch. 3-4's buffers and textures
// beyond those of elements.wgsl and receive.wgsl, the batch-mode bits the
// Rust side sets (redistribute/mod.rs), and small helpers.

@group(0) @binding(15) var<storage, read> emission: array<vec4<f32>>;
@group(0) @binding(16) var<storage, read_write> old_shot: array<vec4<f32>>;
// Per static element under geometry: the shot radiosity it held when it
// was covered, which it no longer shows nor shoots but which its light in
// the room still stands for, so that the cross projection blocks and
// unblocks it like any other shot radiosity (`held` in
// gpu/progressive/regather.rs). Zero elsewhere.
@group(0) @binding(35) var<storage, read> held: array<vec4<f32>>;
// The element each pixel of a moving tile's gathering hemicube sees
// (hemicube.wgsl `fs_element`; NO_PATCH: nothing), slot k in rows
// k GATHER_RESOLUTION onwards, five faces a row.
@group(0) @binding(17) var front_ids: texture_2d<u32>;
// The back hemicubes as drawn (hemicube.wgsl `fs_back`): per pixel the
// element seen (NO_PATCH: nothing) and its distance from the eye
// (bitcast f32), slot k in rows k back.resolution onwards, five faces a
// row. `shade_back` turns them into `back_rad`.
@group(0) @binding(24) var back_ids: texture_2d<u32>;
// The back hemicubes shaded: shot radiosity of the static set in rgb and
// the distance in a (0: nothing there), written by `shade_back` through
// `back_rad_out` and sampled by the cross projection through `back_rad`.
@group(0) @binding(18) var back_rad: texture_2d<f32>;
@group(0) @binding(31) var back_rad_out: texture_storage_2d<rgba16float, write>;
@group(0) @binding(19) var back_sampler: sampler;
@group(0) @binding(20) var<uniform> back_shooters: array<Shooter, MAX_BATCH>;
@group(0) @binding(21) var<uniform> back: Batch;
// Irradiance H each element of a moving tile gathered in this move (rgb;
// the tile's value, the same for all its texels), w = 1 once gathered and
// 2 once `smooth_moving` has added it to the element's radiosity.
// `smooth_moving` interpolates it between tile centres.
@group(0) @binding(22) var<storage, read_write> gathered: array<vec4<f32>>;
// What `smooth_moving` gave an element beyond its tile's constant ρ H
// (rgb): taken out of the shot radiosity the next move takes back, which
// then equals what the tile shot.
@group(0) @binding(23) var<storage, read_write> smoothed: array<vec4<f32>>;
// Irradiance H each element of a moving tile gathered again once every
// batch of the move had run (`regather_moving`; the tile's value, w = 1
// once gathered): the light the texels show, interpolated between tile
// centres by `smooth_moving`.
@group(0) @binding(25) var<storage, read_write> regathered: array<vec4<f32>>;
// Irradiance from the emitters' emission at each element of M at its new
// position (rgb, w = 0), computed per element on the CPU
// (`element_direct_light` in server/src/direct.rs): the front hemicubes
// leave emission out (hemicube.wgsl), so a tile gathers only reflected
// light, and every texel gets its own direct light instead of its tile's.
// Once every batch has run, a texel at a contact holds instead the
// radiosity it gathered on its own (w = 1, regather.rs `gather_contacts`),
// which the second `smooth_moving` shows where it is below the tiles'.
@group(0) @binding(26) var<storage, read> moving_direct: array<vec4<f32>>;
// What the static set shows the moving tiles' hemicubes, one texel per
// element (`shown_texel`), in rgb, with w = 1 (0: an element of a moving
// object, which shows nothing; the back hemicubes do not draw them):
// written by `shade_static` / `shade_total` right before the
// hemicubes are read, so that a pixel reads one texel (`shade_back`,
// `front_irradiance`) instead of three of an element's records.
// shown_back_out: shot radiosity B - B^u (the cross projection's back
// hemicubes). shown_front_out: reflected shot radiosity B - E - B^u (the
// tiles' gathering), or with `shade_total` what the texels show.
@group(0) @binding(28) var shown_back_out: texture_storage_2d<rgba32float, write>;
@group(0) @binding(29) var shown_front_out: texture_storage_2d<rgba32float, write>;
// The same texture as `shown_front_out`, read by the gathers (another
// binding: a dispatch may not write and read one texture).
@group(0) @binding(30) var shown_front: texture_2d<f32>;
@group(0) @binding(32) var shown_back: texture_2d<f32>;
// Which of a cross job's new-pose slots reach each element (the plane
// test and the visibility `reconstruct_dyn` marks them by), MARK_WORDS
// words an element, bit k of word w for slot w MARK_CHUNK + k: the next
// job's old-pose slots when they are these (KEPT_MARKS). The element, the
// shooter and the item buffer are the same, so the marks are too.
@group(0) @binding(33) var<storage, read_write> marks: array<u32>;

// Scratch of the workgroup reductions: radiosity sums, area sums.
var<workgroup> partial: array<vec3<f32>, 64>;
var<workgroup> partial_power: array<f32, 256>;

// Batch.mode: the kind in the low byte, flags above.
const KIND_MASK: u32 = 0xffu;
// Incremental, Alg. 4.3 line 4: M shoots its negated old shot radiosity to
// C from its old position. Slots 0..n: old hemicubes.
const KIND_NEGATIVE: u32 = 1u;
// Incremental, Alg. 4.3 lines 7-19: a patch of C shoots; slots 0..n: new
// hemicubes, n..2n: old hemicubes of the same shooters. T holds B^u in
// energy[k] and B^s in energy[n + k].
const KIND_STATIC: u32 = 2u;
// Cross redistribution, Alg. 4.4-4.5: tiles of M shoot; slots 0..n: new
// front, n..2n: new back, 2n..3n: old front, 3n..4n: old back hemicubes.
// T holds the new total radiosity in energy[k] and the negated old shot
// radiosity in energy[n + k].
const KIND_CROSS: u32 = 3u;
// The new position exists (M is inserted or moved, not removed).
const HAS_NEW: u32 = 0x100u;
// The old position exists (M is removed or moved, not inserted).
const HAS_OLD: u32 = 0x200u;
// reset_moving: keep the emission as unshot radiosity (incremental: it is
// shot again by the progressive iterations that follow).
const RESET_UNSHOT: u32 = 0x400u;
// Cross: the batch's tiles have no back hemicubes (a closed object, whose
// front faces hide all it hides from a point outside it); its slots are
// [new front, old front] instead of [new front, new back, old front, old
// back].
const ONE_SIDED: u32 = 0x800u;
// Cross: the old-pose slots are the last cross job's new-pose ones, item
// buffers and all (gpu/progressive/redistribute/resources.rs `Kept`), so which of
// them reach an element is what that job marked (`marks`).
const KEPT_MARKS: u32 = 0x1000u;

// Side length of the cross projection's sampling grid on a shooter (thesis
// Alg. 4.5 gridSize, 4 by default).
override CROSS_GRID: u32 = 4u;
// A receiver whose form factor to a tile is below this samples the tile's
// projection through the coarse grid (`cross_coarse_below` in
// server/src/gpu/progressive/mod.rs; 0: never).
override CROSS_COARSE_BELOW: f32 = 0.0;

fn coarse_grid() -> u32 {
    return max(CROSS_GRID / 2u, 1u);
}

// Side length (texels) of the tiles moving patches are cut into for cross
// redistribution (`ProgressiveOptions::cross_tile`).
override CROSS_TILE: u32 = 5u;

// Top-face resolution of the front hemicubes a moving tile gathers from,
// in the move and again after it (`gather_moving`, `regather_moving`):
// they see reflected light only, which varies slowly
// (`ProgressiveSolver::gather_resolution`).
override GATHER_RESOLUTION: u32 = 32u;

// reconstruct_dyn takes the cross method's slots MARK_CHUNK at a time:
// first the cheap tests and the visibility mark the slots that reach the
// element, then only the marked ones pay for the form factor and the
// projection. A GPU whose lanes agree skips the rest either way; lavapipe
// runs both sides of every branch under a mask but leaves a loop once no
// lane is in it, so an unmarked slot costs nothing only by not being
// looped over.
const MARK_CHUNK: u32 = 32u;
// Words of `marks` per element: a bit per new-pose slot of a cross job
// (half of its at most MAX_BATCH slots).
const MARK_WORDS: u32 = (MAX_BATCH / 2u + MARK_CHUNK - 1u) / MARK_CHUNK;

// The lowest marked bit of `marked`, which is cleared.
fn next_marked(marked: ptr<function, u32>) -> u32 {
    let b = firstTrailingBit(*marked);
    *marked &= *marked - 1u;
    return b;
}

fn is_moving(el: Element) -> bool {
    return (object_flags[bitcast<u32>(el.lookup.w)] & OBJECT_MOVING) != 0u;
}

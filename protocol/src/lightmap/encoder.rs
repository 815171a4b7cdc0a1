//! The server side of the lightmap codec: quantize, compare per tile,
//! publish deltas, serve keyframes.

use std::collections::BTreeMap;

use super::{Lightmap, TileRect, ZSTD_LEVEL, compress_tile, dequantize, quantize_into, residual};
use crate::{Delta, Keyframe, ObjectSeq, PixelFormat};

/// Default absolute floor of the change rule: changes among values below
/// this are judged against `epsilon * floor` rather than against the values
/// themselves, so that noise in near-black texels does not resend tiles.
pub const DEFAULT_EPSILON_FLOOR: f32 = 1.0 / 1024.0;

/// The error budget's measure of one channel: `|target - held| /
/// max(held, target, floor)` (0 when they are equal, whatever the floor).
/// A texel is within a budget `epsilon` when this is at most `epsilon` for
/// every channel.
pub fn budget_measure(held: f32, target: f32, floor: f32) -> f32 {
    let d = (target - held).abs();
    if d == 0.0 {
        0.0
    } else {
        d / held.max(target).max(floor)
    }
}

/// Owns the last published quantized state of one lightmap, and the
/// solver's quantized lightmap it follows.
///
/// # What a delta carries: the error budget
///
/// Let `held` be a channel of a texel as receivers hold it (the state after
/// the last delta) and `target` the same channel of the solver's lightmap
/// being published, both *after* quantization and decoding. The texel is
/// within the budget if, for every channel,
///
/// ```text
/// |target - held| <= epsilon * max(held, target, floor)
/// ```
///
/// [`Encoder::publish`] sends, as residuals (PROTOCOL.md §5), exactly
///
/// - every texel that is not within the budget (it is sent exactly), and
/// - when the lightmap published is exactly the previous one (the scene
///   holds still), every texel that still differs: receivers converge to
///   the solver's lightmap bit for bit once the scene settles, one publish
///   after it does (a server publishes its lightmap once more when its
///   solver goes idle with texels waiting).
///
/// Every other texel waits, receivers keep what they have, and so does the
/// encoder's state. After every publish, therefore, every texel receivers
/// hold is within the budget of the lightmap just published. With
/// `epsilon = 0` every texel whose quantized bits differ is sent. `floor` is
/// [`DEFAULT_EPSILON_FLOOR`] unless set with [`Encoder::with_floor`].
pub struct Encoder {
    current: Lightmap,
    /// The quantized lightmap of the last publish (what the solver said),
    /// in the layout of `current.texels`.
    target: Vec<u8>,
    epsilon: f32,
    floor: f32,
    /// Texels of `current` that differ from `target`.
    pending: usize,
    /// Compressed payload of every tile of `current`, so keyframes cost a copy.
    compressed: Vec<Vec<u8>>,
    /// Latest seq per object included so far, for keyframes.
    reflected: BTreeMap<u32, u64>,
    compressor: zstd::bulk::Compressor<'static>,
}

impl std::fmt::Debug for Encoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Encoder")
            .field("width", &self.current.width)
            .field("height", &self.current.height)
            .field("tile_size", &self.current.tile_size)
            .field("format", &self.current.format)
            .field("version", &self.current.version)
            .field("epsilon", &self.epsilon)
            .field("floor", &self.floor)
            .field("pending", &self.pending)
            .finish_non_exhaustive()
    }
}

impl Encoder {
    /// An encoder whose state is the all-zero lightmap at version 0 (what a
    /// fresh [`Lightmap::new`] holds).
    ///
    /// # Panics
    /// If `tile_size` is 0, or `epsilon` is negative or not finite.
    pub fn new(width: u32, height: u32, tile_size: u16, format: PixelFormat, epsilon: f32) -> Self {
        assert!(
            epsilon.is_finite() && epsilon >= 0.0,
            "Encoder epsilon must be finite and >= 0, got {epsilon}"
        );
        let current = Lightmap::new(width, height, tile_size, format);
        let mut compressor =
            zstd::bulk::Compressor::new(ZSTD_LEVEL).expect("zstd compressor at level 3");
        // All-zero tiles come in at most four shapes (interior, right
        // column, bottom row, corner): compress each shape once.
        let mut by_shape: BTreeMap<(u32, u32), Vec<u8>> = BTreeMap::new();
        let mut scratch = Vec::new();
        let compressed = (0..current.tile_count())
            .map(|i| {
                let r = current.tile_rect(i).expect("index in range");
                by_shape
                    .entry((r.width, r.height))
                    .or_insert_with(|| {
                        scratch.clear();
                        current.read_tile(r, &mut scratch);
                        compress_tile(&mut compressor, &scratch)
                    })
                    .clone()
            })
            .collect();
        Encoder {
            target: current.texels.clone(),
            current,
            epsilon,
            floor: DEFAULT_EPSILON_FLOOR,
            pending: 0,
            compressed,
            reflected: BTreeMap::new(),
            compressor,
        }
    }

    /// Sets the absolute floor of the epsilon rule.
    ///
    /// # Panics
    /// If `floor` is negative or not finite.
    pub fn with_floor(mut self, floor: f32) -> Self {
        assert!(
            floor.is_finite() && floor >= 0.0,
            "floor must be finite and >= 0"
        );
        self.floor = floor;
        self
    }

    /// Sets the zstd level of the tiles compressed from now on (default
    /// [`ZSTD_LEVEL`]; 1 is fastest, 19 and up are slow).
    ///
    /// # Panics
    /// If `level` is not within 1..=22.
    pub fn with_zstd_level(mut self, level: i32) -> Self {
        assert!(
            (1..=22).contains(&level),
            "zstd level must be within 1..=22, got {level}"
        );
        self.compressor =
            zstd::bulk::Compressor::new(level).expect("a zstd compressor at a valid level");
        self
    }

    /// The compressed texels of tile `index` of the current state, as a
    /// keyframe carries them (`None` if out of range).
    pub fn keyframe_tile(&self, index: u32) -> Option<&[u8]> {
        self.compressed.get(index as usize).map(Vec::as_slice)
    }

    /// Texels whose held value differs from the last published target
    /// (0: receivers hold the solver's lightmap exactly).
    pub fn pending_texels(&self) -> usize {
        self.pending
    }

    /// The relative error budget.
    pub fn epsilon(&self) -> f32 {
        self.epsilon
    }

    /// The absolute floor of the epsilon rule.
    pub fn floor(&self) -> f32 {
        self.floor
    }

    /// Quantizes `rgb` (`width * height` texels, row-major) as the new
    /// target, and returns the delta from the current version to the next
    /// that carries the texels the budget rule above selects, as residual
    /// tiles. The state becomes exactly what a client holds after applying
    /// that delta. The version is bumped even when no tile changed (the
    /// delta then only carries `reflected`); a server that drops such a
    /// delta must merge it into the next one. Publishing the same `rgb`
    /// again sends whatever still waits.
    ///
    /// # Panics
    /// If `rgb.len() != width * height`.
    pub fn publish(&mut self, rgb: &[[f32; 3]], reflected: Vec<ObjectSeq>) -> Delta {
        let (w, h) = (self.current.width as usize, self.current.height as usize);
        assert_eq!(
            rgb.len(),
            w * h,
            "Encoder::publish: expected {w}x{h} = {} texels, got {}",
            w * h,
            rgb.len()
        );
        let format = self.current.format;
        let bpt = format.bytes_per_texel();
        let mut target = std::mem::take(&mut self.target);
        let mut fresh = vec![0u8; bpt];
        let mut settled = true;
        for (i, &c) in rgb.iter().enumerate() {
            quantize_into(format, c, &mut fresh);
            let t = &mut target[i * bpt..(i + 1) * bpt];
            if t != &fresh[..] {
                settled = false;
                t.copy_from_slice(&fresh);
            }
        }
        self.target = target;
        let mut tiles = Vec::new();
        let (mut held, mut goal, mut next) = (Vec::new(), Vec::new(), Vec::new());
        let mut pending = 0;
        for index in 0..self.current.tile_count() {
            let rect = self.current.tile_rect(index).expect("index in range");
            held.clear();
            self.current.read_tile(rect, &mut held);
            goal.clear();
            read_rect(&self.target, w, bpt, rect, &mut goal);
            // Sent: texels over the budget; once the whole lightmap holds
            // still, every texel that differs.
            next.clear();
            next.extend_from_slice(&held);
            let mut sent = false;
            for t in (0..held.len()).step_by(bpt) {
                let (a, b) = (&held[t..t + bpt], &goal[t..t + bpt]);
                if a == b {
                    continue;
                }
                if settled || self.deviation(a, b) > self.epsilon {
                    next[t..t + bpt].copy_from_slice(b);
                    sent = true;
                } else {
                    pending += 1;
                }
            }
            if sent {
                tiles.push((index, residual::encode(format, &held, &next)));
                self.compressed[index as usize] = compress_tile(&mut self.compressor, &next);
                self.current.write_tile(rect, &next);
            }
        }
        let residual = residual::pack(&self.current.layout(), &tiles, &mut self.compressor);
        self.pending = pending;
        let base_version = self.current.version;
        self.current.version += 1;
        for r in &reflected {
            self.reflected.insert(r.object, r.seq);
        }
        Delta {
            base_version,
            version: self.current.version,
            reflected,
            residual,
        }
    }

    /// The budget rule's measure for one texel: the largest channel
    /// deviation over `max(old, new, floor)` (so a texel is within the
    /// budget when this is at most `epsilon`).
    fn deviation(&self, old: &[u8], new: &[u8]) -> f32 {
        let (a, b) = (
            dequantize(self.current.format, old),
            dequantize(self.current.format, new),
        );
        (0..3)
            .map(|i| budget_measure(a[i], b[i], self.floor))
            .fold(0.0, f32::max)
    }

    /// Every tile of the current state, with the latest seq per object
    /// reflected so far (sorted by object).
    pub fn keyframe(&self) -> Keyframe {
        Keyframe::new(self.current.version, &self.reflected, &self.compressed)
    }

    /// The current (last published) state: exactly what a client holds.
    pub fn state(&self) -> &Lightmap {
        &self.current
    }

    /// The rectangle of tile `index` (see [`Lightmap::tile_rect`]).
    pub fn tile_rect(&self, index: u32) -> Option<TileRect> {
        self.current.tile_rect(index)
    }
}

/// Appends the bytes of `rect` of a `width`-texel-wide row-major buffer.
fn read_rect(texels: &[u8], width: usize, bpt: usize, rect: TileRect, out: &mut Vec<u8>) {
    let row = rect.width as usize * bpt;
    for y in rect.y..rect.y + rect.height {
        let start = (y as usize * width + rect.x as usize) * bpt;
        out.extend_from_slice(&texels[start..start + row]);
    }
}

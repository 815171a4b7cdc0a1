//! The server side of the lightmap codec: quantize, compare per tile,
//! publish deltas, serve keyframes.

use std::collections::BTreeMap;

use super::{Lightmap, TileRect, ZSTD_LEVEL, compress_tile, dequantize, quantize_into};
use crate::{Delta, Keyframe, ObjectSeq, PixelFormat, Tile};

/// Default absolute floor of the change rule: changes among values below
/// this are judged against `epsilon * floor` rather than against the values
/// themselves, so that noise in near-black texels does not resend tiles.
pub const DEFAULT_EPSILON_FLOOR: f32 = 1.0 / 1024.0;

/// Owns the last published quantized state of one lightmap.
///
/// # The epsilon rule
///
/// Let `old` and `new` be a channel of a texel *after* quantization and
/// decoding (so both are exactly what a client could display). The texel
/// changed if, for some channel,
///
/// ```text
/// |new - old| > epsilon * max(old, new, floor)
/// ```
///
/// and a tile is sent if any of its texels changed. With `epsilon = 0` every
/// tile whose quantized bits differ is sent. `floor` is
/// [`DEFAULT_EPSILON_FLOOR`] unless set with [`Encoder::with_floor`].
pub struct Encoder {
    current: Lightmap,
    epsilon: f32,
    floor: f32,
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
            current,
            epsilon,
            floor: DEFAULT_EPSILON_FLOOR,
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

    /// The relative threshold of the epsilon rule.
    pub fn epsilon(&self) -> f32 {
        self.epsilon
    }

    /// The absolute floor of the epsilon rule.
    pub fn floor(&self) -> f32 {
        self.floor
    }

    /// Quantizes `rgb` (`width * height` texels, row-major), compares each
    /// tile with the current state by the epsilon rule, and returns the
    /// delta from the current version to the next, carrying the tiles that
    /// changed. The state becomes exactly what a client holds after applying
    /// that delta: new texels in sent tiles, old texels elsewhere. The
    /// version is bumped even when no tile changed (the delta then only
    /// carries `reflected`); a server that drops such a delta must merge it
    /// into the next one.
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
        let mut tiles = Vec::new();
        let mut fresh = Vec::new();
        for index in 0..self.current.tile_count() {
            let rect = self.current.tile_rect(index).expect("index in range");
            fresh.clear();
            fresh.resize(rect.width as usize * rect.height as usize * bpt, 0);
            let mut changed = false;
            for (r, y) in (rect.y..rect.y + rect.height).enumerate() {
                for (c, x) in (rect.x..rect.x + rect.width).enumerate() {
                    let t = (r * rect.width as usize + c) * bpt;
                    let out = &mut fresh[t..t + bpt];
                    quantize_into(format, rgb[y as usize * w + x as usize], out);
                    if !changed {
                        let s = (y as usize * w + x as usize) * bpt;
                        let old = &self.current.texels[s..s + bpt];
                        changed = old != out && self.exceeds(old, out);
                    }
                }
            }
            if changed {
                self.current.write_tile(rect, &fresh);
                let data = compress_tile(&mut self.compressor, &fresh);
                self.compressed[index as usize] = data.clone();
                tiles.push(Tile { index, data });
            }
        }
        let base_version = self.current.version;
        self.current.version += 1;
        for r in &reflected {
            self.reflected.insert(r.object, r.seq);
        }
        Delta {
            base_version,
            version: self.current.version,
            reflected,
            tiles,
        }
    }

    /// The epsilon rule for one texel.
    fn exceeds(&self, old: &[u8], new: &[u8]) -> bool {
        let (a, b) = (
            dequantize(self.current.format, old),
            dequantize(self.current.format, new),
        );
        (0..3).any(|i| (b[i] - a[i]).abs() > self.epsilon * a[i].max(b[i]).max(self.floor))
    }

    /// Every tile of the current state, with the latest seq per object
    /// reflected so far (sorted by object).
    pub fn keyframe(&self) -> Keyframe {
        Keyframe {
            version: self.current.version,
            reflected: self
                .reflected
                .iter()
                .map(|(&object, &seq)| ObjectSeq { object, seq })
                .collect(),
            tiles: self
                .compressed
                .iter()
                .enumerate()
                .map(|(i, data)| Tile {
                    index: i as u32,
                    data: data.clone(),
                })
                .collect(),
        }
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

//! The lightmap codec: quantized texels, tiles, keyframes and deltas.
//!
//! The server's solver produces linear RGB radiosity per texel. An
//! [`Encoder`] quantizes it to the scene's [`PixelFormat`] (RGB9E5 by
//! default), cuts the atlas into `tile_size`-square tiles (row-major tile
//! indices; the last column and row of tiles are clipped at the atlas
//! border), and compares every tile with the state it last published. A
//! tile is sent only if some channel of some texel changed by more than the
//! encoder's epsilon (the rule is on [`Encoder`]); each sent tile is its
//! texels' little-endian bytes, row-major, compressed as one zstd frame at
//! level [`ZSTD_LEVEL`]. Compressing per tile keeps tiles independent, so
//! deltas can be [`merge`]d without recompressing.
//!
//! The encoder then sets its state to exactly what a client holds after
//! applying the delta: new texels for sent tiles, the *old* texels for
//! tiles that were not sent. A client's [`Lightmap`] applies keyframes and
//! deltas (atomically: an invalid frame changes nothing), so server and
//! client stay bit-identical at every version.

mod encoder;
mod merge;
pub mod residual;
mod rgb9e5;
mod texel;

pub use encoder::{DEFAULT_EPSILON_FLOOR, Encoder, budget_measure};
pub use merge::merge;
pub use rgb9e5::{RGB9E5_MAX, rgb9e5_decode, rgb9e5_encode};
pub use texel::{dequantize, max_value, quantize_into};

use crate::{Delta, Keyframe, PixelFormat, SceneInfo, Tile};

/// zstd compression level for tile payloads.
pub const ZSTD_LEVEL: i32 = 3;

/// The largest atlas, in texels, that [`Lightmap::for_scene`] accepts
/// (8192 x 8192), so that a hostile Welcome cannot make a client allocate
/// without bound.
pub const MAX_ATLAS_TEXELS: u64 = 8192 * 8192;

/// Why a keyframe, delta or merge was refused. Nothing is modified when one
/// of these is returned.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ApplyError {
    /// The delta's base is not the version held (ask for a resync).
    #[error("delta's base version is {base}, but the state it would apply to is at version {have}")]
    WrongBase {
        /// The version held (or, for [`merge`], the first delta's `version`).
        have: u64,
        /// The delta's `base_version`.
        base: u64,
    },
    /// A delta whose `version` is not greater than its `base_version`.
    #[error("delta goes from version {base} to version {version}; versions must increase")]
    NotIncreasing {
        /// `base_version`.
        base: u64,
        /// `version`.
        version: u64,
    },
    /// A tile index at or beyond the tile count.
    #[error("tile index {index} is out of range: the lightmap has {count} tiles")]
    TileOutOfRange {
        /// The offending index.
        index: u32,
        /// Tiles in the lightmap.
        count: u32,
    },
    /// The same tile index twice in one keyframe or delta.
    #[error("tile index {index} appears more than once")]
    DuplicateTile {
        /// The repeated index.
        index: u32,
    },
    /// A keyframe that does not carry every tile.
    #[error("keyframe carries {got} tiles but the lightmap has {expected}")]
    MissingTiles {
        /// Tiles in the lightmap.
        expected: u32,
        /// Tiles in the keyframe.
        got: usize,
    },
    /// A tile whose payload does not decompress to exactly its texel bytes.
    #[error("tile {index} decompresses to {got} bytes, expected exactly {expected}")]
    TileLength {
        /// Tile index.
        index: u32,
        /// Width * height * bytes per texel of that tile.
        expected: usize,
        /// What the payload declares or yields (at least `expected + 1` when
        /// it overflowed the bounded buffer without declaring a size).
        got: u64,
    },
    /// A delta's residual payload that does not decode (PROTOCOL.md §5).
    #[error("the delta's residual payload {0}")]
    Residual(String),
    /// A tile payload that is not a valid zstd frame.
    #[error("tile {index} is not a valid zstd frame: {reason}")]
    Decompress {
        /// Tile index.
        index: u32,
        /// zstd's reason.
        reason: String,
    },
    /// Dimensions that cannot form a lightmap (zero tile size, too large, or
    /// a texel buffer of the wrong length).
    #[error("invalid lightmap layout: {0}")]
    Layout(String),
}

/// A lightmap's shape: what a [`merge`] needs to know about the tiles it
/// composes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Tile edge length in texels (positive).
    pub tile_size: u16,
    /// Texel format.
    pub format: PixelFormat,
}

impl Layout {
    /// The layout of a scene received in a Welcome.
    pub fn of_scene(scene: &SceneInfo) -> Self {
        Layout {
            width: scene.atlas_width,
            height: scene.atlas_height,
            tile_size: scene.tile_size,
            format: scene.format,
        }
    }

    /// The indices of the tiles a delta of this layout carries, ascending
    /// (decompressing its payload; the same checks as applying it).
    pub fn delta_tiles(&self, d: &Delta) -> Result<Vec<u32>, ApplyError> {
        if d.residual.is_empty() {
            return Ok(Vec::new());
        }
        let mut dec = zstd::bulk::Decompressor::new()
            .map_err(|e| ApplyError::Residual(format!("zstd: {e}")))?;
        Ok(residual::unpack(self, &d.residual, &mut dec)?
            .into_iter()
            .map(|(index, _)| index)
            .collect())
    }

    /// `ceil(width / tile_size) * ceil(height / tile_size)` (0 for tile size 0).
    pub fn tile_count(&self) -> u32 {
        if self.tile_size == 0 {
            return 0;
        }
        let ts = u32::from(self.tile_size);
        self.width.div_ceil(ts) * self.height.div_ceil(ts)
    }

    /// Decompressed bytes of tile `index`, or `None` if out of range (or
    /// the tile size is 0).
    pub fn tile_bytes(&self, index: u32) -> Option<usize> {
        if self.tile_size == 0 {
            return None;
        }
        let ts = u32::from(self.tile_size);
        let tiles_x = self.width.div_ceil(ts);
        if index >= tiles_x * self.height.div_ceil(ts) {
            return None;
        }
        let (x, y) = ((index % tiles_x) * ts, (index / tiles_x) * ts);
        let texels = ts.min(self.width - x) as usize * ts.min(self.height - y) as usize;
        Some(texels * self.format.bytes_per_texel())
    }
}

/// A tile's rectangle in the atlas, in texels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileRect {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Width: `tile_size`, or less in the last tile column.
    pub width: u32,
    /// Height: `tile_size`, or less in the last tile row.
    pub height: u32,
}

/// A quantized lightmap: what a client holds. Server ([`Encoder::state`])
/// and client both keep one and both produce bit-identical contents.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Lightmap {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Tile edge length in texels.
    pub tile_size: u16,
    /// Texel format.
    pub format: PixelFormat,
    /// The version of the last applied keyframe or delta (0 when new).
    pub version: u64,
    /// `width * height` texels, row-major, each `format.bytes_per_texel()`
    /// little-endian bytes: the layout of a GPU texture of format
    /// `Rgb9e5Ufloat` / `Rgba16Float`, so it uploads as is.
    pub texels: Vec<u8>,
}

impl Lightmap {
    /// An all-zero lightmap at version 0.
    ///
    /// # Panics
    /// If `tile_size` is 0 or the texel buffer size overflows `usize`; use
    /// [`Lightmap::for_scene`] for dimensions that come off the wire.
    pub fn new(width: u32, height: u32, tile_size: u16, format: PixelFormat) -> Self {
        assert!(tile_size > 0, "Lightmap tile_size must be positive");
        let len = (width as usize)
            .checked_mul(height as usize)
            .and_then(|n| n.checked_mul(format.bytes_per_texel()))
            .expect("Lightmap size overflows usize");
        Lightmap {
            width,
            height,
            tile_size,
            format,
            version: 0,
            texels: vec![0; len],
        }
    }

    /// An all-zero lightmap for a scene received in a Welcome, refusing
    /// layouts a well-behaved server never sends (tile size 0, more than
    /// [`MAX_ATLAS_TEXELS`] texels).
    pub fn for_scene(scene: &SceneInfo) -> Result<Self, ApplyError> {
        if scene.tile_size == 0 {
            return Err(ApplyError::Layout("tile size is 0".into()));
        }
        let texels = u64::from(scene.atlas_width) * u64::from(scene.atlas_height);
        if texels > MAX_ATLAS_TEXELS {
            return Err(ApplyError::Layout(format!(
                "atlas {}x{} has more than {MAX_ATLAS_TEXELS} texels",
                scene.atlas_width, scene.atlas_height
            )));
        }
        Ok(Lightmap::new(
            scene.atlas_width,
            scene.atlas_height,
            scene.tile_size,
            scene.format,
        ))
    }

    /// Tile columns: `ceil(width / tile_size)`.
    pub fn tiles_x(&self) -> u32 {
        self.width.div_ceil(u32::from(self.tile_size))
    }

    /// Tile rows: `ceil(height / tile_size)`.
    pub fn tiles_y(&self) -> u32 {
        self.height.div_ceil(u32::from(self.tile_size))
    }

    /// `tiles_x * tiles_y`.
    pub fn tile_count(&self) -> u32 {
        self.tiles_x() * self.tiles_y()
    }

    /// The rectangle of tile `index`, or `None` if out of range.
    pub fn tile_rect(&self, index: u32) -> Option<TileRect> {
        if index >= self.tile_count() {
            return None;
        }
        let ts = u32::from(self.tile_size);
        let (x, y) = ((index % self.tiles_x()) * ts, (index / self.tiles_x()) * ts);
        Some(TileRect {
            x,
            y,
            width: ts.min(self.width - x),
            height: ts.min(self.height - y),
        })
    }

    /// Bytes of tile `rect` once decompressed.
    fn tile_len(&self, rect: TileRect) -> usize {
        rect.width as usize * rect.height as usize * self.format.bytes_per_texel()
    }

    /// The decoded RGB of texel (x, y).
    pub fn texel(&self, x: u32, y: u32) -> [f32; 3] {
        let bpt = self.format.bytes_per_texel();
        let i = (y as usize * self.width as usize + x as usize) * bpt;
        dequantize(self.format, &self.texels[i..i + bpt])
    }

    /// All texels decoded to linear RGB, row-major (for rendering and tests).
    pub fn to_rgb(&self) -> Vec<[f32; 3]> {
        self.texels
            .chunks_exact(self.format.bytes_per_texel())
            .map(|t| dequantize(self.format, t))
            .collect()
    }

    /// Appends the uncompressed bytes of tile `rect` to `out`.
    fn read_tile(&self, rect: TileRect, out: &mut Vec<u8>) {
        let bpt = self.format.bytes_per_texel();
        let row = rect.width as usize * bpt;
        for y in rect.y..rect.y + rect.height {
            let start = (y as usize * self.width as usize + rect.x as usize) * bpt;
            out.extend_from_slice(&self.texels[start..start + row]);
        }
    }

    /// Overwrites tile `rect` with `data` (exactly its uncompressed bytes).
    fn write_tile(&mut self, rect: TileRect, data: &[u8]) {
        let bpt = self.format.bytes_per_texel();
        let row = rect.width as usize * bpt;
        for (r, y) in (rect.y..rect.y + rect.height).enumerate() {
            let start = (y as usize * self.width as usize + rect.x as usize) * bpt;
            self.texels[start..start + row].copy_from_slice(&data[r * row..(r + 1) * row]);
        }
    }

    /// Replaces every texel with the keyframe's and takes its version. The
    /// keyframe must carry each tile exactly once; on error nothing changes.
    pub fn apply_keyframe(&mut self, k: &Keyframe) -> Result<(), ApplyError> {
        self.check_layout()?;
        if k.tiles.len() != self.tile_count() as usize {
            return Err(ApplyError::MissingTiles {
                expected: self.tile_count(),
                got: k.tiles.len(),
            });
        }
        let decoded = self.decode_tiles(&k.tiles)?;
        for (rect, data) in decoded {
            self.write_tile(rect, &data);
        }
        self.version = k.version;
        Ok(())
    }

    /// Applies a delta onto exactly its base version: the residual of each
    /// tile it carries is added onto the tile held (PROTOCOL.md §5). The
    /// payload is checked and decompressed before the first texel is
    /// written, so on error nothing changes.
    pub fn apply_delta(&mut self, d: &Delta) -> Result<(), ApplyError> {
        self.apply_delta_tiles(d).map(|_| ())
    }

    /// [`Lightmap::apply_delta`], returning the indices of the tiles it
    /// changed (ascending).
    pub fn apply_delta_tiles(&mut self, d: &Delta) -> Result<Vec<u32>, ApplyError> {
        if d.base_version != self.version {
            return Err(ApplyError::WrongBase {
                have: self.version,
                base: d.base_version,
            });
        }
        if d.version <= d.base_version {
            return Err(ApplyError::NotIncreasing {
                base: d.base_version,
                version: d.version,
            });
        }
        self.check_layout()?;
        let tiles = if d.residual.is_empty() {
            Vec::new()
        } else {
            let mut dec = zstd::bulk::Decompressor::new()
                .map_err(|e| ApplyError::Residual(format!("zstd: {e}")))?;
            residual::unpack(&self.layout(), &d.residual, &mut dec)?
        };
        let mut texels = Vec::new();
        let mut changed = Vec::with_capacity(tiles.len());
        for (index, planes) in tiles {
            let rect = self.tile_rect(index).expect("unpack checked the index");
            texels.clear();
            self.read_tile(rect, &mut texels);
            residual::apply(self.format, &mut texels, &planes);
            self.write_tile(rect, &texels);
            changed.push(index);
        }
        self.version = d.version;
        Ok(changed)
    }

    /// Tile `index` of this state as a keyframe tile: its texels, compressed.
    ///
    /// # Panics
    /// If `index` is out of range.
    pub fn keyframe_tile(&self, index: u32) -> Tile {
        let rect = self.tile_rect(index).expect("tile index in range");
        let mut texels = Vec::new();
        self.read_tile(rect, &mut texels);
        Tile {
            index,
            data: compress_once(&texels),
        }
    }

    /// The residual payload of a delta that takes this state to `to`'s
    /// (same layout) in the tiles `indices` (ascending, distinct).
    ///
    /// # Panics
    /// If the layouts differ or an index is out of range or repeated.
    pub fn delta_payload(&self, to: &Lightmap, indices: &[u32]) -> Vec<u8> {
        assert_eq!(
            self.layout(),
            to.layout(),
            "delta_payload between different layouts"
        );
        let tiles: Vec<(u32, Vec<u8>)> = indices
            .iter()
            .map(|&index| {
                let rect = self.tile_rect(index).expect("tile index in range");
                let (mut old, mut new) = (Vec::new(), Vec::new());
                self.read_tile(rect, &mut old);
                to.read_tile(rect, &mut new);
                (index, residual::encode(self.format, &old, &new))
            })
            .collect();
        let mut c = zstd::bulk::Compressor::new(ZSTD_LEVEL).expect("zstd compressor");
        residual::pack(&self.layout(), &tiles, &mut c)
    }

    /// The layout (dimensions, tile size, format) without the texels.
    pub fn layout(&self) -> Layout {
        Layout {
            width: self.width,
            height: self.height,
            tile_size: self.tile_size,
            format: self.format,
        }
    }

    fn check_layout(&self) -> Result<(), ApplyError> {
        let expected = self.width as usize * self.height as usize * self.format.bytes_per_texel();
        if self.tile_size == 0 || self.texels.len() != expected {
            return Err(ApplyError::Layout(format!(
                "{}x{} {:?} needs {expected} texel bytes and a positive tile size, have {} bytes and tile size {}",
                self.width,
                self.height,
                self.format,
                self.texels.len(),
                self.tile_size
            )));
        }
        Ok(())
    }

    /// Validates indices (in range, no duplicates) and decompresses every
    /// tile to exactly its size, without touching `self`.
    fn decode_tiles(&self, tiles: &[Tile]) -> Result<Vec<(TileRect, Vec<u8>)>, ApplyError> {
        let count = self.tile_count();
        let mut seen = vec![false; count as usize];
        for t in tiles {
            if t.index >= count {
                return Err(ApplyError::TileOutOfRange {
                    index: t.index,
                    count,
                });
            }
            if std::mem::replace(&mut seen[t.index as usize], true) {
                return Err(ApplyError::DuplicateTile { index: t.index });
            }
        }
        let mut dec = zstd::bulk::Decompressor::new().map_err(|e| ApplyError::Decompress {
            index: tiles.first().map_or(0, |t| t.index),
            reason: e.to_string(),
        })?;
        tiles
            .iter()
            .map(|t| {
                let rect = self.tile_rect(t.index).expect("index checked above");
                let data = decompress_tile(&mut dec, t, self.tile_len(rect))?;
                Ok((rect, data))
            })
            .collect()
    }
}

/// Decompresses one tile into a buffer of exactly `expected` bytes: zstd
/// cannot write past it, so a hostile payload cannot inflate beyond the
/// tile's size.
pub(crate) fn decompress_tile(
    dec: &mut zstd::bulk::Decompressor<'_>,
    tile: &Tile,
    expected: usize,
) -> Result<Vec<u8>, ApplyError> {
    let index = tile.index;
    match zstd::zstd_safe::get_frame_content_size(&tile.data) {
        Ok(Some(declared)) if declared != expected as u64 => {
            return Err(ApplyError::TileLength {
                index,
                expected,
                got: declared,
            });
        }
        Ok(Some(_)) => {}
        Ok(None) => {
            return Err(ApplyError::Decompress {
                index,
                reason: "the zstd frame does not declare its content size".into(),
            });
        }
        Err(_) => {
            return Err(ApplyError::Decompress {
                index,
                reason: "no zstd frame header".into(),
            });
        }
    }
    // One frame and nothing after it (PROTOCOL.md §5): a second frame
    // would otherwise be decompressed into the same buffer.
    match zstd::zstd_safe::find_frame_compressed_size(&tile.data) {
        Ok(n) if n == tile.data.len() => {}
        Ok(n) => {
            return Err(ApplyError::Decompress {
                index,
                reason: format!("{} bytes after the zstd frame", tile.data.len() - n),
            });
        }
        Err(_) => {
            return Err(ApplyError::Decompress {
                index,
                reason: "not a whole zstd frame".into(),
            });
        }
    }
    let mut buf = vec![0u8; expected];
    let n = dec
        .decompress_to_buffer(&tile.data[..], &mut buf[..])
        .map_err(|e| {
            if e.to_string().contains("too small") {
                ApplyError::TileLength {
                    index,
                    expected,
                    got: expected as u64 + 1,
                }
            } else {
                ApplyError::Decompress {
                    index,
                    reason: e.to_string(),
                }
            }
        })?;
    if n != expected {
        return Err(ApplyError::TileLength {
            index,
            expected,
            got: n as u64,
        });
    }
    Ok(buf)
}

/// Compresses one tile's bytes at level [`ZSTD_LEVEL`] with a fresh context.
fn compress_once(data: &[u8]) -> Vec<u8> {
    zstd::bulk::compress(data, ZSTD_LEVEL)
        .expect("zstd compression of an in-memory tile cannot fail")
}

/// Compresses one tile's uncompressed bytes with `c` (level [`ZSTD_LEVEL`]).
pub(crate) fn compress_tile(c: &mut zstd::bulk::Compressor<'_>, data: &[u8]) -> Vec<u8> {
    c.compress(data)
        .expect("zstd compression of an in-memory tile cannot fail")
}

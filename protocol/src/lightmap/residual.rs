//! Tile residuals: how a delta tile says "change these texels by this much"
//! (PROTOCOL.md §5, "Delta tiles").
//!
//! A residual is computed field by field on the texel's integer fields,
//! modulo each field's width, so that
//!
//! - applying it onto the base reproduces the new texel bit for bit, whatever
//!   the values (no floating point is involved);
//! - two residuals of consecutive deltas compose by adding them field by
//!   field ([`compose`]), which is how deltas merge without knowing the
//!   state they apply to;
//! - a texel that did not change has the all-zero residual, and small
//!   changes have small residuals, which after the zig-zag map and the split
//!   into byte planes below leaves long runs of zero bytes for zstd.
//!
//! Fields per format (the wire layout of §5):
//!
//! - `Rgb9e5`: red, green, blue mantissas (9 bits each) and the shared
//!   exponent (5 bits);
//! - `Rgba16f`: the four binary16 bit patterns (16 bits each). For the
//!   non-negative values a server sends, the bit pattern is monotone in the
//!   value, so a residual is a difference in steps of the half-float grid.
//!
//! Each field difference `d = (new - old) mod 2^w` is read as a `w`-bit
//! two's-complement number `s` and zig-zag mapped,
//! `z = (s << 1) ^ (s >> (w - 1))` (0, -1, 1, -2, ... become 0, 1, 2, 3,
//! ...), and the tile's texels are laid out in byte planes, every plane
//! holding one byte per texel in row-major order:
//!
//! - `Rgb9e5`, 4 planes: the low 8 bits of red's `z`, of green's, of blue's,
//!   then one byte `zr >> 8 | (zg >> 8) << 1 | (zb >> 8) << 2 | ze << 3`;
//! - `Rgba16f`, 8 planes: the low bytes of R, G, B, A's `z`, then their high
//!   bytes.
//!
//! A residual is therefore exactly as long as the tile's texels, and every
//! byte string of that length is a valid residual.
//!
//! A delta carries the residuals of all its tiles in one zstd frame
//! ([`pack`], [`unpack`]): a bitmap of the tiles it carries (bit `i % 8` of
//! byte `i / 8` for tile `i`, `ceil(tile_count / 8)` bytes, unused bits 0),
//! then the residual of every tile whose bit is set, in ascending tile
//! order. One frame for the whole delta compresses far better than one per
//! tile (a tile's residual is a few hundred bytes, too few for zstd to
//! learn from), and the bitmap costs less than a list of indices.

use super::{ApplyError, Layout};
use crate::PixelFormat;

/// Field widths of one texel, in wire order.
fn widths(format: PixelFormat) -> &'static [u32] {
    match format {
        PixelFormat::Rgb9e5 => &[9, 9, 9, 5],
        PixelFormat::Rgba16f => &[16, 16, 16, 16],
    }
}

/// The texel at `bytes` (little-endian wire form) split into its fields.
fn fields(format: PixelFormat, bytes: &[u8]) -> [u32; 4] {
    match format {
        PixelFormat::Rgb9e5 => {
            let v = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
            [v & 0x1FF, (v >> 9) & 0x1FF, (v >> 18) & 0x1FF, v >> 27]
        }
        PixelFormat::Rgba16f => {
            [0, 1, 2, 3].map(|i| u32::from(u16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]])))
        }
    }
}

/// Writes `f` back as the texel's wire bytes.
fn store(format: PixelFormat, f: [u32; 4], out: &mut [u8]) {
    match format {
        PixelFormat::Rgb9e5 => {
            let v = f[0] | (f[1] << 9) | (f[2] << 18) | (f[3] << 27);
            out[..4].copy_from_slice(&v.to_le_bytes());
        }
        PixelFormat::Rgba16f => {
            for (i, x) in f.into_iter().enumerate() {
                out[2 * i..2 * i + 2].copy_from_slice(&(x as u16).to_le_bytes());
            }
        }
    }
}

fn mask(w: u32) -> u32 {
    (1u32 << w) - 1
}

/// Zig-zag of the `w`-bit two's-complement number `d`.
fn zigzag(d: u32, w: u32) -> u32 {
    let s = ((d << (32 - w)) as i32) >> (32 - w);
    (((s << 1) ^ (s >> 31)) as u32) & mask(w)
}

/// Inverse of [`zigzag`], as a `w`-bit two's-complement number.
fn unzigzag(z: u32, w: u32) -> u32 {
    ((z >> 1) ^ (z & 1).wrapping_neg()) & mask(w)
}

/// The zig-zagged field residuals of texel `t` of `planes` (`n` texels).
fn read_planes(format: PixelFormat, planes: &[u8], n: usize, t: usize) -> [u32; 4] {
    let p = |k: usize| u32::from(planes[k * n + t]);
    match format {
        PixelFormat::Rgb9e5 => {
            let high = p(3);
            [
                p(0) | (high & 1) << 8,
                p(1) | (high >> 1 & 1) << 8,
                p(2) | (high >> 2 & 1) << 8,
                high >> 3,
            ]
        }
        PixelFormat::Rgba16f => [0, 1, 2, 3].map(|c| p(c) | p(c + 4) << 8),
    }
}

/// Writes zig-zagged field residuals `z` as texel `t` of `planes`.
fn write_planes(format: PixelFormat, z: [u32; 4], planes: &mut [u8], n: usize, t: usize) {
    match format {
        PixelFormat::Rgb9e5 => {
            for c in 0..3 {
                planes[c * n + t] = z[c] as u8;
            }
            planes[3 * n + t] =
                ((z[0] >> 8) | (z[1] >> 8) << 1 | (z[2] >> 8) << 2 | z[3] << 3) as u8;
        }
        PixelFormat::Rgba16f => {
            for c in 0..4 {
                planes[c * n + t] = z[c] as u8;
                planes[(c + 4) * n + t] = (z[c] >> 8) as u8;
            }
        }
    }
}

/// The residual that takes the texels `old` to `new` (both a tile's
/// little-endian texels, same length), as byte planes of the same length.
pub fn encode(format: PixelFormat, old: &[u8], new: &[u8]) -> Vec<u8> {
    let bpt = format.bytes_per_texel();
    debug_assert_eq!(old.len(), new.len());
    let n = new.len() / bpt;
    let mut planes = vec![0u8; new.len()];
    let w = widths(format);
    for t in 0..n {
        let (a, b) = (
            fields(format, &old[t * bpt..(t + 1) * bpt]),
            fields(format, &new[t * bpt..(t + 1) * bpt]),
        );
        let z = [0, 1, 2, 3].map(|i| zigzag(b[i].wrapping_sub(a[i]) & mask(w[i]), w[i]));
        write_planes(format, z, &mut planes, n, t);
    }
    planes
}

/// Applies residual `planes` onto `texels` (a tile's little-endian texels,
/// same length) in place.
pub fn apply(format: PixelFormat, texels: &mut [u8], planes: &[u8]) {
    let bpt = format.bytes_per_texel();
    debug_assert_eq!(texels.len(), planes.len());
    let n = texels.len() / bpt;
    let w = widths(format);
    for t in 0..n {
        let texel = &mut texels[t * bpt..(t + 1) * bpt];
        let f = fields(format, texel);
        let z = read_planes(format, planes, n, t);
        let new = [0, 1, 2, 3].map(|i| f[i].wrapping_add(unzigzag(z[i], w[i])) & mask(w[i]));
        store(format, new, texel);
    }
}

/// The residual equal to applying `first` and then `second` (both byte
/// planes of one tile, same length).
pub fn compose(format: PixelFormat, first: &[u8], second: &[u8]) -> Vec<u8> {
    let bpt = format.bytes_per_texel();
    debug_assert_eq!(first.len(), second.len());
    let n = first.len() / bpt;
    let w = widths(format);
    let mut planes = vec![0u8; first.len()];
    for t in 0..n {
        let (a, b) = (
            read_planes(format, first, n, t),
            read_planes(format, second, n, t),
        );
        let z = [0, 1, 2, 3].map(|i| {
            let sum = unzigzag(a[i], w[i]).wrapping_add(unzigzag(b[i], w[i])) & mask(w[i]);
            zigzag(sum, w[i])
        });
        write_planes(format, z, &mut planes, n, t);
    }
    planes
}

/// The payload of a delta carrying `tiles` (ascending, distinct indices of
/// `layout`, each with its residual planes of exactly the tile's size),
/// compressed with `c`; empty when `tiles` is.
///
/// # Panics
/// If an index is out of range or repeated, or a residual has the wrong size.
pub fn pack(
    layout: &Layout,
    tiles: &[(u32, Vec<u8>)],
    c: &mut zstd::bulk::Compressor<'_>,
) -> Vec<u8> {
    if tiles.is_empty() {
        return Vec::new();
    }
    let count = layout.tile_count();
    let mut raw = vec![0u8; count.div_ceil(8) as usize];
    let mut last = None;
    for (index, planes) in tiles {
        assert!(last < Some(*index), "tiles must be ascending and distinct");
        assert_eq!(
            Some(planes.len()),
            layout.tile_bytes(*index),
            "tile {index}"
        );
        raw[(*index / 8) as usize] |= 1 << (*index % 8);
        last = Some(*index);
    }
    for (_, planes) in tiles {
        raw.extend_from_slice(planes);
    }
    super::compress_tile(c, &raw)
}

/// Reads a delta's payload: the tiles it carries, ascending, each with its
/// residual planes. Refuses (without allocating beyond the atlas's size) a
/// payload that is not one zstd frame declaring its content size, whose
/// content is larger than a bitmap and every tile, whose bitmap sets a bit
/// past the last tile, or whose length is not exactly the bitmap plus the
/// tiles it sets.
pub fn unpack(
    layout: &Layout,
    payload: &[u8],
    d: &mut zstd::bulk::Decompressor<'_>,
) -> Result<Vec<(u32, Vec<u8>)>, ApplyError> {
    if payload.is_empty() {
        return Ok(Vec::new());
    }
    let bad = |reason: String| ApplyError::Residual(reason);
    let count = layout.tile_count();
    let bitmap = count.div_ceil(8) as usize;
    let all = layout.width as usize * layout.height as usize * layout.format.bytes_per_texel();
    let most = bitmap + all;
    let declared = match zstd::zstd_safe::get_frame_content_size(payload) {
        Ok(Some(n)) => n,
        Ok(None) => {
            return Err(bad(
                "the zstd frame does not declare its content size".into()
            ));
        }
        Err(_) => return Err(bad("not a zstd frame".into())),
    };
    if declared > most as u64 {
        return Err(bad(format!(
            "declares {declared} bytes; a delta of this atlas holds at most {most}"
        )));
    }
    let mut raw = vec![0u8; declared as usize];
    let n = d
        .decompress_to_buffer(payload, &mut raw[..])
        .map_err(|e| bad(format!("zstd: {e}")))?;
    if n != raw.len() {
        return Err(bad(format!("holds {n} bytes but declares {declared}")));
    }
    if raw.len() < bitmap {
        return Err(bad(format!(
            "{} bytes cannot hold the {bitmap}-byte tile bitmap",
            raw.len()
        )));
    }
    let mut tiles = Vec::new();
    let mut at = bitmap;
    for byte in 0..bitmap {
        for bit in 0..8 {
            if raw[byte] >> bit & 1 == 0 {
                continue;
            }
            let index = (byte * 8 + bit) as u32;
            let Some(len) = layout.tile_bytes(index) else {
                return Err(bad(format!(
                    "the bitmap sets tile {index}; the atlas has {count} tiles"
                )));
            };
            if at + len > raw.len() {
                return Err(bad(format!(
                    "ends inside tile {index} ({} bytes, {len} needed from byte {at})",
                    raw.len()
                )));
            }
            tiles.push((index, raw[at..at + len].to_vec()));
            at += len;
        }
    }
    if at != raw.len() {
        return Err(bad(format!(
            "{} bytes left over after the tiles the bitmap sets",
            raw.len() - at
        )));
    }
    Ok(tiles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lightmap::quantize_into;

    fn texels(format: PixelFormat, rgb: &[[f32; 3]]) -> Vec<u8> {
        let bpt = format.bytes_per_texel();
        let mut out = vec![0; rgb.len() * bpt];
        for (i, c) in rgb.iter().enumerate() {
            quantize_into(format, *c, &mut out[i * bpt..(i + 1) * bpt]);
        }
        out
    }

    #[test]
    fn zigzag_maps_small_signed_differences_to_small_numbers_and_back() {
        for w in [5, 9, 16] {
            for d in 0..(1u32 << w) {
                assert_eq!(unzigzag(zigzag(d, w), w), d, "w {w} d {d}");
            }
            assert_eq!(zigzag(0, w), 0);
            assert_eq!(zigzag(mask(w), w), 1, "-1");
            assert_eq!(zigzag(1, w), 2, "+1");
        }
    }

    #[test]
    fn an_unchanged_tile_has_an_all_zero_residual_and_a_change_applies_exactly() {
        for format in [PixelFormat::Rgb9e5, PixelFormat::Rgba16f] {
            let old = texels(format, &[[1.0, 0.5, 0.25], [0.0; 3], [3.0, 2.0, 1e-6]]);
            let new = texels(
                format,
                &[[1.0, 0.5, 0.25], [65000.0, 0.0, 1.0], [2.9, 2.1, 0.0]],
            );
            assert!(encode(format, &old, &old).iter().all(|&b| b == 0));
            let r = encode(format, &old, &new);
            let n = 3;
            assert!(
                (0..format.bytes_per_texel()).all(|k| r[k * n] == 0),
                "the unchanged first texel has a zero residual in every plane"
            );
            let mut held = old.clone();
            apply(format, &mut held, &r);
            assert_eq!(held, new, "{format:?}");
            let back = encode(format, &new, &old);
            let mut round = old.clone();
            apply(format, &mut round, &compose(format, &r, &back));
            assert_eq!(
                round, old,
                "{format:?}: a change and its inverse compose to nothing"
            );
        }
    }
}

//! Merging consecutive deltas, so a slow client skips forward with one
//! frame instead of a queue.

use std::collections::BTreeMap;

use super::{ApplyError, Layout, ZSTD_LEVEL, residual};
use crate::{Delta, ObjectSeq};

/// Merges `a: base -> v1` and `b: v1 -> v2` of a lightmap of `layout` into
/// `base -> v2`. The tiles are the union; a tile both carry gets the
/// composed residual ([`residual::compose`]), so applying the result equals
/// applying `a` then `b`, whatever state they apply to. `reflected` is the
/// union, `b`'s seq winning per object, sorted by object.
///
/// Errors: [`ApplyError::WrongBase`] unless `b.base_version == a.version`,
/// and any error applying either payload would give.
pub fn merge(layout: &Layout, a: &Delta, b: &Delta) -> Result<Delta, ApplyError> {
    if b.base_version != a.version {
        return Err(ApplyError::WrongBase {
            have: a.version,
            base: b.base_version,
        });
    }
    let mut reflected: BTreeMap<u32, u64> = BTreeMap::new();
    for r in a.reflected.iter().chain(&b.reflected) {
        reflected.insert(r.object, r.seq);
    }
    let reflected = reflected
        .into_iter()
        .map(|(object, seq)| ObjectSeq { object, seq })
        .collect();
    let payload = if a.residual.is_empty() {
        b.residual.clone()
    } else if b.residual.is_empty() {
        a.residual.clone()
    } else {
        let zstd = |e: std::io::Error| ApplyError::Residual(format!("zstd: {e}"));
        let mut d = zstd::bulk::Decompressor::new().map_err(zstd)?;
        let mut tiles: BTreeMap<u32, Vec<u8>> = residual::unpack(layout, &a.residual, &mut d)?
            .into_iter()
            .collect();
        for (index, second) in residual::unpack(layout, &b.residual, &mut d)? {
            let composed = match tiles.get(&index) {
                Some(first) => residual::compose(layout.format, first, &second),
                None => second,
            };
            tiles.insert(index, composed);
        }
        let tiles: Vec<(u32, Vec<u8>)> = tiles.into_iter().collect();
        let mut c = zstd::bulk::Compressor::new(ZSTD_LEVEL).map_err(zstd)?;
        residual::pack(layout, &tiles, &mut c)
    };
    Ok(Delta {
        base_version: a.base_version,
        version: b.version,
        reflected,
        residual: payload,
    })
}

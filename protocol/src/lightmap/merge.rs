//! Merging consecutive deltas, so a slow client skips forward with one
//! frame instead of a queue.

use std::collections::BTreeMap;

use super::ApplyError;
use crate::{Delta, ObjectSeq, Tile};

/// Merges `a: base -> v1` and `b: v1 -> v2` into `base -> v2`. Tiles are the
/// union, `b`'s payload winning where both carry a tile; `reflected` is the
/// union, `b`'s seq winning per object. Both outputs are sorted (tiles by
/// index, reflected by object). Applying the result equals applying `a` then
/// `b`.
///
/// Errors: [`ApplyError::WrongBase`] unless `b.base_version == a.version`,
/// [`ApplyError::DuplicateTile`] if either input repeats a tile index
/// (tile indices are otherwise checked when the merged delta is applied).
pub fn merge(a: &Delta, b: &Delta) -> Result<Delta, ApplyError> {
    if b.base_version != a.version {
        return Err(ApplyError::WrongBase {
            have: a.version,
            base: b.base_version,
        });
    }
    let mut tiles: BTreeMap<u32, &Vec<u8>> = BTreeMap::new();
    for d in [a, b] {
        let mut own = std::collections::HashSet::new();
        for t in &d.tiles {
            if !own.insert(t.index) {
                return Err(ApplyError::DuplicateTile { index: t.index });
            }
            tiles.insert(t.index, &t.data);
        }
    }
    let mut reflected: BTreeMap<u32, u64> = BTreeMap::new();
    for r in a.reflected.iter().chain(&b.reflected) {
        reflected.insert(r.object, r.seq);
    }
    Ok(Delta {
        base_version: a.base_version,
        version: b.version,
        reflected: reflected
            .into_iter()
            .map(|(object, seq)| ObjectSeq { object, seq })
            .collect(),
        tiles: tiles
            .into_iter()
            .map(|(index, data)| Tile {
                index,
                data: data.clone(),
            })
            .collect(),
    })
}

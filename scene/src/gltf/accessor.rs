//! Reading accessors with every byte range checked.
//!
//! The `gltf` crate's readers assume the file is well-formed; a file is input
//! from outside, so this reader checks the accessor's type and component
//! type against what the attribute allows (glTF 2.0 §3.7.2.1, "Meshes") and
//! that every element lies inside its buffer view and buffer, and returns a
//! message instead of panicking.

use ::gltf::accessor::{DataType, Dimensions};
use glam::{Vec2, Vec3};

pub(super) struct Reader<'b> {
    /// Loaded buffers; `None` where loading failed.
    pub buffers: &'b [Option<Vec<u8>>],
}

fn dims(d: Dimensions) -> usize {
    match d {
        Dimensions::Scalar => 1,
        Dimensions::Vec2 => 2,
        Dimensions::Vec3 => 3,
        Dimensions::Vec4 => 4,
        Dimensions::Mat2 => 4,
        Dimensions::Mat3 => 9,
        Dimensions::Mat4 => 16,
    }
}

fn size(t: DataType) -> usize {
    match t {
        DataType::I8 | DataType::U8 => 1,
        DataType::I16 | DataType::U16 => 2,
        DataType::U32 | DataType::F32 => 4,
    }
}

fn name(a: &::gltf::Accessor) -> String {
    match a.name() {
        Some(n) => format!("accessor #{} \"{n}\"", a.index()),
        None => format!("accessor #{}", a.index()),
    }
}

impl Reader<'_> {
    /// The bytes of each element (`count` slices of `elem` bytes), or `None`
    /// when the accessor has no buffer view (all zeros, glTF §3.6.2.1).
    fn elements<'a>(
        &'a self,
        a: &::gltf::Accessor,
        what: &str,
        elem: usize,
    ) -> Result<Option<Vec<&'a [u8]>>, String> {
        let acc = name(a);
        if a.sparse().is_some() {
            return Err(format!(
                "{what} {acc} is sparse; sparse accessors are not supported"
            ));
        }
        let count = a.count();
        let Some(view) = a.view() else {
            // All zeros; bound the allocation a file can ask for.
            if count > 1 << 26 {
                return Err(format!(
                    "{what} {acc} has no buffer view and count {count}: too large"
                ));
            }
            return Ok(None);
        };
        let buffer_index = view.buffer().index();
        let Some(Some(buffer)) = self.buffers.get(buffer_index) else {
            return Err(format!(
                "{what} {acc} reads buffer #{buffer_index}, which could not be loaded"
            ));
        };
        let stride = view.stride().unwrap_or(elem);
        if stride < elem {
            return Err(format!(
                "{what} {acc}: buffer view #{} has byteStride {stride}, less than the {elem}-byte element",
                view.index()
            ));
        }
        let view_end = view
            .offset()
            .checked_add(view.length())
            .filter(|&e| e <= buffer.len())
            .ok_or_else(|| {
                format!(
                    "{what} {acc}: buffer view #{} (bytes {}..+{}) runs past the end of buffer #{buffer_index} ({} bytes)",
                    view.index(),
                    view.offset(),
                    view.length(),
                    buffer.len()
                )
            })?;
        let start = view.offset().checked_add(a.offset());
        let end = match count {
            0 => start,
            n => start
                .and_then(|s| stride.checked_mul(n - 1).and_then(|x| x.checked_add(s)))
                .and_then(|s| s.checked_add(elem)),
        };
        let (Some(start), Some(end)) = (start, end) else {
            return Err(format!("{what} {acc}: byte range overflows"));
        };
        if end > view_end {
            return Err(format!(
                "{what} {acc}: {count} elements from byte {} need bytes up to {end}, past the end of buffer view #{} ({view_end})",
                start,
                view.index()
            ));
        }
        Ok(Some(
            (0..count)
                .map(|i| &buffer[start + i * stride..start + i * stride + elem])
                .collect(),
        ))
    }

    /// Float vectors: f32, or (when `normalized_ok`) normalised u8/u16, as
    /// glTF allows for TEXCOORD_n.
    fn floats<const N: usize>(
        &self,
        a: &::gltf::Accessor,
        what: &str,
        normalized_ok: bool,
    ) -> Result<Vec<[f32; N]>, String> {
        let acc = name(a);
        let d = dims(a.dimensions());
        if d != N {
            return Err(format!(
                "{what} {acc} has type {:?}; {what} must be VEC{N}",
                a.dimensions()
            ));
        }
        let t = a.data_type();
        let ok = t == DataType::F32
            || (normalized_ok && a.normalized() && matches!(t, DataType::U8 | DataType::U16));
        if !ok {
            let allowed = if normalized_ok {
                "FLOAT, or normalized UNSIGNED_BYTE/UNSIGNED_SHORT"
            } else {
                "FLOAT"
            };
            return Err(format!(
                "{what} {acc} has component type {t:?}{}; {what} must be {allowed}",
                if a.normalized() { " (normalized)" } else { "" }
            ));
        }
        let c = size(t);
        let Some(elements) = self.elements(a, what, c * N)? else {
            return Ok(vec![[0.0; N]; a.count()]);
        };
        Ok(elements
            .into_iter()
            .map(|e| {
                std::array::from_fn(|k| {
                    let b = &e[k * c..(k + 1) * c];
                    match t {
                        DataType::U8 => b[0] as f32 / 255.0,
                        DataType::U16 => u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0,
                        _ => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                    }
                })
            })
            .collect())
    }

    pub fn vec3(&self, a: &::gltf::Accessor, what: &str) -> Result<Vec<Vec3>, String> {
        Ok(self
            .floats::<3>(a, what, false)?
            .into_iter()
            .map(Vec3::from)
            .collect())
    }

    pub fn vec2(&self, a: &::gltf::Accessor, what: &str) -> Result<Vec<Vec2>, String> {
        Ok(self
            .floats::<2>(a, what, true)?
            .into_iter()
            .map(Vec2::from)
            .collect())
    }

    /// Indices: SCALAR of UNSIGNED_BYTE/SHORT/INT, not normalised.
    pub fn indices(&self, a: &::gltf::Accessor) -> Result<Vec<u32>, String> {
        let acc = name(a);
        if a.dimensions() != Dimensions::Scalar {
            return Err(format!(
                "indices {acc} has type {:?}; indices must be SCALAR",
                a.dimensions()
            ));
        }
        let t = a.data_type();
        if !matches!(t, DataType::U8 | DataType::U16 | DataType::U32) || a.normalized() {
            return Err(format!(
                "indices {acc} has component type {t:?}{}; indices must be UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT",
                if a.normalized() { " (normalized)" } else { "" }
            ));
        }
        let Some(elements) = self.elements(a, "indices", size(t))? else {
            return Ok(vec![0; a.count()]);
        };
        Ok(elements
            .into_iter()
            .map(|b| match t {
                DataType::U8 => b[0] as u32,
                DataType::U16 => u16::from_le_bytes([b[0], b[1]]) as u32,
                _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            })
            .collect())
    }
}

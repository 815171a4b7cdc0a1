//! One element's hemicube tile (the top face and the upper halves of the
//! side faces, `3 res x res` pixels): where the tiles of a pass lie in its
//! target, each face's viewport, and the delta form factors that weigh
//! every pixel.

use crate::gpu::device::GpuError;

/// Upper bound on the memory of the hemicube target (colour and depth) of
/// one pass; fewer elements are batched at high resolutions.
const TARGET_BYTES: u64 = 64 << 20;

/// Bytes per hemicube pixel: `Rgba32Float` colour and `Depth32Float`.
const PIXEL_BYTES: u64 = 16 + 4;

/// The tiles of one pass in the hemicube target.
pub(super) struct TileLayout {
    /// Even top-face resolution.
    pub(super) res: u32,
    /// Elements (tiles) per pass.
    pub(super) capacity: u32,
    /// Tiles per target row, and target rows.
    pub(super) columns: u32,
    pub(super) rows: u32,
}

impl TileLayout {
    /// The layout for hemicubes of `hemicube_resolution` (rounded up to
    /// an even number), at most `batch_elements` tiles, within the
    /// adapter's `limits` (`GatherOptions` states both).
    pub(super) fn new(
        limits: &wgpu::Limits,
        hemicube_resolution: u32,
        batch_elements: u32,
    ) -> Result<Self, GpuError> {
        let res = hemicube_resolution.max(2).div_ceil(2) * 2;
        let max_dim = limits.max_texture_dimension_2d;
        if 3 * res > max_dim {
            return Err(GpuError::TooLarge(format!(
                "a gather hemicube resolution of {res} needs a {} pixel wide tile; the adapter allows {max_dim}",
                3 * res
            )));
        }
        let tile_bytes = 3 * u64::from(res) * u64::from(res) * PIXEL_BYTES;
        let wanted = u64::from(batch_elements.max(1))
            .min((TARGET_BYTES / tile_bytes).max(1))
            .min(u64::from(limits.max_compute_workgroups_per_dimension))
            as u32;
        // A roughly square target, within the adapter's texture size.
        let columns = (max_dim / (3 * res))
            .min(((f64::from(wanted) / 3.0).sqrt().ceil() as u32).max(1))
            .max(1);
        let capacity = wanted.min(columns * (max_dim / res));
        let rows = capacity.div_ceil(columns);
        Ok(Self {
            res,
            capacity,
            columns,
            rows,
        })
    }
}

/// Delta form factors of one tile, row-major over its `3 res x res`
/// pixels: the top face in columns `0..res`, then the upper halves of the
/// side faces 1, 2 (columns `res..2 res`, rows `0..res/2` and
/// `res/2..res`) and 3, 4 (columns `2 res..3 res`). Normalised to sum to
/// one, so that a closed scene conserves energy exactly (the raw sum
/// exceeds 1 by the discretisation error: 5e-4 at res 32, 1e-4 at 64).
pub(super) fn delta_form_factors(res: u32) -> Vec<f32> {
    let half = res / 2;
    let da = (2.0 / f64::from(res)).powi(2);
    let centre = |i: u32| (f64::from(i) + 0.5) / f64::from(res) * 2.0 - 1.0;
    let mut values = Vec::with_capacity((3 * res * res) as usize);
    for row in 0..res {
        for col in 0..3 * res {
            let x = centre(col % res);
            let value = if col < res {
                // Top face at distance 1 along the normal, pixel (x, y).
                let y = -centre(row);
                da / (std::f64::consts::PI * (x * x + y * y + 1.0).powi(2))
            } else {
                // Side face: viewport row `row % half` of the upper half;
                // y is the height above the horizon (ndc y, in (0, 1)).
                let y = -centre(row % half);
                y * da / (std::f64::consts::PI * (x * x + y * y + 1.0).powi(2))
            };
            values.push(value);
        }
    }
    let sum: f64 = values.iter().sum();
    values.iter().map(|v| (v / sum) as f32).collect()
}

/// Viewport (x, y, size) and scissor height of face `face` of the tile at
/// `origin`: the side faces' viewports are full faces, scissored to their
/// upper half (below the horizon there is nothing to gather).
pub(super) fn face_viewport(origin: (u32, u32), face: u32, res: u32) -> (u32, u32, u32) {
    let (x, y) = origin;
    if face == 0 {
        (x, y, res)
    } else {
        let k = face - 1;
        (x + res * (1 + k / 2), y + (k % 2) * (res / 2), res / 2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::hemicube::FACES;

    /// The delta form factors of a hemicube sum to one (after
    /// normalisation), and before it the discretisation error is small:
    /// the hemicube integrates the cosine-weighted hemisphere.
    #[test]
    fn delta_form_factors_sum_to_one() {
        for res in [8u32, 32, 64] {
            let values = delta_form_factors(res);
            assert_eq!(values.len(), (3 * res * res) as usize);
            let sum: f64 = values.iter().map(|v| f64::from(*v)).sum();
            assert!((sum - 1.0).abs() < 1e-5, "res {res}: {sum}");
            assert!(values.iter().all(|v| *v > 0.0));
        }
    }

    /// Tiles of the side faces do not overlap and cover the tile.
    #[test]
    fn face_viewports_tile_three_res_by_res() {
        let res = 8;
        let mut covered = vec![0u32; (3 * res * res) as usize];
        for face in 0..FACES {
            let (x, y, rows) = face_viewport((0, 0), face, res);
            for r in y..y + rows {
                for c in x..x + res {
                    covered[(r * 3 * res + c) as usize] += 1;
                }
            }
        }
        assert!(covered.iter().all(|c| *c == 1));
    }
}

//! How far a lightmap is from a reference: the one accuracy metric of tests,
//! benchmarks and BENCHMARKS.md.
//!
//! Emitter texels are nearly exact in every solver (B = E plus a little
//! reflected light) and far brighter than everything else, so any sum that
//! includes them is dominated by them: on `cornell-large` an NRMSE over all
//! texels read 0.83% while the non-emitting texels were 4.97% off. The
//! metric therefore looks only at elements whose material emits nothing,
//! and weighs each by its area, so that a region counts by the surface it
//! covers, not by how finely it happens to be charted:
//!
//! - **NRMSE** `sqrt(Σ A_i |B_i − R_i|² / Σ A_i |R_i|²)`, `|·|` the
//!   Euclidean norm of the RGB triple;
//! - **p95_rel**, the 95th percentile (nearest rank, by element count) of
//!   the per-element relative error `|B_i − R_i| / |R_i|` over the elements
//!   whose `|R_i|` is above 1% of the area-weighted mean `|R|` (so that a
//!   black texel does not divide by zero): where the NRMSE says "on
//!   average", p95 says "and in the worst twentieth of the places you look".
//!
//! Callers can narrow the set further ([`accuracy_where`]), e.g. to leave
//! out texels that are inside geometry and never seen.

use glam::Vec3;

use lightwire_scene::atlas::Atlas;

/// Fraction of the mean reference magnitude below which an element is left
/// out of the relative-error percentile.
pub const P95_FLOOR: f64 = 0.01;

/// The accuracy of a lightmap against a reference (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Accuracy {
    /// Area-weighted NRMSE over the non-emitting elements.
    pub nrmse: f64,
    /// 95th percentile of the per-element relative error.
    pub p95_rel: f64,
    /// How many elements were compared.
    pub elements: usize,
}

impl std::fmt::Display for Accuracy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "NRMSE {:.2}%, p95 {:.1}% over {} non-emitting elements",
            self.nrmse * 100.0,
            self.p95_rel * 100.0,
            self.elements
        )
    }
}

/// [`Accuracy`] of `values` against `reference`, both indexed like
/// `atlas.elements`, over every non-emitting element. `None` when the
/// lengths differ from the atlas or the reference is black everywhere the
/// metric looks.
pub fn accuracy(atlas: &Atlas, values: &[Vec3], reference: &[Vec3]) -> Option<Accuracy> {
    accuracy_where(atlas, values, reference, |_| true)
}

/// The elements both metrics compare: non-emitting, standing for a surface
/// (texels of a triangle's chart above its diagonal weigh nothing and must
/// not count in a percentile), and `keep(i)`. `None` when `values` or
/// `reference` does not hold one value per element.
fn compared(
    atlas: &Atlas,
    values: &[Vec3],
    reference: &[Vec3],
    keep: impl Fn(usize) -> bool,
) -> Option<Vec<usize>> {
    let n = atlas.elements.len();
    if values.len() != n || reference.len() != n {
        return None;
    }
    Some(
        (0..n)
            .filter(|&i| {
                let e = &atlas.elements[i];
                e.emission.max_element() <= 0.0 && e.covers_surface() && keep(i)
            })
            .collect(),
    )
}

/// The relative errors `|V_i - R_i| / |R_i|`, sorted, of the `picked`
/// elements whose `|R_i|` is above [`P95_FLOOR`] of the area-weighted mean
/// `magnitude / total_area`.
fn relative_errors(
    picked: &[usize],
    values: &[Vec3],
    reference: &[Vec3],
    (magnitude, total_area): (f64, f64),
) -> Vec<f64> {
    let floor = P95_FLOOR * magnitude / total_area;
    let mut relative: Vec<f64> = picked
        .iter()
        .filter_map(|&i| {
            let r = reference[i].as_dvec3().length();
            (r > floor).then(|| (values[i].as_dvec3() - reference[i].as_dvec3()).length() / r)
        })
        .collect();
    relative.sort_by(f64::total_cmp);
    relative
}

/// [`accuracy`] over the non-emitting elements `i` for which `keep(i)`
/// (elements that stand for no surface are always left out).
pub fn accuracy_where(
    atlas: &Atlas,
    values: &[Vec3],
    reference: &[Vec3],
    keep: impl Fn(usize) -> bool,
) -> Option<Accuracy> {
    let picked = compared(atlas, values, reference, keep)?;
    let area = |i: usize| f64::from(atlas.elements[i].area);
    let (mut diff, mut norm, mut magnitude, mut total_area) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for &i in &picked {
        let (v, r) = (values[i].as_dvec3(), reference[i].as_dvec3());
        diff += area(i) * (v - r).length_squared();
        norm += area(i) * r.length_squared();
        magnitude += area(i) * r.length();
        total_area += area(i);
    }
    if norm <= 0.0 || total_area <= 0.0 {
        return None;
    }
    let relative = relative_errors(&picked, values, reference, (magnitude, total_area));
    let p95_rel = match relative.len() {
        0 => 0.0,
        len => relative[((0.95 * len as f64).ceil() as usize).clamp(1, len) - 1],
    };
    Some(Accuracy {
        nrmse: (diff / norm).sqrt(),
        p95_rel,
        elements: picked.len(),
    })
}

/// How closely a lightmap agrees with another of the same scene, texel by
/// texel: where [`Accuracy`] says how far from the truth, this says whether
/// two states a viewer should not tell apart (a scene after moves and a
/// fresh one, issue 57) are the same where it looks. Over the
/// non-emitting elements that cover a surface, with `keep(i)`, and whose
/// `|R_i|` is above [`P95_FLOOR`] of the area-weighted mean (lit).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Agreement {
    /// Lit elements compared.
    pub elements: usize,
    /// Share of them more than 1%, 2% and 5% off (relative error
    /// `|B_i − R_i| / |R_i|`).
    pub over_1: f64,
    pub over_2: f64,
    pub over_5: f64,
    /// 99th percentile (nearest rank) and largest relative error.
    pub p99: f64,
    pub worst: f64,
    /// Total light `Σ A_i (B_i channels summed)` over the reference's,
    /// minus one, over every compared non-emitting element (lit or not).
    pub total: f64,
}

impl std::fmt::Display for Agreement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} lit texels: {:.1}% > 1% off, {:.1}% > 2%, {:.1}% > 5%, p99 {:.2}%, worst {:.2}%, light {:+.2}%",
            self.elements,
            self.over_1 * 100.0,
            self.over_2 * 100.0,
            self.over_5 * 100.0,
            self.p99 * 100.0,
            self.worst * 100.0,
            self.total * 100.0
        )
    }
}

/// [`Agreement`] of `values` with `reference` over the elements `i` with
/// `keep(i)`. `None` when the lengths differ or nothing is lit.
pub fn agreement(
    atlas: &Atlas,
    values: &[Vec3],
    reference: &[Vec3],
    keep: impl Fn(usize) -> bool,
) -> Option<Agreement> {
    let picked = compared(atlas, values, reference, keep)?;
    let area = |i: usize| f64::from(atlas.elements[i].area);
    let total_area: f64 = picked.iter().map(|&i| area(i)).sum();
    let magnitude: f64 = picked
        .iter()
        .map(|&i| area(i) * reference[i].as_dvec3().length())
        .sum();
    if total_area <= 0.0 || magnitude <= 0.0 {
        return None;
    }
    let relative = relative_errors(&picked, values, reference, (magnitude, total_area));
    let count = relative.len();
    if count == 0 {
        return None;
    }
    let share = |bound: f64| relative.iter().filter(|&&r| r > bound).count() as f64 / count as f64;
    let light = |b: &[Vec3]| -> f64 {
        picked
            .iter()
            .map(|&i| area(i) * f64::from(b[i].element_sum()))
            .sum()
    };
    Some(Agreement {
        elements: count,
        over_1: share(0.01),
        over_2: share(0.02),
        over_5: share(0.05),
        p99: relative[((0.99 * count as f64).ceil() as usize).clamp(1, count) - 1],
        worst: relative[count - 1],
        total: light(values) / light(reference) - 1.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightwire_scene::Scene;

    /// A 1 x 1 floor (white) under a 0.2 x 0.2 light, charted at 10
    /// texels/m: 11 x 11 floor elements and a few light elements.
    fn room() -> Atlas {
        let scene = Scene::parse(
            r#"{
              "name": "metric", "lightmap": { "texel_density": 10 },
              "materials": [
                { "name": "white", "albedo": [0.5, 0.5, 0.5] },
                { "name": "light", "albedo": [0, 0, 0], "emission": [100, 100, 100] }
              ],
              "surfaces": [
                { "name": "floor", "material": "white",
                  "quad": { "origin": [0, 0, 0], "u": [0, 0, 1], "v": [1, 0, 0] } },
                { "name": "light", "material": "light",
                  "quad": { "origin": [0.4, 1, 0.4], "u": [0.2, 0, 0], "v": [0, 0, 0.2] } }
              ]
            }"#,
            "metric test",
        )
        .expect("scene");
        Atlas::build(&scene).expect("atlas")
    }

    fn emits(atlas: &Atlas, i: usize) -> bool {
        atlas.elements[i].emission.max_element() > 0.0
    }

    #[test]
    fn identical_is_zero_and_a_ten_percent_scale_is_a_tenth() {
        let atlas = room();
        let r: Vec<Vec3> = (0..atlas.elements.len())
            .map(|i| Vec3::new(1.0 + i as f32 * 0.01, 2.0, 3.0))
            .collect();
        let same = accuracy(&atlas, &r, &r).expect("lit");
        assert_eq!((same.nrmse, same.p95_rel), (0.0, 0.0));
        let scaled: Vec<Vec3> = r.iter().map(|v| *v * 1.1).collect();
        let a = accuracy(&atlas, &scaled, &r).expect("lit");
        assert!((a.nrmse - 0.1).abs() < 1e-6, "{a}");
        assert!((a.p95_rel - 0.1).abs() < 1e-6, "{a}");
        assert_eq!(accuracy(&atlas, &r[..1], &r), None);
    }

    /// The case the old metric hid: emitters exact and bright, every other
    /// texel 20% too dark. Over all texels that reads as about 1%; the
    /// metric must say 20%.
    #[test]
    fn an_emitter_dominated_lightmap_cannot_hide_a_dark_room() {
        let atlas = room();
        let reference: Vec<Vec3> = (0..atlas.elements.len())
            .map(|i| Vec3::splat(if emits(&atlas, i) { 100.0 } else { 1.0 }))
            .collect();
        let values: Vec<Vec3> = (0..atlas.elements.len())
            .map(|i| reference[i] * if emits(&atlas, i) { 1.0 } else { 0.8 })
            .collect();
        // What the old metric (all texels, unweighted) would have said.
        let (d, n) = values
            .iter()
            .zip(&reference)
            .fold((0.0, 0.0), |(d, n), (v, r)| {
                (d + (*v - *r).length_squared(), n + r.length_squared())
            });
        let old = f32::sqrt(d / n);
        assert!(old < 0.01, "the old metric passes it: {old}");
        let a = accuracy(&atlas, &values, &reference).expect("lit");
        assert!((a.nrmse - 0.2).abs() < 1e-6, "{a}");
        assert!((a.p95_rel - 0.2).abs() < 1e-6, "{a}");
        let lit = (0..atlas.elements.len())
            .filter(|&i| !emits(&atlas, i))
            .count();
        assert_eq!(a.elements, lit);
    }

    /// Area weighting: an error on a border texel (half or quarter area)
    /// counts less than the same error on an interior texel.
    #[test]
    fn errors_weigh_by_element_area() {
        let atlas = room();
        let reference = vec![Vec3::ONE; atlas.elements.len()];
        let floor = |corner: bool| {
            (0..atlas.elements.len())
                .find(|&i| {
                    let [a, b] = atlas.elements[i].texel;
                    let c = atlas.charts[atlas.elements[i].patch as usize];
                    let edge_a = a == c.x || a == c.x + c.w - 1;
                    let edge_b = b == c.y || b == c.y + c.h - 1;
                    !emits(&atlas, i)
                        && if corner {
                            edge_a && edge_b
                        } else {
                            !edge_a && !edge_b
                        }
                })
                .expect("texel")
        };
        let off = |i: usize| {
            let mut v = reference.clone();
            v[i] = Vec3::splat(2.0);
            accuracy(&atlas, &v, &reference).expect("lit").nrmse
        };
        let (corner, interior) = (off(floor(true)), off(floor(false)));
        assert!(
            (interior / corner - 2.0).abs() < 1e-3,
            "a corner texel has a quarter of an interior one's area: {corner} vs {interior}"
        );
    }

    /// The percentile sees a small badly wrong region the NRMSE averages
    /// away, and ignores black reference texels instead of dividing by zero.
    #[test]
    fn p95_sees_a_bad_twentieth_and_skips_black_texels() {
        let atlas = room();
        let floor: Vec<usize> = (0..atlas.elements.len())
            .filter(|&i| !emits(&atlas, i))
            .collect();
        let mut reference = vec![Vec3::ONE; atlas.elements.len()];
        let mut values = reference.clone();
        // 7 of the 121 floor texels (5.8%) are 50% too bright.
        for &i in &floor[..7] {
            values[i] = Vec3::splat(1.5);
        }
        // One black reference texel with a non-zero value: left out of p95.
        reference[floor[60]] = Vec3::ZERO;
        values[floor[60]] = Vec3::splat(0.001);
        let a = accuracy_where(&atlas, &values, &reference, |_| true).expect("lit");
        assert!((a.p95_rel - 0.5).abs() < 1e-6, "{a}");
        assert!(a.nrmse < 0.15, "{a}");
        // Narrowing the set with `keep` drops the bad texels.
        let kept =
            accuracy_where(&atlas, &values, &reference, |i| !floor[..7].contains(&i)).expect("lit");
        assert_eq!(kept.p95_rel, 0.0);
    }
}

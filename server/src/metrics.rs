//! Error metrics for comparing lightmaps from different solvers.

use glam::Vec3;

/// Normalised RMS error of `values` against `reference`, per element:
/// `sqrt(Σ |v_i - r_i|² / Σ |r_i|²)`, where `|·|` is the Euclidean norm of
/// the RGB triple. Only covered texels (elements) are passed in, so
/// uncovered atlas texels never dilute it. Returns `None` when the lengths
/// differ or the reference is all zero.
pub fn nrmse(values: &[Vec3], reference: &[Vec3]) -> Option<f64> {
    if values.len() != reference.len() {
        return None;
    }
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    for (v, r) in values.iter().zip(reference) {
        diff += f64::from((*v - *r).length_squared());
        norm += f64::from(r.length_squared());
    }
    (norm > 0.0).then(|| (diff / norm).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nrmse_of_identical_is_zero_and_of_a_ten_percent_scale_is_a_tenth() {
        let r = vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.5, 0.0, 4.0)];
        assert_eq!(nrmse(&r, &r), Some(0.0));
        let scaled: Vec<Vec3> = r.iter().map(|v| *v * 1.1).collect();
        let e = nrmse(&scaled, &r).expect("non-zero reference");
        assert!((e - 0.1).abs() < 1e-6, "{e}");
        assert_eq!(nrmse(&r[..1], &r), None);
    }
}

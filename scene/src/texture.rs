//! Albedo textures: a glTF base colour texture, decoded to linear RGB, and
//! how a triangle maps it.
//!
//! A texel of the lightmap is one radiosity element with one albedo, so a
//! textured surface's element albedo is the texture averaged over the
//! element's footprint ([`AlbedoMap::region_average`], times the material's
//! `baseColorFactor`), as issue 18 asks: a checker floor lit by a lamp
//! reflects the mean of its squares under each lightmap texel, and a
//! lightmap fine enough to resolve the squares gets each square's albedo.
//! The path tracer, which shares none of that averaging, looks the texture
//! up at each point a path bounces off ([`AlbedoMap::sample`]); the mean of
//! its point lookups over a texel is the same average.
//!
//! Colour: glTF base colour textures are sRGB-encoded (glTF 2.0 §3.9.2,
//! "baseColorTexture"), the factor is linear; the texels are decoded with
//! the sRGB transfer function and alpha is ignored. Sampling follows the
//! texture's sampler: `magFilter` nearest or linear (glTF's default, an
//! implementation's choice, is linear here), and per axis repeat, mirrored
//! repeat or clamp to edge. UV `(0, 0)` is the image's top-left corner
//! (glTF §3.7.2.1).

use std::sync::Arc;

use glam::{Vec2, Vec3};

/// How texture coordinates outside [0, 1] wrap, per axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wrap {
    Repeat,
    MirroredRepeat,
    ClampToEdge,
}

impl Wrap {
    /// The texel index `i` (any integer) wraps to, for `n` texels.
    fn index(self, i: i64, n: u32) -> usize {
        let n = i64::from(n.max(1));
        let k = match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::MirroredRepeat => {
                let m = i.rem_euclid(2 * n);
                if m >= n { 2 * n - 1 - m } else { m }
            }
            Wrap::ClampToEdge => i.clamp(0, n - 1),
        };
        k as usize
    }
}

/// How a texture is filtered when magnified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filter {
    Nearest,
    Linear,
}

/// Most pixels a texture may have (4096 x 4096; decoded it takes 12 bytes
/// a pixel).
pub const MAX_PIXELS: u64 = 4096 * 4096;

/// A decoded texture: linear RGB, row 0 at `v = 0`.
#[derive(Clone, PartialEq)]
pub struct Texture {
    /// Where it came from, for messages (`image #0 "checker"`).
    pub name: String,
    pub width: u32,
    pub height: u32,
    texels: Vec<Vec3>,
    pub wrap: [Wrap; 2],
    pub filter: Filter,
}

impl std::fmt::Debug for Texture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Texture({:?}, {}x{}, {:?}, {:?})",
            self.name, self.width, self.height, self.wrap, self.filter
        )
    }
}

/// The sRGB transfer function, decoding (IEC 61966-2-1).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// Decodes a PNG or JPEG (the formats glTF allows) holding sRGB colour.
    pub fn decode(
        name: &str,
        bytes: &[u8],
        wrap: [Wrap; 2],
        filter: Filter,
    ) -> Result<Texture, String> {
        let image =
            image::load_from_memory(bytes).map_err(|e| format!("cannot decode the image: {e}"))?;
        let pixels = u64::from(image.width()) * u64::from(image.height());
        if pixels > MAX_PIXELS {
            return Err(format!(
                "the image is {} x {} pixels; an albedo texture may have at most {MAX_PIXELS} (it is averaged into lightmap texels, which are far coarser)",
                image.width(),
                image.height()
            ));
        }
        let rgb = image.to_rgb32f();
        let (width, height) = rgb.dimensions();
        // `to_rgb32f` maps 8- and 16-bit channels to [0, 1] without touching
        // the transfer function, so the sRGB decoding is still to do.
        let texels = rgb
            .pixels()
            .map(|p| {
                Vec3::new(
                    srgb_to_linear(p[0]),
                    srgb_to_linear(p[1]),
                    srgb_to_linear(p[2]),
                )
            })
            .collect();
        // The texels match the dimensions: only an empty image is refused.
        Texture::from_linear(name, width, height, texels, wrap, filter)
            .ok_or_else(|| "the image has no pixels".to_string())
    }

    /// A texture from linear texels (row-major, `width × height`), for tests
    /// and generated content.
    pub fn from_linear(
        name: &str,
        width: u32,
        height: u32,
        texels: Vec<Vec3>,
        wrap: [Wrap; 2],
        filter: Filter,
    ) -> Option<Texture> {
        (width > 0 && height > 0 && texels.len() == (width as usize) * (height as usize)).then(
            || Texture {
                name: name.to_string(),
                width,
                height,
                texels,
                wrap,
                filter,
            },
        )
    }

    fn texel(&self, x: i64, y: i64) -> Vec3 {
        let x = self.wrap[0].index(x, self.width);
        let y = self.wrap[1].index(y, self.height);
        self.texels[y * self.width as usize + x]
    }

    /// The filtered linear colour at `uv`.
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let x = f64::from(uv.x) * f64::from(self.width);
        let y = f64::from(uv.y) * f64::from(self.height);
        match self.filter {
            Filter::Nearest => self.texel(x.floor() as i64, y.floor() as i64),
            Filter::Linear => {
                let (x, y) = (x - 0.5, y - 0.5);
                let (x0, y0) = (x.floor(), y.floor());
                let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
                let (x0, y0) = (x0 as i64, y0 as i64);
                let top = self.texel(x0, y0).lerp(self.texel(x0 + 1, y0), fx);
                let bottom = self.texel(x0, y0 + 1).lerp(self.texel(x0 + 1, y0 + 1), fx);
                top.lerp(bottom, fy)
            }
        }
    }
}

/// Fewest and most samples per axis [`AlbedoMap::region_average`] takes
/// over one element's footprint: a footprint inside one texture pixel is
/// still sampled 8 × 8, so that where a pixel's edge crosses it (a
/// magnified checker's square under a lightmap texel) the mean is within
/// 1/16 of the difference across the edge.
pub const MIN_SAMPLES_PER_AXIS: u32 = 8;
/// See [`MIN_SAMPLES_PER_AXIS`].
pub const MAX_SAMPLES_PER_AXIS: u32 = 32;

/// A texture laid on a triangle patch: the texture coordinates at the
/// patch's corners `(s, t) = (0, 0), (1, 0), (1, 1)`, that is at `origin`,
/// `origin + u`, `origin + u + v` (`PatchShape::Triangle`), interpolated
/// linearly in between.
#[derive(Debug, Clone, PartialEq)]
pub struct AlbedoMap {
    pub texture: Arc<Texture>,
    pub uv: [Vec2; 3],
}

impl AlbedoMap {
    /// Texture coordinates at patch parameters `(s, t)`.
    pub fn uv_at(&self, s: f32, t: f32) -> Vec2 {
        let [a, b, c] = self.uv;
        a + (b - a) * s + (c - b) * t
    }

    /// The texture's colour at patch parameters `(s, t)`.
    pub fn sample(&self, s: f32, t: f32) -> Vec3 {
        self.texture.sample(self.uv_at(s, t))
    }

    /// The texture averaged over `region = [s0, t0, s1, t1]` of the patch
    /// (only its part with `t <= s` when `triangle`): the mean of a grid of
    /// point samples, two per texture pixel the region spans along each
    /// axis, within [`MIN_SAMPLES_PER_AXIS`] and [`MAX_SAMPLES_PER_AXIS`]
    /// (a minified texture's pixels are then sampled, not all read, as a GPU
    /// samples a texture without mipmaps). `None` when the region
    /// holds no surface (a triangle chart's texel above the diagonal).
    pub fn region_average(&self, region: [f32; 4], triangle: bool) -> Option<Vec3> {
        let [s0, t0, s1, t1] = region;
        let size = Vec2::new(self.texture.width as f32, self.texture.height as f32);
        let [a, b, c] = self.uv;
        let pixels_s = ((b - a) * size).length() * (s1 - s0);
        let pixels_t = ((c - b) * size).length() * (t1 - t0);
        let count = |pixels: f32| {
            ((2.0 * pixels).ceil() as u32).clamp(MIN_SAMPLES_PER_AXIS, MAX_SAMPLES_PER_AXIS)
        };
        let (ns, nt) = (count(pixels_s), count(pixels_t));
        let mut sum = Vec3::ZERO;
        let mut n = 0u32;
        for j in 0..nt {
            let t = t0 + (t1 - t0) * (j as f32 + 0.5) / nt as f32;
            for i in 0..ns {
                let s = s0 + (s1 - s0) * (i as f32 + 0.5) / ns as f32;
                if triangle && t > s {
                    continue;
                }
                sum += self.sample(s, t);
                n += 1;
            }
        }
        (n > 0).then(|| sum / n as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker(filter: Filter, wrap: Wrap) -> Texture {
        // 2 × 2: black, white / white, black.
        let (k, w) = (Vec3::ZERO, Vec3::ONE);
        Texture::from_linear("checker", 2, 2, vec![k, w, w, k], [wrap; 2], filter)
            .expect("4 texels")
    }

    #[test]
    fn an_image_larger_than_the_limit_is_refused_with_its_size() {
        let mut png = Vec::new();
        let encoder = image::codecs::png::PngEncoder::new(&mut png);
        let pixels = vec![0u8; 4097 * 4096];
        image::ImageEncoder::write_image(
            encoder,
            &pixels,
            4097,
            4096,
            image::ExtendedColorType::L8,
        )
        .expect("PNG");
        let error =
            Texture::decode("big", &png, [Wrap::Repeat; 2], Filter::Linear).expect_err("too big");
        assert!(error.contains("4097 x 4096"), "{error}");
    }

    #[test]
    fn srgb_decoding_matches_the_standard_curve() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        // sRGB 188/255 is linear 0.5 to within a code value.
        assert!((srgb_to_linear(188.0 / 255.0) - 0.5).abs() < 0.005);
        assert!((srgb_to_linear(0.04) - 0.04 / 12.92).abs() < 1e-7);
    }

    #[test]
    fn nearest_sampling_picks_the_pixel_under_the_point_with_v_down() {
        let t = checker(Filter::Nearest, Wrap::Repeat);
        assert_eq!(t.sample(Vec2::new(0.25, 0.25)), Vec3::ZERO);
        assert_eq!(t.sample(Vec2::new(0.75, 0.25)), Vec3::ONE);
        assert_eq!(t.sample(Vec2::new(0.25, 0.75)), Vec3::ONE);
        assert_eq!(t.sample(Vec2::new(0.75, 0.75)), Vec3::ZERO);
    }

    #[test]
    fn wrap_modes_repeat_mirror_and_clamp() {
        let repeat = checker(Filter::Nearest, Wrap::Repeat);
        let mirror = checker(Filter::Nearest, Wrap::MirroredRepeat);
        let clamp = checker(Filter::Nearest, Wrap::ClampToEdge);
        // u = 1.25 is pixel 2: repeat -> 0 (black), mirror -> 1 (white),
        // clamp -> 1 (white).
        let uv = Vec2::new(1.25, 0.25);
        assert_eq!(repeat.sample(uv), Vec3::ZERO);
        assert_eq!(mirror.sample(uv), Vec3::ONE);
        assert_eq!(clamp.sample(uv), Vec3::ONE);
        // u = -0.25 is pixel -1: repeat -> 1, mirror -> 0, clamp -> 0.
        let uv = Vec2::new(-0.25, 0.25);
        assert_eq!(repeat.sample(uv), Vec3::ONE);
        assert_eq!(mirror.sample(uv), Vec3::ZERO);
        assert_eq!(clamp.sample(uv), Vec3::ZERO);
    }

    #[test]
    fn linear_sampling_blends_neighbours_halfway_between_centres() {
        let t = checker(Filter::Linear, Wrap::ClampToEdge);
        // Between pixel (0,0) black and (1,0) white, on row 0's centre line.
        let mid = t.sample(Vec2::new(0.5, 0.25));
        assert!((mid - Vec3::splat(0.5)).abs().max_element() < 1e-6, "{mid}");
        // At a pixel centre, the pixel itself.
        assert!(t.sample(Vec2::new(0.25, 0.25)).max_element() < 1e-6);
    }

    #[test]
    fn a_footprint_over_whole_checker_periods_averages_to_the_mean() {
        let texture = Arc::new(checker(Filter::Nearest, Wrap::Repeat));
        // A triangle whose (s, t) square maps to 3 × 3 texture periods.
        let map = AlbedoMap {
            texture,
            uv: [Vec2::ZERO, Vec2::new(3.0, 0.0), Vec2::new(3.0, 3.0)],
        };
        let quad = map
            .region_average([0.0, 0.0, 1.0, 1.0], false)
            .expect("samples");
        assert!(
            (quad - Vec3::splat(0.5)).abs().max_element() < 1e-6,
            "{quad}"
        );
        // One texture pixel's footprint, (s, t) in [0, 1/6]²: black only.
        let one = map
            .region_average([0.0, 0.0, 1.0 / 6.0, 1.0 / 6.0], false)
            .expect("samples");
        assert_eq!(one, Vec3::ZERO);
        // Above a triangle's diagonal there is nothing to average.
        assert_eq!(map.region_average([0.0, 0.5, 0.4, 1.0], true), None);
    }
}

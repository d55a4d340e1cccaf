//! Procedural textures for every material: bark, paint, brick, concrete, grass, clothes...
//!
//! The camera classifier learns appearance, so each material has its own structure (bark:
//! vertical fissures; paint: smooth with faint brush marks; brick: courses and mortar),
//! instances vary through their colour and seed, and the colour ranges of bark and post
//! paint overlap on purpose (the paper's hard case). Pure functions of (material, colour,
//! seed): deterministic everywhere.

use crate::description::{Appearance, Material};

/// An RGBA8 image, row-major, sRGB.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

/// Texture side in pixels; textures tile, so this bounds memory, not detail per metre.
pub const TEXTURE_SIZE: u32 = 128;

/// Physical size one texture tile covers (metres), so texture detail has a real scale.
pub fn tile_size_m(material: Material) -> [f64; 2] {
    match material {
        Material::Bark => [0.6, 0.8],
        Material::PalmBark => [0.6, 0.6],
        Material::Foliage => [1.5, 1.5],
        Material::Paint => [0.5, 0.5],
        Material::Brick => [1.0, 0.6],
        Material::Concrete => [1.0, 1.0],
        Material::Grass => [1.0, 1.0],
        Material::Clothes => [0.4, 0.4],
        Material::Skin => [0.3, 0.3],
        Material::Checker => [1.0, 1.0],
    }
}

/// Generates the texture of an appearance.
pub fn generate(appearance: &Appearance) -> Texture {
    generate_sized(appearance, TEXTURE_SIZE)
}

pub fn generate_sized(appearance: &Appearance, size: u32) -> Texture {
    let n = size as usize;
    let base = appearance.colour;
    let seed = appearance.texture_seed ^ material_salt(appearance.material);
    let mut rgba = Vec::with_capacity(n * n * 4);
    for y in 0..n {
        for x in 0..n {
            // Texture coordinates in [0, 1); noise is periodic over the tile so it repeats
            // seamlessly along a trunk.
            let u = x as f64 / n as f64;
            let v = y as f64 / n as f64;
            let c = shade(appearance.material, base, seed, u, v);
            rgba.extend_from_slice(&[to_u8(c[0]), to_u8(c[1]), to_u8(c[2]), 255]);
        }
    }
    Texture { width: size, height: size, rgba }
}

fn material_salt(m: Material) -> u64 {
    match m {
        Material::Bark => 0x1b873593,
        Material::PalmBark => 0x2c1b3c6d,
        Material::Foliage => 0x297a2d39,
        Material::Paint => 0x5bd1e995,
        Material::Brick => 0x68e31da4,
        Material::Concrete => 0x3c6ef372,
        Material::Grass => 0x1f83d9ab,
        Material::Clothes => 0x5be0cd19,
        Material::Skin => 0x6a09e667,
        Material::Checker => 0,
    }
}

fn shade(material: Material, base: [f64; 3], seed: u64, u: f64, v: f64) -> [f64; 3] {
    let scale = |c: [f64; 3], k: f64| c.map(|x| x * k);
    match material {
        Material::Bark => {
            // Vertical ridges broken by dark fissures, with fine grain.
            let ridges = fbm(seed, u * 10.0, v * 2.0, 10, 2, 3);
            let fissure = fbm(seed ^ 7, u * 18.0, v * 3.0, 18, 3, 2);
            let dark = if fissure < 0.38 { 0.45 + fissure } else { 1.0 };
            let grain = value_noise(seed ^ 99, u * 64.0, v * 64.0, 64, 64);
            scale(base, (0.65 + 0.55 * ridges) * dark * (0.9 + 0.2 * grain))
        }
        Material::PalmBark => {
            // Horizontal rings from old frond bases.
            let ring = ((v * 6.0 * std::f64::consts::TAU).sin() * 0.5 + 0.5).powf(3.0);
            let n = fbm(seed, u * 8.0, v * 8.0, 8, 8, 2);
            scale(base, 0.7 + 0.35 * n - 0.35 * ring)
        }
        Material::Foliage => {
            let n = fbm(seed, u * 12.0, v * 12.0, 12, 12, 3);
            let blotch = if n > 0.55 { 1.25 } else { 0.75 };
            scale(base, blotch * (0.7 + 0.5 * n))
        }
        Material::Paint => {
            // Smooth, slightly glossy, faint vertical brush marks and a few scuffs.
            let brush = value_noise(seed, u * 40.0, v * 2.0, 40, 2);
            let scuff = fbm(seed ^ 3, u * 6.0, v * 6.0, 6, 6, 2);
            let s = if scuff > 0.75 { 1.25 } else { 1.0 };
            scale(base, (0.95 + 0.1 * brush) * s)
        }
        Material::Brick => {
            let rows = 8.0;
            let cols = 4.0;
            let row = (v * rows).floor();
            let offset = if row as i64 % 2 == 0 { 0.0 } else { 0.5 };
            let fu = (u * cols + offset).fract();
            let fv = (v * rows).fract();
            let mortar = fu < 0.06 || fv < 0.1;
            let brick_id = ((u * cols + offset).floor() as i64).rem_euclid(cols as i64) as u64 + 17 * row as u64;
            let per_brick = hash01(seed ^ brick_id.wrapping_mul(0x9e3779b97f4a7c15));
            let n = value_noise(seed, u * 48.0, v * 48.0, 48, 48);
            if mortar {
                [0.62, 0.60, 0.56].map(|m| m * (0.9 + 0.2 * n))
            } else {
                scale(base, (0.8 + 0.35 * per_brick) * (0.92 + 0.16 * n))
            }
        }
        Material::Concrete => {
            let n = fbm(seed, u * 16.0, v * 16.0, 16, 16, 3);
            scale(base, 0.8 + 0.35 * n)
        }
        Material::Grass => {
            let blades = value_noise(seed, u * 96.0, v * 24.0, 96, 24);
            let patches = fbm(seed ^ 5, u * 4.0, v * 4.0, 4, 4, 2);
            let c = scale(base, 0.7 + 0.5 * blades);
            [c[0] * (0.8 + 0.5 * patches), c[1] * (0.9 + 0.2 * patches), c[2]]
        }
        Material::Clothes => {
            // Woven fabric: a fine cross-hatch and folds.
            let weave =
                ((u * 64.0 * std::f64::consts::TAU).sin() * (v * 64.0 * std::f64::consts::TAU).sin()) * 0.5 + 0.5;
            let folds = fbm(seed, u * 4.0, v * 4.0, 4, 4, 2);
            scale(base, 0.8 + 0.1 * weave + 0.3 * folds)
        }
        Material::Skin => scale(base, 0.95 + 0.1 * value_noise(seed, u * 8.0, v * 8.0, 8, 8)),
        // A 2 x 2 tile of squares; boards repeat it (see the board's UVs). `base` is the
        // light squares' colour, the dark ones are near black.
        Material::Checker => {
            if (u < 0.5) != (v < 0.5) {
                [0.05, 0.05, 0.05]
            } else {
                base
            }
        }
    }
}

fn to_u8(c: f64) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// SplitMix64 finaliser: a well-mixed hash of integer lattice points.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e3779b97f4a7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
    z ^ (z >> 31)
}

fn hash01(z: u64) -> f64 {
    (mix(z) >> 11) as f64 / (1u64 << 53) as f64
}

fn lattice(seed: u64, ix: i64, iy: i64, px: i64, py: i64) -> f64 {
    let x = ix.rem_euclid(px.max(1)) as u64;
    let y = iy.rem_euclid(py.max(1)) as u64;
    hash01(seed ^ mix(x.wrapping_mul(0x632be59bd9b4e019) ^ y.wrapping_mul(0x85157af5)))
}

/// Periodic value noise in [0, 1]: lattice values smoothly interpolated, repeating every
/// (`px`, `py`) cells so textures tile.
fn value_noise(seed: u64, x: f64, y: f64, px: i64, py: i64) -> f64 {
    let (ix, iy) = (x.floor() as i64, y.floor() as i64);
    let (fx, fy) = (x - x.floor(), y - y.floor());
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let a = lattice(seed, ix, iy, px, py);
    let b = lattice(seed, ix + 1, iy, px, py);
    let c = lattice(seed, ix, iy + 1, px, py);
    let d = lattice(seed, ix + 1, iy + 1, px, py);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Fractal sum of `octaves` periodic value noises, normalised to [0, 1].
fn fbm(seed: u64, x: f64, y: f64, px: i64, py: i64, octaves: u32) -> f64 {
    let (mut sum, mut amp, mut norm, mut f) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        let k = f as i64;
        sum += amp * value_noise(seed.wrapping_add(o as u64 * 7919), x * f, y * f, px * k, py * k);
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mean_rgb(t: &Texture) -> [f64; 3] {
        let n = (t.width * t.height) as f64;
        let mut m = [0.0; 3];
        for px in t.rgba.chunks(4) {
            for k in 0..3 {
                m[k] += px[k] as f64 / 255.0 / n;
            }
        }
        m
    }

    #[test]
    fn textures_are_deterministic_and_vary_with_seed() {
        let a = Appearance { material: Material::Bark, colour: [0.35, 0.27, 0.2], texture_seed: 1 };
        let b = Appearance { texture_seed: 2, ..a.clone() };
        assert_eq!(generate(&a), generate(&a));
        assert_ne!(generate(&a), generate(&b));
    }

    #[test]
    fn texture_mean_follows_base_colour() {
        for material in [Material::Bark, Material::Paint, Material::Brick, Material::Grass, Material::Clothes] {
            let a = Appearance { material, colour: [0.5, 0.3, 0.2], texture_seed: 9 };
            let m = mean_rgb(&generate(&a));
            assert!(m[0] > m[1] && m[1] > m[2], "{material:?}: mean {m:?} lost the colour order");
        }
    }

    #[test]
    fn bark_is_more_textured_than_paint() {
        // The classifier needs texture to tell trees from posts of overlapping colour.
        let std_grey = |m: Material| {
            let t = generate(&Appearance { material: m, colour: [0.3, 0.24, 0.18], texture_seed: 4 });
            let g: Vec<f64> = t.rgba.chunks(4).map(|p| (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0).collect();
            let mean = g.iter().sum::<f64>() / g.len() as f64;
            (g.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / g.len() as f64).sqrt()
        };
        assert!(std_grey(Material::Bark) > 2.0 * std_grey(Material::Paint));
    }

    #[test]
    fn noise_tiles_seamlessly() {
        // Periodic noise: value at x equals value at x + period.
        for i in 0..50 {
            let x = i as f64 * 0.37;
            assert!((value_noise(3, x, 1.3, 8, 8) - value_noise(3, x + 8.0, 1.3, 8, 8)).abs() < 1e-12);
        }
    }
}

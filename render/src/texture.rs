//! Texture colour: sRGB <-> linear light conversions and the mip chain built on the CPU for
//! every uploaded texture, averaged in linear light.

use crate::TextureData;

pub(crate) fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.0031308 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

/// All mip levels of `t`, level 0 first, each a 2x2 box filter of the previous one in
/// linear light (alpha linearly). Returns the bytes and the level count.
pub(crate) fn mip_chain(t: &TextureData) -> (Vec<u8>, u32) {
    let lut: Vec<f32> = (0..256).map(|i| srgb_to_linear(i as f32 / 255.0)).collect();
    let mut data = t.rgba.clone();
    let (mut w, mut h) = (t.width as usize, t.height as usize);
    let mut level_start = 0;
    let mut levels = 1;
    while w > 1 || h > 1 {
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let mut next = Vec::with_capacity(nw * nh * 4);
        for y in 0..nh {
            for x in 0..nw {
                // Odd sides: the last row/column folds into the last output texel's pair.
                let xs = [(2 * x).min(w - 1), (2 * x + 1).min(w - 1)];
                let ys = [(2 * y).min(h - 1), (2 * y + 1).min(h - 1)];
                let mut sum = [0.0f32; 4];
                for &sy in &ys {
                    for &sx in &xs {
                        let p = &data[level_start + 4 * (sy * w + sx)..][..4];
                        for k in 0..3 {
                            sum[k] += lut[p[k] as usize];
                        }
                        sum[3] += p[3] as f32 / 255.0;
                    }
                }
                for linear in &sum[..3] {
                    next.push((linear_to_srgb(linear / 4.0) * 255.0).round().clamp(0.0, 255.0) as u8);
                }
                next.push((sum[3] / 4.0 * 255.0).round().clamp(0.0, 255.0) as u8);
            }
        }
        level_start = data.len();
        data.extend_from_slice(&next);
        (w, h) = (nw, nh);
        levels += 1;
    }
    (data, levels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mip_chain_averages_in_linear_light_down_to_one_texel() {
        let t = TextureData { width: 4, height: 2, rgba: [[0u8, 0, 0, 255], [255, 255, 255, 255]].repeat(4).concat() };
        let (data, levels) = mip_chain(&t);
        assert_eq!(levels, 3); // 4x2, 2x1, 1x1
        assert_eq!(data.len(), 4 * (8 + 2 + 1));
        // Half black, half white in linear light is sRGB 188, not 128.
        let last = &data[data.len() - 4..];
        assert!((last[0] as i32 - 188).abs() <= 1, "{last:?}");
        assert_eq!(last[3], 255);
    }
}

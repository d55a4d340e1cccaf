//! Patch features (paper section 3.1): the image is cut into L x L patches; each pixel gets
//! its colour and G Gabor magnitudes, so a patch is an L*L*(3+G) vector; PCA projects it to
//! d dimensions (the appearance z_A); the norms of the four neighbours' z_A (up, down,
//! left, right) are appended, giving the (d + 4)-dimensional [`PatchFeature`] rows.
//!
//! A caller that needs only some patches (the online phase classifies only the image
//! columns a laser cluster projects to) passes a [`PatchRect`]: only that region, one
//! patch ring around it (for the neighbour norms) and the filter margin are processed, and
//! the result equals the whole-image computation for those patches.
//!
//! ```
//! use slam::features::{FeatureConfig, ImageRef, PatchRect, raw_patches};
//! let rgb = vec![128u8; 36 * 27 * 3];
//! let image = ImageRef::new(36, 27, &rgb).unwrap();
//! let config = FeatureConfig::default();
//! let raw = raw_patches(&image, &config, &PatchRect::whole(&image, config.patch_size)).unwrap();
//! assert_eq!(raw.shape(), (4 * 3, 9 * 9 * (3 + 4)));
//! ```

pub mod gabor;
pub mod pca;

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

pub use gabor::{GaborBank, GaborFilter, Plane};
pub use pca::Pca;

/// What can go wrong computing features.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FeatureError {
    #[error("image data has {found} bytes, {width}x{height} RGB needs {expected}")]
    ImageSize { width: u32, height: u32, expected: usize, found: usize },
    #[error("image {width}x{height} is smaller than one {patch_size}x{patch_size} patch")]
    TooSmall { width: u32, height: u32, patch_size: u32 },
    #[error("patch rectangle {rect:?} lies outside the {cols}x{rows} patch grid")]
    Rect { rect: PatchRect, cols: u32, rows: u32 },
    #[error("PCA expects {expected}-dimensional patch vectors, this configuration gives {found}")]
    PcaMismatch { expected: usize, found: usize },
    #[error("training: {0}")]
    Training(String),
    #[error("feature settings: {0}")]
    Settings(#[from] crate::settings::InvalidSetting),
    #[error(transparent)]
    Classify(#[from] crate::classifier::ClassifyError),
    #[error("an appearance vector of {found} values, the PCA gives {expected}")]
    AppearanceLength { expected: usize, found: usize },
    #[error("a mosaic of {cells} cells and {appearance} appearance vectors: they must pair up")]
    Mosaic { cells: usize, appearance: usize },
    /// A located cluster (built field by field) without laser hits, or with one outside
    /// its patch rectangle.
    #[error("a located cluster needs laser hits, all inside its patch rectangle {rect:?}")]
    Hits { rect: PatchRect },
    #[error("a plane of {width}x{height} pixels with {found} values")]
    PlaneSize { width: usize, height: usize, found: usize },
    #[error("pixel region {region:?} (x, y, width, height) reaches outside a {width}x{height} plane")]
    Region { region: (usize, usize, usize, usize), width: usize, height: usize },
}

/// A borrowed 8-bit RGB image, row-major.
#[derive(Debug, Clone, Copy)]
pub struct ImageRef<'a> {
    pub width: u32,
    pub height: u32,
    pub rgb: &'a [u8],
}

impl<'a> ImageRef<'a> {
    pub fn new(width: u32, height: u32, rgb: &'a [u8]) -> Result<Self, FeatureError> {
        let image = ImageRef { width, height, rgb };
        image.check()?;
        Ok(image)
    }

    /// [`FeatureError::ImageSize`] unless the buffer holds width x height RGB pixels (an
    /// image built field by field rather than by `new` may not).
    fn check(&self) -> Result<(), FeatureError> {
        // Saturated where the product overflows: no buffer is that long.
        let expected = (self.width as usize).saturating_mul(self.height as usize).saturating_mul(3);
        if self.rgb.len() != expected {
            let (width, height, found) = (self.width, self.height, self.rgb.len());
            return Err(FeatureError::ImageSize { width, height, expected, found });
        }
        Ok(())
    }

    /// Patch grid size (cols, rows); partial patches at the right and bottom are dropped.
    /// Patches of no size make no grid.
    pub fn grid(&self, patch_size: u32) -> (u32, u32) {
        (self.width.checked_div(patch_size).unwrap_or(0), self.height.checked_div(patch_size).unwrap_or(0))
    }
}

/// Why a patch index taken from a rectangle's own rows (`0..features.z.nrows()`) is one of
/// its patches: the `expect` message for [`PatchRect::patch`] there.
pub const IN_RECT: &str = "an index below the rectangle's patch count";

/// A rectangle of patches: columns `col0..col1`, rows `row0..row1` (end exclusive).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PatchRect {
    pub col0: u32,
    pub col1: u32,
    pub row0: u32,
    pub row1: u32,
}

impl PatchRect {
    pub fn whole(image: &ImageRef, patch_size: u32) -> PatchRect {
        let (cols, rows) = image.grid(patch_size);
        PatchRect { col0: 0, col1: cols, row0: 0, row1: rows }
    }

    /// Whole-height columns `col0..col1` (the online phase's laser columns).
    pub fn columns(image: &ImageRef, patch_size: u32, col0: u32, col1: u32) -> PatchRect {
        let (_, rows) = image.grid(patch_size);
        PatchRect { col0, col1, row0: 0, row1: rows }
    }

    /// Columns in the rectangle (none where `col1` is not past `col0`).
    pub fn cols(&self) -> u32 {
        self.col1.saturating_sub(self.col0)
    }

    /// Rows in the rectangle (none where `row1` is not past `row0`).
    pub fn rows(&self) -> u32 {
        self.row1.saturating_sub(self.row0)
    }

    pub fn len(&self) -> usize {
        self.cols() as usize * self.rows() as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// (col, row) of the i-th patch, row-major within the rectangle; `None` for `i` past
    /// its last patch.
    pub fn patch(&self, i: usize) -> Option<(u32, u32)> {
        (i < self.len()).then(|| {
            let cols = self.cols() as usize;
            (self.col0 + (i % cols) as u32, self.row0 + (i / cols) as u32)
        })
    }

    fn grown(&self, cols: u32, rows: u32) -> PatchRect {
        PatchRect {
            col0: self.col0.saturating_sub(1),
            col1: self.col1.saturating_add(1).min(cols),
            row0: self.row0.saturating_sub(1),
            row1: self.row1.saturating_add(1).min(rows),
        }
    }

    fn check(&self, image: &ImageRef, patch_size: u32) -> Result<(), FeatureError> {
        let (cols, rows) = image.grid(patch_size);
        if cols == 0 || rows == 0 {
            return Err(FeatureError::TooSmall { width: image.width, height: image.height, patch_size });
        }
        if self.col0 >= self.col1 || self.row0 >= self.row1 || self.col1 > cols || self.row1 > rows {
            return Err(FeatureError::Rect { rect: *self, cols, rows });
        }
        Ok(())
    }
}

/// Patch size and filter bank (the parts of the feature pipeline fixed before training).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureConfig {
    /// Patch side L in pixels (the paper: 9).
    pub patch_size: u32,
    pub bank: GaborBank,
    /// Gain per channel (r, g, b, then the Gabor magnitudes) applied before the PCA; empty
    /// means 1. Training sets each to 1 / the channel's standard deviation, so the faint
    /// Gabor magnitudes are not drowned by colour in the principal components.
    #[serde(default)]
    pub channel_gain: Vec<f32>,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        FeatureConfig { patch_size: 9, bank: GaborBank::default(), channel_gain: Vec::new() }
    }
}

impl FeatureConfig {
    /// The largest patch the features describe (pixels a side).
    pub const MAX_PATCH_SIZE: u32 = 64;

    /// The first setting that makes no sense, with its path (`bank.filters[1].sigma_px`).
    pub fn validate(&self) -> Result<(), crate::settings::InvalidSetting> {
        use crate::settings::InvalidSetting;
        let max = Self::MAX_PATCH_SIZE;
        if !(1..=max).contains(&self.patch_size) {
            return Err(InvalidSetting::new(
                "patch_size",
                format!("must be 1 to {max} pixels, got {}", self.patch_size),
            ));
        }
        for (i, f) in self.bank.filters.iter().enumerate() {
            f.validate().map_err(|e| InvalidSetting::in_table(&format!("bank.filters[{i}]"), e))?;
        }
        let n = 3 + self.bank.len();
        if !self.channel_gain.is_empty() && self.channel_gain.len() != n {
            return Err(InvalidSetting::new(
                "channel_gain",
                format!(
                    "has {} gains for {n} channels (r, g, b and {} filters)",
                    self.channel_gain.len(),
                    self.bank.len()
                ),
            ));
        }
        if let Some(g) = self.channel_gain.iter().find(|g| !(g.is_finite() && **g > 0.0)) {
            return Err(InvalidSetting::new("channel_gain", format!("gains must be finite and positive, got {g}")));
        }
        Ok(())
    }

    /// The gain of every channel (1 where none is set).
    pub fn gains(&self) -> Vec<f32> {
        let n = 3 + self.bank.len();
        if self.channel_gain.len() == n { self.channel_gain.clone() } else { vec![1.0; n] }
    }

    /// Length of a raw patch vector, L * L * (3 + G).
    pub fn raw_dims(&self) -> usize {
        self.patch_size as usize * self.patch_size as usize * (3 + self.bank.len())
    }

    /// The pixels that the features of `rect` read in an image `width` x `height`: the
    /// rectangle, the neighbour ring around it and the filters' reach (what a camera
    /// rendering only the pixels a consumer reads must render).
    pub fn pixels_read(&self, rect: &PatchRect, width: u32, height: u32) -> PixelRegion {
        let l = self.patch_size;
        let big = rect.grown(width.checked_div(l).unwrap_or(0), height.checked_div(l).unwrap_or(0));
        let r = self.bank.radius();
        let px = |patch: u32| patch as usize * l as usize;
        let (x0, x1) = reach(px(big.col0), px(big.col1), r, width as usize);
        let (y0, y1) = reach(px(big.row0), px(big.row1), r, height as usize);
        PixelRegion { columns: (x0 as u32, x1 as u32), rows: (y0 as u32, y1 as u32) }
    }
}

/// A rectangle of pixels: columns `columns.0..columns.1`, rows `rows.0..rows.1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PixelRegion {
    pub columns: (u32, u32),
    pub rows: (u32, u32),
}

impl PixelRegion {
    /// Whether it holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.columns.0 >= self.columns.1 || self.rows.0 >= self.rows.1
    }

    /// Whether pixel (u, v) lies in it.
    pub fn contains(&self, u: u32, v: u32) -> bool {
        (self.columns.0..self.columns.1).contains(&u) && (self.rows.0..self.rows.1).contains(&v)
    }

    /// Whether `other` lies wholly in it (an empty one always does).
    pub fn covers(&self, other: &PixelRegion) -> bool {
        other.is_empty()
            || (self.columns.0 <= other.columns.0
                && other.columns.1 <= self.columns.1
                && self.rows.0 <= other.rows.0
                && other.rows.1 <= self.rows.1)
    }
}

/// `lo..hi` widened by `margin` on both sides, within `0..limit`.
fn reach(lo: usize, hi: usize, margin: usize, limit: usize) -> (usize, usize) {
    (lo.saturating_sub(margin).min(limit), hi.saturating_add(margin).min(limit))
}

/// Raw patch vectors (rows, row-major over `rect`): per pixel r, g, b in [0, 1] then the
/// G Gabor magnitudes. A `rect` outside the image's grid, or settings that are not valid,
/// are a [`FeatureError`].
pub fn raw_patches(image: &ImageRef, config: &FeatureConfig, rect: &PatchRect) -> Result<DMatrix<f64>, FeatureError> {
    config.validate()?;
    image.check()?;
    rect.check(image, config.patch_size)?;
    let buf = raw_patch_buffer(image, config, rect);
    let dims = config.raw_dims();
    // The buffer is row-major N x dims, i.e. column-major dims x N.
    Ok(DMatrix::from_iterator(dims, rect.len(), buf.into_iter().map(f64::from)).transpose())
}

/// [`raw_patches`] as a row-major f32 buffer (the fast path of feature extraction).
fn raw_patch_buffer(image: &ImageRef, config: &FeatureConfig, rect: &PatchRect) -> Vec<f32> {
    let l = config.patch_size as usize;
    let g = config.bank.len();
    let w = image.width as usize;
    let h = image.height as usize;
    let margin = config.bank.radius();
    let (x0, x1) = (rect.col0 as usize * l, rect.col1 as usize * l);
    let (y0, y1) = (rect.row0 as usize * l, rect.row1 as usize * l);
    let (cx0, cx1) = reach(x0, x1, margin, w);
    let (cy0, cy1) = reach(y0, y1, margin, h);
    let (cw, ch) = (cx1 - cx0, cy1 - cy0);
    let mut grey = Plane { width: cw, height: ch, data: vec![0.0; cw * ch] };
    for y in 0..ch {
        let src = &image.rgb[((cy0 + y) * w + cx0) * 3..((cy0 + y) * w + cx1) * 3];
        // The sum of three bytes is exact in f32 whichever way it is added; as an integer
        // the loop is cheaper.
        for (g, px) in grey.data[y * cw..(y + 1) * cw].iter_mut().zip(src.chunks_exact(3)) {
            *g = (px[0] as u16 + px[1] as u16 + px[2] as u16) as f32 * (1.0 / 765.0);
        }
    }
    // Responses at the patches' pixels only (the margin is read, not filtered).
    let (rw, rh) = (x1 - x0, y1 - y0);
    let responses = config
        .bank
        .apply_within(&grey, (x0 - cx0, y0 - cy0, rw, rh))
        .expect("the patches lie inside the crop grown around them");
    let stride = 3 + g;
    let gain = config.gains();
    let (gr, gg, gb) = (gain[0] / 255.0, gain[1] / 255.0, gain[2] / 255.0);
    let dims = l * l * stride;
    let n = rect.len();
    let mut rows = vec![0.0f32; n * dims];
    for (i, out) in rows.chunks_exact_mut(dims).enumerate() {
        let (c, r) = rect.patch(i).expect(IN_RECT);
        let (px0, py0) = (c as usize * l, r as usize * l);
        // Each pixel's values: r, g, b, then the Gabor magnitudes.
        for (py, dst) in out.chunks_exact_mut(l * stride).enumerate() {
            let y = py0 + py;
            let rgb = &image.rgb[(y * w + px0) * 3..(y * w + px0 + l) * 3];
            for (d, c) in dst.chunks_exact_mut(stride).zip(rgb.chunks_exact(3)) {
                d[0] = c[0] as f32 * gr;
                d[1] = c[1] as f32 * gg;
                d[2] = c[2] as f32 * gb;
            }
            // A channel at a time, each response's row read in order.
            let ci = (y - y0) * rw + (px0 - x0);
            for (k, (resp, gk)) in responses.iter().zip(&gain[3..]).enumerate() {
                for (d, v) in dst[3 + k..].iter_mut().step_by(stride).zip(&resp.data[ci..ci + l]) {
                    *d = v * gk;
                }
            }
        }
    }
    rows
}

/// Feature rows of the patches in a rectangle.
#[derive(Debug, Clone, PartialEq)]
pub struct PatchFeatures {
    pub rect: PatchRect,
    /// One row per patch (row-major over `rect`): z_A (d values) then the neighbour norms
    /// up, down, left, right.
    pub z: DMatrix<f64>,
}

impl PatchFeatures {
    /// Row index of patch (col, row), if it lies in the rectangle.
    pub fn index(&self, col: u32, row: u32) -> Option<usize> {
        let r = &self.rect;
        (col >= r.col0 && col < r.col1 && row >= r.row0 && row < r.row1)
            .then(|| ((row - r.row0) * r.cols() + (col - r.col0)) as usize)
    }
}

/// The trained feature pipeline: configuration plus PCA (stored in model files).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureExtractor {
    pub config: FeatureConfig,
    pub pca: Pca,
}

/// Name of one feature dimension, for CSV headers.
pub fn feature_names(d: usize) -> Vec<String> {
    (0..d)
        .map(|i| format!("z{i}"))
        .chain(["norm_up", "norm_down", "norm_left", "norm_right"].map(String::from))
        .collect()
}

impl FeatureExtractor {
    pub fn new(config: FeatureConfig, pca: Pca) -> Result<Self, FeatureError> {
        config.validate()?;
        if !config.channel_gain.is_empty() && config.channel_gain.len() != 3 + config.bank.len() {
            return Err(FeatureError::Training(format!(
                "{} channel gains for {} channels",
                config.channel_gain.len(),
                3 + config.bank.len()
            )));
        }
        if pca.input_dims() != config.raw_dims() {
            return Err(FeatureError::PcaMismatch { expected: pca.input_dims(), found: config.raw_dims() });
        }
        Ok(FeatureExtractor { config, pca })
    }

    /// Dimension of a feature row: d + 4.
    pub fn dims(&self) -> usize {
        self.pca.dims() + 4
    }

    /// Features of the patches in `rect` (the whole grid when `None`). A neighbour outside
    /// the grid contributes the patch's own norm.
    pub fn features(&self, image: &ImageRef, rect: Option<PatchRect>) -> Result<PatchFeatures, FeatureError> {
        // An image or extractor built field by field rather than by `new` is checked here:
        // a buffer shorter than its size, or settings that make no sense, would panic below.
        image.check()?;
        self.config.validate()?;
        if self.pca.input_dims() != self.config.raw_dims() {
            return Err(FeatureError::PcaMismatch { expected: self.pca.input_dims(), found: self.config.raw_dims() });
        }
        let l = self.config.patch_size;
        let rect = rect.unwrap_or_else(|| PatchRect::whole(image, l));
        rect.check(image, l)?;
        let (cols, rows) = image.grid(l);
        let big = rect.grown(cols, rows);
        let za = self.pca.project_rows_f32(&raw_patch_buffer(image, &self.config, &big), big.len());
        let d = self.pca.dims();
        let norms: Vec<f64> = (0..za.nrows()).map(|i| za.row(i).norm()).collect();
        let big_index = |c: u32, r: u32| ((r - big.row0) * big.cols() + (c - big.col0)) as usize;
        let mut z = DMatrix::zeros(rect.len(), d + 4);
        for i in 0..rect.len() {
            let (c, r) = rect.patch(i).expect(IN_RECT);
            let me = big_index(c, r);
            for j in 0..d {
                z[(i, j)] = za[(me, j)];
            }
            let own = norms[me];
            let up = if r > 0 { norms[big_index(c, r - 1)] } else { own };
            let down = if r + 1 < rows { norms[big_index(c, r + 1)] } else { own };
            let left = if c > 0 { norms[big_index(c - 1, r)] } else { own };
            let right = if c + 1 < cols { norms[big_index(c + 1, r)] } else { own };
            z[(i, d)] = up;
            z[(i, d + 1)] = down;
            z[(i, d + 2)] = left;
            z[(i, d + 3)] = right;
        }
        Ok(PatchFeatures { rect, z })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn textured_image(w: u32, h: u32, seed: u64) -> Vec<u8> {
        let mut s = seed;
        (0..w * h)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let noise = (s >> 59) as u8;
                let stripe = if (x / 3 + y / 5) % 2 == 0 { 60 } else { 0 };
                [(x * 2 % 200) as u8 + noise, (y * 3 % 180) as u8 + stripe, 90 + noise]
            })
            .collect()
    }

    fn extractor(image: &ImageRef) -> FeatureExtractor {
        let config = FeatureConfig::default();
        let raw = raw_patches(image, &config, &PatchRect::whole(image, 9)).unwrap();
        FeatureExtractor::new(config, Pca::fit(&raw, 6).unwrap()).unwrap()
    }

    #[test]
    fn column_subset_equals_the_whole_image_computation() {
        let (w, h) = (130, 100);
        let rgb = textured_image(w, h, 1);
        let image = ImageRef::new(w, h, &rgb).unwrap();
        let fx = extractor(&image);
        let whole = fx.features(&image, None).unwrap();
        for (c0, c1) in [(0, 2), (5, 8), (12, 14), (13, 14)] {
            let part = fx.features(&image, Some(PatchRect::columns(&image, 9, c0, c1))).unwrap();
            for i in 0..part.rect.len() {
                let (c, r) = part.rect.patch(i).expect(IN_RECT);
                let j = whole.index(c, r).unwrap();
                let diff = (part.z.row(i) - whole.z.row(j)).amax();
                assert!(diff < 1e-9, "patch ({c},{r}) differs by {diff}");
            }
        }
    }

    #[test]
    fn features_read_no_pixel_outside_the_region_they_say() {
        let (w, h) = (130, 100);
        let rgb = textured_image(w, h, 1);
        let image = ImageRef::new(w, h, &rgb).unwrap();
        let fx = extractor(&image);
        let other = textured_image(w, h, 9);
        for rect in [
            PatchRect::columns(&image, 9, 0, 2),
            PatchRect::columns(&image, 9, 5, 8),
            PatchRect::columns(&image, 9, 13, 14),
            PatchRect { col0: 4, col1: 7, row0: 3, row1: 6 },
            PatchRect { col0: 9, col1: 14, row0: 0, row1: 2 },
            PatchRect { col0: 1, col1: 3, row0: 8, row1: 11 },
        ] {
            let region = fx.config.pixels_read(&rect, w, h);
            // A different image outside the region: the features must not change.
            let mixed: Vec<u8> = (0..(w * h) as usize)
                .flat_map(|i| {
                    let (u, v) = (i as u32 % w, i as u32 / w);
                    if region.contains(u, v) { &rgb[3 * i..3 * i + 3] } else { &other[3 * i..3 * i + 3] }
                })
                .copied()
                .collect();
            let a = fx.features(&image, Some(rect)).unwrap();
            let b = fx.features(&ImageRef::new(w, h, &mixed).unwrap(), Some(rect)).unwrap();
            assert_eq!(a, b, "{rect:?} read outside {region:?}");
            // ...and the region is no larger than the ring and the filters' reach.
            let reach = 9 + fx.config.bank.radius() as u32;
            let (x0, x1) = region.columns;
            let (y0, y1) = region.rows;
            assert!(x0 + reach >= rect.col0 * 9 && x1 <= (rect.col1 * 9 + reach).min(w), "{region:?} for {rect:?}");
            assert!(y0 + reach >= rect.row0 * 9 && y1 <= (rect.row1 * 9 + reach).min(h), "{region:?} for {rect:?}");
        }
    }

    #[test]
    fn feature_rows_have_d_plus_4_values_and_neighbour_norms() {
        let (w, h) = (90, 45);
        let rgb = textured_image(w, h, 2);
        let image = ImageRef::new(w, h, &rgb).unwrap();
        let fx = extractor(&image);
        let f = fx.features(&image, None).unwrap();
        assert_eq!(f.z.shape(), (10 * 5, 6 + 4));
        let norm = |c: u32, r: u32| f.z.row(f.index(c, r).unwrap()).columns(0, 6).norm();
        let i = f.index(4, 2).unwrap();
        assert!((f.z[(i, 6)] - norm(4, 1)).abs() < 1e-12);
        assert!((f.z[(i, 7)] - norm(4, 3)).abs() < 1e-12);
        assert!((f.z[(i, 8)] - norm(3, 2)).abs() < 1e-12);
        assert!((f.z[(i, 9)] - norm(5, 2)).abs() < 1e-12);
        // At the top-left corner the missing neighbours use the patch's own norm.
        let i0 = f.index(0, 0).unwrap();
        assert!((f.z[(i0, 6)] - norm(0, 0)).abs() < 1e-12 && (f.z[(i0, 8)] - norm(0, 0)).abs() < 1e-12);
    }

    #[test]
    fn pca_explains_the_variance_it_keeps_and_back_projects() {
        let (w, h) = (90, 90);
        let rgb = textured_image(w, h, 3);
        let image = ImageRef::new(w, h, &rgb).unwrap();
        let config = FeatureConfig::default();
        let raw = raw_patches(&image, &config, &PatchRect::whole(&image, 9)).unwrap();
        let full = Pca::fit(&raw, raw.nrows() - 1).unwrap();
        assert!((full.explained_variance - 1.0).abs() < 1e-9);
        // With all directions kept, back-projection reproduces a patch.
        let z = full.project(&raw.rows(3, 1).into_owned()).unwrap();
        let back = full.back_project(z.row(0).transpose().as_slice()).unwrap();
        assert!((back - raw.row(3).transpose()).amax() < 1e-8);
        let small = Pca::fit(&raw, 3).unwrap();
        assert!(small.explained_variance > 0.0 && small.explained_variance < 1.0);
        assert!(small.variances.windows(2).all(|v| v[0] >= v[1]));
    }

    #[test]
    fn bad_images_and_rects_are_errors() {
        assert!(matches!(ImageRef::new(10, 10, &[0u8; 10]), Err(FeatureError::ImageSize { .. })));
        let rgb = vec![0u8; 40 * 40 * 3];
        let image = ImageRef::new(40, 40, &rgb).unwrap();
        let fx = extractor(&ImageRef::new(130, 100, &textured_image(130, 100, 1)).unwrap());
        assert!(matches!(
            fx.features(&image, Some(PatchRect { col0: 3, col1: 9, row0: 0, row1: 1 })),
            Err(FeatureError::Rect { .. })
        ));
        let tiny = vec![0u8; 5 * 5 * 3];
        assert!(matches!(fx.features(&ImageRef::new(5, 5, &tiny).unwrap(), None), Err(FeatureError::TooSmall { .. })));
    }
}

//! The Gabor filter bank that gives patches their texture channels.
//!
//! Kernel (OpenCV's `getGaborKernel` convention): exp(-(x_r^2 + gamma^2 y_r^2) / (2 sigma^2))
//! cos(2 pi x_r / lambda + psi) with x_r = x cos(theta) + y sin(theta) and
//! y_r = y cos(theta) - x sin(theta). Two changes, both so that the channels carry texture and not brightness
//! (the colour channels already do): the Gaussian envelope times a constant is subtracted
//! so the kernel sums to zero, and the kernel is scaled to unit L1 norm, so a response lies
//! in [-1, 1] for intensities in [0, 1]. A channel is the response's magnitude.
//! Orientations 0 and 90 degrees are separable and filtered as two 1-D passes.

use serde::{Deserialize, Serialize};

use super::FeatureError;

/// One filter of the bank.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GaborFilter {
    /// Orientation of the carrier, degrees (0 responds to vertical stripes).
    pub theta_deg: f64,
    /// Carrier wavelength, pixels.
    pub lambda_px: f64,
    /// Envelope standard deviation along the carrier, pixels.
    pub sigma_px: f64,
    /// Envelope aspect ratio (across / along the carrier).
    pub gamma: f64,
    /// Carrier phase, radians.
    pub psi: f64,
}

/// Widest envelope a filter may have (pixels): its kernel is then 321 pixels across, half
/// an image; wider ones only cost time (and 1e6 would allocate without bound).
pub const MAX_SIGMA_PX: f64 = 64.0;

impl GaborFilter {
    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        // A carrier shorter than two pixels aliases (Nyquist); a zero one divides by zero.
        if !(self.lambda_px.is_finite() && self.lambda_px >= 2.0) {
            return Err(("lambda_px", format!("must be at least 2 pixels, got {}", self.lambda_px)));
        }
        if !(self.sigma_px > 0.0 && self.sigma_px <= MAX_SIGMA_PX) {
            return Err(("sigma_px", format!("must be in (0, {MAX_SIGMA_PX}] pixels, got {}", self.sigma_px)));
        }
        if !(self.gamma > 0.0 && self.gamma <= 10.0) {
            return Err(("gamma", format!("must be in (0, 10], got {}", self.gamma)));
        }
        for (name, v) in [("theta_deg", self.theta_deg), ("psi", self.psi)] {
            if !v.is_finite() {
                return Err((name, format!("must be finite, got {v}")));
            }
        }
        Ok(())
    }

    /// Kernel half-width along the carrier: 2.5 envelope standard deviations.
    pub fn carrier_radius(&self) -> usize {
        (2.5 * self.sigma_px).ceil() as usize
    }

    /// Kernel half-width across the carrier: 2.5 standard deviations of the envelope
    /// there (sigma / gamma).
    pub fn across_radius(&self) -> usize {
        (2.5 * self.sigma_px / self.gamma.min(1.0)).ceil() as usize
    }

    /// Largest half-width: the margin a crop needs for exact responses.
    pub fn radius(&self) -> usize {
        self.carrier_radius().max(self.across_radius())
    }

    fn orientation(&self) -> Option<bool> {
        // Modulo a whole turn: at 180 and 270 degrees the carrier runs the other way, which
        // only a phase of 0 or pi leaves unchanged, so those take the general kernel.
        let t = self.theta_deg.rem_euclid(360.0);
        if t.abs() < 1e-9 {
            Some(false)
        } else if (t - 90.0).abs() < 1e-9 {
            Some(true)
        } else {
            None
        }
    }

    /// Half-widths (x, y) of the kernel's support: rectangular for 0 and 90 degrees,
    /// square otherwise.
    pub fn support(&self) -> (usize, usize) {
        match self.orientation() {
            Some(false) => (self.carrier_radius(), self.across_radius()),
            Some(true) => (self.across_radius(), self.carrier_radius()),
            None => (self.radius(), self.radius()),
        }
    }

    /// The filter as two 1-D kernels (horizontal, vertical) when its orientation allows.
    pub fn separable(&self) -> Option<(Vec<f32>, Vec<f32>)> {
        let rotated = self.orientation()?;
        let (rc, ra) = (self.carrier_radius() as i64, self.across_radius() as i64);
        let carrier: Vec<f64> = (-rc..=rc).map(|x| self.carrier_1d(x as f64)).collect();
        let across: Vec<f64> =
            (-ra..=ra).map(|y| (-(self.gamma * y as f64).powi(2) / (2.0 * self.sigma_px.powi(2))).exp()).collect();
        let norm = carrier.iter().map(|v| v.abs()).sum::<f64>() * across.iter().sum::<f64>();
        let (a, b): (Vec<f32>, Vec<f32>) =
            (carrier.iter().map(|v| (v / norm) as f32).collect(), across.iter().map(|&v| v as f32).collect());
        Some(if rotated { (b, a) } else { (a, b) })
    }

    /// Zero-mean carrier times envelope along the carrier axis.
    fn carrier_1d(&self, x: f64) -> f64 {
        let r = self.carrier_radius() as i64;
        let env = |x: f64| (-x * x / (2.0 * self.sigma_px.powi(2))).exp();
        let wave = |x: f64| (2.0 * std::f64::consts::PI * x / self.lambda_px + self.psi).cos();
        let (s_wave, s_env): (f64, f64) =
            (-r..=r).map(|x| x as f64).fold((0.0, 0.0), |(a, b), x| (a + env(x) * wave(x), b + env(x)));
        env(x) * (wave(x) - s_wave / s_env)
    }

    /// The full 2-D kernel over [`Self::support`], row-major.
    pub fn kernel_2d(&self) -> Vec<f32> {
        let (rx, ry) = (self.support().0 as i64, self.support().1 as i64);
        let (st, ct) = self.theta_deg.to_radians().sin_cos();
        let env = |x: f64, y: f64| {
            let (xr, yr) = (x * ct + y * st, -x * st + y * ct);
            (
                (-(xr * xr + self.gamma.powi(2) * yr * yr) / (2.0 * self.sigma_px.powi(2))).exp(),
                (2.0 * std::f64::consts::PI * xr / self.lambda_px + self.psi).cos(),
            )
        };
        let pts: Vec<(f64, f64)> = (-ry..=ry).flat_map(|y| (-rx..=rx).map(move |x| (x as f64, y as f64))).collect();
        let (sw, se) = pts.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
            let (e, w) = env(x, y);
            (a + e * w, b + e)
        });
        let k: Vec<f64> = pts
            .iter()
            .map(|&(x, y)| {
                let (e, w) = env(x, y);
                e * (w - sw / se)
            })
            .collect();
        let norm: f64 = k.iter().map(|v| v.abs()).sum();
        k.iter().map(|v| (v / norm) as f32).collect()
    }
}

/// The bank: the paper used two orientations and two scales.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GaborBank {
    pub filters: Vec<GaborFilter>,
}

impl Default for GaborBank {
    /// Orientations 0 and 90 degrees; wavelengths 4 and 8 px (bark furrows and leaf
    /// litter at the distances the robot sees them); sigma = lambda / 2 (about one octave
    /// of bandwidth); gamma = 0.5; psi = 0.
    fn default() -> Self {
        let mut filters = Vec::new();
        for lambda_px in [4.0, 8.0] {
            for theta_deg in [0.0, 90.0] {
                filters.push(GaborFilter { theta_deg, lambda_px, sigma_px: lambda_px / 2.0, gamma: 0.5, psi: 0.0 });
            }
        }
        GaborBank { filters }
    }
}

impl GaborBank {
    pub fn len(&self) -> usize {
        self.filters.len()
    }

    pub fn is_empty(&self) -> bool {
        self.filters.is_empty()
    }

    /// Largest kernel half-width: the margin a crop needs for exact responses.
    pub fn radius(&self) -> usize {
        self.filters.iter().map(|f| f.radius()).max().unwrap_or(0)
    }

    /// |response| of every filter on a grey plane, with replicated borders. A plane whose
    /// data is not width x height values is [`FeatureError::PlaneSize`]; an empty plane
    /// has empty responses.
    pub fn apply(&self, grey: &Plane) -> Result<Vec<Plane>, FeatureError> {
        grey.check()?;
        if grey.data.is_empty() {
            return Ok(self.filters.iter().map(|_| grey.clone()).collect());
        }
        Ok(self
            .filters
            .iter()
            .map(|f| {
                let mut out = match f.separable() {
                    Some((h, v)) => convolve_cols(&convolve_rows(grey, &h), &v),
                    None => convolve_2d(grey, &f.kernel_2d(), f.support()),
                };
                out.data.iter_mut().for_each(|v| *v = v.abs());
                out
            })
            .collect())
    }

    /// |response| of every filter at the pixels of `region` (x, y, width, height) of a grey
    /// plane with replicated borders: bit for bit the values [`GaborBank::apply`] gives
    /// there, but only those are filtered. A crop's margin is read, never filtered: with the
    /// default bank's 20 px margin around a cluster's patches that is over half the pixels.
    /// A region reaching outside the plane is [`FeatureError::Region`], a plane as
    /// [`GaborBank::apply`] checks it.
    pub fn apply_within(&self, grey: &Plane, region: (usize, usize, usize, usize)) -> Result<Vec<Plane>, FeatureError> {
        grey.check()?;
        let (x0, y0, rw, rh) = region;
        let inside = |start: usize, len: usize, limit: usize| start.checked_add(len).is_some_and(|end| end <= limit);
        if !(inside(x0, rw, grey.width) && inside(y0, rh, grey.height)) {
            return Err(FeatureError::Region { region, width: grey.width, height: grey.height });
        }
        if rw == 0 || rh == 0 {
            return Ok(self.filters.iter().map(|_| Plane { width: rw, height: rh, data: vec![] }).collect());
        }
        Ok(self
            .filters
            .iter()
            .map(|f| {
                let mut out = match f.separable() {
                    Some((h, v)) => convolve_separable_within(grey, &h, &v, region),
                    // Not separable: filter everything and keep the region.
                    None => {
                        let full = convolve_2d(grey, &f.kernel_2d(), f.support());
                        let data = (y0..y0 + rh)
                            .flat_map(|y| full.data[y * grey.width + x0..y * grey.width + x0 + rw].iter().copied())
                            .collect();
                        Plane { width: rw, height: rh, data }
                    }
                };
                out.data.iter_mut().for_each(|v| *v = v.abs());
                out
            })
            .collect())
    }
}

/// `convolve_cols(convolve_rows(src, h), v)` at `region` only: the row pass over the
/// region's columns and the rows the column pass reads, then the column pass over the
/// region. Borders replicate `src`'s edges as the full passes do, and every output sums
/// the same taps in the same order, so the values are identical.
fn convolve_separable_within(
    src: &Plane,
    h: &[f32],
    v: &[f32],
    (x0, y0, rw, rh): (usize, usize, usize, usize),
) -> Plane {
    let (rx, ry) = (h.len() / 2, v.len() / 2);
    let (w, height) = (src.width, src.height);
    if rw == 0 || rh == 0 {
        return Plane { width: rw, height: rh, data: Vec::new() };
    }
    // Source rows the column pass reads, clamped to the plane.
    let (ya, yb) = (y0.saturating_sub(ry), (y0 + rh + ry).min(height));
    let mut rows = vec![0.0f32; rw * (yb - ya)];
    let mut padded = vec![0.0f32; w + 2 * rx];
    for (y, dst) in (ya..yb).zip(rows.chunks_exact_mut(rw.max(1))) {
        let row = &src.data[y * w..(y + 1) * w];
        padded[..rx].fill(row[0]);
        padded[rx..rx + w].copy_from_slice(row);
        padded[rx + w..].fill(row[w - 1]);
        convolve_line(&padded[x0..], 1, h, dst);
    }
    // Rows y0 - ry .. y0 + rh + ry of the row pass, edges replicated: the row pass itself
    // unless the region is within ry of the plane's top or bottom.
    let column = if ya + ry == y0 && yb == y0 + rh + ry {
        rows
    } else {
        let mut column = Vec::with_capacity(rw * (rh + 2 * ry));
        for y in y0 as i64 - ry as i64..(y0 + rh + ry) as i64 {
            let sy = y.clamp(0, height as i64 - 1) as usize - ya;
            column.extend_from_slice(&rows[sy * rw..(sy + 1) * rw]);
        }
        column
    };
    let mut out = vec![0.0f32; rw * rh];
    for (y, dst) in out.chunks_exact_mut(rw.max(1)).enumerate() {
        convolve_line(&column[y * rw..], rw, v, dst);
    }
    Plane { width: rw, height: rh, data: out }
}

/// A single-channel f32 image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Plane {
    /// [`FeatureError::PlaneSize`] unless the data holds width x height values.
    fn check(&self) -> Result<(), FeatureError> {
        if self.width.checked_mul(self.height) == Some(self.data.len()) {
            Ok(())
        } else {
            Err(FeatureError::PlaneSize { width: self.width, height: self.height, found: self.data.len() })
        }
    }
}

/// Horizontal 1-D convolution (correlation; the kernels are symmetric or antisymmetric and
/// used consistently) with replicated borders.
fn convolve_rows(src: &Plane, kernel: &[f32]) -> Plane {
    let r = kernel.len() / 2;
    let (w, h) = (src.width, src.height);
    let mut out = vec![0.0f32; w * h];
    let mut padded = vec![0.0f32; w + 2 * r];
    for y in 0..h {
        let row = &src.data[y * w..(y + 1) * w];
        padded[..r].fill(row[0]);
        padded[r..r + w].copy_from_slice(row);
        padded[r + w..].fill(row[w - 1]);
        let dst = &mut out[y * w..(y + 1) * w];
        convolve_line(&padded, 1, kernel, dst);
    }
    Plane { width: w, height: h, data: out }
}

/// Vertical 1-D convolution with replicated borders.
fn convolve_cols(src: &Plane, kernel: &[f32]) -> Plane {
    let r = kernel.len() / 2;
    let (w, h) = (src.width, src.height);
    // Rows replicated above and below, so every output row reads whole rows.
    let mut padded = Vec::with_capacity(w * (h + 2 * r));
    for y in 0..h + 2 * r {
        let sy = y.saturating_sub(r).min(h - 1);
        padded.extend_from_slice(&src.data[sy * w..(sy + 1) * w]);
    }
    let mut out = vec![0.0f32; w * h];
    for (y, dst) in out.chunks_exact_mut(w).enumerate() {
        convolve_line(&padded[y * w..], w, kernel, dst);
    }
    Plane { width: w, height: h, data: out }
}

/// dst[x] = sum over k of kernel[k] * src[x + k * step], the taps added in order from
/// zero. Blocks of outputs stay in registers over all taps instead of every tap reading
/// and writing the whole line, and several blocks go side by side: bit-identical to the
/// plain loop (each output's sum runs in the same order).
fn convolve_line(src: &[f32], step: usize, kernel: &[f32], dst: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { convolve_line_avx(src, step, kernel, dst) };
    }
    convolve_line_body(src, step, kernel, dst)
}

/// The same loop compiled for AVX's 8-wide registers (the baseline x86-64 target has
/// 4-wide SSE): about twice the speed. Without FMA every product and sum is rounded as
/// in the baseline code, so results are bit-identical on every x86-64 processor.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn convolve_line_avx(src: &[f32], step: usize, kernel: &[f32], dst: &mut [f32]) {
    convolve_line_body(src, step, kernel, dst)
}

/// Outputs per block of [`convolve_line`].
const BLOCK: usize = 16;

/// Blocks filtered together: their sums are independent, so the processor overlaps them
/// (one block alone waits on its own additions).
const BLOCKS: usize = 4;

/// dst[x..x + BLOCK] for each `x` of `starts`, over all taps. A function, not a closure,
/// so that it is inlined into the AVX copy and compiled for it (closures do not inherit
/// target features).
#[inline(always)]
fn convolve_blocks<const N: usize>(src: &[f32], step: usize, kernel: &[f32], starts: [usize; N], dst: &mut [f32]) {
    let mut acc = [[0.0f32; BLOCK]; N];
    for (k, &kv) in kernel.iter().enumerate() {
        for (a, &x) in acc.iter_mut().zip(&starts) {
            let s = &src[x + k * step..x + k * step + BLOCK];
            for j in 0..BLOCK {
                a[j] += kv * s[j];
            }
        }
    }
    for (a, &x) in acc.iter().zip(&starts) {
        dst[x..x + BLOCK].copy_from_slice(a);
    }
}

#[inline(always)]
fn convolve_line_body(src: &[f32], step: usize, kernel: &[f32], dst: &mut [f32]) {
    let w = dst.len();
    if w >= BLOCK {
        let mut x = 0;
        while x + BLOCKS * BLOCK <= w {
            convolve_blocks(src, step, kernel, std::array::from_fn::<_, BLOCKS, _>(|b| x + b * BLOCK), dst);
            x += BLOCKS * BLOCK;
        }
        // The rest in at most BLOCKS blocks, the last ending at the line's end: its overlap
        // with the one before is computed again, to the same values.
        let last = w - BLOCK;
        match (w - x).div_ceil(BLOCK) {
            0 => {}
            1 => convolve_blocks(src, step, kernel, [last], dst),
            2 => convolve_blocks(src, step, kernel, [x, last], dst),
            3 => convolve_blocks(src, step, kernel, [x, x + BLOCK, last], dst),
            _ => convolve_blocks(src, step, kernel, [x, x + BLOCK, x + 2 * BLOCK, last], dst),
        }
        return;
    }
    for (x, d) in dst.iter_mut().enumerate() {
        let mut acc = 0.0f32;
        for (k, &kv) in kernel.iter().enumerate() {
            acc += kv * src[x + k * step];
        }
        *d = acc;
    }
}

/// Full 2-D correlation with replicated borders (orientations that are not separable).
fn convolve_2d(src: &Plane, kernel: &[f32], (rx, r): (usize, usize)) -> Plane {
    let side_x = 2 * rx + 1;
    let side = 2 * r + 1;
    let (w, h) = (src.width, src.height);
    let mut out = Plane { width: w, height: h, data: vec![0.0; w * h] };
    for ky in 0..side {
        let row_kernel = &kernel[ky * side_x..(ky + 1) * side_x];
        let shifted = Plane {
            width: w,
            height: h,
            data: (0..h)
                .flat_map(|y| {
                    let sy = (y as i64 + ky as i64 - r as i64).clamp(0, h as i64 - 1) as usize;
                    src.data[sy * w..(sy + 1) * w].iter().copied()
                })
                .collect(),
        };
        let part = convolve_rows(&shifted, row_kernel);
        for (o, p) in out.data.iter_mut().zip(part.data) {
            *o += p;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_plane(w: usize, h: usize) -> Plane {
        let mut s = 12345u64;
        let data = (0..w * h)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (s >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        Plane { width: w, height: h, data }
    }

    /// Where a filter takes the separable path, the two 1-D kernels' product is its 2-D
    /// kernel, at any phase; at 180 and 270 degrees the carrier runs the other way.
    #[test]
    fn separable_kernels_are_the_2d_kernel_at_every_orientation_and_phase() {
        let base = GaborBank::default().filters[0].clone();
        for theta_deg in [0.0, 90.0, 180.0, 270.0, -90.0, 360.0, 45.0] {
            for psi in [0.0, std::f64::consts::FRAC_PI_4, std::f64::consts::FRAC_PI_2, 1.0] {
                let f = GaborFilter { theta_deg, psi, ..base.clone() };
                let Some((h, v)) = f.separable() else { continue };
                let full = f.kernel_2d();
                let product: Vec<f32> = v.iter().flat_map(|&b| h.iter().map(move |&a| a * b)).collect();
                assert_eq!(full.len(), product.len(), "{theta_deg} deg");
                let worst = full.iter().zip(&product).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
                let scale = full.iter().map(|a| a.abs()).fold(0.0f32, f32::max);
                assert!(worst <= 1e-5 * scale, "theta {theta_deg}, psi {psi}: off by {worst} of {scale}");
            }
        }
    }

    #[test]
    fn blocked_convolutions_equal_the_plain_tap_by_tap_sums_bit_for_bit() {
        // The plain loops, output by output, taps in order from zero, borders replicated.
        let plain = |p: &Plane, kernel: &[f32], vertical: bool| -> Vec<f32> {
            let r = (kernel.len() / 2) as i64;
            let (w, h) = (p.width as i64, p.height as i64);
            let mut out = Vec::new();
            for y in 0..h {
                for x in 0..w {
                    let mut acc = 0.0f32;
                    for (k, &kv) in kernel.iter().enumerate() {
                        let (sx, sy) = if vertical {
                            (x, (y + k as i64 - r).clamp(0, h - 1))
                        } else {
                            ((x + k as i64 - r).clamp(0, w - 1), y)
                        };
                        acc += kv * p.data[(sy * w + sx) as usize];
                    }
                    out.push(acc);
                }
            }
            out
        };
        // Widths that leave every count of blocks after the groups, and lines narrower than one.
        for (w, h) in [(40, 31), (17, 5), (3, 50), (1, 1), (16, 3), (64, 4), (113, 3), (130, 2), (200, 2)] {
            let img = random_plane(w, h);
            for f in GaborBank::default().filters {
                let (hk, vk) = f.separable().unwrap();
                let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
                assert_eq!(bits(convolve_rows(&img, &hk).data), bits(plain(&img, &hk, false)), "rows {w}x{h}");
                assert_eq!(bits(convolve_cols(&img, &vk).data), bits(plain(&img, &vk, true)), "cols {w}x{h}");
            }
        }
    }

    #[test]
    fn filtering_within_a_region_gives_the_whole_planes_values_bit_for_bit() {
        let mut bank = GaborBank::default();
        // A non-separable filter takes the fallback path.
        bank.filters.push(GaborFilter { theta_deg: 45.0, lambda_px: 4.0, sigma_px: 2.0, gamma: 0.5, psi: 0.0 });
        for (w, h) in [(90, 70), (40, 31), (17, 5)] {
            let img = random_plane(w, h);
            let whole = bank.apply(&img).unwrap();
            // Interior, touching each edge, the whole plane, one pixel, none.
            for region in [
                (21, 20, 30, 25),
                (0, 0, 12, 9),
                (w - 13, h - 4, 13, 4),
                (0, 0, w, h),
                (w / 2, h / 2, 1, 1),
                (3, 2, 0, 4),
            ] {
                let (x0, y0, rw, rh) = region;
                if x0 + rw > w || y0 + rh > h {
                    continue;
                }
                for (k, (part, full)) in bank.apply_within(&img, region).unwrap().iter().zip(&whole).enumerate() {
                    let expected: Vec<f32> =
                        (y0..y0 + rh).flat_map(|y| full.data[y * w + x0..y * w + x0 + rw].iter().copied()).collect();
                    assert_eq!((part.width, part.height), (rw, rh));
                    assert!(
                        part.data.iter().zip(&expected).all(|(a, b)| a.to_bits() == b.to_bits()),
                        "filter {k}, {w}x{h}, region {region:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn separable_filters_equal_their_full_2d_kernels() {
        let img = random_plane(40, 31);
        for f in GaborBank::default().filters {
            let (hk, vk) = f.separable().expect("0 and 90 degrees are separable");
            let sep = convolve_cols(&convolve_rows(&img, &hk), &vk);
            let full = convolve_2d(&img, &f.kernel_2d(), f.support());
            let err = sep.data.iter().zip(&full.data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(err < 1e-5, "theta {} lambda {}: {err}", f.theta_deg, f.lambda_px);
        }
    }

    #[test]
    fn kernels_have_no_dc_and_unit_l1_norm() {
        for theta_deg in [0.0, 30.0, 90.0, 135.0] {
            let f = GaborFilter { theta_deg, lambda_px: 6.0, sigma_px: 3.0, gamma: 0.5, psi: 0.0 };
            let k = f.kernel_2d();
            assert!(k.iter().sum::<f32>().abs() < 1e-5);
            assert!((k.iter().map(|v| v.abs()).sum::<f32>() - 1.0).abs() < 1e-5);
        }
        // A flat image gives no response.
        let flat = Plane { width: 20, height: 20, data: vec![0.7; 400] };
        for p in GaborBank::default().apply(&flat).unwrap() {
            assert!(p.data.iter().all(|v| v.abs() < 1e-5));
        }
    }

    #[test]
    fn orientation_selects_stripe_direction() {
        // Vertical stripes of period 4 px excite theta = 0 at lambda 4, not theta = 90.
        let (w, h) = (48, 48);
        let data = (0..w * h).map(|i| if (i % w) % 4 < 2 { 1.0 } else { 0.0 }).collect();
        let img = Plane { width: w, height: h, data };
        let out = GaborBank::default().apply(&img).unwrap();
        let centre = |p: &Plane| p.data[24 * w + 24];
        assert!(centre(&out[0]) > 10.0 * centre(&out[1]).max(1e-6), "{} vs {}", centre(&out[0]), centre(&out[1]));
    }
}

//! Getting the images back: copying the render targets into the readback buffer (whole,
//! or region by region), mapping it and unpacking it into a `Frame`, with the pixels not
//! rendered zeroed.

use crate::{Frame, Region, RenderError, Renderer};

/// Where one target's rows lie in the shared readback buffer.
#[derive(Clone, Copy)]
pub(crate) struct Plane {
    pub(crate) offset: u64,
    pub(crate) bytes_per_row: u32,
    pub(crate) bytes_per_pixel: u32,
}

impl Renderer {
    /// Copies the targets into the readback buffer (only the `spans` when they fit),
    /// submits `encoder` with the frame's draws and unpacks the images into `frame`: only
    /// the `spans` if `partial` (regions were asked for), else all of them.
    pub(crate) fn read_back(
        &self,
        mut encoder: wgpu::CommandEncoder,
        spans: &[Region],
        partial: bool,
        frame: &mut Frame,
    ) -> Result<(), RenderError> {
        let whole = Region::whole(self.width, self.height);
        // Only the rendered regions leave the GPU when they fit the buffer one by one.
        let layout = match (spans != [whole]).then(|| self.span_planes(spans)).flatten() {
            Some(per_span) => spans.iter().copied().zip(per_span).collect(),
            None => vec![(whole, self.planes.clone())],
        };
        for (region, planes) in &layout {
            let (x, y) = (region.columns.0, region.rows.0);
            let (width, height) = (region.columns.1 - x, region.rows.1 - y);
            for (target, plane) in self.targets.iter().zip(planes) {
                encoder.copy_texture_to_buffer(
                    wgpu::TexelCopyTextureInfo { origin: wgpu::Origin3d { x, y, z: 0 }, ..target.as_image_copy() },
                    wgpu::TexelCopyBufferInfo {
                        buffer: &self.readback,
                        layout: wgpu::TexelCopyBufferLayout {
                            offset: plane.offset,
                            bytes_per_row: Some(plane.bytes_per_row),
                            rows_per_image: Some(height),
                        },
                    },
                    wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                );
            }
        }
        self.queue.submit(Some(encoder.finish()));
        self.check_gpu_error()?;

        let slice = self.readback.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::Wait { submission_index: None, timeout: None })
            .map_err(|e| RenderError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| RenderError::Readback(e.to_string()))?
            .map_err(|e| RenderError::Readback(e.to_string()))?;
        let unpacked = match slice.get_mapped_range() {
            Ok(data) => {
                self.unpack(&data, &layout, frame, partial.then_some(spans));
                Ok(())
            }
            Err(e) => Err(RenderError::Readback(e.to_string())),
        };
        // Unmapped even on error, so the next frame can map it again.
        self.readback.unmap();
        unpacked?;
        self.check_gpu_error()
    }

    /// Where each region's rows of each target go in the readback buffer: the regions one
    /// after another, rows padded as copies require; `None` when they would not fit.
    fn span_planes(&self, spans: &[Region]) -> Option<Vec<Vec<Plane>>> {
        let mut offset = 0u64;
        let layout = spans
            .iter()
            .map(|r| {
                self.planes
                    .iter()
                    .map(|p| {
                        let bytes_per_row = (p.bytes_per_pixel * (r.columns.1 - r.columns.0))
                            .next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
                        let plane = Plane { offset, bytes_per_row, bytes_per_pixel: p.bytes_per_pixel };
                        offset += bytes_per_row as u64 * (r.rows.1 - r.rows.0) as u64;
                        plane
                    })
                    .collect()
            })
            .collect();
        (offset <= self.readback.size()).then_some(layout)
    }

    /// Copies the readback buffer, laid out as `layout` says (each copied region and its
    /// targets' rows), into `frame`: all of it, or only the pixel regions `spans`, the
    /// rest zeroed.
    fn unpack(&self, data: &[u8], layout: &[(Region, Vec<Plane>)], frame: &mut Frame, spans: Option<&[Region]>) {
        let (w, h) = (self.width as usize, self.height as usize);
        let whole = [Region::whole(self.width, self.height)];
        let copied = spans.unwrap_or(&whole);
        self.prepare_frame(frame, copied);
        // Row `y` of columns `a..b` of a target, copied as `plane` from (`first`, `top`) on.
        let row = |plane: &Plane, (first, top): (usize, usize), y: usize, (a, b): (usize, usize)| {
            let start = plane.offset as usize + (y - top) * plane.bytes_per_row as usize;
            let bytes = plane.bytes_per_pixel as usize;
            &data[start + bytes * (a - first)..start + bytes * (b - first)]
        };
        // The regions' columns in row `y`, reused row to row.
        let mut in_row: Vec<(u32, u32)> = Vec::with_capacity(copied.len());
        for y in 0..h {
            in_row.clear();
            in_row.extend(copied.iter().filter(|r| (r.rows.0..r.rows.1).contains(&(y as u32))).map(|r| r.columns));
            for &(a, b) in &in_row {
                let (region, planes) = layout
                    .iter()
                    .find(|(r, _)| {
                        r.columns.0 <= a && b <= r.columns.1 && r.rows.0 <= y as u32 && (y as u32) < r.rows.1
                    })
                    .expect("every region is copied, alone or in the whole frame");
                let origin = (region.columns.0 as usize, region.rows.0 as usize);
                let (a, b) = (a as usize, b as usize);
                let (i0, i1) = (w * y + a, w * y + b);
                for (d, s) in frame.rgb[3 * i0..3 * i1]
                    .chunks_exact_mut(3)
                    .zip(row(&planes[0], origin, y, (a, b)).chunks_exact(4))
                {
                    d.copy_from_slice(&s[..3]);
                }
                let ids = row(&planes[1], origin, y, (a, b)).chunks_exact(4);
                for ((instance, class), s) in frame.instance[i0..i1].iter_mut().zip(&mut frame.class[i0..i1]).zip(ids) {
                    let v = u32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    *instance = (v >> 8) as u16;
                    *class = (v & 0xff) as u8;
                }
                let Some(depth) = planes.get(2) else { continue };
                for (d, s) in frame.depth_m[i0..i1].iter_mut().zip(row(depth, origin, y, (a, b)).chunks_exact(4)) {
                    let z = f32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    *d = if z > 0.0 { z } else { f32::INFINITY };
                }
            }
        }
        frame.regions = spans.map(<[_]>::to_vec);
    }
    /// Sizes `frame`'s images for this renderer and says which of its pixels may hold
    /// a drawing: a frame of no images (a new one) is made blank, as if nothing were
    /// rendered, and is written once, not zeroed and blanked. A frame reused from a render
    /// of regions at this size holds pixels only there, so only those need blanking, not
    /// the whole image (most of it, when a consumer reads small regions of each frame).
    fn size_frame(&self, frame: &mut Frame) -> Held {
        let n = self.width as usize * self.height as usize;
        let depth = if self.planes.len() > 2 { n } else { 0 };
        let new =
            frame.rgb.is_empty() && frame.instance.is_empty() && frame.class.is_empty() && frame.depth_m.is_empty();
        let same_size = (frame.width, frame.height) == (self.width, self.height)
            && frame.rgb.len() == 3 * n
            && frame.instance.len() == n
            && frame.class.len() == n
            && frame.depth_m.len() == depth;
        let held = match frame.regions.take() {
            _ if new => Held::Nothing,
            Some(regions) if same_size && regions.iter().all(|r| r.fits(self.width, self.height)) => {
                Held::Regions(regions)
            }
            _ => Held::Anything,
        };
        frame.width = self.width;
        frame.height = self.height;
        // Filled here, in one pass, rather than allocated zeroed: a zeroed allocation this
        // large comes as new pages that the kernel faults in and clears (7.6% of a
        // `paper_park` profile, against 1.7% for filling and blanking; wall time did not
        // move measurably either way).
        frame.rgb.resize(3 * n, 0);
        frame.instance.resize(n, 0);
        frame.class.resize(n, 0);
        frame.depth_m.resize(depth, if new { f32::INFINITY } else { 0.0 });
        held
    }

    /// Sizes `frame` and zeroes what an earlier drawing may have left in it, except where
    /// all of it is about to be `copied` over: a reused frame of regions is blanked only
    /// there, any other reused frame whole.
    fn prepare_frame(&self, frame: &mut Frame, copied: &[Region]) {
        match self.size_frame(frame) {
            Held::Nothing => {}
            Held::Regions(held) => held.iter().for_each(|r| blank_region(frame, r)),
            Held::Anything if copied == [Region::whole(self.width, self.height)] => {}
            Held::Anything => blank_region(frame, &Region::whole(self.width, self.height)),
        }
    }

    /// `frame` with nothing rendered: every column empty.
    pub(crate) fn blank(&self, frame: &mut Frame) {
        self.prepare_frame(frame, &[]);
        frame.regions = Some(Vec::new());
    }
}

/// Which pixels of a frame about to be written may hold an earlier drawing.
enum Held {
    /// None: a new frame, made blank.
    Nothing,
    /// Only these regions (a frame reused from a render of regions).
    Regions(Vec<Region>),
    /// Any (a whole render, or a frame of another size or unknown history).
    Anything,
}

/// Zeroes `region` of `frame` (depth: infinity).
fn blank_region(frame: &mut Frame, region: &Region) {
    let w = frame.width as usize;
    let (a, b) = (region.columns.0 as usize, region.columns.1 as usize);
    for y in region.rows.0 as usize..region.rows.1 as usize {
        let (i0, i1) = (w * y + a, w * y + b);
        frame.rgb[3 * i0..3 * i1].fill(0);
        frame.instance[i0..i1].fill(0);
        frame.class[i0..i1].fill(0);
        if !frame.depth_m.is_empty() {
            frame.depth_m[i0..i1].fill(f32::INFINITY);
        }
    }
}

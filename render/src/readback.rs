//! Getting the images back: copying the render targets into the readback buffer (whole,
//! or column span by column span), mapping it and unpacking it into a `Frame`, with the
//! columns not rendered zeroed.

use crate::{Frame, RenderError, Renderer};

/// Where one target's rows lie in the shared readback buffer.
#[derive(Clone, Copy)]
pub(crate) struct Plane {
    pub(crate) offset: u64,
    pub(crate) bytes_per_row: u32,
    pub(crate) bytes_per_pixel: u32,
}

impl Renderer {
    /// Copies the targets into the readback buffer (only the columns `spans` when they fit),
    /// submits `encoder` with the frame's draws and unpacks the images into `frame`:
    /// only the columns `spans` if `columns` were asked for, else all of them.
    pub(crate) fn read_back(
        &self,
        mut encoder: wgpu::CommandEncoder,
        spans: &[(u32, u32)],
        columns: Option<&[(u32, u32)]>,
        frame: &mut Frame,
    ) -> Result<(), RenderError> {
        // Only the rendered columns leave the GPU when they fit the buffer span by span.
        let layout = match (spans != [(0, self.width)]).then(|| self.span_planes(spans)).flatten() {
            Some(per_span) => spans.iter().copied().zip(per_span).collect(),
            None => vec![((0, self.width), self.planes.clone())],
        };
        for ((start, end), planes) in &layout {
            for (target, plane) in self.targets.iter().zip(planes) {
                encoder.copy_texture_to_buffer(
                    wgpu::TexelCopyTextureInfo {
                        origin: wgpu::Origin3d { x: *start, y: 0, z: 0 },
                        ..target.as_image_copy()
                    },
                    wgpu::TexelCopyBufferInfo {
                        buffer: &self.readback,
                        layout: wgpu::TexelCopyBufferLayout {
                            offset: plane.offset,
                            bytes_per_row: Some(plane.bytes_per_row),
                            rows_per_image: Some(self.height),
                        },
                    },
                    wgpu::Extent3d { width: end - start, height: self.height, depth_or_array_layers: 1 },
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
                self.unpack(&data, &layout, frame, if columns.is_some() { Some(spans) } else { None });
                Ok(())
            }
            Err(e) => Err(RenderError::Readback(e.to_string())),
        };
        // Unmapped even on error, so the next frame can map it again.
        self.readback.unmap();
        unpacked?;
        self.check_gpu_error()
    }

    /// Where each span's rows of each target go in the readback buffer: the spans one after
    /// another, rows padded as copies require; `None` when they would not fit.
    fn span_planes(&self, spans: &[(u32, u32)]) -> Option<Vec<Vec<Plane>>> {
        let mut offset = 0u64;
        let layout = spans
            .iter()
            .map(|&(start, end)| {
                self.planes
                    .iter()
                    .map(|p| {
                        let bytes_per_row =
                            (p.bytes_per_pixel * (end - start)).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
                        let plane = Plane { offset, bytes_per_row, bytes_per_pixel: p.bytes_per_pixel };
                        offset += bytes_per_row as u64 * self.height as u64;
                        plane
                    })
                    .collect()
            })
            .collect();
        (offset <= self.readback.size()).then_some(layout)
    }

    /// Copies the readback buffer, laid out as `layout` says (each copied span's column range
    /// and its targets' rows), into `frame`: all of it, or only the pixel columns `spans`,
    /// the rest zeroed.
    fn unpack(
        &self,
        data: &[u8],
        layout: &[((u32, u32), Vec<Plane>)],
        frame: &mut Frame,
        spans: Option<&[(u32, u32)]>,
    ) {
        let (w, h) = (self.width as usize, self.height as usize);
        self.size_frame(frame);
        let whole = [(0, self.width)];
        let copied = spans.unwrap_or(&whole);
        let empty = if spans.is_some() { gaps(copied, self.width) } else { Vec::new() };
        // Row `y` of columns `a..b` of a target, copied as `plane` from column `first` on.
        let row = |plane: &Plane, first: usize, y: usize, (a, b): (usize, usize)| {
            let start = plane.offset as usize + y * plane.bytes_per_row as usize;
            let bytes = plane.bytes_per_pixel as usize;
            &data[start + bytes * (a - first)..start + bytes * (b - first)]
        };
        for y in 0..h {
            blank_row(frame, y, &empty);
            for &(a, b) in copied {
                let ((first, _), planes) = layout
                    .iter()
                    .find(|((s, e), _)| *s <= a && b <= *e)
                    .expect("every span is copied, alone or in the whole frame");
                let (a, b, first) = (a as usize, b as usize, *first as usize);
                let (i0, i1) = (w * y + a, w * y + b);
                for (d, s) in
                    frame.rgb[3 * i0..3 * i1].chunks_exact_mut(3).zip(row(&planes[0], first, y, (a, b)).chunks_exact(4))
                {
                    d.copy_from_slice(&s[..3]);
                }
                let ids = row(&planes[1], first, y, (a, b)).chunks_exact(4);
                for ((instance, class), s) in frame.instance[i0..i1].iter_mut().zip(&mut frame.class[i0..i1]).zip(ids) {
                    let v = u32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    *instance = (v >> 8) as u16;
                    *class = (v & 0xff) as u8;
                }
                let Some(depth) = planes.get(2) else { continue };
                for (d, s) in frame.depth_m[i0..i1].iter_mut().zip(row(depth, first, y, (a, b)).chunks_exact(4)) {
                    let z = f32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    *d = if z > 0.0 { z } else { f32::INFINITY };
                }
            }
        }
        frame.columns = spans.map(<[_]>::to_vec);
    }

    /// Sizes `frame`'s images for this renderer (contents left as they were).
    fn size_frame(&self, frame: &mut Frame) {
        let n = self.width as usize * self.height as usize;
        frame.width = self.width;
        frame.height = self.height;
        frame.rgb.resize(3 * n, 0);
        frame.instance.resize(n, 0);
        frame.class.resize(n, 0);
        frame.depth_m.resize(if self.planes.len() > 2 { n } else { 0 }, 0.0);
    }

    /// `frame` with nothing rendered: every column empty.
    pub(crate) fn blank(&self, frame: &mut Frame) {
        self.size_frame(frame);
        let empty = [(0, self.width as usize)];
        for y in 0..self.height as usize {
            blank_row(frame, y, &empty);
        }
        frame.columns = Some(Vec::new());
    }
}

/// The pixel columns of `0..width` outside the sorted disjoint `spans`.
fn gaps(spans: &[(u32, u32)], width: u32) -> Vec<(usize, usize)> {
    let mut out = Vec::with_capacity(spans.len() + 1);
    let mut from = 0;
    for &(a, b) in spans {
        if a > from {
            out.push((from as usize, a as usize));
        }
        from = b;
    }
    if from < width {
        out.push((from as usize, width as usize));
    }
    out
}

/// Zeroes row `y` of `frame` in the pixel columns `empty` (depth: infinity).
fn blank_row(frame: &mut Frame, y: usize, empty: &[(usize, usize)]) {
    let w = frame.width as usize;
    for &(a, b) in empty {
        let (i0, i1) = (w * y + a, w * y + b);
        frame.rgb[3 * i0..3 * i1].fill(0);
        frame.instance[i0..i1].fill(0);
        frame.class[i0..i1].fill(0);
        if !frame.depth_m.is_empty() {
            frame.depth_m[i0..i1].fill(f32::INFINITY);
        }
    }
}

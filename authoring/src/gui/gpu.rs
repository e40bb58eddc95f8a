//! The canvas's pictures on the GPU: mip-mapped textures drawn by a minimal pipeline of our own
//! (through egui's paint callbacks) instead of egui's image meshes.
//!
//! Why: egui's textured meshes go through its general shader (blending, colour multiply, gamma
//! maths) which a software rasteriser (lavapipe) shades at about 4x the cost of a plain texture
//! copy — on two cores that was the whole frame budget. A shader that only samples, drawn
//! without blending for the pictures and with premultiplied blending for the hint overlay, hits
//! llvmpipe's fast path (measured on this machine: a 1280x800 frame of a 10 MP photo 46 ms ->
//! 11 ms). Mip levels keep a zoomed-out photo free of aliasing and its reads local.
//!
//! Colours stay in the sRGB encoding end to end (textures and framebuffer are both `Unorm`), as
//! egui's own images do; mip levels are averaged in that encoding (display only).

use eframe::egui::{self, Rect};
use eframe::egui_wgpu::{self, CallbackResources, CallbackTrait, ScreenDescriptor};
use eframe::wgpu;

const SHADER: &str = r#"
struct Quad { ndc: vec4<f32>, uv: vec4<f32> };
@group(0) @binding(0) var<uniform> quad: Quad;
@group(1) @binding(0) var tex: texture_2d<f32>;
@group(1) @binding(1) var samp: sampler;
struct V { @builtin(position) pos: vec4<f32>, @location(0) uv: vec2<f32> };
// Two triangles over the quad; corner k in 0..1 on both axes.
@vertex fn vs(@builtin(vertex_index) i: u32) -> V {
    var corners = array<vec2<f32>, 6>(vec2(0.0, 0.0), vec2(1.0, 0.0), vec2(0.0, 1.0),
                                      vec2(1.0, 0.0), vec2(1.0, 1.0), vec2(0.0, 1.0));
    let k = corners[i];
    var o: V;
    o.pos = vec4(mix(quad.ndc.xy, quad.ndc.zw, k), 0.0, 1.0);
    o.uv = mix(quad.uv.xy, quad.uv.zw, k);
    return o;
}
@fragment fn fs(v: V) -> @location(0) vec4<f32> { return textureSample(tex, samp, v.uv); }
"#;

/// Number of mip levels down to 1x1.
pub fn mip_levels(size: [u32; 2]) -> u32 {
    32 - size[0].max(size[1]).max(1).leading_zeros()
}

/// The pixel rectangle `[x, y, w, h]` of mip level `level` that depends on the level-0
/// rectangle `rect`, clamped to that level's size. Each level halves, rounding outwards, plus
/// one texel each side: with odd sizes a level's texel reads slightly off its two sources.
pub fn mip_rect(rect: [u32; 4], size: [u32; 2], level: u32) -> [u32; 4] {
    let [mut x0, mut y0] = [rect[0], rect[1]];
    let [mut x1, mut y1] = [rect[0] + rect[2], rect[1] + rect[3]];
    for l in 1..=level {
        let (lw, lh) = ((size[0] >> l).max(1), (size[1] >> l).max(1));
        x0 = (x0 / 2).saturating_sub(1);
        y0 = (y0 / 2).saturating_sub(1);
        x1 = (x1.div_ceil(2) + 1).min(lw);
        y1 = (y1.div_ceil(2) + 1).min(lh);
    }
    [x0, y0, x1.saturating_sub(x0), y1.saturating_sub(y0)]
}

/// Screen rectangle (points) and texture rectangle (0..1) to the uniform block:
/// normalised device coordinates of the quad, then its texture coordinates.
fn quad_uniform(quad: Rect, uv: Rect, screen_points: [f32; 2]) -> [f32; 8] {
    let nx = |x: f32| x / screen_points[0] * 2.0 - 1.0;
    let ny = |y: f32| 1.0 - y / screen_points[1] * 2.0;
    [nx(quad.min.x), ny(quad.min.y), nx(quad.max.x), ny(quad.max.y), uv.min.x, uv.min.y, uv.max.x, uv.max.y]
}

/// A uniform block holding one quad (`quad_uniform`'s layout).
fn uniform_slot(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    layout: &wgpu::BindGroupLayout,
    data: &[f32; 8],
) -> Slot {
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("restage quad"),
        size: 32,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    queue.write_buffer(&buffer, 0, bytemuck::cast_slice(data));
    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("restage quad"),
        layout,
        entries: &[wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() }],
    });
    Slot { buffer, bind }
}

/// A picture on the GPU with its mip chain.
pub struct GpuImage {
    texture: wgpu::Texture,
    bind: wgpu::BindGroup,
    /// Level k's view bound as the source of level k+1 (mip generation).
    level_binds: Vec<wgpu::BindGroup>,
    level_views: Vec<wgpu::TextureView>,
    /// Texture size (the picture may be shown downscaled when larger than the adapter allows).
    pub size: [u32; 2],
}

/// One uniform block per draw in a frame (a callback's uniforms are written before any draw).
struct Slot {
    buffer: wgpu::Buffer,
    bind: wgpu::BindGroup,
}

pub struct Pictures {
    device: wgpu::Device,
    queue: wgpu::Queue,
    opaque: wgpu::RenderPipeline,
    blended: wgpu::RenderPipeline,
    mipmap: wgpu::RenderPipeline,
    quad_layout: wgpu::BindGroupLayout,
    tex_layout: wgpu::BindGroupLayout,
    /// Nearest when magnified (a conservator sees the pixels), trilinear when reduced.
    view_sampler: wgpu::Sampler,
    /// Bilinear at a destination texel's centre: the mean of the four source texels.
    mip_sampler: wgpu::Sampler,
    slots: Vec<Slot>,
    used: usize,
    /// The whole-target quad every mip level is drawn with (its scissor limits the work).
    mip_quad: Slot,
    /// The largest texture side the adapter takes.
    pub max_side: u32,
}

impl Pictures {
    /// The window's renderer: pictures drawn into frames of `rs.target_format`.
    pub fn for_window(rs: &egui_wgpu::RenderState) -> Self {
        Self::new(rs.device.clone(), rs.queue.clone(), rs.target_format)
    }

    pub fn new(device: wgpu::Device, queue: wgpu::Queue, target: wgpu::TextureFormat) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("restage canvas"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let quad_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("restage quad"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let tex_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("restage picture"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("restage canvas"),
            bind_group_layouts: &[Some(&quad_layout), Some(&tex_layout)],
            immediate_size: 0,
        });
        let pipeline = |format: wgpu::TextureFormat, blend: Option<wgpu::BlendState>| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("restage canvas"),
                layout: Some(&layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs"),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format,
                        blend,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                multiview_mask: None,
                cache: None,
            })
        };
        let opaque = pipeline(target, None);
        let blended = pipeline(target, Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING));
        let mipmap = pipeline(wgpu::TextureFormat::Rgba8Unorm, None);
        let view_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("restage view"),
            mag_filter: wgpu::FilterMode::Nearest,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let mip_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("restage mip"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let whole = Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0));
        let mip_quad = uniform_slot(&device, &queue, &quad_layout, &quad_uniform(whole, whole, [1.0, 1.0]));
        Self {
            mip_quad,
            max_side: device.limits().max_texture_dimension_2d,
            device,
            queue,
            opaque,
            blended,
            mipmap,
            quad_layout,
            tex_layout,
            view_sampler,
            mip_sampler,
            slots: Vec::new(),
            used: 0,
        }
    }

    fn tex_bind(&self, view: &wgpu::TextureView, sampler: &wgpu::Sampler) -> wgpu::BindGroup {
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("restage picture"),
            layout: &self.tex_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(view) },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::Sampler(sampler) },
            ],
        })
    }

    /// Uploads an RGBA picture (`size`, rows of `4 * size[0]` bytes) with its mip chain.
    pub fn image(&self, size: [u32; 2], rgba: &[u8]) -> GpuImage {
        let levels = mip_levels(size);
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("restage picture"),
            size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
            mip_level_count: levels,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_DST
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        let level_views: Vec<_> = (0..levels)
            .map(|l| {
                texture.create_view(&wgpu::TextureViewDescriptor {
                    base_mip_level: l,
                    mip_level_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let level_binds = level_views.iter().map(|v| self.tex_bind(v, &self.mip_sampler)).collect();
        let bind = self.tex_bind(&texture.create_view(&Default::default()), &self.view_sampler);
        let img = GpuImage { texture, bind, level_binds, level_views, size };
        self.update(&img, [0, 0, size[0], size[1]], rgba);
        img
    }

    /// Writes the level-0 rectangle `rect` (`[x, y, w, h]`, rows of `4 * w` bytes) and
    /// recomputes the part of every mip level that depends on it.
    pub fn update(&self, img: &GpuImage, rect: [u32; 4], rgba: &[u8]) {
        let [x, y, w, h] = rect;
        if w == 0 || h == 0 {
            return;
        }
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &img.texture,
                mip_level: 0,
                origin: wgpu::Origin3d { x, y, z: 0 },
                aspect: wgpu::TextureAspect::All,
            },
            rgba,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * w), rows_per_image: Some(h) },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        let mut encoder = self.device.create_command_encoder(&Default::default());
        for level in 1..img.level_views.len() as u32 {
            let [sx, sy, sw, sh] = mip_rect(rect, img.size, level);
            if sw == 0 || sh == 0 {
                break;
            }
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("restage mip"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &img.level_views[level as usize],
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
                })],
                ..Default::default()
            });
            pass.set_pipeline(&self.mipmap);
            pass.set_bind_group(0, &self.mip_quad.bind, &[]);
            pass.set_bind_group(1, &img.level_binds[level as usize - 1], &[]);
            pass.set_scissor_rect(sx, sy, sw, sh);
            pass.draw(0..6, 0..1);
        }
        self.queue.submit([encoder.finish()]);
    }

    /// Starts a frame: the uniform blocks of the previous frame's draws are free again.
    pub fn begin_frame(&mut self) {
        self.used = 0;
    }

    /// Draws `uv` (0..1 texture coordinates) of `img` onto the screen rectangle `quad`
    /// (points), clipped to `clip`; `blend` for a premultiplied overlay.
    pub fn draw(
        &mut self,
        painter: &egui::Painter,
        clip: Rect,
        quad: Rect,
        uv: Rect,
        img: &GpuImage,
        blend: bool,
    ) {
        if self.used == self.slots.len() {
            let slot = uniform_slot(&self.device, &self.queue, &self.quad_layout, &[0.0; 8]);
            self.slots.push(slot);
        }
        let slot = &self.slots[self.used];
        self.used += 1;
        let callback = Draw {
            quad,
            uv,
            buffer: slot.buffer.clone(),
            quad_bind: slot.bind.clone(),
            tex_bind: img.bind.clone(),
            pipeline: if blend { self.blended.clone() } else { self.opaque.clone() },
        };
        painter
            .with_clip_rect(clip)
            .add(egui_wgpu::Callback::new_paint_callback(clip.intersect(quad), callback));
    }
}

/// One picture quad in a frame.
struct Draw {
    quad: Rect,
    uv: Rect,
    buffer: wgpu::Buffer,
    quad_bind: wgpu::BindGroup,
    tex_bind: wgpu::BindGroup,
    pipeline: wgpu::RenderPipeline,
}

impl CallbackTrait for Draw {
    fn prepare(
        &self,
        _device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &ScreenDescriptor,
        _encoder: &mut wgpu::CommandEncoder,
        _resources: &mut CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let points = [
            screen.size_in_pixels[0] as f32 / screen.pixels_per_point,
            screen.size_in_pixels[1] as f32 / screen.pixels_per_point,
        ];
        queue.write_buffer(&self.buffer, 0, bytemuck::cast_slice(&quad_uniform(self.quad, self.uv, points)));
        Vec::new()
    }

    fn paint(
        &self,
        info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        _resources: &CallbackResources,
    ) {
        // egui sets the viewport to the callback's rectangle, rounded to pixels; the quad is
        // placed in whole-screen coordinates instead so that rounding cannot shift it
        // (egui's scissor, the clip rectangle, stays).
        let [w, h] = info.screen_size_px;
        pass.set_viewport(0.0, 0.0, w as f32, h as f32, 0.0, 1.0);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.quad_bind, &[]);
        pass.set_bind_group(1, &self.tex_bind, &[]);
        pass.draw(0..6, 0..1);
    }
}

/// Which tiles of a mostly empty overlay hold anything, so that only those are drawn (a
/// blended quad over the whole picture costs a software rasteriser as much as the picture).
pub struct TileMask {
    size: [u32; 2],
    tile: u32,
    cols: u32,
    filled: Vec<bool>,
}

impl TileMask {
    pub fn new(size: [u32; 2], tile: u32) -> Self {
        let cols = size[0].div_ceil(tile);
        let rows = size[1].div_ceil(tile);
        Self { size, tile, cols, filled: vec![false; (cols * rows) as usize] }
    }

    pub fn size(&self) -> [u32; 2] {
        self.size
    }

    /// Re-reads the tiles touching `rect` (`[x, y, w, h]`) from `filled(x, y)`.
    pub fn update(&mut self, rect: [u32; 4], filled: impl Fn(u32, u32) -> bool) {
        let t = self.tile;
        let [x, y, w, h] = rect;
        for ty in y / t..(y + h).div_ceil(t).min(self.size[1].div_ceil(t)) {
            for tx in x / t..(x + w).div_ceil(t).min(self.cols) {
                let (x0, y0) = (tx * t, ty * t);
                let (x1, y1) = ((x0 + t).min(self.size[0]), (y0 + t).min(self.size[1]));
                self.filled[(ty * self.cols + tx) as usize] =
                    (y0..y1).any(|py| (x0..x1).any(|px| filled(px, py)));
            }
        }
    }

    /// Runs of filled tiles, row by row, within the pixel rectangle `visible`
    /// (`[x, y, w, h]`): each `[x0, y0, x1, y1]` in pixels, ends exclusive.
    pub fn runs(&self, visible: [u32; 4]) -> Vec<[u32; 4]> {
        let t = self.tile;
        let [x, y, w, h] = visible;
        let (c0, c1) = (x / t, (x + w).div_ceil(t).min(self.cols));
        let mut out = Vec::new();
        for ty in y / t..(y + h).div_ceil(t).min(self.size[1].div_ceil(t)) {
            let mut tx = c0;
            while tx < c1 {
                if !self.filled[(ty * self.cols + tx) as usize] {
                    tx += 1;
                    continue;
                }
                let start = tx;
                while tx < c1 && self.filled[(ty * self.cols + tx) as usize] {
                    tx += 1;
                }
                let y1 = ((ty + 1) * t).min(self.size[1]);
                out.push([start * t, ty * t, (tx * t).min(self.size[0]), y1]);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mip_levels_reach_one_texel() {
        assert_eq!(mip_levels([1, 1]), 1);
        assert_eq!(mip_levels([2, 1]), 2);
        assert_eq!(mip_levels([3872, 2592]), 12);
        assert_eq!(mip_levels([4096, 10]), 13);
    }

    #[test]
    fn mip_rect_rounds_outwards_and_stays_inside() {
        let size = [3872, 2592];
        assert_eq!(mip_rect([0, 0, 3872, 2592], size, 0), [0, 0, 3872, 2592]);
        assert_eq!(mip_rect([0, 0, 3872, 2592], size, 1), [0, 0, 1936, 1296]);
        // Texels 5..8 x 7..9 feed 2..4 x 3..5 at level 1, and one more each side.
        assert_eq!(mip_rect([5, 7, 3, 2], size, 1), [1, 2, 4, 4]);
        assert_eq!(mip_rect([5, 7, 3, 2], size, 2), [0, 0, 4, 4]);
        for level in 0..12 {
            let [x, y, w, h] = mip_rect([3800, 2500, 72, 92], size, level);
            assert!(x + w <= (size[0] >> level).max(1) && y + h <= (size[1] >> level).max(1));
            assert!(w >= 1 && h >= 1);
        }
    }

    #[test]
    fn tile_mask_runs_cover_exactly_the_filled_tiles() {
        let (w, h) = (300u32, 200u32);
        let mut marks = vec![false; (w * h) as usize];
        let mut mask = TileMask::new([w, h], 64);
        assert!(mask.runs([0, 0, w, h]).is_empty());
        // Two touching tiles in row 0 make one run; a lone pixel in the last (partial) tile.
        for (x, y) in [(10, 5), (70, 60), (299, 199)] {
            marks[(y * w + x) as usize] = true;
            mask.update([x, y, 1, 1], |px, py| marks[(py * w + px) as usize]);
        }
        assert_eq!(mask.runs([0, 0, w, h]), vec![[0, 0, 128, 64], [256, 192, 300, 200]]);
        // Clipped to what is visible (whole tiles still).
        assert_eq!(mask.runs([100, 0, 50, 50]), vec![[64, 0, 128, 64]]);
        // Erasing empties the tile again.
        marks[(5 * w + 10) as usize] = false;
        mask.update([0, 0, 64, 64], |px, py| marks[(py * w + px) as usize]);
        assert_eq!(mask.runs([0, 0, w, h])[0], [64, 0, 128, 64]);
    }

    /// Mip level `level` of `img` read back, tightly packed RGBA rows.
    fn read_level(g: &restage_authoring::gpu::Gpu, img: &GpuImage, level: u32) -> Vec<u8> {
        let (w, h) = ((img.size[0] >> level).max(1), (img.size[1] >> level).max(1));
        let row = (4 * w).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let buffer = g.device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: (row * h) as u64,
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = g.device.create_command_encoder(&Default::default());
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &img.texture,
                mip_level: level,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(h),
                },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        g.queue.submit([encoder.finish()]);
        let padded: Vec<u8> = g.read(&buffer, (row * h) as usize).expect("readback");
        padded.chunks(row as usize).flat_map(|r| r[..4 * w as usize].to_vec()).collect()
    }

    #[test]
    fn mip_chain_averages_and_follows_partial_updates() {
        let Some(g) = restage_authoring::gpu::for_tests() else { return };
        let pictures = Pictures::new(g.device.clone(), g.queue.clone(), wgpu::TextureFormat::Rgba8Unorm);
        // 8x4, columns alternating 0 and 200: every texel of level 1 is their mean.
        let rgba: Vec<u8> =
            (0..4).flat_map(|_| (0..8).flat_map(|x| [if x % 2 == 0 { 0 } else { 200 }; 4])).collect();
        let img = pictures.image([8, 4], &rgba);
        let near = |got: u8, want: f64| (got as f64 - want).abs() <= 1.0;
        let l1 = read_level(g, &img, 1);
        assert_eq!(l1.len(), 4 * 2 * 4);
        assert!(l1.iter().all(|&v| near(v, 100.0)), "level 1 {l1:?}");
        // A 2x2 block at (4, 0) made white: its level-1 texel (2, 0) follows, the rest stays,
        // and level 2's texel (1, 0) averages one white and three grey texels.
        pictures.update(&img, [4, 0, 2, 2], &[255; 16]);
        let l1 = read_level(g, &img, 1);
        for (i, px) in l1.chunks(4).enumerate() {
            let want = if i == 2 { 255.0 } else { 100.0 };
            assert!(px.iter().all(|&v| near(v, want)), "level 1 texel {i}: {px:?}");
        }
        let l2 = read_level(g, &img, 2);
        assert!(l2[..4].iter().all(|&v| near(v, 100.0)), "level 2 texel 0: {:?}", &l2[..4]);
        assert!(l2[4..].iter().all(|&v| near(v, (255.0 + 300.0) / 4.0)), "level 2 texel 1: {:?}", &l2[4..]);
        assert_eq!(read_level(g, &img, 3).len(), 4);
    }

    #[test]
    fn quad_uniform_maps_points_to_device_coordinates() {
        let q = quad_uniform(
            Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(100.0, 50.0)),
            Rect::from_min_max(egui::pos2(0.25, 0.0), egui::pos2(0.5, 1.0)),
            [200.0, 100.0],
        );
        assert_eq!(q, [-1.0, 1.0, 0.0, 0.0, 0.25, 0.0, 0.5, 1.0]);
    }
}

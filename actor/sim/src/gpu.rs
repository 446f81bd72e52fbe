//! The headless wgpu renderer: RGB (u8), metric z-depth (f32) and instance
//! ids (u32) in one render pass to three colour targets, read back to the
//! CPU. It runs on Vulkan: a real GPU, or Mesa's lavapipe on machines
//! without one. The scene's triangles are uploaded once per geometry
//! generation, so a step that moves nothing re-renders without re-uploading.

use nalgebra::{Matrix4, Point3};
use wgpu::util::DeviceExt;

use crate::geometry::SceneGeometry;
use crate::mesh::{scene_mesh, InstanceRange, MeshVertex};
use crate::raycast::{Camera, Frame, LIGHT};
use crate::scene::aabb_corners;

/// Nearest depth the renderer draws, metres (reverse-Z keeps precision far out).
const NEAR_M: f32 = 0.01;

/// Why the GPU renderer could not start or render.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No Vulkan adapter: no GPU driver and no software rasteriser installed.
    #[error(
        "no Vulkan adapter found ({0}); install a GPU driver, or Mesa's software \
         rasteriser lavapipe with `apt-get install mesa-vulkan-drivers`, or use the CPU \
         renderer (`--renderer cpu`)"
    )]
    NoAdapter(String),
    /// The adapter refused to make a device.
    #[error("the Vulkan adapter {adapter} could not create a device: {reason}")]
    Device {
        /// The adapter's name.
        adapter: String,
        /// What wgpu said.
        reason: String,
    },
    /// Reading the rendered images back failed.
    #[error("reading the rendered frame back from the GPU failed: {0}")]
    Readback(String),
}

/// Uniforms of one draw; the layout matches `gpu.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Uniforms {
    view_proj: [f32; 16],
    eye: [f32; 4],
    light: [f32; 4],
    /// x: largest depth drawn, metres.
    params: [f32; 4],
}

/// Size-dependent render targets and the readback buffer.
struct Targets {
    width: u32,
    height: u32,
    colour: wgpu::Texture,
    depth_out: wgpu::Texture,
    ids: wgpu::Texture,
    /// Views of colour, depth_out and ids, in that order.
    views: [wgpu::TextureView; 3],
    zbuffer: wgpu::TextureView,
    readback: wgpu::Buffer,
    padded_row: u32,
}

/// The uploaded scene.
struct Uploaded {
    generation: u64,
    vertices: wgpu::Buffer,
    instances: Vec<InstanceRange>,
}

/// A headless renderer on one wgpu device.
pub struct GpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::RenderPipeline,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    targets: Option<Targets>,
    scene: Option<Uploaded>,
    adapter: String,
}

impl std::fmt::Debug for GpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuRenderer")
            .field("adapter", &self.adapter)
            .finish_non_exhaustive()
    }
}

const COLOUR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_OUT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
const ID_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
const ZBUFFER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

impl GpuRenderer {
    /// Opens the first Vulkan adapter (a real GPU is preferred over lavapipe).
    pub fn new() -> Result<Self, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::VULKAN;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let name = format!("{} ({:?}, {})", info.name, info.device_type, info.driver);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("sim renderer"),
            required_features: wgpu::Features::empty(),
            required_limits: wgpu::Limits::downlevel_defaults(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device {
            adapter: name.clone(),
            reason: e.to_string(),
        })?;
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("sim renderer"),
            source: wgpu::ShaderSource::Wgsl(include_str!("gpu.wgsl").into()),
        });
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("uniforms"),
            size: std::mem::size_of::<Uniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("uniforms"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("uniforms"),
            layout: &layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniforms.as_entire_binding(),
            }],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("sim renderer"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Uint32, 4 => Float32x3, 5 => Uint32
        ];
        let target = |format| {
            Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        };
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("sim renderer"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<MeshVertex>() as u64,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &attributes,
                })],
            },
            primitive: wgpu::PrimitiveState {
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: ZBUFFER_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[
                    target(COLOUR_FORMAT),
                    target(DEPTH_OUT_FORMAT),
                    target(ID_FORMAT),
                ],
            }),
            multiview_mask: None,
            cache: None,
        });
        Ok(Self {
            device,
            queue,
            pipeline,
            uniforms,
            bind_group,
            targets: None,
            scene: None,
            adapter: name,
        })
    }

    /// The adapter in use, e.g. `llvmpipe (LLVM 15.0.6, 256 bits) (Cpu, llvmpipe)`.
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    fn targets(&mut self, width: u32, height: u32) -> &Targets {
        if self
            .targets
            .as_ref()
            .is_none_or(|t| t.width != width || t.height != height)
        {
            self.targets = Some(make_targets(&self.device, width, height));
        }
        self.targets.as_ref().expect("just made")
    }

    fn upload(&mut self, geometry: &SceneGeometry) {
        if self
            .scene
            .as_ref()
            .is_some_and(|s| s.generation == geometry.generation())
        {
            return;
        }
        let mesh = scene_mesh(geometry);
        let vertices = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("scene"),
                contents: bytemuck::cast_slice(&mesh.vertices),
                usage: wgpu::BufferUsages::VERTEX,
            });
        self.scene = Some(Uploaded {
            generation: geometry.generation(),
            vertices,
            instances: mesh.instances,
        });
    }

    /// Renders `geometry` from `camera`, as [`crate::raycast::render`] does:
    /// depths beyond `max_depth_m` are 0 with id 0 and black.
    pub fn render(
        &mut self,
        geometry: &SceneGeometry,
        camera: &Camera,
        max_depth_m: f32,
    ) -> Result<Frame, GpuError> {
        let (width, height) = (camera.width as u32, camera.height as u32);
        self.upload(geometry);
        let uniforms = Uniforms {
            view_proj: view_projection(camera).as_slice().try_into().expect("4x4"),
            eye: {
                let e = camera.t_world_camera * Point3::origin();
                [e.x, e.y, e.z, 1.0]
            },
            light: {
                let l = LIGHT.normalize();
                [l.x, l.y, l.z, 0.0]
            },
            params: [max_depth_m, 0.0, 0.0, 0.0],
        };
        self.queue
            .write_buffer(&self.uniforms, 0, bytemuck::bytes_of(&uniforms));
        self.targets(width, height);
        let (targets, scene) = (
            self.targets.as_ref().expect("made above"),
            self.scene.as_ref().expect("uploaded above"),
        );
        let views = &targets.views;
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        {
            let attachment = |view| {
                Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })
            };
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("sim frame"),
                color_attachments: &[
                    attachment(&views[0]),
                    attachment(&views[1]),
                    attachment(&views[2]),
                ],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &targets.zbuffer,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            for range in visible_ranges(&scene.instances, camera, max_depth_m) {
                pass.draw(range, 0..1);
            }
        }
        let plane = u64::from(targets.padded_row) * u64::from(height);
        for (k, texture) in [&targets.colour, &targets.depth_out, &targets.ids]
            .into_iter()
            .enumerate()
        {
            encoder.copy_texture_to_buffer(
                texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &targets.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: k as u64 * plane,
                        bytes_per_row: Some(targets.padded_row),
                        rows_per_image: Some(height),
                    },
                },
                wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
            );
        }
        self.queue.submit([encoder.finish()]);
        let (sender, receiver) = std::sync::mpsc::channel();
        targets
            .readback
            .map_async(wgpu::MapMode::Read, .., move |r| {
                // The receiver waits below; if it is gone there is nobody to tell.
                let _ = sender.send(r);
            });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        receiver
            .recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let frame = {
            let bytes = targets
                .readback
                .get_mapped_range(..)
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            unpack(
                &bytes,
                width as usize,
                height as usize,
                targets.padded_row as usize,
            )
        };
        targets.readback.unmap();
        Ok(frame)
    }
}

/// Camera-to-clip with reverse-Z (near plane at depth 1, infinity at 0),
/// x right and y down in the camera mapping to NDC right and up; pixel
/// centres land where [`Camera::ray`] puts them.
fn view_projection(camera: &Camera) -> Matrix4<f32> {
    let f = camera.focal_px();
    let (sx, sy) = (
        2.0 * f / camera.width as f32,
        2.0 * f / camera.height as f32,
    );
    #[rustfmt::skip]
    let projection = Matrix4::new(
        sx,  0.0, 0.0,    0.0,
        0.0, -sy, 0.0,    0.0,
        0.0, 0.0, 0.0,    NEAR_M,
        0.0, 0.0, 1.0,    0.0,
    );
    projection * camera.t_world_camera.inverse().to_homogeneous()
}

/// The vertex ranges of the instances whose boxes may be in view (a box is
/// left out only when all its corners lie outside one plane of the view
/// frustum), adjacent ranges merged into one draw.
fn visible_ranges(
    instances: &[InstanceRange],
    camera: &Camera,
    max_depth_m: f32,
) -> Vec<std::ops::Range<u32>> {
    let t_camera_world = camera.t_world_camera.inverse();
    let f = camera.focal_px();
    // One pixel of margin on each side.
    let tan_x = (camera.width as f32 / 2.0 + 1.0) / f;
    let tan_y = (camera.height as f32 / 2.0 + 1.0) / f;
    let mut draws: Vec<std::ops::Range<u32>> = Vec::new();
    for instance in instances {
        let (lo, hi) = (instance.aabb_min, instance.aabb_max);
        let corners = aabb_corners(&lo, &hi).map(|c| t_camera_world * c);
        let outside = |test: &dyn Fn(&Point3<f32>) -> bool| corners.iter().all(test);
        if outside(&|p| p.z < NEAR_M)
            || outside(&|p| p.z > max_depth_m)
            || outside(&|p| p.x > tan_x * p.z)
            || outside(&|p| p.x < -tan_x * p.z)
            || outside(&|p| p.y > tan_y * p.z)
            || outside(&|p| p.y < -tan_y * p.z)
        {
            continue;
        }
        match draws.last_mut() {
            Some(last) if last.end == instance.vertices.start => last.end = instance.vertices.end,
            _ => draws.push(instance.vertices.clone()),
        }
    }
    draws
}

fn make_targets(device: &wgpu::Device, width: u32, height: u32) -> Targets {
    let texture = |format, usage| {
        device.create_texture(&wgpu::TextureDescriptor {
            label: None,
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let out = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
    let align = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let padded_row = (4 * width).div_ceil(align) * align;
    let (colour, depth_out, ids) = (
        texture(COLOUR_FORMAT, out),
        texture(DEPTH_OUT_FORMAT, out),
        texture(ID_FORMAT, out),
    );
    let views =
        [&colour, &depth_out, &ids].map(|t| t.create_view(&wgpu::TextureViewDescriptor::default()));
    Targets {
        width,
        height,
        colour,
        depth_out,
        ids,
        views,
        zbuffer: texture(ZBUFFER_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT)
            .create_view(&wgpu::TextureViewDescriptor::default()),
        readback: device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: 3 * u64::from(padded_row) * u64::from(height),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }),
        padded_row,
    }
}

/// The three planes of the readback buffer as a [`Frame`].
fn unpack(bytes: &[u8], width: usize, height: usize, padded_row: usize) -> Frame {
    let plane = padded_row * height;
    let n = width * height;
    let mut frame = Frame {
        width,
        height,
        rgb: Vec::with_capacity(3 * n),
        depth_m: Vec::with_capacity(n),
        ids: Vec::with_capacity(n),
    };
    let word = |at: usize| [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]];
    for v in 0..height {
        for u in 0..width {
            let at = v * padded_row + 4 * u;
            frame.rgb.extend_from_slice(&bytes[at..at + 3]);
            frame.depth_m.push(f32::from_le_bytes(word(plane + at)));
            frame.ids.push(u32::from_le_bytes(word(2 * plane + at)));
        }
    }
    frame
}

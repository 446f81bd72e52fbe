//! The renderer a simulator draws with, chosen at run time: the wgpu
//! renderer (a GPU, or lavapipe) or the CPU ray-cast reference; by default
//! the first when the machine has a Vulkan adapter, else the second, so a
//! fresh machine without Vulkan drivers runs rather than failing.

use std::str::FromStr;

use crate::geometry::SceneGeometry;
use crate::gpu::{GpuError, GpuRenderer};
use crate::raycast::{render, Camera, Frame};

/// Which renderer to use (`--renderer auto|gpu|cpu`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RendererChoice {
    /// wgpu when a Vulkan adapter exists, else the CPU ray caster (said
    /// once on stderr).
    #[default]
    Auto,
    /// wgpu on Vulkan: a real GPU or Mesa's lavapipe; an error without one.
    Gpu,
    /// The CPU ray-cast reference renderer.
    Cpu,
}

impl FromStr for RendererChoice {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(Self::Auto),
            "gpu" => Ok(Self::Gpu),
            "cpu" => Ok(Self::Cpu),
            other => Err(format!(
                "unknown renderer `{other}`: use `auto` (gpu when a Vulkan adapter exists, else \
                 cpu), `gpu` (wgpu: a GPU or lavapipe) or `cpu` (ray casting)"
            )),
        }
    }
}

/// An open renderer.
#[derive(Debug)]
pub enum Renderer {
    /// The wgpu renderer.
    Gpu(Box<GpuRenderer>),
    /// The CPU reference.
    Cpu,
}

impl Renderer {
    /// Opens the chosen renderer; the GPU one fails when no Vulkan adapter exists.
    pub fn open(choice: RendererChoice) -> Result<Self, GpuError> {
        Ok(match choice {
            RendererChoice::Gpu => Self::Gpu(Box::new(GpuRenderer::new()?)),
            RendererChoice::Cpu => Self::Cpu,
            RendererChoice::Auto => match GpuRenderer::new() {
                Ok(gpu) => Self::Gpu(Box::new(gpu)),
                Err(GpuError::NoAdapter(why)) => {
                    static SAID: std::sync::Once = std::sync::Once::new();
                    SAID.call_once(|| {
                        eprintln!(
                            "renderer: no Vulkan adapter ({why}); rendering on the CPU. For the \
                             GPU renderer install a GPU driver or Mesa's lavapipe \
                             (`apt-get install mesa-vulkan-drivers`); `--renderer cpu` says this \
                             choice explicitly"
                        )
                    });
                    Self::Cpu
                }
                Err(other) => return Err(other),
            },
        })
    }

    /// What renders, for logs: the adapter's name or "CPU ray casting".
    pub fn describe(&self) -> String {
        match self {
            Self::Gpu(g) => format!("wgpu on {}", g.adapter()),
            Self::Cpu => "CPU ray casting".into(),
        }
    }

    /// Renders `geometry` from `camera`; nothing beyond `max_depth_m`.
    pub fn render(
        &mut self,
        geometry: &SceneGeometry,
        camera: &Camera,
        max_depth_m: f32,
    ) -> Result<Frame, GpuError> {
        match self {
            Self::Gpu(g) => g.render(geometry, camera, max_depth_m),
            Self::Cpu => Ok(render(geometry, camera, max_depth_m)),
        }
    }
}

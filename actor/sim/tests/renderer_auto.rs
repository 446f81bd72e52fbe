//! The default renderer on a machine without a Vulkan driver: `auto` falls
//! back to the CPU ray caster instead of failing, while an explicit `gpu`
//! still fails with the install hint. The Vulkan loader is pointed at a
//! driver list that does not exist (this test binary's own process), which
//! is what a fresh machine without `mesa-vulkan-drivers` looks like.

use sim::gpu::GpuError;
use sim::renderer::{Renderer, RendererChoice};

#[test]
fn without_a_vulkan_driver_auto_renders_on_the_cpu_and_gpu_says_what_to_install() {
    for variable in ["VK_ICD_FILENAMES", "VK_DRIVER_FILES"] {
        // SAFETY: this test binary has no other test thread that reads the environment.
        unsafe { std::env::set_var(variable, "/nonexistent/no-driver.json") };
    }
    let auto = Renderer::open(RendererChoice::Auto).expect("auto always opens a renderer");
    assert_eq!(auto.describe(), "CPU ray casting");
    match Renderer::open(RendererChoice::Gpu) {
        Err(error @ GpuError::NoAdapter(_)) => {
            assert!(error.to_string().contains("mesa-vulkan-drivers"), "{error}")
        }
        other => panic!("gpu without a driver: {other:?}"),
    }
    assert_eq!("auto".parse::<RendererChoice>(), Ok(RendererChoice::Auto));
    assert_eq!(RendererChoice::default(), RendererChoice::Auto);
}

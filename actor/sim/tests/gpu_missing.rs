//! Without any Vulkan driver the GPU renderer refuses to start with a message
//! that names the package to install. (Its own test binary: it hides the
//! drivers through the Vulkan loader's environment for the whole process.)

use sim::gpu::{GpuError, GpuRenderer};

#[test]
fn no_vulkan_driver_gives_an_error_naming_the_package() {
    let nowhere = std::env::temp_dir().join("no-such-vulkan-icd.json");
    std::env::set_var("VK_ICD_FILENAMES", &nowhere);
    std::env::set_var("VK_DRIVER_FILES", &nowhere);
    let error = GpuRenderer::new().expect_err("no driver, no renderer");
    assert!(matches!(error, GpuError::NoAdapter(_)), "{error:?}");
    let message = error.to_string();
    println!("{message}");
    assert!(message.contains("mesa-vulkan-drivers"), "{message}");
    assert!(message.contains("--renderer cpu"), "{message}");
}

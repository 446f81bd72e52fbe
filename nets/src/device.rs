//! Choosing where the networks run, at run time (`--device cpu|gpu`).

use std::str::FromStr;

use burn::prelude::*;

/// Where to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceChoice {
    /// burn's pure-Rust `flex` backend: builds offline, runs anywhere.
    Cpu,
    /// The GPU backend this binary was built with: libtorch on CUDA
    /// (`gpu-torch` feature) or else burn's wgpu backend (Vulkan on Linux,
    /// `gpu` feature); needs a GPU.
    Gpu,
}

impl FromStr for DeviceChoice {
    type Err = DeviceError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "cpu" => Ok(Self::Cpu),
            "gpu" => Ok(Self::Gpu),
            other => Err(DeviceError::Unknown(other.to_string())),
        }
    }
}

/// Why a device could not be opened.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeviceError {
    /// Not `cpu` or `gpu`.
    #[error("unknown device {0:?}: use `cpu` or `gpu`")]
    Unknown(String),
    /// This binary was built without the GPU backend.
    #[error("this build has no GPU backend: rebuild with `--features nets/gpu` (needs a Vulkan driver at run time) or `--features nets/gpu-torch,training/gpu-torch` (needs libtorch with CUDA; deploy/build-gpu-torch.sh), or use `--device cpu`")]
    NotBuilt,
    /// The GPU backend found no usable adapter.
    #[error("no usable GPU: {0}; use `--device cpu`")]
    Unavailable(String),
    /// A setting of the GPU backend (an environment variable) is not valid.
    #[error("{0}")]
    Setting(String),
}

/// Opens the chosen device and checks that it can run a tensor operation.
pub fn open_device(choice: DeviceChoice) -> Result<Device, DeviceError> {
    match choice {
        DeviceChoice::Cpu => Ok(Device::flex()),
        DeviceChoice::Gpu => open_gpu(),
    }
}

/// Whether this build has the libtorch backend (`gpu-torch`).
pub const LIBTORCH: bool = cfg!(feature = "gpu-torch");

/// The GPU backend's build options in this binary, for benchmark reports:
/// `cpu only`, `libtorch (CUDA)`, or `wgpu` followed by the `gpu-*`
/// features it was built with.
pub fn backend_features() -> String {
    if cfg!(feature = "gpu-torch") {
        return "libtorch (CUDA)".into();
    }
    let mut features = Vec::new();
    if cfg!(feature = "gpu") {
        features.push("wgpu");
    }
    for (on, name) in [
        (cfg!(feature = "gpu-fusion"), "fusion"),
        (cfg!(feature = "gpu-autotune"), "autotune"),
        (cfg!(feature = "gpu-vulkan"), "vulkan (SPIR-V)"),
    ] {
        if on {
            features.push(name);
        }
    }
    if features.is_empty() {
        "cpu only".into()
    } else {
        features.join(" + ")
    }
}

/// True for the CPU backend. Its forward pass of one sample runs on one
/// thread and a batch costs the same per sample, so callers with several
/// independent samples do better running them on threads of their own.
pub fn is_cpu(device: &Device) -> bool {
    *device == Device::flex()
}

/// True on burn's wgpu backend: its matrix products have no split-K, so a
/// product whose inner dimension is a whole batch runs on few cores
/// (`conv_matmul` then takes one product per image).
pub fn is_wgpu(device: &Device) -> bool {
    cfg!(feature = "gpu") && !cfg!(feature = "gpu-torch") && !is_cpu(device)
}

/// libtorch on the first CUDA device. libtorch is linked, not loaded, so a
/// missing library stops the program before this runs (the loader names
/// it); a libtorch without CUDA or a machine without a GPU fails the probe.
///
/// `AFX_CUDA_WAIT` (`spin`, `yield`, `block`) sets how threads wait for the
/// GPU ([`crate::cuda_wait`]); unset leaves CUDA's heuristic, which spins.
///
/// `AFX_CUDNN_BENCHMARK=1` has cuDNN time its algorithms for each new
/// shape and keep the fastest (PyTorch's `torch.backends.cudnn.benchmark`),
/// for measuring whether the U-Net's inference gains from it
/// (docs/notebook/2026-11-27-gpu-check-free-running.md); off by default.
#[cfg(feature = "gpu-torch")]
#[allow(deprecated)] // burn 0.22 marks libtorch deprecated; chosen all the same (decision 0010)
fn open_gpu() -> Result<Device, DeviceError> {
    // Before libtorch makes the context, so that it is made with the flags.
    if let Some(wait) = crate::cuda_wait::from_env().map_err(DeviceError::Setting)? {
        let flags = crate::cuda_wait::apply(wait, 0).map_err(DeviceError::Unavailable)?;
        eprintln!("CUDA waits: {wait:?} (AFX_CUDA_WAIT; context flags {flags:#x})");
    }
    let device = probe(|| Device::libtorch_cuda(0), "libtorch could not use CUDA")?;
    if std::env::var("AFX_CUDNN_BENCHMARK").is_ok_and(|v| v == "1") {
        tch::Cuda::cudnn_set_benchmark(true);
        eprintln!("cuDNN benchmark mode on (AFX_CUDNN_BENCHMARK=1)");
    }
    Ok(device)
}

#[cfg(all(feature = "gpu", not(feature = "gpu-torch")))]
fn open_gpu() -> Result<Device, DeviceError> {
    probe(
        || Device::wgpu(Default::default()),
        "the wgpu backend failed to start",
    )
}

/// Opens a device with `open` and runs one small computation on it; a
/// backend that panics (wgpu without an adapter, libtorch without CUDA)
/// becomes an error.
#[cfg(any(feature = "gpu", feature = "gpu-torch"))]
fn probe(open: impl FnOnce() -> Device, failure: &str) -> Result<Device, DeviceError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || {
        let device = open();
        let probe: f32 = Tensor::<1>::ones([4], &device).sum().into_scalar::<f32>();
        (probe == 4.0).then_some(device)
    }))
    .map_err(|panic| {
        let message = panic
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| failure.into());
        DeviceError::Unavailable(message)
    })?
    .ok_or_else(|| DeviceError::Unavailable("a test computation gave a wrong result".into()))
}

#[cfg(not(any(feature = "gpu", feature = "gpu-torch")))]
fn open_gpu() -> Result<Device, DeviceError> {
    Err(DeviceError::NotBuilt)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn choices_parse_and_the_cpu_always_opens() {
        assert_eq!("cpu".parse::<DeviceChoice>(), Ok(DeviceChoice::Cpu));
        assert_eq!("gpu".parse::<DeviceChoice>(), Ok(DeviceChoice::Gpu));
        let err = "tpu".parse::<DeviceChoice>().unwrap_err();
        assert!(err.to_string().contains("use `cpu` or `gpu`"));
        assert!(open_device(DeviceChoice::Cpu).is_ok_and(|d| is_cpu(&d)));
        #[cfg(not(any(feature = "gpu", feature = "gpu-torch")))]
        assert!(matches!(
            open_device(DeviceChoice::Gpu),
            Err(DeviceError::NotBuilt)
        ));
    }
}

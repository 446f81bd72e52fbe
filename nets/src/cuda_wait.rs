//! How a host thread waits for the GPU on libtorch (`AFX_CUDA_WAIT`).
//!
//! Why: CUDA's default for a thread that waits for the device (a blocking
//! copy back, a synchronisation) is a heuristic that spins the thread on
//! its core whenever the process has fewer CUDA contexts than the machine
//! has cores, which is always the case here. So every process's waiting
//! threads (an actor's U-Net batching thread, the learner's trainers) keep
//! a core busy while the GPU works, cores the environments need: on the
//! H200 the 64-px whole system kept nearly every core busy for far less
//! environment work than that
//! (docs/notebook/2026-11-28-what-holds-the-whole-system.md).
//! `AFX_CUDA_WAIT=block` makes such threads sleep until the GPU is done
//! (`yield` yields the core while polling, `spin` spins always); unset
//! leaves CUDA's heuristic. It sets the scheduling flags of the device's
//! primary context, the one libtorch uses, through the driver
//! (`cuDevicePrimaryCtxSetFlags`), before libtorch makes that context
//! (`device::open_device`).

use std::str::FromStr;

/// How a waiting host thread behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CudaWait {
    /// Spin on the core until the GPU is done (lowest latency).
    Spin,
    /// Poll, yielding the core between polls.
    Yield,
    /// Sleep until the GPU is done (frees the core, adds a wake-up).
    Block,
}

/// The driver's scheduling bits of a context's flags (`CU_CTX_SCHED_MASK`).
const SCHED_MASK: u32 = 0x07;

impl CudaWait {
    /// The driver's flag (`CU_CTX_SCHED_SPIN`, `_YIELD`, `_BLOCKING_SYNC`).
    fn flag(self) -> u32 {
        match self {
            Self::Spin => 0x01,
            Self::Yield => 0x02,
            Self::Block => 0x04,
        }
    }

    /// `flags` with their scheduling bits replaced by this one's.
    fn replace_in(self, flags: u32) -> u32 {
        (flags & !SCHED_MASK) | self.flag()
    }
}

impl FromStr for CudaWait {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "spin" => Ok(Self::Spin),
            "yield" => Ok(Self::Yield),
            "block" => Ok(Self::Block),
            other => Err(format!(
                "AFX_CUDA_WAIT={other:?}: use spin, yield or block (or leave it unset for CUDA's own choice)"
            )),
        }
    }
}

/// The choice `AFX_CUDA_WAIT` makes, if set.
pub fn from_env() -> Result<Option<CudaWait>, String> {
    std::env::var("AFX_CUDA_WAIT")
        .ok()
        .map(|v| v.parse())
        .transpose()
}

type CuInit = unsafe extern "C" fn(u32) -> i32;
type CuDeviceGet = unsafe extern "C" fn(*mut i32, i32) -> i32;
type CuGetState = unsafe extern "C" fn(i32, *mut u32, *mut i32) -> i32;
type CuSetFlags = unsafe extern "C" fn(i32, u32) -> i32;

/// The driver's function `name`, of type `T`.
///
/// # Safety
/// `T` must be the function's C signature.
unsafe fn driver<'a, T>(
    library: &'a libloading::Library,
    name: &str,
) -> Result<libloading::Symbol<'a, T>, String> {
    // SAFETY: the caller vouches for the signature.
    unsafe { library.get::<T>(name.as_bytes()) }.map_err(|e| format!("{name}: {e}"))
}

/// A driver call's result as a `Result`.
fn check(what: &str, code: i32) -> Result<(), String> {
    match code {
        0 => Ok(()),
        code => Err(format!("{what} failed (CUresult {code})")),
    }
}

/// Sets how threads wait for CUDA device `ordinal`; returns its context's
/// flags after.
pub fn apply(wait: CudaWait, ordinal: i32) -> Result<u32, String> {
    // SAFETY: libcuda.so.1 is the CUDA driver, whose initialisers have no
    // preconditions; libtorch loads the same library, and it stays loaded
    // (the handle is leaked below).
    let library = unsafe { libloading::Library::new("libcuda.so.1") }
        .map_err(|e| format!("cannot load the CUDA driver (libcuda.so.1): {e}"))?;
    // SAFETY: the types are the C signatures of cuda.h (CUdevice is an int,
    // CUresult an enum the size of one), and each call gets valid pointers
    // to locals for its outputs.
    let flags = unsafe {
        let init = driver::<CuInit>(&library, "cuInit")?;
        let device_get = driver::<CuDeviceGet>(&library, "cuDeviceGet")?;
        let get_state = driver::<CuGetState>(&library, "cuDevicePrimaryCtxGetState")?;
        let set_flags = driver::<CuSetFlags>(&library, "cuDevicePrimaryCtxSetFlags_v2")?;
        check("cuInit", init(0))?;
        let mut device = 0;
        check("cuDeviceGet", device_get(&mut device, ordinal))?;
        let (mut flags, mut active) = (0, 0);
        let state = get_state(device, &mut flags, &mut active);
        check("cuDevicePrimaryCtxGetState", state)?;
        let set = set_flags(device, wait.replace_in(flags));
        check("cuDevicePrimaryCtxSetFlags", set)?;
        let state = get_state(device, &mut flags, &mut active);
        check("cuDevicePrimaryCtxGetState", state)?;
        flags
    };
    std::mem::forget(library);
    Ok(flags)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_replace_only_the_scheduling_bits() {
        assert_eq!("block".parse(), Ok(CudaWait::Block));
        assert_eq!("spin".parse(), Ok(CudaWait::Spin));
        assert_eq!("yield".parse(), Ok(CudaWait::Yield));
        assert!("blocking"
            .parse::<CudaWait>()
            .unwrap_err()
            .contains("spin, yield or block"));
        // CU_CTX_LMEM_RESIZE_TO_MAX (0x10) stays; auto (0) or spin becomes block.
        assert_eq!(CudaWait::Block.replace_in(0x10), 0x14);
        assert_eq!(CudaWait::Block.replace_in(0x11), 0x14);
        assert_eq!(CudaWait::Yield.replace_in(0x04), 0x02);
    }

    #[test]
    fn blocking_waits_are_set_on_a_machine_with_a_gpu() {
        if !tch::Cuda::is_available() {
            return; // no driver or device here: nothing to set
        }
        let flags = apply(CudaWait::Block, 0).expect("the driver takes the flag");
        assert_eq!(flags & SCHED_MASK, 0x04, "flags after: {flags:#x}");
        // And back, so that other tests in this process see CUDA's choice.
        let flags = apply(CudaWait::Spin, 0).expect("the driver takes the flag");
        assert_eq!(flags & SCHED_MASK, 0x01, "flags after: {flags:#x}");
    }
}

//! Fuzzes what an actor does with the bytes of a weights message
//! (`actor::episode_loop`'s loader): the bundle's header metadata, the
//! policy's and the U-Net's tensors taken out of the bundle, and loading them
//! into the networks of a 64 px `ours` task. Any bytes must load or be
//! refused with an error, never a panic or an abort.
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use nets::policy::{PolicyLayout, PolicyNet};
use nets::unet::AffordanceUnet;
use nets::weights::{load_safetensors, metadata, unbundle};

fn layout() -> &'static PolicyLayout {
    static LAYOUT: OnceLock<PolicyLayout> = OnceLock::new();
    LAYOUT.get_or_init(|| {
        let task = proto::TaskSpec {
            image_size: 64,
            ..proto::TaskSpec::default()
        };
        task.layout()
    })
}

fuzz_target!(|data: &[u8]| {
    let _ = metadata(data);
    let device =
        nets::device::open_device(nets::device::DeviceChoice::Cpu).expect("the CPU device");
    if let Ok(bytes) = unbundle(data, proto::WEIGHTS_POLICY_PREFIX) {
        let mut net = PolicyNet::new(layout(), &device);
        let _ = load_safetensors(&mut net, bytes);
    }
    if let Ok(bytes) = unbundle(data, proto::WEIGHTS_UNET_PREFIX) {
        let mut unet = AffordanceUnet::new(4, 2, &device);
        let _ = load_safetensors(&mut unet, bytes);
    }
});

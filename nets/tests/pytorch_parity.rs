//! The PyTorch module (`nets/python/afx_torch.py`) loads a weights
//! file by name and computes what the Rust forward passes compute: the
//! U-Net's calibrated probabilities on one RGB-D frame (with unseen depth),
//! and the policy's log-probabilities, value and GRU state over three steps,
//! for a policy with and one without memory. The largest differences are
//! printed. Runs where PyTorch is installed (`AFX_TORCH_PYTHON` names the
//! Python, default `python3`); skipped with a message elsewhere, unless
//! `AFX_REQUIRE_TORCH` is set.

use std::path::Path;
use std::process::Command;

use burn::prelude::*;
use nets::policy::{CpuPolicy, ObsDtype, PolicyLayout, PolicyNet};
use nets::unet::AffordanceUnet;
use nets::unet_inference::UnetInference;
use nets::weights::{bundle, to_safetensors};
use serde_json::json;

const TEMPERATURE: f32 = 0.7;
const HEIGHT: usize = 32;
const WIDTH: usize = 48;

/// A deterministic pseudo-random stream in [0, 1).
struct Stream(u64);

impl Stream {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Writes the weights, the inputs and the Rust outputs into `dir`.
fn write_case(dir: &Path, layout: &PolicyLayout, seed: u64) {
    let device = Device::flex();
    device.seed(seed);
    let unet = AffordanceUnet::new(4, 2, &device);
    let policy = PolicyNet::new(layout, &device);
    let mut metadata = std::collections::HashMap::new();
    metadata.insert("unet_temperature".to_string(), TEMPERATURE.to_string());
    let unet_bytes = to_safetensors(&unet).unwrap();
    let policy_bytes = to_safetensors(&policy).unwrap();
    let weights = bundle(
        &[
            (proto::WEIGHTS_UNET_PREFIX, &unet_bytes),
            (proto::WEIGHTS_POLICY_PREFIX, &policy_bytes),
        ],
        metadata,
    )
    .unwrap();
    std::fs::write(dir.join("weights.safetensors"), weights).unwrap();

    // A frame: colour gradients with noise, depth 0.5–4 m with a block never seen.
    let mut stream = Stream(seed);
    let pixels = HEIGHT * WIDTH;
    let rgb: Vec<u8> = (0..pixels * 3)
        .map(|i| ((i * 7 % 256) as f32 * 0.5 + stream.next() * 127.0) as u8)
        .collect();
    let depth: Vec<f32> = (0..pixels)
        .map(|i| {
            let (y, x) = (i / WIDTH, i % WIDTH);
            if (4..10).contains(&y) && (30..40).contains(&x) {
                f32::NAN
            } else {
                0.5 + 3.5 * stream.next()
            }
        })
        .collect();
    // The actor's U-Net input: [r, g, b, depth] planes, colour in 0..1,
    // depth in metres, nothing seen as 0.
    let mut input = Vec::with_capacity(4 * pixels);
    for c in 0..3 {
        input.extend((0..pixels).map(|p| f32::from(rgb[p * 3 + c]) / 255.0));
    }
    input.extend(depth.iter().map(|&d| if d.is_finite() { d } else { 0.0 }));
    let logits = UnetInference::new(unet, &device).logits(&[&input], HEIGHT, WIDTH);
    let probabilities: Vec<f32> = logits[0]
        .iter()
        .map(|&l| 1.0 / (1.0 + (-l / TEMPERATURE).exp()))
        .collect();
    let spread = probabilities.iter().fold(0.0f32, |m, &p| m.max(p))
        - probabilities.iter().fold(1.0f32, |m, &p| m.min(p));
    assert!(spread > 1e-3, "the frame must give varied probabilities");

    let cpu = CpuPolicy::from_network(&policy, layout).expect("a policy the CPU pass computes");
    let mut hidden: Option<Vec<f32>> = None;
    let mut steps = Vec::new();
    for _ in 0..3 {
        let observation: Vec<f32> = (0..layout.obs_len()).map(|_| stream.next()).collect();
        let mask: Vec<u8> = (0..layout.n_actions)
            .map(|a| u8::from(a % 4 != 3))
            .collect();
        let step = cpu.forward(&observation, &mask, hidden.as_deref());
        steps.push(json!({
            "observation": observation,
            "mask": mask,
            "log_probs": step.log_probs,
            "value": step.value,
            "hidden": step.hidden,
        }));
        hidden = step.hidden;
    }
    let case = json!({
        "image_size": layout.image_size,
        "height": HEIGHT,
        "width": WIDTH,
        "rgb": rgb,
        "depth_m": depth.iter().map(|d| d.is_finite().then_some(*d)).collect::<Vec<_>>(),
        "probabilities": probabilities,
        "policy_steps": steps,
    });
    std::fs::write(dir.join("case.json"), case.to_string()).unwrap();
}

/// Runs the module's parity check on `dir`; `None` where PyTorch is missing
/// and not required.
fn torch_parity(dir: &Path) -> Option<serde_json::Value> {
    let required = std::env::var_os("AFX_REQUIRE_TORCH").is_some();
    let python = std::env::var("AFX_TORCH_PYTHON").unwrap_or_else(|_| "python3".into());
    let module = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/afx_torch.py");
    let output = match Command::new(&python)
        .arg(&module)
        .arg("--parity")
        .arg(dir)
        .output()
    {
        Ok(o) => o,
        Err(e) if !required => {
            eprintln!("skipping: {python} not runnable ({e})");
            return None;
        }
        Err(e) => panic!("{python} not runnable: {e}"),
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        if stderr.contains("ModuleNotFoundError") && !required {
            eprintln!(
                "skipping the PyTorch parity check: `pip install torch safetensors numpy` \
                 (or set AFX_TORCH_PYTHON to a Python that has them)"
            );
            return None;
        }
        panic!("the PyTorch module failed:\n{stderr}");
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    Some(serde_json::from_str(stdout.trim()).expect("the module prints JSON"))
}

fn check(name: &str, layout: PolicyLayout, seed: u64) {
    let dir = std::env::temp_dir().join(format!("nets-torch-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_case(&dir, &layout, seed);
    let Some(diff) = torch_parity(&dir) else {
        return;
    };
    eprintln!("{name}: largest differences, PyTorch against Rust: {diff}");
    for (field, tolerance) in [
        ("unet_probability", 1e-5),
        ("policy_log_prob", 1e-4),
        ("policy_value", 1e-5),
        ("policy_hidden", 1e-5),
    ] {
        let value = diff[field].as_f64().expect(field);
        assert!(value <= tolerance, "{name}: {field} differs by {value}");
    }
    assert!((diff["temperature"].as_f64().unwrap() - f64::from(TEMPERATURE)).abs() < 1e-6);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn pytorch_computes_what_the_rust_networks_compute() {
    check(
        "without-memory",
        PolicyLayout {
            image_channels: vec![6, 4],
            image_size: 64,
            vector_dims: vec![20, 1],
            n_actions: 12,
            obs_dtype: ObsDtype::F32,
            gru_hidden: None,
        },
        3,
    );
    check(
        "with-memory",
        PolicyLayout {
            image_channels: vec![6],
            image_size: 64,
            vector_dims: vec![20, 1],
            n_actions: 12,
            obs_dtype: ObsDtype::F32,
            gru_hidden: Some(32),
        },
        4,
    );
}

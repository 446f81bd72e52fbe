//! The weights file opens with Python's `safetensors` package, with the names
//! and shapes the networks have. Skipped with a message when Python or the
//! package is missing, unless `AFX_REQUIRE_PYTHON_CHECKS` is set (CI sets it).

use std::collections::BTreeMap;
use std::process::Command;

use burn::prelude::*;
use nets::policy::{ObsDtype, PolicyLayout, PolicyNet};
use nets::unet::AffordanceUnet;
use nets::weights::to_safetensors;

/// What Python saw per tensor: shape, dtype, sum of absolute values.
type Seen = BTreeMap<String, (Vec<usize>, String, f64)>;

const READER: &str = r#"
import json, sys
from safetensors.numpy import load_file
tensors = load_file(sys.argv[1])
print(json.dumps({name: [list(t.shape), str(t.dtype), float(abs(t).sum())] for name, t in tensors.items()}))
"#;

fn python_shapes(path: &std::path::Path) -> Option<Seen> {
    let required = std::env::var_os("AFX_REQUIRE_PYTHON_CHECKS").is_some();
    let output = match Command::new("python3")
        .arg("-c")
        .arg(READER)
        .arg(path)
        .output()
    {
        Ok(o) => o,
        Err(e) if !required => {
            eprintln!("skipping: python3 not runnable ({e})");
            return None;
        }
        Err(e) => panic!("python3 not runnable: {e}"),
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        if stderr.contains("ModuleNotFoundError") && !required {
            eprintln!("skipping: `pip install safetensors numpy` to run this check");
            return None;
        }
        panic!("Python's safetensors could not read the weights:\n{stderr}");
    }
    let parsed: Seen = parse(&String::from_utf8_lossy(&output.stdout));
    Some(parsed)
}

/// Parses the reader's JSON: `{name: [shape, dtype, abs-sum]}`.
fn parse(json: &str) -> Seen {
    let value: serde_json::Value = serde_json::from_str(json).expect("the reader prints JSON");
    value
        .as_object()
        .expect("an object")
        .iter()
        .map(|(name, v)| {
            let shape = v[0]
                .as_array()
                .expect("shape")
                .iter()
                .map(|d| d.as_u64().expect("dimension") as usize)
                .collect();
            let dtype = v[1].as_str().expect("dtype").to_string();
            (name.clone(), (shape, dtype, v[2].as_f64().expect("sum")))
        })
        .collect()
}

#[test]
fn python_safetensors_reads_policy_and_unet_weights() {
    let device = Device::flex();
    let policy = PolicyNet::new(
        &PolicyLayout {
            image_channels: vec![4],
            image_size: 128,
            vector_dims: vec![15],
            n_actions: 8,
            obs_dtype: ObsDtype::F32,
            gru_hidden: None,
        },
        &device,
    );
    let unet = AffordanceUnet::new(4, 2, &device);
    let dir = std::env::temp_dir().join(format!("nets-python-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (name, bytes) in [
        ("policy", to_safetensors(&policy).unwrap()),
        ("unet", to_safetensors(&unet).unwrap()),
    ] {
        let rust = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let path = dir.join(format!("{name}.safetensors"));
        std::fs::write(&path, &bytes).unwrap();
        let Some(python) = python_shapes(&path) else {
            return;
        };
        assert_eq!(python.len(), rust.len(), "{name}: tensor count");
        for (tensor_name, view) in rust.tensors() {
            let (shape, dtype, sum) = python
                .get(&tensor_name)
                .unwrap_or_else(|| panic!("{name}: Python lacks {tensor_name}"));
            assert_eq!(shape, view.shape(), "{name}: {tensor_name}");
            assert_eq!(dtype, "float32");
            let rust_sum: f64 = view
                .data()
                .chunks(4)
                .map(|c| f64::from(f32::from_le_bytes(c.try_into().unwrap()).abs()))
                .sum();
            assert!(
                (sum - rust_sum).abs() <= 1e-6 * rust_sum.max(1.0),
                "{name}: {tensor_name} values differ"
            );
        }
        eprintln!("{name}: Python read {} tensors", python.len());
    }
    std::fs::remove_dir_all(&dir).ok();
}

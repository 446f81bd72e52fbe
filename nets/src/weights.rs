//! Networks as safetensors bytes: for broadcasting weights to actors and for
//! checkpoints. Names follow the module tree the way a PyTorch `state_dict`
//! does (`actor.fc1.weight`, `images.0.conv1.bias`), and linear weights are
//! stored PyTorch's way round (`[out, in]`), so the files open in PyTorch.

use burn::module::Module;
use burn::store::{BurnToPyTorchAdapter, ModuleSnapshot, PyTorchToBurnAdapter, SafetensorsStore};
use safetensors::SafeTensors;

/// Why weights could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    /// Writing or parsing the safetensors bytes failed.
    #[error("safetensors: {0}")]
    Format(String),
    /// The bytes do not fit the network (missing tensors, other shapes).
    #[error(
        "the weights do not fit this network (were they made for another configuration?): {0}"
    )]
    Mismatch(String),
}

/// Puts several networks' safetensors bytes into one file, each tensor name
/// prefixed with its network's prefix (`policy.`, `unet.`), with `metadata`
/// in the file's header: the weights message and the checkpoint carry both
/// networks and the learner's side information in one blob.
pub fn bundle(
    parts: &[(&str, &[u8])],
    metadata: std::collections::HashMap<String, String>,
) -> Result<Vec<u8>, WeightsError> {
    let parsed = parts
        .iter()
        .map(|(prefix, bytes)| {
            SafeTensors::deserialize(bytes)
                .map(|t| (*prefix, t))
                .map_err(|e| WeightsError::Format(e.to_string()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut views = Vec::new();
    for (prefix, tensors) in &parsed {
        for (name, view) in tensors.iter() {
            views.push((format!("{prefix}{name}"), view));
        }
    }
    let metadata = (!metadata.is_empty()).then_some(metadata);
    safetensors::serialize(views, metadata).map_err(|e| WeightsError::Format(e.to_string()))
}

/// The header metadata of a safetensors file (empty if it has none).
pub fn metadata(bytes: &[u8]) -> Result<std::collections::HashMap<String, String>, WeightsError> {
    let (_, header) =
        SafeTensors::read_metadata(bytes).map_err(|e| WeightsError::Format(e.to_string()))?;
    Ok(header.metadata().clone().unwrap_or_default())
}

/// The tensors of `bytes` whose names start with `prefix`, prefix removed, as
/// a safetensors file of their own; an error if there are none.
pub fn unbundle(bytes: &[u8], prefix: &str) -> Result<Vec<u8>, WeightsError> {
    let tensors =
        SafeTensors::deserialize(bytes).map_err(|e| WeightsError::Format(e.to_string()))?;
    let views: Vec<_> = tensors
        .iter()
        .filter_map(|(name, view)| name.strip_prefix(prefix).map(|n| (n.to_string(), view)))
        .collect();
    if views.is_empty() {
        return Err(WeightsError::Mismatch(format!(
            "no tensor named {prefix}… in the weights"
        )));
    }
    safetensors::serialize(views, None).map_err(|e| WeightsError::Format(e.to_string()))
}

/// Serialises every parameter of `module`.
pub fn to_safetensors<M: Module + ModuleSnapshot>(module: &M) -> Result<Vec<u8>, WeightsError> {
    let mut store = SafetensorsStore::from_bytes(None).with_to_adapter(BurnToPyTorchAdapter);
    module
        .save_into(&mut store)
        .map_err(|e| WeightsError::Format(e.to_string()))?;
    store
        .get_bytes()
        .map_err(|e| WeightsError::Format(e.to_string()))
}

/// Loads `bytes` into `module`, which must have exactly the same parameters
/// and shapes; on any mismatch `module` is left unusable and an error says what differs.
pub fn load_safetensors<M: Module + ModuleSnapshot>(
    module: &mut M,
    bytes: Vec<u8>,
) -> Result<(), WeightsError> {
    let mut store = SafetensorsStore::from_bytes(Some(bytes))
        .with_from_adapter(PyTorchToBurnAdapter)
        .validate(true)
        .allow_partial(false);
    let result = module
        .load_from(&mut store)
        .map_err(|e| WeightsError::Mismatch(e.to_string()))?;
    if !result.is_success() || !result.missing.is_empty() || !result.unused.is_empty() {
        return Err(WeightsError::Mismatch(result.to_string()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::{ObsDtype, PolicyLayout, PolicyNet};
    use burn::prelude::*;

    fn config(n_actions: usize) -> PolicyLayout {
        PolicyLayout {
            image_channels: vec![3],
            image_size: 64,
            vector_dims: vec![7],
            n_actions,
            obs_dtype: ObsDtype::F32,
            gru_hidden: Some(16),
        }
    }

    /// Every parameter as raw f32 bits, in module order.
    fn parameters(module: &PolicyNet) -> Vec<Vec<u32>> {
        let bytes = to_safetensors(module).unwrap();
        let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let mut names: Vec<String> = tensors.names().into_iter().map(String::from).collect();
        names.sort();
        names
            .iter()
            .map(|n| {
                tensors
                    .tensor(n)
                    .unwrap()
                    .data()
                    .chunks(4)
                    .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
                    .collect()
            })
            .collect()
    }

    #[test]
    fn round_trip_is_bit_exact_with_pytorch_names() {
        let device = Device::flex();
        let a = PolicyNet::new(&config(5), &device);
        let bytes = to_safetensors(&a).unwrap();
        let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let names = tensors.names();
        assert!(names.contains(&"actor.fc1.weight"), "{names:?}");
        assert!(names.contains(&"images.0.conv1.weight"));
        // PyTorch's Linear stores [out, in].
        assert_eq!(tensors.tensor("actor.out.weight").unwrap().shape(), [5, 32]);

        let mut b = PolicyNet::new(&config(5), &device);
        assert_ne!(parameters(&a), parameters(&b));
        load_safetensors(&mut b, bytes).unwrap();
        assert_eq!(parameters(&a), parameters(&b));
    }

    #[test]
    fn bundled_networks_come_back_out_bit_exact() {
        let device = Device::flex();
        let a = PolicyNet::new(&config(5), &device);
        let b = crate::unet::AffordanceUnet::new(4, 2, &device);
        let (pa, pb) = (to_safetensors(&a).unwrap(), to_safetensors(&b).unwrap());
        let info = std::collections::HashMap::from([("env_steps".to_string(), "42".to_string())]);
        let both = bundle(&[("policy.", &pa), ("unet.", &pb)], info.clone()).unwrap();
        assert_eq!(metadata(&both).unwrap(), info);
        let names: Vec<String> = SafeTensors::deserialize(&both)
            .unwrap()
            .names()
            .into_iter()
            .map(String::from)
            .collect();
        assert!(names
            .iter()
            .all(|n| n.starts_with("policy.") || n.starts_with("unet.")));
        let mut a2 = PolicyNet::new(&config(5), &device);
        load_safetensors(&mut a2, unbundle(&both, "policy.").unwrap()).unwrap();
        assert_eq!(parameters(&a), parameters(&a2));
        let mut b2 = crate::unet::AffordanceUnet::new(4, 2, &device);
        load_safetensors(&mut b2, unbundle(&both, "unet.").unwrap()).unwrap();
        assert_eq!(
            to_safetensors(&b).unwrap().len(),
            to_safetensors(&b2).unwrap().len()
        );
        assert!(unbundle(&both, "critic.").is_err());
    }

    #[test]
    fn mismatched_shapes_are_refused_with_a_clear_error() {
        let device = Device::flex();
        let bytes = to_safetensors(&PolicyNet::new(&config(5), &device)).unwrap();
        let mut other = PolicyNet::new(&config(6), &device);
        let err = load_safetensors(&mut other, bytes).unwrap_err();
        assert!(matches!(err, WeightsError::Mismatch(_)), "{err}");
        assert!(err.to_string().contains("another configuration"), "{err}");
        let err = load_safetensors(&mut other, b"not safetensors".to_vec()).unwrap_err();
        assert!(!err.to_string().is_empty());
    }
}

//! Named f32 tensors to and from safetensors bytes, with shape checks.

use safetensors::{Dtype, SafeTensors};

/// Why weights could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum NetsError {
    /// The bytes are not a safetensors file.
    #[error("not a safetensors file: {0}")]
    Format(String),
    /// A tensor the network needs is absent.
    #[error("tensor {0:?} is missing from the weights")]
    Missing(String),
    /// A tensor has another shape or type than the network expects.
    #[error("tensor {name:?} has shape {got:?} ({dtype}), the network expects {expected:?} (F32): were the weights made for another configuration?")]
    Shape {
        /// Tensor name.
        name: String,
        /// Shape in the file.
        got: Vec<usize>,
        /// Shape the network needs.
        expected: Vec<usize>,
        /// Element type in the file.
        dtype: String,
    },
}

/// An ordered list of named f32 tensors (name, shape, values).
#[derive(Debug, Default, Clone, PartialEq)]
pub struct NamedTensors(pub Vec<(String, Vec<usize>, Vec<f32>)>);

impl NamedTensors {
    /// Serialises to safetensors bytes.
    pub fn to_safetensors(&self) -> Vec<u8> {
        let bytes: Vec<Vec<u8>> = self
            .0
            .iter()
            .map(|(_, _, v)| v.iter().flat_map(|x| x.to_le_bytes()).collect())
            .collect();
        let views = self.0.iter().zip(&bytes).map(|((name, shape, _), data)| {
            let view = safetensors::tensor::TensorView::new(Dtype::F32, shape.clone(), data)
                .expect("shape and data length agree by construction");
            (name.clone(), view)
        });
        safetensors::serialize(views, None).expect("serialising in-memory f32 tensors cannot fail")
    }

    /// Reads `name` from `file` as f32 values of exactly `shape`.
    pub fn read(
        file: &SafeTensors<'_>,
        name: &str,
        shape: &[usize],
    ) -> Result<Vec<f32>, NetsError> {
        let view = file
            .tensor(name)
            .map_err(|_| NetsError::Missing(name.to_string()))?;
        if view.dtype() != Dtype::F32 || view.shape() != shape {
            return Err(NetsError::Shape {
                name: name.to_string(),
                got: view.shape().to_vec(),
                expected: shape.to_vec(),
                dtype: format!("{:?}", view.dtype()),
            });
        }
        Ok(view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    }

    /// Parses safetensors bytes.
    pub fn parse(bytes: &[u8]) -> Result<SafeTensors<'_>, NetsError> {
        SafeTensors::deserialize(bytes).map_err(|e| NetsError::Format(e.to_string()))
    }
}

//! Saving and restoring an optimiser's state (Adam's moments and step
//! counts) with a checkpoint, so a resumed run continues the same
//! optimisation instead of restarting Adam from zero moments.
//!
//! burn keys optimiser state by `ParamId`, a random number drawn when a
//! network is built, so a network rebuilt from saved weights has new ids and
//! the saved state would match nothing. [`OptimizerState`] therefore stores,
//! next to burn's record, each parameter's module path and the id it had;
//! restoring gives the rebuilt network's parameters their saved ids (found by
//! path) and then loads the record.

use std::collections::BTreeMap;

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::optim::ModuleOptimizer;
use burn::prelude::Tensor;
use burn::tensor::Bytes;

/// Why an optimiser state could not be saved or restored.
#[derive(Debug, thiserror::Error)]
pub enum OptimizerStateError {
    /// burn could not encode or decode the record.
    #[error("optimiser record: {0}")]
    Record(String),
    /// The parameter list is not valid JSON of the expected shape.
    #[error("optimiser parameter list: {0}")]
    ParameterList(#[from] serde_json::Error),
    /// The saved state belongs to a network with other parameters.
    #[error(
        "the saved optimiser state does not fit this network: {missing} of its parameters are \
         missing here (first: {first_missing:?}) and {extra} here are not in it (first: \
         {first_extra:?})"
    )]
    Mismatch {
        /// Saved parameters the network lacks.
        missing: usize,
        /// The first of them.
        first_missing: Option<String>,
        /// Network parameters the saved state lacks.
        extra: usize,
        /// The first of them.
        first_extra: Option<String>,
    },
    /// Two parameters of the network share a module path.
    #[error("two parameters share the module path {0:?}")]
    DuplicatePath(String),
}

/// One parameter as the saved state knows it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SavedParameter {
    /// The id burn's record uses for it.
    pub id: u64,
    /// Its shape (a state for another shape must not be loaded).
    pub shape: Vec<usize>,
}

/// An optimiser's state in portable form: burn's record plus the module path
/// and shape of every parameter it refers to.
#[derive(Debug, Clone, PartialEq)]
pub struct OptimizerState {
    /// burn's optimiser record (burnpack bytes).
    pub record: Vec<u8>,
    /// Module path → the parameter.
    pub parameters: BTreeMap<String, SavedParameter>,
}

impl OptimizerState {
    /// Captures `optimizer`'s state for the parameters of `net`.
    pub fn capture<M: Module>(
        optimizer: &ModuleOptimizer,
        net: &M,
    ) -> Result<Self, OptimizerStateError> {
        let record = optimizer
            .into_bytes()
            .map_err(|e| OptimizerStateError::Record(e.to_string()))?;
        let parameters = parameters(net)?
            .into_iter()
            .map(|(path, (id, shape))| {
                (
                    path,
                    SavedParameter {
                        id: id.val(),
                        shape,
                    },
                )
            })
            .collect();
        Ok(Self {
            record: record.to_vec(),
            parameters,
        })
    }

    /// The parameter list as JSON (stored next to the record).
    pub fn parameter_list_json(&self) -> Vec<u8> {
        serde_json::to_vec_pretty(&self.parameters).expect("a map of plain records")
    }

    /// Reassembles a state from the two stored parts.
    pub fn from_parts(
        record: Vec<u8>,
        parameter_list_json: &[u8],
    ) -> Result<Self, OptimizerStateError> {
        Ok(Self {
            record,
            parameters: serde_json::from_slice(parameter_list_json)?,
        })
    }

    /// Gives `net`'s parameters the ids this state was saved with and returns
    /// `optimizer` (freshly built with the run's settings) loaded with the
    /// state. Fails, changing nothing, when the parameters differ.
    pub fn restore<M: Module>(
        &self,
        net: M,
        optimizer: ModuleOptimizer,
    ) -> Result<(M, ModuleOptimizer), OptimizerStateError> {
        let current = parameters(&net)?;
        let fits = |path: &String, saved: &SavedParameter| {
            current
                .get(path)
                .is_some_and(|(_, shape)| *shape == saved.shape)
        };
        let missing: Vec<&String> = self
            .parameters
            .iter()
            .filter(|(path, saved)| !fits(path, saved))
            .map(|(path, _)| path)
            .collect();
        let extra: Vec<&String> = current
            .keys()
            .filter(|p| !self.parameters.contains_key(*p))
            .collect();
        if !missing.is_empty() || !extra.is_empty() {
            return Err(OptimizerStateError::Mismatch {
                missing: missing.len(),
                first_missing: missing.first().map(|s| s.to_string()),
                extra: extra.len(),
                first_extra: extra.first().map(|s| s.to_string()),
            });
        }
        let optimizer = optimizer
            .from_bytes(Bytes::from_bytes_vec(self.record.clone()))
            .map_err(|e| OptimizerStateError::Record(e.to_string()))?;
        let mut renamer = IdAssigner {
            path: Vec::new(),
            saved: &self.parameters,
        };
        Ok((net.map(&mut renamer), optimizer))
    }
}

/// A parameter's id and shape.
type Parameter = (ParamId, Vec<usize>);

/// Module path (`encoder.conv1.weight`) → id and shape of every float parameter.
fn parameters<M: Module>(net: &M) -> Result<BTreeMap<String, Parameter>, OptimizerStateError> {
    let mut collector = ParameterCollector::default();
    net.visit(&mut collector);
    match collector.duplicate {
        Some(path) => Err(OptimizerStateError::DuplicatePath(path)),
        None => Ok(collector.parameters),
    }
}

#[derive(Default)]
struct ParameterCollector {
    path: Vec<String>,
    parameters: BTreeMap<String, Parameter>,
    duplicate: Option<String>,
}

impl ModuleVisitor for ParameterCollector {
    fn enter_module(&mut self, name: &str, _container_type: &str) {
        self.path.push(name.to_string());
    }

    fn exit_module(&mut self, _name: &str, _container_type: &str) {
        self.path.pop();
    }

    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let path = self.path.join(".");
        let shape = param.val().dims().to_vec();
        if self
            .parameters
            .insert(path.clone(), (param.id, shape))
            .is_some()
        {
            self.duplicate.get_or_insert(path);
        }
    }
}

struct IdAssigner<'a> {
    path: Vec<String>,
    saved: &'a BTreeMap<String, SavedParameter>,
}

impl ModuleMapper for IdAssigner<'_> {
    fn enter_module(&mut self, name: &str, _container_type: &str) {
        self.path.push(name.to_string());
    }

    fn exit_module(&mut self, _name: &str, _container_type: &str) {
        self.path.pop();
    }

    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some(saved) = self.saved.get(&self.path.join(".")) else {
            return param; // not reached: `restore` checked the paths first
        };
        let (_, value, mapper) = param.consume();
        Param::from_mapped_value(ParamId::from(saved.id), value, mapper)
    }
}

//! A linear actor-critic over flat observations.

use crate::tensors::{NamedTensors, NetsError};

/// `logits = W_a · obs + b_a`, `value = w_v · obs + b_v`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearActorCritic {
    /// Observation length.
    pub obs_dim: usize,
    /// Number of actions.
    pub n_actions: usize,
    /// All parameters, flat: `[W_a (n_actions × obs_dim), b_a, w_v (obs_dim), b_v]`.
    pub params: Vec<f32>,
}

impl LinearActorCritic {
    /// A network with all parameters zero: the uniform policy over allowed actions.
    pub fn zeros(obs_dim: usize, n_actions: usize) -> Self {
        let len = n_actions * obs_dim + n_actions + obs_dim + 1;
        Self {
            obs_dim,
            n_actions,
            params: vec![0.0; len],
        }
    }

    fn value_offset(&self) -> usize {
        self.n_actions * self.obs_dim + self.n_actions
    }

    /// Action logits for one observation: `[obs_dim] -> [n_actions]`.
    pub fn logits(&self, obs: &[f32]) -> Vec<f32> {
        let (w, rest) = self.params.split_at(self.n_actions * self.obs_dim);
        w.chunks_exact(self.obs_dim)
            .zip(&rest[..self.n_actions])
            .map(|(row, b)| row.iter().zip(obs).map(|(a, x)| a * x).sum::<f32>() + b)
            .collect()
    }

    /// Critic value for one observation: `[obs_dim] -> scalar`.
    pub fn value(&self, obs: &[f32]) -> f32 {
        let at = self.value_offset();
        let w = &self.params[at..at + self.obs_dim];
        w.iter().zip(obs).map(|(a, x)| a * x).sum::<f32>() + self.params[at + self.obs_dim]
    }

    /// Adds `scale · d(logits · g_logits + value · g_value)/dparams` for one
    /// observation into `grad` (same layout as `params`).
    pub fn accumulate_grad(
        &self,
        obs: &[f32],
        g_logits: &[f32],
        g_value: f32,
        scale: f32,
        grad: &mut [f32],
    ) {
        let d = self.obs_dim;
        let n = self.n_actions;
        for (a, &g) in g_logits.iter().enumerate() {
            let g = g * scale;
            for (dst, x) in grad[a * d..(a + 1) * d].iter_mut().zip(obs) {
                *dst += g * x;
            }
            grad[n * d + a] += g;
        }
        let at = self.value_offset();
        for (dst, x) in grad[at..at + d].iter_mut().zip(obs) {
            *dst += g_value * scale * x;
        }
        grad[at + d] += g_value * scale;
    }

    /// Named tensors, PyTorch `state_dict` style.
    pub fn to_tensors(&self) -> NamedTensors {
        let (d, n) = (self.obs_dim, self.n_actions);
        let p = &self.params;
        let at = self.value_offset();
        NamedTensors(vec![
            (
                "policy.actor.weight".into(),
                vec![n, d],
                p[..n * d].to_vec(),
            ),
            ("policy.actor.bias".into(), vec![n], p[n * d..at].to_vec()),
            (
                "policy.critic.weight".into(),
                vec![1, d],
                p[at..at + d].to_vec(),
            ),
            ("policy.critic.bias".into(), vec![1], p[at + d..].to_vec()),
        ])
    }

    /// Loads weights of the given shape from safetensors bytes, refusing any mismatch.
    pub fn from_safetensors(
        bytes: &[u8],
        obs_dim: usize,
        n_actions: usize,
    ) -> Result<Self, NetsError> {
        let file = NamedTensors::parse(bytes)?;
        let mut params = NamedTensors::read(&file, "policy.actor.weight", &[n_actions, obs_dim])?;
        params.extend(NamedTensors::read(
            &file,
            "policy.actor.bias",
            &[n_actions],
        )?);
        params.extend(NamedTensors::read(
            &file,
            "policy.critic.weight",
            &[1, obs_dim],
        )?);
        params.extend(NamedTensors::read(&file, "policy.critic.bias", &[1])?);
        Ok(Self {
            obs_dim,
            n_actions,
            params,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn safetensors_round_trip_is_bit_exact_and_shapes_are_checked() {
        let mut net = LinearActorCritic::zeros(3, 2);
        for (i, p) in net.params.iter_mut().enumerate() {
            *p = (i as f32).sin();
        }
        let bytes = net.to_tensors().to_safetensors();
        assert_eq!(
            LinearActorCritic::from_safetensors(&bytes, 3, 2).unwrap(),
            net
        );
        let err = LinearActorCritic::from_safetensors(&bytes, 4, 2).unwrap_err();
        assert!(err.to_string().contains("expects [2, 4]"), "{err}");
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let mut net = LinearActorCritic::zeros(3, 2);
        for (i, p) in net.params.iter_mut().enumerate() {
            *p = 0.1 * i as f32 - 0.3;
        }
        let obs = [0.5, -1.0, 2.0];
        let (g_logits, g_value) = ([0.7, -0.2], 1.3);
        let f = |n: &LinearActorCritic| {
            n.logits(&obs)
                .iter()
                .zip(g_logits)
                .map(|(l, g)| l * g)
                .sum::<f32>()
                + n.value(&obs) * g_value
        };
        let mut grad = vec![0.0; net.params.len()];
        net.accumulate_grad(&obs, &g_logits, g_value, 1.0, &mut grad);
        for (i, &analytic) in grad.iter().enumerate() {
            let mut plus = net.clone();
            plus.params[i] += 1e-2;
            let mut minus = net.clone();
            minus.params[i] -= 1e-2;
            let numeric = (f(&plus) - f(&minus)) / 2e-2;
            assert!(
                (numeric - analytic).abs() < 1e-3,
                "param {i}: {numeric} vs {analytic}"
            );
        }
    }
}

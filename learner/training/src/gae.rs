//! Generalised advantage estimation (Schulman et al., 2016).

/// Advantages and returns of one trajectory of `rewards.len()` steps.
///
/// `values[t]` is the critic's estimate at step `t`; `dones[t]` says the
/// episode ended with step `t` (nothing is bootstrapped across it);
/// `last_value` is the estimate for the state after the last step (ignored
/// if the last step ended an episode). Returns `(advantages, returns)` with
/// `returns = advantages + values`.
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    dones: &[bool],
    last_value: f32,
    gamma: f32,
    lambda: f32,
) -> (Vec<f32>, Vec<f32>) {
    let n = rewards.len();
    assert!(
        values.len() == n && dones.len() == n,
        "gae: rewards, values and dones must have one entry per step"
    );
    let mut advantages = vec![0.0; n];
    let mut running = 0.0;
    for t in (0..n).rev() {
        let next_value = if t + 1 < n { values[t + 1] } else { last_value };
        let not_done = if dones[t] { 0.0 } else { 1.0 };
        let delta = rewards[t] + gamma * next_value * not_done - values[t];
        running = delta + gamma * lambda * not_done * running;
        advantages[t] = running;
    }
    let returns = advantages.iter().zip(values).map(|(a, v)| a + v).collect();
    (advantages, returns)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_a_hand_computed_example() {
        // gamma 0.5, lambda 0.5, an episode ending at step 1, then one more step.
        let rewards = [1.0, 2.0, 4.0];
        let values = [0.5, 1.0, 2.0];
        let dones = [false, true, false];
        let (adv, ret) = gae(&rewards, &values, &dones, 8.0, 0.5, 0.5);
        // t=2: delta = 4 + 0.5*8 - 2 = 6;            A2 = 6
        // t=1: delta = 2 + 0 - 1 = 1 (episode ends);  A1 = 1
        // t=0: delta = 1 + 0.5*1 - 0.5 = 1;           A0 = 1 + 0.25*1 = 1.25
        assert_eq!(adv, vec![1.25, 1.0, 6.0]);
        assert_eq!(ret, vec![1.75, 2.0, 8.0]);
    }
}

//! A categorical distribution over logits with invalid actions masked out.

/// Log-probabilities of `logits` with `mask[i] == 0` actions set to −∞.
/// Returns all −∞ if nothing is allowed.
pub fn log_softmax_masked(logits: &[f32], mask: &[u8]) -> Vec<f32> {
    let max = logits
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m != 0)
        .map(|(&l, _)| l)
        .fold(f32::NEG_INFINITY, f32::max);
    let sum: f32 = logits
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m != 0)
        .map(|(&l, _)| (l - max).exp())
        .sum();
    let log_z = max + sum.ln();
    logits
        .iter()
        .zip(mask)
        .map(|(&l, &m)| if m != 0 { l - log_z } else { f32::NEG_INFINITY })
        .collect()
}

/// Samples an allowed action by inverse CDF with `uniform` in [0, 1).
/// Returns the action and its log-probability, or `None` if nothing is allowed.
pub fn sample(log_probs: &[f32], uniform: f32) -> Option<(u32, f32)> {
    let mut cumulative = 0.0f32;
    let mut last_allowed = None;
    for (i, &lp) in log_probs.iter().enumerate() {
        if lp == f32::NEG_INFINITY {
            continue;
        }
        last_allowed = Some((i as u32, lp));
        cumulative += lp.exp();
        if uniform < cumulative {
            return last_allowed;
        }
    }
    // Rounding can leave the cumulative sum just below 1.
    last_allowed
}

/// Entropy (nats) of the masked distribution.
pub fn entropy(log_probs: &[f32]) -> f32 {
    log_probs
        .iter()
        .filter(|lp| lp.is_finite())
        .map(|&lp| -lp.exp() * lp)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masked_actions_get_no_mass_and_are_never_sampled() {
        let lp = log_softmax_masked(&[5.0, 0.0, 0.0, 9.0], &[0, 1, 1, 0]);
        assert_eq!(lp[0], f32::NEG_INFINITY);
        assert_eq!(lp[3], f32::NEG_INFINITY);
        assert!((lp[1] - 0.5f32.ln()).abs() < 1e-6);
        for i in 0..1000 {
            let (a, _) = sample(&lp, i as f32 / 1000.0).unwrap();
            assert!(a == 1 || a == 2);
        }
        assert!((entropy(&lp) - 2.0f32.ln()).abs() < 1e-6);
        assert!(sample(&log_softmax_masked(&[1.0], &[0]), 0.5).is_none());
    }
}

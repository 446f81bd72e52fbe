//! Sampling from a categorical distribution with invalid actions masked out.

/// Samples an allowed action by inverse CDF with `uniform` in [0, 1), from
/// log-probabilities where masked actions hold −∞. Returns the action and
/// its log-probability, or `None` if nothing is allowed.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masked_actions_are_never_sampled_and_mass_follows_probability() {
        let half = 0.5f32.ln();
        let lp = [f32::NEG_INFINITY, half, half, f32::NEG_INFINITY];
        let mut counts = [0; 4];
        for i in 0..1000 {
            let (a, l) = sample(&lp, i as f32 / 1000.0).unwrap();
            assert_eq!(l, half);
            counts[a as usize] += 1;
        }
        assert_eq!(counts, [0, 500, 500, 0]);
        assert!(sample(&[f32::NEG_INFINITY], 0.5).is_none());
        // Just below 1 after rounding: still an allowed action.
        assert_eq!(sample(&lp, 0.999_999_9).map(|(a, _)| a), Some(2));
    }
}

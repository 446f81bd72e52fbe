//! Temperature scaling (Guo et al., 2017): one scalar `T` that divides the
//! logits so that sigmoid probabilities are calibrated on held-out data. The
//! paper suggests it for annotation by confidence, which thresholds
//! probabilities at 0.9 / 0.1 and so needs them to mean what they say.

/// Mean negative log-likelihood of `labels` under `sigmoid(logit / t)`.
pub fn nll(logits: &[f32], labels: &[bool], t: f64) -> f64 {
    weighted_nll(logits, labels, &[], t)
}

/// [`nll`] with each sample weighted by `weights` (empty: all 1), divided
/// by the weights' sum.
pub fn weighted_nll(logits: &[f32], labels: &[bool], weights: &[f32], t: f64) -> f64 {
    let weight = |i: usize| weights.get(i).map_or(1.0, |&w| f64::from(w));
    let total: f64 = (0..logits.len()).map(weight).sum();
    logits
        .iter()
        .zip(labels)
        .enumerate()
        .map(|(i, (&x, &y))| {
            let z = f64::from(x) / t;
            // −log σ(z) = softplus(−z); −log(1 − σ(z)) = softplus(z).
            let softplus = |v: f64| v.max(0.0) + (-v.abs()).exp().ln_1p();
            weight(i) * if y { softplus(-z) } else { softplus(z) }
        })
        .sum::<f64>()
        / total.max(f64::MIN_POSITIVE)
}

/// The temperature in [0.05, 20] minimising [`nll`], by golden-section search
/// on log T (the NLL is unimodal in it). Returns 1 when there is no data.
pub fn fit_temperature(logits: &[f32], labels: &[bool]) -> f32 {
    fit_weighted_temperature(logits, labels, &[])
}

/// [`fit_temperature`] minimising [`weighted_nll`]: with weights that make
/// each class weigh half, the temperature keeps the odds of a network
/// trained with balanced classes (`nets::unet::ClassBalance::Classes`).
pub fn fit_weighted_temperature(logits: &[f32], labels: &[bool], weights: &[f32]) -> f32 {
    if logits.is_empty() {
        return 1.0;
    }
    let f = |log_t: f64| weighted_nll(logits, labels, weights, log_t.exp());
    let (mut lo, mut hi) = (0.05f64.ln(), 20f64.ln());
    let golden = (5f64.sqrt() - 1.0) / 2.0;
    let mut a = hi - golden * (hi - lo);
    let mut b = lo + golden * (hi - lo);
    let (mut fa, mut fb) = (f(a), f(b));
    for _ in 0..80 {
        if fa < fb {
            hi = b;
            b = a;
            fb = fa;
            a = hi - golden * (hi - lo);
            fa = f(a);
        } else {
            lo = a;
            a = b;
            fa = fb;
            b = lo + golden * (hi - lo);
            fb = f(b);
        }
    }
    ((lo + hi) / 2.0).exp() as f32
}

/// Calibrated probability of a logit.
pub fn calibrated(logit: f32, temperature: f32) -> f32 {
    1.0 / (1.0 + (-logit / temperature).exp())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    #[test]
    fn a_weight_of_two_counts_as_a_sample_twice() {
        let mut rng = StdRng::seed_from_u64(3);
        let logits: Vec<f32> = (0..2_000).map(|_| rng.random_range(-6.0..6.0)).collect();
        let labels: Vec<bool> = logits
            .iter()
            .map(|&x| rng.random::<f32>() < calibrated(x, if x > 0.0 { 3.0 } else { 1.0 }))
            .collect();
        // The positive-logit half twice over, and once with weight 2.
        let twice: Vec<usize> = (0..logits.len())
            .chain((0..logits.len()).filter(|&i| logits[i] > 0.0))
            .collect();
        let duplicated = fit_temperature(
            &twice.iter().map(|&i| logits[i]).collect::<Vec<_>>(),
            &twice.iter().map(|&i| labels[i]).collect::<Vec<_>>(),
        );
        let weights: Vec<f32> = logits
            .iter()
            .map(|&x| if x > 0.0 { 2.0 } else { 1.0 })
            .collect();
        let weighted = fit_weighted_temperature(&logits, &labels, &weights);
        assert!(
            (duplicated - weighted).abs() < 1e-3,
            "{duplicated} vs {weighted}"
        );
        let plain = fit_temperature(&logits, &labels);
        assert!(
            (plain - weighted).abs() > 0.05,
            "the weights matter: {plain} vs {weighted}"
        );
    }

    #[test]
    fn recovers_the_temperature_of_overconfident_logits() {
        // Labels drawn from sigmoid(x / 2.5): logits x are 2.5× overconfident.
        let mut rng = StdRng::seed_from_u64(9);
        let logits: Vec<f32> = (0..40_000).map(|_| rng.random_range(-8.0..8.0)).collect();
        let labels: Vec<bool> = logits
            .iter()
            .map(|&x| rng.random::<f32>() < calibrated(x, 2.5))
            .collect();
        let t = fit_temperature(&logits, &labels);
        assert!((t - 2.5).abs() < 0.1, "fitted {t}");
        assert!(nll(&logits, &labels, f64::from(t)) < nll(&logits, &labels, 1.0));
        assert_eq!(fit_temperature(&[], &[]), 1.0);
    }
}

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
        .map(|(i, (&x, &y))| weight(i) * label_nll(f64::from(x) / t, y))
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
///
/// The search evaluates the NLL about 80 times; a gate's frames at 128 px
/// hold ~2 M labelled pixels, so each evaluation runs over the logits binned
/// by label (in narrow bins of logits) rather than over every pixel.
pub fn fit_weighted_temperature(logits: &[f32], labels: &[bool], weights: &[f32]) -> f32 {
    if logits.is_empty() {
        return 1.0;
    }
    let binned = BinnedLogits::new(logits, labels, weights);
    golden_section_on_log_t(|t| binned.nll(t))
}

/// [`fit_weighted_temperature`] over every logit (each step of the search
/// a pass over all of them): the reference the binned fit is tested and
/// benchmarked against.
pub fn fit_weighted_temperature_exact(logits: &[f32], labels: &[bool], weights: &[f32]) -> f32 {
    if logits.is_empty() {
        return 1.0;
    }
    golden_section_on_log_t(|t| weighted_nll(logits, labels, weights, t))
}

/// The temperature in [0.05, 20] minimising `nll(t)`, by golden-section
/// search on log T (the NLL is unimodal in it).
fn golden_section_on_log_t(nll: impl Fn(f64) -> f64) -> f32 {
    let f = |log_t: f64| nll(log_t.exp());
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

/// −log σ(z) for a positive label, −log(1 − σ(z)) for a negative one.
fn label_nll(z: f64, positive: bool) -> f64 {
    // −log σ(z) = softplus(−z); −log(1 − σ(z)) = softplus(z).
    let softplus = |v: f64| v.max(0.0) + (-v.abs()).exp().ln_1p();
    if positive {
        softplus(-z)
    } else {
        softplus(z)
    }
}

/// Width of a bin of [`BinnedLogits`], in logits.
const BIN_WIDTH: f64 = 1.0 / 64.0;
/// Logits within ± this are binned; the rarer ones beyond are kept as they are.
const BINNED_RANGE: f64 = 32.0;

/// Logits summarised per label in narrow bins: each bin's summed weight and
/// the weighted mean of its logits, which stands for them in the NLL. The NLL
/// of a logit is smooth, so the error is second order in the spread within
/// a bin: a few parts in a million of the NLL on the test's gate-like
/// logits, at temperatures from 0.05 to 20 (tested against [`weighted_nll`]).
struct BinnedLogits {
    /// (logit, positive, weight) of each non-empty bin (its weighted mean
    /// logit) and of each logit beyond ±[`BINNED_RANGE`], kept as it is.
    points: Vec<(f64, bool, f64)>,
    total_weight: f64,
}

impl BinnedLogits {
    fn new(logits: &[f32], labels: &[bool], weights: &[f32]) -> Self {
        let n_bins = (2.0 * BINNED_RANGE / BIN_WIDTH) as usize;
        // Per label (negative, positive): (weight, weight × logit) per bin.
        let mut bins = [vec![(0.0, 0.0); n_bins], vec![(0.0, 0.0); n_bins]];
        let mut points = Vec::new();
        let mut total_weight = 0.0;
        for (i, (&x, &y)) in logits.iter().zip(labels).enumerate() {
            let (x, w) = (f64::from(x), weights.get(i).map_or(1.0, |&w| f64::from(w)));
            total_weight += w;
            if x.abs() < BINNED_RANGE {
                let bin = (((x + BINNED_RANGE) / BIN_WIDTH) as usize).min(n_bins - 1);
                let slot = &mut bins[usize::from(y)][bin];
                slot.0 += w;
                slot.1 += w * x;
            } else {
                points.push((x, y, w));
            }
        }
        for (label, bins) in bins.iter().enumerate() {
            let filled = bins.iter().filter(|(w, _)| *w > 0.0);
            points.extend(filled.map(|&(w, wx)| (wx / w, label == 1, w)));
        }
        Self {
            points,
            total_weight,
        }
    }

    /// [`weighted_nll`] at temperature `t`, over the bins.
    fn nll(&self, t: f64) -> f64 {
        let sum: f64 = (self.points.iter())
            .map(|&(x, y, w)| w * label_nll(x / t, y))
            .sum();
        sum / self.total_weight.max(f64::MIN_POSITIVE)
    }
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

    #[test]
    fn binned_logits_give_the_nll_and_the_temperature_of_every_pixel() {
        // Logits of a gate's shape: most pixels confident negatives, a few
        // positives, some far beyond the binned range, weights per class.
        let mut rng = StdRng::seed_from_u64(21);
        let logits: Vec<f32> = (0..200_000)
            .map(|i| match i % 100 {
                0 => rng.random_range(-80.0..80.0),
                1..=9 => rng.random_range(-4.0..12.0),
                _ => rng.random_range(-15.0..3.0),
            })
            .collect();
        let labels: Vec<bool> = logits
            .iter()
            .map(|&x| rng.random::<f32>() < calibrated(x, 1.7))
            .collect();
        let positives = labels.iter().filter(|&&y| y).count() as f32;
        let negatives = labels.len() as f32 - positives;
        let weights: Vec<f32> = labels
            .iter()
            .map(|&y| if y { 0.5 / positives } else { 0.5 / negatives })
            .collect();
        let binned = BinnedLogits::new(&logits, &labels, &weights);
        for t in [0.05, 0.3, 1.0, 1.7, 5.0, 20.0] {
            let exact = weighted_nll(&logits, &labels, &weights, t);
            let approx = binned.nll(t);
            assert!(
                (exact - approx).abs() <= 1e-4 * exact,
                "t = {t}: exact {exact}, binned {approx}"
            );
        }
        let exact_fit = fit_weighted_temperature_exact(&logits, &labels, &weights);
        let fit = fit_weighted_temperature(&logits, &labels, &weights);
        assert!(
            (fit - exact_fit).abs() < 1e-3 * exact_fit,
            "{fit} vs {exact_fit}"
        );
    }
}

//! `cargo bench -p nets --bench cpu_policy`: the actor's CPU pass of the
//! policy (`nets::policy::CpuPolicy::forward`) for one observation of the
//! default `ours` task at 64 and 128 px, as an actor's environment thread
//! runs it every step. Medians of 200 passes after 20 unmeasured ones;
//! `AFX_SIDES=128` limits the sides, `AFX_SHARES=0.01,0.1` the sweep below.
//!
//! A second table sweeps the share of nonzero values in every image plane
//! (0 / 1 masks, as most of the state's planes are) and times the pass
//! with every plane added pixel by pixel against every plane through the
//! first layers' GEMMs, alternated: where the two cross is where
//! `nets::policy::SPARSE_PLANES_BELOW` belongs.

use std::time::Instant;

use nets::policy::{CpuPolicy, PolicyNet};

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return; // `cargo test --benches` asks benches to list themselves
    }
    let device = nets::device::open_device(nets::device::DeviceChoice::Cpu)
        .expect("the CPU device always opens");
    let sides: Vec<usize> = std::env::var("AFX_SIDES").map_or(vec![64, 128], |s| {
        s.split(',')
            .map(|v| v.trim().parse().expect("AFX_SIDES: sides like 64,128"))
            .collect()
    });
    println!("| side | image channels | CPU pass, median | 10th / 90th percentile |");
    println!("|---|---|---|---|");
    let shares: Vec<f64> =
        std::env::var("AFX_SHARES").map_or(vec![0.01, 0.05, 0.1, 0.2, 0.3, 0.5], |s| {
            s.split(',')
                .map(|v| v.trim().parse().expect("AFX_SHARES: shares like 0.01,0.1"))
                .collect()
        });
    let mut sweeps = Vec::new();
    for side in sides {
        let layout = proto::TaskSpec {
            image_size: side,
            ..proto::TaskSpec::default()
        }
        .layout();
        let policy = CpuPolicy::from_network(&PolicyNet::new(&layout, &device), &layout)
            .expect("the default task's policy has the CPU pass");
        let observation: Vec<f32> = (0..layout.obs_len())
            .map(|i| (i % 13) as f32 / 13.0)
            .collect();
        let mask = vec![1u8; layout.n_actions];
        let times = pass_times(&[&policy], &observation, &mask, 200).remove(0);
        println!(
            "| {side} | {:?} | {:.3} ms | {:.3} / {:.3} ms |",
            layout.image_channels,
            times.at(0.5),
            times.at(0.1),
            times.at(0.9)
        );
        sweeps.push((side, policy, layout));
    }
    println!();
    println!("| side | share of nonzero values in every image plane | pixel by pixel | through the GEMMs | ratio |");
    println!("|---|---|---|---|---|");
    for (side, policy, layout) in sweeps {
        let pixels = policy.clone().with_sparse_planes_below(f32::INFINITY);
        let gemms = policy.with_sparse_planes_below(0.0);
        let image_values: usize = layout.image_channels.iter().sum::<usize>() * side * side;
        for &share in &shares {
            // A fixed pseudo-random pick of pixels, the vectors left dense.
            let observation: Vec<u8> = (0..layout.obs_len())
                .map(|i| {
                    let h = (i as u64).wrapping_mul(2_654_435_761) % 10_000;
                    u8::from(i >= image_values || (h as f64) < share * 10_000.0) * 255
                })
                .collect();
            let mask = vec![1u8; layout.n_actions];
            let [pixels, gemms] = pass_times(&[&pixels, &gemms], &observation, &mask, 100)
                .try_into()
                .expect("two policies, two times");
            println!(
                "| {side} | {share} | {:.3} ms | {:.3} ms | {:.2} |",
                pixels.at(0.5),
                gemms.at(0.5),
                pixels.at(0.5) / gemms.at(0.5)
            );
        }
    }
}

/// Sorted pass times, milliseconds.
#[derive(Debug)]
struct Times(Vec<f64>);

impl Times {
    /// The `q`-quantile.
    fn at(&self, q: f64) -> f64 {
        self.0[((self.0.len() - 1) as f64 * q) as usize]
    }
}

/// `repeats` timed passes of each policy, alternated, after 20 unmeasured rounds.
fn pass_times<T: nets::policy::ObservationValue>(
    policies: &[&CpuPolicy],
    observation: &[T],
    mask: &[u8],
    repeats: usize,
) -> Vec<Times> {
    let mut times = vec![Vec::with_capacity(repeats); policies.len()];
    for round in 0..repeats + 20 {
        for (policy, times) in policies.iter().zip(&mut times) {
            let started = Instant::now();
            std::hint::black_box(policy.forward(observation, mask, None));
            if round >= 20 {
                times.push(started.elapsed().as_secs_f64() * 1e3);
            }
        }
    }
    times
        .into_iter()
        .map(|mut t| {
            t.sort_by(f64::total_cmp);
            Times(t)
        })
        .collect()
}

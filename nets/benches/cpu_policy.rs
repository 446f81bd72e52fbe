//! `cargo bench -p nets --bench cpu_policy`: the actor's CPU pass of the
//! policy (`nets::policy::CpuPolicy::forward`) for one observation of the
//! default `ours` task at 64 and 128 px, as an actor's environment thread
//! runs it every step. Medians of 200 passes after 20 unmeasured ones;
//! `AFX_SIDES=128` limits the sides.

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
        let mut times: Vec<f64> = (0..220)
            .map(|_| {
                let started = Instant::now();
                std::hint::black_box(policy.forward(&observation, &mask, None));
                started.elapsed().as_secs_f64() * 1e3
            })
            .skip(20)
            .collect();
        times.sort_by(f64::total_cmp);
        let at = |q: f64| times[((times.len() - 1) as f64 * q) as usize];
        println!(
            "| {side} | {:?} | {:.3} ms | {:.3} / {:.3} ms |",
            layout.image_channels,
            at(0.5),
            at(0.1),
            at(0.9)
        );
    }
}

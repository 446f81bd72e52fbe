#!/usr/bin/env python3
"""The learning core's networks in PyTorch, timed like `cargo bench -p training`.

Same architectures as `nets` (policy: three conv encoders 8x8/4,
4x4/2, 3x3/2 + linear 64, MLPs for 1-D inputs, tanh heads (64, 32, out);
U-Net: levels (24, 48, 92, 164), double 3x3 convs, max-pool, transposed
convs), the same batch sizes and the same PPO update (4 epochs x 2
minibatches, clipped losses, Adam, global grad-norm clipping). Prints one
`name: median X ms [p10 L, p90 H] of N` line per measurement (a warm-up call
first; the spread is the extremes for fewer than ten repeats), on CPU unless
--device says otherwise.

Usage: python3 learner/training/benches/torch_reference.py [--envs 8] [--repeats 5] [--device cpu]
       python3 learner/training/benches/torch_reference.py --gpu-check --ppo-steps 1024 \
           --image-channels 10,8,8 --vector-dims 160,1 --actions 30 --device cuda
(--gpu-check: only the learner's training shapes, PPO at 64 and 128 px and the U-Net step, as
`AFX_BENCH_ONLY=gpu-check cargo bench -p training` runs them and passes the task's shapes.)
Needs `pip install torch` (CPU wheels: https://download.pytorch.org/whl/cpu).
"""

import argparse
import sys
import time
from pathlib import Path

try:
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
except ImportError as e:
    sys.exit(f"needs torch (pip install torch): {e}")


# The networks themselves come from the project's PyTorch module, which loads
# the Rust networks' weights by name (and is checked against them).
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "nets" / "python"))
from afx_torch import AffordanceUnet as Unet  # noqa: E402
from afx_torch import PolicyNet  # noqa: E402


def Policy(image_channels=(4, 4, 2), vector_dims=(50, 1), n_actions=8, size=128):
    """The policy without memory for these inputs (see `afx_torch.PolicyNet`)."""
    return PolicyNet({"image_channels": list(image_channels), "image_size": size,
                      "vector_dims": list(vector_dims), "n_actions": n_actions,
                      "gru_hidden": None})


def masked_bce_dice(logits, labels, known):
    """`nets::unet::masked_bce_dice`, operation for operation's worth: per affordance plane the
    BCE over its labelled pixels plus Dice where the batch has positives, summed over the planes
    that have labels and divided by their count (the same value as the Rust loss to float
    rounding, checked on a batch with a plane without positives: 1.5805372 against 1.5805376)."""
    dims = (0, 2, 3)
    labelled = known.sum(dims)
    bce = (F.binary_cross_entropy_with_logits(logits, labels, reduction="none") * known).sum(dims)
    bce = bce / labelled.clamp_min(1.0)
    p = torch.sigmoid(logits) * known
    y = labels * known
    positives = y.sum(dims)
    dice = (2 * (p * y).sum(dims) + 1) / (p.sum(dims) + positives + 1)
    dice_loss = (1 - dice) * (positives > 0).float()
    planes = (labelled > 0).float().sum().clamp_min(1.0)
    return (bce + dice_loss).sum() / planes


def timed(repeats, f):
    """Milliseconds of `repeats` calls of `f` after a warm-up call, sorted."""
    f()
    out = []
    for _ in range(max(repeats, 1)):
        t = time.perf_counter()
        f()
        out.append((time.perf_counter() - t) * 1e3)
    return sorted(out)


def quantile(samples, q):
    return samples[round(q * (len(samples) - 1))]


def ppo_update_fn(policy, rows, image_channels, vector_dims, n_actions, size, dev, sync):
    """One PPO update (4 epochs x 2 minibatches) on `rows` random steps, as a closure."""
    images = [torch.rand(rows, c, size, size, device=dev) for c in image_channels]
    vectors = [torch.rand(rows, d, device=dev) for d in vector_dims]
    mask = torch.ones(rows, n_actions, dtype=torch.bool, device=dev)
    actions = torch.randint(0, n_actions, (rows,), device=dev)
    old_lp = torch.full((rows,), -float(torch.log(torch.tensor(float(n_actions)))), device=dev)
    old_v, returns = torch.rand(rows, device=dev), torch.rand(rows, device=dev)
    adv_all = torch.rand(rows, device=dev) - 0.5
    popt = torch.optim.Adam(policy.parameters(), lr=2e-4, eps=1e-5)

    def ppo_update():
        for _ in range(4):
            order = torch.randperm(rows, device=dev)
            for idx in order.chunk(2):
                lp, v, _ = policy([t[idx] for t in images], [t[idx] for t in vectors], mask[idx])
                new = lp.gather(1, actions[idx, None]).squeeze(1)
                ratio = (new - old_lp[idx]).exp()
                adv = adv_all[idx]
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                pg = torch.max(-adv * ratio, -adv * ratio.clamp(0.8, 1.2)).mean()
                vc = old_v[idx] + (v - old_v[idx]).clamp(-0.2, 0.2)
                vl = 0.5 * torch.max((v - returns[idx]) ** 2, (vc - returns[idx]) ** 2).mean()
                ent = -(lp.exp() * lp).sum(1).mean()
                loss = pg - 0.01 * ent + 0.5 * vl
                popt.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
                popt.step()
        sync()

    return ppo_update


def ints(text):
    return tuple(int(x) for x in text.split(","))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--gpu-check", action="store_true",
                        help="only the learner's training shapes: PPO at 64 and 128 px, U-Net step")
    parser.add_argument("--ppo-steps", type=int, default=1024)
    parser.add_argument("--image-channels", type=ints, default=(4, 4, 2))
    parser.add_argument("--vector-dims", type=ints, default=(50, 1))
    parser.add_argument("--actions", type=int, default=8)
    args = parser.parse_args()
    dev = torch.device(args.device)
    sync = (lambda: torch.cuda.synchronize()) if dev.type == "cuda" else (lambda: None)
    torch.manual_seed(1)
    results = {}

    if args.gpu_check:
        for size in (64, 128):
            policy = Policy(args.image_channels, args.vector_dims, args.actions, size).to(dev)
            update = ppo_update_fn(policy, args.ppo_steps, args.image_channels, args.vector_dims,
                                   args.actions, size, dev, sync)
            results[f"ppo_update_{args.ppo_steps}_{size}px_ms"] = timed(args.repeats, update)

    unet = Unet().to(dev)
    opt = torch.optim.Adam(unet.parameters(), lr=1e-3, weight_decay=1e-4)
    x = torch.rand(8, 4, 128, 128, device=dev)
    raw = torch.randint(0, 3, (8, 2, 128, 128), device=dev)
    labels, known = (raw == 1).float(), (raw != 2).float()

    def unet_step():
        opt.zero_grad()
        masked_bce_dice(unet(x), labels, known).backward()
        opt.step()
        sync()

    results["unet_train_step_batch8_ms"] = timed(max(args.repeats, 5), unet_step)
    if args.gpu_check:
        report(results, dev)
        return
    one = x[:1]

    def unet_infer():
        with torch.no_grad():
            unet(one).cpu()

    results["unet_inference_1frame_ms"] = timed(max(args.repeats, 5), unet_infer)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    results["unet_inference_1frame_1thread_ms"] = timed(max(args.repeats, 5), unet_infer)
    torch.set_num_threads(threads)

    policy = Policy().to(dev)

    def inputs(rows):
        images = [torch.rand(rows, c, 128, 128, device=dev) for c in (4, 4, 2)]
        vectors = [torch.rand(rows, d, device=dev) for d in (50, 1)]
        return images, vectors, torch.ones(rows, 8, dtype=torch.bool, device=dev)

    step = inputs(1)

    def policy_infer():
        with torch.no_grad():
            policy(*step)[0].cpu()

    results["policy_inference_1step_ms"] = timed(max(args.repeats, 5), policy_infer)

    rows = args.envs * 600
    ppo_update = ppo_update_fn(policy, rows, (4, 4, 2), (50, 1), 8, 128, dev, sync)

    name = f"ppo_update_{args.envs}x600_ms"
    results[name] = timed(1, ppo_update)  # one warm-up, one timed: an update takes minutes on a CPU

    report(results, dev)


def report(results, dev):
    print(f"pytorch {torch.__version__} ({dev}, {torch.get_num_threads()} threads):")
    for k, v in results.items():
        print(
            f"  {k}: median {quantile(v, 0.5):.1f} ms "
            f"[p10 {quantile(v, 0.1):.1f}, p90 {quantile(v, 0.9):.1f}] of {len(v)}"
        )


if __name__ == "__main__":
    main()

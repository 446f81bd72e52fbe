#!/usr/bin/env python3
"""The affordance U-Net's inference in PyTorch, timed like `cargo bench -p nets --bench unet_inference`.

One call per batch: the images' floats copied to the device, the forward pass
without gradients, the logits copied back (as the actor's U-Net batching thread
does), at 128 px for batches of 1, 2, 4, 8 and 16, in full precision and in
half precision with channels-last tensors, each with cuDNN's benchmark mode off
and on. Medians of 30 calls after 5 unmeasured ones. Prints a Markdown table.

Usage: python3 learner/training/benches/torch_unet_inference.py [--device cuda] [--side 128] [--quick]
(--quick: full precision with benchmark mode off only, what the actors run.)
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

try:
    import torch
except ImportError as e:
    sys.exit(f"needs torch (pip install torch): {e}")

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "nets" / "python"))
from afx_torch import AffordanceUnet  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--side", type=int, default=128)
    parser.add_argument("--batches", default="1,2,4,8,16")
    parser.add_argument("--quick", action="store_true",
                        help="full precision, cuDNN benchmark mode off only")
    args = parser.parse_args()
    dev = torch.device(args.device)
    batches = [int(b) for b in args.batches.split(",")]
    print(f"PyTorch {torch.__version__} U-Net inference, {args.side} px, {dev}")
    print("| precision | cuDNN benchmark | images | call, median | per image |")
    print("|---|---|---|---|---|")
    for half in (False,) if args.quick else (False, True):
        for benchmark in (False,) if args.quick else (False, True):
            torch.backends.cudnn.benchmark = benchmark
            net = AffordanceUnet(4, 2).to(dev).eval()
            if half:
                net = net.half().to(memory_format=torch.channels_last)
            for n in batches:
                images = torch.rand(n, 4, args.side, args.side).numpy()

                def call():
                    with torch.no_grad():
                        x = torch.from_numpy(images).to(dev)
                        if half:
                            x = x.half().contiguous(memory_format=torch.channels_last)
                        return net(x).float().cpu().numpy()

                times = []
                for k in range(35):
                    started = time.perf_counter()
                    call()
                    if k >= 5:
                        times.append((time.perf_counter() - started) * 1e3)
                median = statistics.median(times)
                print(f"| {'half, channels-last' if half else 'full'} | {'on' if benchmark else 'off'} "
                      f"| {n} | {median:.2f} ms | {median / n:.2f} ms |")


if __name__ == "__main__":
    main()

"""Offline prototype (docs/notebook/2026-12-01-unet-batch-norm.md): does
normalisation in the affordance U-Net make the same number of gradient steps
go further?  PyTorch mirror of the learner's
U-Net (nets/src/unet.rs), loss (masked_bce_dice, `classes`), Adam 1e-3 with
weight decay 1e-4, batches of 8, mirrored frames.  Trains on the run's own
labels (L2) of training-room episodes and scores held-out rooms against the
ground truth (L0), per frame pixel F1 at 0.5 (median) and at the best
threshold, per affordance.

usage: python 2026-12-01-unet-batch-norm.py DATASET HISTORY NORM STEPS SEED [RUNG]
  DATASET: a dataset written by `deploy/local.sh --dataset DIR` (proto/src/ladder.rs)
  HISTORY: the recording run's history.jsonl (which room each episode was in)
  NORM: none | batch | group
"""
import glob
import json
import os
import re
import struct
import sys
import time

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "nets", "python"))
import afx_torch  # noqa: E402

HEADER, SUB = 48, 24
RUNGS = {"ground-truth": 0, "tried-truth": 1, "run": 2}


def load_episode(path):
    b = open(path, "rb").read()
    p = memoryview(b)[HEADER:]
    ep, n, h, w, a = struct.unpack_from("<QIIII", p, 0)
    pix = n * h * w
    off = SUB
    depth = np.frombuffer(p, "<f4", pix, off).reshape(n, h, w)
    off += 4 * pix
    rgb = np.frombuffer(p, np.uint8, pix * 3, off).reshape(n, h, w, 3)
    off += 3 * pix
    labels = np.frombuffer(p, np.uint8, pix * a, off).reshape(n, a, h, w)
    assert off + pix * a == len(p), (path, off + pix * a, len(p))
    x = np.concatenate(
        [rgb.transpose(0, 3, 1, 2).astype(np.float32) / 255.0, depth[:, None]], axis=1
    )
    return x, labels.copy()


def scenes_of(history):
    scene = {}
    for line in open(history):
        r = json.loads(line)
        if r.get("kind") == "episode":
            scene[(r["actor"], r["episode"])] = r["scene"]
    return scene


def unet(kind):
    """The project's U-Net in PyTorch (`nets/python/afx_torch.py`), with
    `kind` normalisation between each 3 x 3 convolution and its ReLU."""
    net = afx_torch.AffordanceUnet()
    if kind == "none":
        return net
    for level in [m for m in net.modules() if isinstance(m, afx_torch.DoubleConv)]:
        for name in ("first", "second"):
            conv = getattr(level, name)
            c = conv.out_channels
            norm = nn.BatchNorm2d(c) if kind == "batch" else nn.GroupNorm(4, c)
            setattr(level, name, nn.Sequential(conv, norm))
    return net


def loss_fn(logits, labels, known, share=0.5):
    dims = (0, 2, 3)
    bce = F.binary_cross_entropy_with_logits(logits, labels, reduction="none")
    pos = labels * known
    neg = known - pos
    n_pos, n_neg = pos.sum(dims), neg.sum(dims)
    mean_pos = (bce * pos).sum(dims) / n_pos.clamp_min(1)
    mean_neg = (bce * neg).sum(dims) / n_neg.clamp_min(1)
    has_pos, has_neg = (n_pos > 0).float(), (n_neg > 0).float()
    both = has_pos * has_neg
    w_pos = has_pos - both * (1 - share)
    w_neg = has_neg - both * share
    bce = mean_pos * w_pos + mean_neg * w_neg
    p = torch.sigmoid(logits) * known
    y = labels * known
    inter = (p * y).sum(dims)
    dice = (2 * inter + 1) / (p.sum(dims) + y.sum(dims) + 1)
    dice_loss = (1 - dice) * has_pos
    planes = ((known.sum(dims)) > 0).float().sum().clamp_min(1)
    return (bce + dice_loss).sum() / planes


THRESHOLDS = [0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9]


def score(net, x, truth):
    """Per affordance: median per-frame pixel F1 at each threshold, where
    the frame has labelled pixels (truth 255 = unknown is left out)."""
    net.eval()
    probs = []
    with torch.no_grad():
        for i in range(0, len(x), 64):
            probs.append(torch.sigmoid(net(torch.from_numpy(x[i : i + 64]))).numpy())
    net.train()
    p = np.concatenate(probs)
    out = {}
    for a, name in enumerate(["pick_up", "push"]):
        t = truth[:, a]
        known = t != 255
        pos = (t == 1) & known
        row = {}
        for th in THRESHOLDS:
            pred = (p[:, a] >= th) & known
            tp = (pred & pos).sum((1, 2))
            fp = (pred & ~pos).sum((1, 2))
            fn = (~pred & pos).sum((1, 2))
            den = 2 * tp + fp + fn
            f1 = np.where(den > 0, 2 * tp / np.maximum(den, 1), np.nan)
            row[th] = float(np.nanmedian(f1))
        out[name] = row
    return out


def main():
    dataset, history, kind, steps, seed = sys.argv[1:6]
    rung = sys.argv[6] if len(sys.argv) > 6 else "run"
    steps, seed = int(steps), int(seed)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    scene = scenes_of(history)
    train_x, train_y, held_x, held_t = [], [], [], []
    for path in sorted(glob.glob(os.path.join(dataset, "episodes", "*.frames"))):
        m = re.search(r"actor(\d+)_step\d+_episode(\d+)", path)
        s = scene.get((int(m.group(1)), int(m.group(2))))
        if s is None:
            continue
        x, labels = load_episode(path)
        r = RUNGS[rung]
        if s % 5 == 0:  # every fifth training room held out
            held_x.append(x)
            held_t.append(labels[:, 0:2])
        else:
            train_x.append(x)
            train_y.append(labels[:, 2 * r : 2 * r + 2])
    train_x, train_y = np.concatenate(train_x), np.concatenate(train_y)
    held_x, held_t = np.concatenate(held_x), np.concatenate(held_t)
    print(
        f"{kind}: train {len(train_x)} frames, held out {len(held_x)}; "
        f"pick-up positives {(train_y[:, 0] == 1).mean():.4%} of pixels",
        flush=True,
    )
    net = unet(kind)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, weight_decay=1e-4)
    started = time.time()
    report = {"norm": kind, "steps": steps, "seed": seed, "rung": rung, "scores": {}}
    checkpoints = {steps // 4, steps // 2, 3 * steps // 4, steps}
    for step in range(1, steps + 1):
        idx = rng.integers(0, len(train_x), 8)
        xb, yb = train_x[idx].copy(), train_y[idx].copy()
        flip = rng.random(8) < 0.5
        xb[flip] = xb[flip][..., ::-1]
        yb[flip] = yb[flip][..., ::-1]
        known = torch.from_numpy((yb != 255).astype(np.float32))
        labels = torch.from_numpy((yb == 1).astype(np.float32))
        loss = loss_fn(net(torch.from_numpy(np.ascontiguousarray(xb))), labels, known)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step in checkpoints:
            s = score(net, held_x, held_t)
            report["scores"][step] = s
            pu, pu_best = s["pick_up"][0.5], max(s["pick_up"].values())
            pu_th = max(s["pick_up"], key=s["pick_up"].get)
            print(
                f"{kind} step {step} ({time.time() - started:.0f} s) loss {loss.item():.3f}: "
                f"pick-up F1 {pu:.3f} (best {pu_best:.3f} at {pu_th}), "
                f"push {s['push'][0.5]:.3f} (best {max(s['push'].values()):.3f})",
                flush=True,
            )
    print(json.dumps(report))


if __name__ == "__main__":
    main()

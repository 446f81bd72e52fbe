#!/usr/bin/env python3
"""The project's networks in PyTorch, loading a run's weights by name.

A checkpoint's `weights.safetensors` (and every weights message) holds both
networks: tensors named `unet.*` (the affordance U-Net) and `policy.*` (the
PPO policy), named as a PyTorch `state_dict` names them, with linear weights
stored `[out, in]`, convolutions `[out, in, kh, kw]` and transposed
convolutions `[in, out, kh, kw]`. The file's metadata holds `unet_temperature`
(probabilities are `sigmoid(logit / T)`) and `env_steps`.

    import afx_torch
    unet, policy, meta = afx_torch.load("runs/r/checkpoints/60113/weights.safetensors",
                                        image_size=64)
    x = afx_torch.unet_input(rgb_uint8_hw3, depth_m_hw)      # [1, 4, H, W]
    probs = afx_torch.probabilities(unet(x), meta["unet_temperature"])
    images, vectors = afx_torch.split_observation(obs, policy.layout)
    log_probs, value, hidden = policy(images, vectors, mask)

`load_run(run_dir)` takes the image size from the run's `config.toml` and the
newest checkpoint. The tensor table is in docs/pytorch.md.

`python3 afx_torch.py --parity DIR` compares these networks with the Rust
forward passes on the inputs and outputs a test wrote into DIR
(`nets/tests/pytorch_parity.rs`) and prints the largest differences.
Needs `pip install torch safetensors numpy`.
"""

import json
import math
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

UNET_CHANNELS = (24, 48, 92, 164)
ENCODER_FEATURES = 64
MASKED_LOGIT = -1e9


class DoubleConv(nn.Module):
    """Two 3x3 'same' convolutions, each followed by ReLU."""

    def __init__(self, inputs, outputs):
        super().__init__()
        self.first = nn.Conv2d(inputs, outputs, 3, padding=1)
        self.second = nn.Conv2d(outputs, outputs, 3, padding=1)

    def forward(self, x):
        return F.relu(self.second(F.relu(self.first(x))))


class UpLevel(nn.Module):
    """2x2 transposed convolution (stride 2), concatenated with the skip, then DoubleConv."""

    def __init__(self, deep, skip):
        super().__init__()
        self.up = nn.ConvTranspose2d(deep, skip, 2, stride=2)
        self.conv = DoubleConv(2 * skip, skip)

    def forward(self, deep, skip):
        return self.conv(torch.cat([self.up(deep), skip], 1))


class AffordanceUnet(nn.Module):
    """`nets::unet::AffordanceUnet`: RGB-D in, one logit plane per affordance out."""

    def __init__(self, input_channels=4, affordances=2):
        super().__init__()
        c = UNET_CHANNELS
        self.down = nn.ModuleList(
            [DoubleConv(input_channels, c[0]), DoubleConv(c[0], c[1]),
             DoubleConv(c[1], c[2]), DoubleConv(c[2], c[3])])
        self.up = nn.ModuleList([UpLevel(c[3], c[2]), UpLevel(c[2], c[1]), UpLevel(c[1], c[0])])
        self.head = nn.Conv2d(c[0], affordances, 1)

    def forward(self, x):
        skips = []
        x = self.down[0](x)
        for level in self.down[1:]:
            skips.append(x)
            x = level(F.max_pool2d(x, 2))
        for level in self.up:
            x = level(x, skips.pop())
        return self.head(x)


def unet_input(rgb, depth_m):
    """The U-Net's input for one frame: `[1, 4, H, W]`, colour in 0..1, depth in
    metres with nothing seen (non-finite) as 0 (`actor`'s `network_input`)."""
    rgb = torch.as_tensor(np.asarray(rgb), dtype=torch.float32) / 255.0
    depth = torch.as_tensor(np.asarray(depth_m), dtype=torch.float32)
    depth = torch.where(torch.isfinite(depth), depth, torch.zeros_like(depth))
    return torch.cat([rgb.permute(2, 0, 1), depth[None]], 0)[None]


def probabilities(logits, temperature=1.0):
    """Affordance probabilities as actors use them: `sigmoid(logit / T)`."""
    return torch.sigmoid(logits / max(float(temperature), 1e-3))


class ConvEncoder(nn.Module):
    """8x8/4, 4x4/2, 3x3/2 valid convolutions with ReLU, then a 64-wide ReLU layer."""

    def __init__(self, channels, fc_inputs):
        super().__init__()
        self.conv1 = nn.Conv2d(channels, 16, 8, stride=4)
        self.conv2 = nn.Conv2d(16, 32, 4, stride=2)
        self.conv3 = nn.Conv2d(32, 32, 3, stride=2)
        self.fc = nn.Linear(fc_inputs, ENCODER_FEATURES)

    def forward(self, x):
        x = F.relu(self.conv3(F.relu(self.conv2(F.relu(self.conv1(x))))))
        return F.relu(self.fc(x.flatten(1)))


class VectorEncoder(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.fc1 = nn.Linear(dim, ENCODER_FEATURES)
        self.fc2 = nn.Linear(ENCODER_FEATURES, ENCODER_FEATURES)

    def forward(self, x):
        return F.relu(self.fc2(F.relu(self.fc1(x))))


class Head(nn.Module):
    """Two tanh layers (64, 32) and a linear output."""

    def __init__(self, inputs, outputs):
        super().__init__()
        self.fc1 = nn.Linear(inputs, 64)
        self.fc2 = nn.Linear(64, 32)
        self.out = nn.Linear(32, outputs)

    def forward(self, x):
        return self.out(torch.tanh(self.fc2(torch.tanh(self.fc1(x)))))


def conv_side(size):
    for kernel, stride in ((8, 4), (4, 2), (3, 2)):
        size = (size - kernel) // stride + 1
    return size


class PolicyNet(nn.Module):
    """`nets::policy::PolicyNet`: one encoder per image group and per vector,
    concatenated, through a GRU for the methods with memory, into the actor
    (masked log-softmax over the actions) and critic heads.

    `layout` is a dict like `proto::PolicyLayout`: image_channels,
    image_size, vector_dims, n_actions, gru_hidden (None without a GRU)."""

    def __init__(self, layout):
        super().__init__()
        self.layout = layout
        side = conv_side(layout["image_size"]) if layout["image_channels"] else 0
        self.images = nn.ModuleList(
            [ConvEncoder(c, 32 * side * side) for c in layout["image_channels"]])
        self.vectors = nn.ModuleList([VectorEncoder(d) for d in layout["vector_dims"]])
        fused = ENCODER_FEATURES * (len(layout["image_channels"]) + len(layout["vector_dims"]))
        hidden = layout["gru_hidden"]
        # burn's GRU resets after the hidden product, as PyTorch's does.
        self.gru = nn.GRU(fused, hidden, batch_first=True) if hidden else None
        trunk = hidden or fused
        self.actor = Head(trunk, layout["n_actions"])
        self.critic = Head(trunk, 1)

    def forward(self, images, vectors, mask, hidden=None):
        """`images`: one `[B, C, S, S]` tensor per group; `vectors`: one `[B, D]`
        per vector; `mask`: `[B, n_actions]` booleans (True = allowed);
        `hidden`: `[B, H]` GRU state (None: zeros). Returns log-probabilities
        `[B, n_actions]`, values `[B]` and the new state (or None)."""
        parts = [e(x) for e, x in zip(self.images, images)]
        parts += [e(x) for e, x in zip(self.vectors, vectors)]
        trunk = torch.cat(parts, 1)
        if self.gru is not None:
            h0 = None if hidden is None else hidden[None]
            out, _ = self.gru(trunk[:, None, :], h0)
            trunk = out[:, 0, :]
            hidden = trunk
        else:
            hidden = None
        logits = self.actor(trunk).masked_fill(~mask, MASKED_LOGIT)
        return F.log_softmax(logits, 1), self.critic(trunk)[:, 0], hidden


def split_observation(obs, layout):
    """A flat observation (rows of `obs_len` values: images then vectors, as
    rollouts carry them; bytes already mapped to 0..1) as the policy's inputs."""
    obs = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
    if obs.dim() == 1:
        obs = obs[None]
    side, at = layout["image_size"], 0
    images, vectors = [], []
    for c in layout["image_channels"]:
        n = c * side * side
        images.append(obs[:, at:at + n].reshape(-1, c, side, side))
        at += n
    for d in layout["vector_dims"]:
        vectors.append(obs[:, at:at + d])
        at += d
    return images, vectors


def _burn_gru_to_torch(tensors, prefix):
    """burn keeps a GRU as three gates, each an input and a hidden transform;
    PyTorch stacks them in the order reset, update, new."""
    def stack(kind, part):
        return torch.cat([tensors[f"{prefix}{g}_gate.{kind}_transform.{part}"]
                          for g in ("reset", "update", "new")], 0)
    return {
        "weight_ih_l0": stack("input", "weight"), "bias_ih_l0": stack("input", "bias"),
        "weight_hh_l0": stack("hidden", "weight"), "bias_hh_l0": stack("hidden", "bias"),
    }


def policy_layout(tensors, image_size):
    """The policy's layout, read from its tensors' shapes."""
    def count(group):
        return len({k.split(".")[2] for k in tensors if k.startswith(f"policy.{group}.")})
    image_channels = [tensors[f"policy.images.{i}.conv1.weight"].shape[1]
                      for i in range(count("images"))]
    vector_dims = [tensors[f"policy.vectors.{i}.fc1.weight"].shape[1]
                   for i in range(count("vectors"))]
    gru = tensors.get("policy.gru.update_gate.hidden_transform.weight")
    return {
        "image_channels": image_channels, "image_size": image_size,
        "vector_dims": vector_dims, "n_actions": tensors["policy.actor.out.weight"].shape[0],
        "gru_hidden": None if gru is None else gru.shape[0],
    }


def load(path, image_size):
    """`(unet, policy, metadata)` from a weights file; either network is None
    when the file lacks it. `image_size` is the run's `[task] image_size`."""
    from safetensors import safe_open
    with safe_open(str(path), "pt") as f:
        tensors = {k: f.get_tensor(k) for k in f.keys()}
        metadata = dict(f.metadata() or {})
    meta = {"unet_temperature": float(metadata.get("unet_temperature", 1.0)),
            "env_steps": int(metadata.get("env_steps", 0))}
    unet = policy = None
    unet_state = {k[len("unet."):]: v for k, v in tensors.items() if k.startswith("unet.")}
    if unet_state:
        unet = AffordanceUnet(unet_state["down.0.first.weight"].shape[1],
                              unet_state["head.weight"].shape[0])
        unet.load_state_dict(unet_state, strict=True)
        unet.eval()
    if any(k.startswith("policy.") for k in tensors):
        layout = policy_layout(tensors, image_size)
        if layout["image_channels"]:
            fc_in = tensors["policy.images.0.fc.weight"].shape[1]
            if fc_in != 32 * conv_side(image_size) ** 2:
                raise ValueError(f"the policy's encoders were made for another image size than "
                                 f"{image_size} (their last layer reads {fc_in} values)")
        policy = PolicyNet(layout)
        state = {k[len("policy."):]: v for k, v in tensors.items()
                 if k.startswith("policy.") and not k.startswith("policy.gru.")}
        if layout["gru_hidden"]:
            state.update({f"gru.{k}": v for k, v in _burn_gru_to_torch(tensors, "policy.gru.").items()})
        policy.load_state_dict(state, strict=True)
        policy.eval()
    return unet, policy, meta


def load_run(run_dir, step=None):
    """`load` on a run directory: its `config.toml`'s image size and its
    newest checkpoint (or `step`)."""
    import tomllib
    run_dir = Path(run_dir)
    config = tomllib.loads((run_dir / "config.toml").read_text())
    image_size = config.get("task", {}).get("image_size", 128)
    steps = sorted(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit())
    if not steps:
        raise FileNotFoundError(f"no checkpoint under {run_dir / 'checkpoints'}")
    chosen = steps[-1] if step is None else step
    return load(run_dir / "checkpoints" / str(chosen) / "weights.safetensors", image_size)


def parity(directory):
    """Compares with the Rust forward passes written by the parity test; prints
    one JSON line of the largest absolute differences."""
    directory = Path(directory)
    case = json.loads((directory / "case.json").read_text())
    unet, policy, meta = load(directory / "weights.safetensors", case["image_size"])
    h, w = case["height"], case["width"]
    rgb = np.array(case["rgb"], dtype=np.uint8).reshape(h, w, 3)
    depth = np.array([math.nan if d is None else d for d in case["depth_m"]],
                     dtype=np.float32).reshape(h, w)
    with torch.no_grad():
        probs = probabilities(unet(unet_input(rgb, depth)), meta["unet_temperature"])[0]
        unet_diff = float((probs.flatten() - torch.tensor(case["probabilities"])).abs().max())
        hidden, policy_diff, value_diff, hidden_diff = None, 0.0, 0.0, 0.0
        for step in case["policy_steps"]:
            images, vectors = split_observation(step["observation"], policy.layout)
            mask = torch.tensor([m != 0 for m in step["mask"]])[None]
            log_probs, value, hidden = policy(images, vectors, mask, hidden)
            allowed = mask[0]
            expected = torch.tensor(step["log_probs"])
            policy_diff = max(policy_diff,
                              float((log_probs[0][allowed] - expected[allowed]).abs().max()))
            value_diff = max(value_diff, abs(float(value[0]) - step["value"]))
            if step.get("hidden") is not None:
                hidden_diff = max(hidden_diff,
                                  float((hidden[0] - torch.tensor(step["hidden"])).abs().max()))
    print(json.dumps({"unet_probability": unet_diff, "policy_log_prob": policy_diff,
                      "policy_value": value_diff, "policy_hidden": hidden_diff,
                      "temperature": meta["unet_temperature"]}))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--parity":
        parity(sys.argv[2])
    else:
        sys.exit(__doc__)

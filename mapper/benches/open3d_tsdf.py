#!/usr/bin/env python3
"""Open3D's block-hashed TSDF on the frames of `cargo bench -p mapper`.

The Rust benchmark writes its frames to target/mapper-bench-frames/frameNN.bin
(16 little-endian f32: the camera-to-world pose, row-major; then 128 x 128 f32
z-depths in metres). This script integrates the same frames into Open3D's
VoxelBlockGrid (block-hashed TSDF) at the same voxel size and truncation, and prints the median
time per frame, the way the Rust benchmark does.

Usage: python3 mapper/benches/open3d_tsdf.py [--frames DIR] [--repeats N]
Needs `pip install open3d numpy` (and libusb-1.0 on Debian for open3d's import).
Run with OMP_NUM_THREADS=1 to compare with one core.
"""

import argparse
import pathlib
import statistics
import sys
import time

WIDTH = HEIGHT = 128
FX = FY = 64.0
CX = CY = 63.5


def load_frames(directory):
    import numpy as np

    frames = []
    for path in sorted(directory.glob("frame*.bin")):
        raw = np.fromfile(path, dtype="<f4")
        if raw.size != 16 + WIDTH * HEIGHT:
            sys.exit(f"{path}: {raw.size} floats, expected {16 + WIDTH * HEIGHT}")
        pose = raw[:16].reshape(4, 4).astype(np.float64)
        depth = raw[16:].reshape(HEIGHT, WIDTH).copy()
        frames.append((pose, depth))
    if not frames:
        sys.exit(f"no frames in {directory}: run `cargo bench -p mapper` first")
    return frames


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    root = pathlib.Path(__file__).resolve().parents[2]
    parser.add_argument("--frames", type=pathlib.Path, default=root / "target/mapper-bench-frames")
    parser.add_argument("--repeats", type=int, default=20, help="passes over the frames to time")
    parser.add_argument("--voxel", type=float, default=0.04, help="voxel size, metres")
    parser.add_argument("--truncation", type=float, default=0.12, help="truncation, metres")
    args = parser.parse_args()

    try:
        import numpy as np
        import open3d as o3d
        import open3d.core as o3c
    except ImportError as e:
        sys.exit(f"needs open3d and numpy (pip install open3d numpy): {e}")

    frames = load_frames(args.frames)
    device = o3c.Device("CPU:0")
    intrinsic = o3c.Tensor(np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]], dtype=np.float64))
    images = [
        (o3d.t.geometry.Image(o3c.Tensor(depth)), o3c.Tensor(np.linalg.inv(pose)))
        for pose, depth in frames
    ]
    # Open3D's block-hashed TSDF (8^3-voxel blocks, like ours). The legacy
    # ScalableTSDFVolume integrates nothing in open3d 0.20 from pip here (an
    # empty volume even for a flat wall), so it cannot serve as the peer.
    volume = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight"),
        attr_dtypes=(o3c.float32, o3c.float32),
        attr_channels=((1), (1)),
        voxel_size=args.voxel,
        block_resolution=8,
        block_count=100_000,
        device=device,
    )
    multiplier = args.truncation / args.voxel

    def integrate(depth, extrinsic):
        blocks = volume.compute_unique_block_coordinates(
            depth, intrinsic, extrinsic, 1.0, 8.0, trunc_voxel_multiplier=multiplier
        )
        volume.integrate(
            blocks, depth, intrinsic, extrinsic, 1.0, 8.0, trunc_voxel_multiplier=multiplier
        )

    for depth, extrinsic in images:  # warm map, as in the Rust benchmark
        integrate(depth, extrinsic)
    times = []
    for _ in range(args.repeats):
        for depth, extrinsic in images:
            start = time.perf_counter()
            integrate(depth, extrinsic)
            times.append(time.perf_counter() - start)
    observed = int((volume.attribute("weight").numpy() > 0).sum())
    if observed == 0:
        sys.exit("open3d integrated nothing: check the frames")
    print(
        f"open3d {o3d.__version__} VoxelBlockGrid: {len(frames)} frames x {args.repeats}, "
        f"median {statistics.median(times) * 1e3:.3f} ms per frame "
        f"(voxel {args.voxel} m, truncation {args.truncation} m; "
        f"{volume.hashmap().size()} blocks, {observed} observed voxels)"
    )


if __name__ == "__main__":
    main()

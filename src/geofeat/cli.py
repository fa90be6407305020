"""The `geofeat` command line: demo, and the commands of later stages."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np


def _demo(args: argparse.Namespace) -> int:
    from .geodesic.polar import polar_patches
    from .geodesic.mesh import build_mesh
    from .io import demo_data_dir, read_demo_frame, read_landmarks
    from .viz import draw_geodesic_support, patch_grid, side_by_side

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frame = read_demo_frame()
    _, landmarks, _ = read_landmarks(demo_data_dir() / "cloud_1.csv")
    print(f"frame: {demo_data_dir() / 'cloud_1'} ({frame.shape[1]}x{frame.shape[0]}, "
          f"{(frame.depth == 0).mean():.1%} missing depth), {len(landmarks)} annotated keypoints")
    t0 = time.perf_counter()
    mesh = build_mesh(frame)
    t1 = time.perf_counter()
    patches = polar_patches(frame, landmarks, radius=args.radius, mesh=mesh)
    t2 = time.perf_counter()
    print(f"depth preprocessing + mesh ({mesh.points.shape[1]}x{mesh.points.shape[0]}): {t1 - t0:.3f} s")
    print(f"geodesic polar patches: {len(patches)} keypoints, {patches.valid.sum()} valid, "
          f"radius {args.radius * 1000:.0f} mm, {t2 - t1:.3f} s "
          f"(first run includes numba compilation)")
    picture = side_by_side(draw_geodesic_support(frame, patches), patch_grid(patches, columns=8))
    path = out / "polar_patches.png"
    cv2.imwrite(str(path), picture)
    np.savez_compressed(out / "polar_patches.npz", keypoints=patches.keypoints, values=patches.values,
                        coords=patches.coords, valid=patches.valid)
    print(f"wrote {path} (keypoints with geodesic rings at 18/37/75 mm, and their 32x32 polar patches)")
    print(f"wrote {out / 'polar_patches.npz'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="geofeat", description="Geodesic-aware local features on RGB-D images.")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the demo on the shipped real Kinect frame")
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument("--radius", type=float, default=0.075, help="geodesic radius in metres (default 0.075)")
    demo.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, TypeError, FileNotFoundError) as error:
        print(f"geofeat {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

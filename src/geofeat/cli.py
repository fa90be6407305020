"""The `geofeat` command line: demo, extract, match (and the commands of later stages)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from .constants import DEFAULT_RADIUS_M, DEPTH_SCALE_M, N_KEYPOINTS


def _demo_patches(out: Path, radius: float) -> None:
    from .geodesic.mesh import build_mesh
    from .geodesic.polar import polar_patches
    from .io import demo_data_dir, read_demo_frame, read_landmarks
    from .viz import draw_geodesic_support, patch_grid, side_by_side

    frame = read_demo_frame()
    _, landmarks, _ = read_landmarks(demo_data_dir() / "cloud_1.csv")
    print(f"frame: {demo_data_dir() / 'cloud_1'} ({frame.shape[1]}x{frame.shape[0]}, "
          f"{(frame.depth == 0).mean():.1%} missing depth), {len(landmarks)} annotated keypoints")
    t0 = time.perf_counter()
    mesh = build_mesh(frame)
    t1 = time.perf_counter()
    patches = polar_patches(frame, landmarks, radius=radius, mesh=mesh)
    t2 = time.perf_counter()
    print(f"depth preprocessing + mesh ({mesh.points.shape[1]}x{mesh.points.shape[0]}): {t1 - t0:.3f} s")
    print(f"geodesic polar patches: {len(patches)} keypoints, {patches.valid.sum()} valid, "
          f"radius {radius * 1000:.0f} mm, {t2 - t1:.3f} s (the first run compiles the numba kernels)")
    picture = side_by_side(draw_geodesic_support(frame, patches), patch_grid(patches, columns=8))
    cv2.imwrite(str(out / "polar_patches.png"), picture)
    print(f"wrote {out / 'polar_patches.png'} (geodesic rings at 18/37/75 mm, and the 32x32 polar patches)")


def _demo_rolled_pair(out: Path, angle: float, n: int) -> None:
    from .descriptors import make_descriptor
    from .frame import roll_camera
    from .io import read_demo_frame
    from .keypoints import detect
    from .matching import match
    from .viz import draw_matches

    frame0 = read_demo_frame()
    frame1, A = roll_camera(frame0, angle)
    k0, k1 = detect(frame0, n), detect(frame1, n)
    truth = k0.xy @ A[:, :2].T + A[:, 2]  # where each reference keypoint really is in frame 1
    print(f"\nrolled pair: the Kinect frame vs the camera rolled by {angle:g} deg; SIFT keypoints "
          f"detected independently: {len(k0)} and {len(k1)}")
    pictures = []
    for name in ("geobit", "orb"):
        descriptor = make_descriptor(name)
        t = time.perf_counter()
        f0, f1 = descriptor.compute(frame0, k0), descriptor.compute(frame1, k1)
        m = match(f0, f1)
        elapsed = time.perf_counter() - t
        has = m.matches0 >= 0
        error = np.full(len(k0), np.inf)
        error[has] = np.linalg.norm(k1.xy[m.matches0[has]] - truth[has], axis=1)
        correct = error < 3.0
        print(f"  {name:7s} {has.sum():5d} matches, {correct.sum():5d} correct (< 3 px), "
              f"{correct.sum() / max(has.sum(), 1):.1%} precision, {elapsed:.2f} s")
        pictures.append(draw_matches(frame0, frame1, k0.xy, k1.xy, np.where(correct, m.matches0, -1),
                                     np.ones(len(k0), bool), max_lines=300,
                                     title=f"{name}: {correct.sum()} correct of {has.sum()}"))
    path = out / "rolled_pair_matches.png"
    cv2.imwrite(str(path), np.concatenate(pictures, axis=0))
    print(f"wrote {path} (correct matches of GeoBit, top, and ORB with SIFT's angle, bottom)")


def _demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _demo_patches(out, args.radius)
    _demo_rolled_pair(out, args.angle, args.keypoints)
    return 0


def _features_path(out: Path, descriptor: str) -> Path:
    return out if out.suffix in (".h5", ".npz") else out / f"features-{descriptor}.h5"


def _extract(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from .descriptors import make_descriptor
    from .features import save_features
    from .io import read_sequence
    from .keypoints import detect

    seq = read_sequence(args.folder, depth_scale=args.depth_scale)
    descriptor = make_descriptor(args.descriptor, radius=args.radius)
    path = _features_path(Path(args.out), args.descriptor)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()
    for name in tqdm(seq.names, desc=f"extract {args.descriptor}", unit="frame"):
        frame = seq.frame(name)
        features = descriptor.compute(frame, detect(frame, args.keypoints))
        save_features(path, features, name=name) if path.suffix == ".h5" else \
            save_features(path.with_name(f"{path.stem}-{name}.npz"), features)
    print(f"wrote {args.descriptor} features of {len(seq)} frames of {seq.folder} to {path}")
    return 0


def _match(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from .bench.protocol import LandmarkTPS
    from .descriptors import make_descriptor
    from .features import save_matches
    from .io import read_sequence
    from .keypoints import detect
    from .matching import match
    from .viz import draw_matches

    seq = read_sequence(args.folder, depth_scale=args.depth_scale)
    if len(seq) < 2:
        raise ValueError(f"folder: {seq.folder} has a single frame; matching needs a reference and a target")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    descriptor = make_descriptor(args.descriptor, radius=args.radius)
    ref = seq.frame(seq.reference)
    k_ref = detect(ref, args.keypoints)
    f_ref = descriptor.compute(ref, k_ref)
    matches_path = out / f"matches-{args.descriptor}.h5"
    if matches_path.exists():
        matches_path.unlink()
    total_matches, total_correct, known = 0, 0, False
    for name in tqdm(seq.targets, desc=f"match {args.descriptor}", unit="pair"):
        tgt = seq.frame(name)
        k_tgt = detect(tgt, args.keypoints)
        m = match(f_ref, descriptor.compute(tgt, k_tgt))
        save_matches(matches_path, m, name=f"{seq.reference}/{name}")
        correct = _correct_matches(seq, name, k_ref.xy, k_tgt.xy, m.matches0, LandmarkTPS)
        summary = f"{(m.matches0 >= 0).sum()} matches"
        total_matches += int((m.matches0 >= 0).sum())
        if correct is not None:
            known = True
            total_correct += int(correct[m.matches0 >= 0].sum())
            summary += f", {int(correct[m.matches0 >= 0].sum())} correct"
        picture = draw_matches(ref, tgt, k_ref.xy, k_tgt.xy, m.matches0, correct, title=f"{args.descriptor}: {summary}")
        cv2.imwrite(str(out / f"{seq.reference}__{name}__{args.descriptor}.png"), picture)
        tqdm.write(f"{seq.reference} -> {name}: {summary}")
    print(f"total: {total_matches} matches" + (f", {total_correct} correct" if known else " (no ground truth)"))
    print(f"wrote {matches_path} and one match picture per pair in {out}")
    return 0


def _correct_matches(seq, target, ref_xy, tgt_xy, matches0, tps_class) -> np.ndarray | None:
    """Per reference keypoint: is its match within 3 px of the ground truth (None when unknown)?
    Ground truth: the simulator's exact correspondences, else a TPS on the csv landmarks."""
    mapped = None
    if hasattr(seq, "correspondences"):
        try:
            mapped, visible = seq.correspondences(seq.reference, target, ref_xy)
            mapped = np.where(visible[:, None], mapped, np.nan)
        except ValueError:
            mapped = None
    if mapped is None and seq.has_landmarks():
        ids_r, xy_r, vis_r = seq.landmarks(seq.reference)
        ids_t, xy_t, vis_t = seq.landmarks(target)
        common = np.intersect1d(ids_r[vis_r], ids_t[vis_t])
        if len(common) >= 4:
            pos_r = {i: p for i, p in zip(ids_r, xy_r)}
            pos_t = {i: p for i, p in zip(ids_t, xy_t)}
            mapped = tps_class(np.array([pos_r[i] for i in common]), np.array([pos_t[i] for i in common]))(ref_xy)
    if mapped is None:
        return None
    ok = matches0 >= 0
    error = np.full(len(ref_xy), np.inf)
    error[ok] = np.linalg.norm(tgt_xy[matches0[ok]] - mapped[ok], axis=1)
    return error < 3.0


def build_parser() -> argparse.ArgumentParser:
    from .descriptors import available_descriptors

    parser = argparse.ArgumentParser(prog="geofeat", description="Geodesic-aware local features on RGB-D images.")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="run the demo on the shipped real Kinect frame")
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument("--radius", type=float, default=DEFAULT_RADIUS_M, help="geodesic radius, metres (default 0.075)")
    demo.add_argument("--angle", type=float, default=60.0, help="camera roll of the rotated pair, degrees (default 60)")
    demo.add_argument("--keypoints", type=int, default=1000, help="SIFT keypoints per frame (default 1000)")
    demo.set_defaults(func=_demo)

    def frames_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("folder", help="a sequence folder in the public layout (<name>-rgb.png, <name>-depth.png, intrinsics.xml)")
        p.add_argument("--descriptor", default="geobit", choices=available_descriptors())
        p.add_argument("--keypoints", type=int, default=N_KEYPOINTS, help="SIFT keypoints per frame (default 2048)")
        p.add_argument("--radius", type=float, default=None, help="geodesic radius, metres (default 0.075)")
        p.add_argument("--depth-scale", type=float, default=None,
                       help=f"metres per depth-PNG unit (default: geofeat.json or {DEPTH_SCALE_M})")

    extract = sub.add_parser("extract", help="detect SIFT keypoints and describe every frame of a sequence")
    frames_options(extract)
    extract.add_argument("--out", required=True, help="features file (.h5 or .npz) or folder")
    extract.set_defaults(func=_extract)

    match = sub.add_parser("match", help="match the reference frame of a sequence to every other frame")
    frames_options(match)
    match.add_argument("--out", required=True, help="output folder (matches .h5 + pictures)")
    match.set_defaults(func=_match)

    from .sim import command as sim_command

    sim_command.add_parser(sub).set_defaults(func=sim_command.run)
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

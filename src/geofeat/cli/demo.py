"""`geofeat demo`: runs the descriptors on the shipped real Kinect frame and on a simulated cloth pair,
and writes pictures of what they see."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from ..constants import DEFAULT_RADIUS_M
from ..outputs import plural, write_picture
from .options import depth_profile_option, finite_number, keypoint_count, radius_value


def _profile_of(profile: str, frame) -> str:
    """The concrete profile name for `frame` ("auto" measured on it)."""
    from ..depth import depth_profile

    return depth_profile(frame) if profile == "auto" else profile


def _demo_patches(out: Path, radius: float, profile: str, into: Path | None = None) -> None:
    """Picture the shipped Kinect frame's geodesic rings and polar patches as `out`/polar_patches.png,
    written into the folder `into` (default `out`; `run` gives the temporary folder it moves into `out`)."""
    from ..depth import SLOPE_NOISE_THRESHOLD, depth_noise
    from ..geodesic.mesh import build_mesh
    from ..geodesic.polar import polar_patches
    from ..io import demo_data_dir, read_demo_frame, read_landmarks
    from ..viz import draw_geodesic_support, patch_grid, ring_distances_mm, side_by_side

    frame = read_demo_frame()
    _, landmarks, _ = read_landmarks(demo_data_dir() / "cloud_1.csv")
    print(f"frame: {demo_data_dir() / 'cloud_1'} ({frame.shape[1]}x{frame.shape[0]}, "
          f"{(frame.depth == 0).mean():.1%} missing depth), {plural(len(landmarks), 'annotated keypoint')}")
    chosen = _profile_of(profile, frame)
    if profile == "auto":  # the number with its unit and the threshold it was compared with
        noise = depth_noise(frame.depth, frame.K).slope_noise
        print(f"depth profile: {chosen} (auto: measured slope noise {noise:.2f} pixel footprints, "
              f"{'above' if noise > SLOPE_NOISE_THRESHOLD else 'at most'} the kinect profile's threshold "
              f"{SLOPE_NOISE_THRESHOLD:g})")
    else:
        print(f"depth profile: {chosen}")
    t0 = time.perf_counter()
    mesh = build_mesh(frame, chosen)
    t1 = time.perf_counter()
    patches = polar_patches(frame, landmarks, radius=radius, mesh=mesh)
    t2 = time.perf_counter()
    print(f"depth preprocessing + mesh ({mesh.points.shape[1]}x{mesh.points.shape[0]}): {t1 - t0:.3f} s")
    print(f"geodesic polar patches: {plural(len(patches), 'keypoint')}, {patches.valid.sum()} valid, "
          f"radius {radius * 1000:.0f} mm, {t2 - t1:.3f} s (the first run compiles the numba kernels)")
    picture = side_by_side(draw_geodesic_support(frame, patches), patch_grid(patches, columns=8))
    write_picture((into or out) / "polar_patches.png", picture)
    rings = "/".join(f"{mm:.0f}" for mm in ring_distances_mm(patches))
    size = "x".join(str(n) for n in patches.values.shape[1:])
    print(f"wrote {out / 'polar_patches.png'} (geodesic rings at {rings} mm, and the {size} polar patches)")


def _demo_match_pair(out: Path, picture_name: str, frame0, frame1, k0, k1, truth: np.ndarray,
                     names: list[str], profile: str, radius: float = DEFAULT_RADIUS_M,
                     into: Path | None = None) -> None:
    """Match frame0 -> frame1 with each descriptor on the same keypoints, print how many matches
    land within 3 px of `truth` (the true positions in frame 1 of k0, NaN = not visible), and save
    the correct matches of the first two descriptors, one above the other, as `out`/`picture_name`
    (written into `into`, default `out`). `radius`: the geodesic radius of the geodesic descriptors,
    metres (the demo's --radius)."""
    from ..descriptors import make_descriptor
    from ..matching import match
    from ..viz import draw_matches

    visible = np.isfinite(truth).all(axis=1)
    pictures = []
    for name in names:
        descriptor = make_descriptor(name, radius=radius, depth_config=_profile_of(profile, frame0))
        t = time.perf_counter()
        m = match(descriptor.compute(frame0, k0), descriptor.compute(frame1, k1))
        elapsed = time.perf_counter() - t
        has = (m.matches0 >= 0) & visible
        error = np.full(len(k0), np.inf)
        error[has] = np.linalg.norm(k1.xy[m.matches0[has]] - truth[has], axis=1)
        correct = error < 3.0
        n_correct, n_visible = int(correct.sum()), int(visible.sum())
        counted = plural(n_correct, "correct match", "correct matches")
        print(f"  {name:8s} {counted:>{len(counted) + 5 - len(str(n_correct))}} "  # counts right-aligned in 5
              f"(< 3 px) of {plural(n_visible, 'keypoint')} with a true position "
              f"({n_correct / max(n_visible, 1):.1%}), {elapsed:.2f} s")
        if len(pictures) < 2:
            pictures.append(draw_matches(frame0, frame1, k0.xy, k1.xy, np.where(correct, m.matches0, -1),
                                         np.ones(len(k0), bool), max_lines=200,
                                         title=f"{name}: {correct.sum()} correct"))
    path = out / picture_name
    write_picture((into or out) / picture_name, np.concatenate(pictures, axis=0))
    print(f"wrote {path} (correct matches of {names[0]}, top, and {names[1]}, bottom)")


def _demo_rolled_pair(out: Path, angle: float, n: int, profile: str, radius: float = DEFAULT_RADIUS_M,
                      into: Path | None = None) -> None:
    from ..frame import roll_camera
    from ..io import read_demo_frame
    from ..keypoints import detect

    frame0 = read_demo_frame()
    frame1, A = roll_camera(frame0, angle)
    k0, k1 = detect(frame0, n, detector="sift"), detect(frame1, n, detector="sift")
    truth = k0.xy @ A[:, :2].T + A[:, 2]  # where each reference keypoint really is in frame 1
    H, W = frame0.shape
    gone = ~((truth >= 0).all(axis=1) & (truth[:, 0] <= W - 1) & (truth[:, 1] <= H - 1))
    truth[gone] = np.nan  # rolled out of the image: nothing there to match, not counted
    print(f"\nrolled pair: the Kinect frame vs the camera rolled by {angle:g} deg; SIFT keypoints "
          f"detected independently: {len(k0)} and {len(k1)}")
    _demo_match_pair(out, "rolled_pair_matches.png", frame0, frame1, k0, k1, truth, ["geobit", "orb"], profile,
                     radius, into)


def _demo_deformed_pair(out: Path, n: int, profile: str, radius: float = DEFAULT_RADIUS_M,
                        into: Path | None = None) -> None:
    from ..io import read_sequence
    from ..keypoints import detect
    from ..sim import simulate_sequence

    folder = simulate_sequence(out / "simulated_cloth", scenario="rotate", n_frames=5, seed=7, progress=False,
                               overwrite=True)
    seq = read_sequence(folder)
    target = seq.targets[-1]
    frame0, frame1 = seq.frame(seq.reference), seq.frame(target)
    k0, k1 = detect(frame0, n, detector="sift"), detect(frame1, n, detector="sift")
    truth, visible = seq.correspondences(seq.reference, target, k0.xy)
    print(f"\nsimulated cloth: {folder} ({len(seq)} frames, wind-blown cloth and a rolling camera); "
          f"{seq.reference} vs {target}, SIFT keypoints {len(k0)} and {len(k1)}")
    _demo_match_pair(out, "simulated_pair_matches.png", frame0, frame1, k0, k1,
                     np.where(visible[:, None], truth, np.nan), ["geopatch", "geobit", "orb", "sift"], profile, radius,
                     into)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `demo` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("demo", help="run the demo on the shipped real Kinect frame")
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    p.add_argument("--radius", type=radius_value, default=DEFAULT_RADIUS_M, help="geodesic radius of the patches and of GeoBit and GeoPatch in both pairs, "
                   "metres (default 0.075)")
    p.add_argument("--angle", type=finite_number, default=60.0, help="camera roll of the rotated pair, degrees (default 60)")
    p.add_argument("--keypoints", type=keypoint_count, default=1000, help="SIFT keypoints per frame (default 1000)")
    depth_profile_option(p, "auto")
    p.set_defaults(func=run)
    return p


#: The pictures `geofeat demo` writes into its folder (beside the sequence folder "simulated_cloth").
DEMO_PICTURES = ("polar_patches.png", "rolled_pair_matches.png", "simulated_pair_matches.png")


def _check_demo_folder(out: Path) -> None:
    """The demo reruns into its own folder freely, but never replaces a picture of the same name that
    geofeat did not write there (one not in the folder's manifest)."""
    from ..outputs import SEQUENCE, check_out_dir, foreign_clashes

    check_out_dir(out, overwrite=True)  # not a file, not under a file
    theirs = foreign_clashes(out, DEMO_PICTURES)
    if theirs:
        raise ValueError(f"--out: {out} already holds {', '.join(theirs)}, which geofeat did not write; "
                         "choose another folder")
    # the simulated sequence replaces only an earlier one: checked now, not after the first pictures
    check_out_dir(out / "simulated_cloth", overwrite=True, strict=True, writes=SEQUENCE)


def kernels_compiled() -> bool:
    """Whether numba's cache already holds the geodesic walk (`walk_polar`), the kernel every first run
    compiles: False on a first run after installing (or with another numba cache folder), when the
    kernels take about a minute to compile on a 2-core CPU; True when unknown (numba's cache
    layout is not public), so that nothing is announced wrongly."""
    import os

    from ..geodesic.walk import walk_polar

    try:
        cache = walk_polar._cache
        return os.path.exists(os.path.join(cache._cache_path, cache._cache_file._index_name))
    except Exception:  # noqa: BLE001 - another numba's internals: say nothing
        return True


def run(args: argparse.Namespace) -> int:
    """`geofeat demo`: geodesic patches of the shipped Kinect frame, a rolled pair and a simulated cloth pair."""
    from ..outputs import output_folder

    out = Path(args.out)
    _check_demo_folder(out)
    if not kernels_compiled():  # a first run is silent for minutes while numba compiles: say so first
        print("first run: compiling geofeat's numba kernels (about a minute on a 2-core CPU; they are cached "
              "for later runs)", flush=True)
    # the pictures are made in a temporary folder and moved in together at the end: written one by one into
    # `out`, an interrupted rerun with another --angle left old and new pictures side by side
    with output_folder(out) as tmp:
        _demo_patches(out, args.radius, args.depth_profile, tmp)
        # --radius for the pairs' geodesic descriptors too (it reached only the patches picture, and GeoBit and
        # GeoPatch matched at 0.075 m whatever it said)
        _demo_rolled_pair(out, args.angle, args.keypoints, args.depth_profile, args.radius, tmp)
        # its sequence, simulated_cloth/, goes straight into `out` (as a folder of its own, whole or not at
        # all): the same sequence whatever the options
        _demo_deformed_pair(out, args.keypoints, args.depth_profile, args.radius, tmp)
    return 0

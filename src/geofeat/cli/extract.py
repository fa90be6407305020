"""`geofeat extract`: detect keypoints and describe every frame of a sequence."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .common import features_path, file_label, finish_skipped, frame_and_keypoints, is_h5, skip_frame
from .options import frames_options, resolve_detection


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `extract` to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser("extract", help="detect keypoints and describe every frame of a sequence")
    frames_options(p)
    p.add_argument("--out", required=True, help="features file (.h5 or .npz) or folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing features file")
    p.add_argument("--device", default="cpu",
                   help="cpu (default), or cuda / cuda:N: GeoPatch's walk, sampling and CNN on the GPU "
                        "(geofeat[cuda]; torch weights; descriptors within about 2e-4 of the CPU torch backend's)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Describe every frame of a sequence and write the features file(s); 1 when a frame was skipped."""
    detection = resolve_detection(args)  # resolved once, for every frame
    gpu = check_device(args.device, args.descriptor)
    import os

    from tqdm import tqdm

    from ..depth import PROFILES, sequence_depth_profile
    from ..descriptors import make_descriptor
    from ..features import save_features
    from ..inputs import resolve_radius
    from ..io import read_sequence
    from ..outputs import (atomic_file, check_out_file, claim_output, clear_stale_partials, partial_name, plural,
                           refuse_input_folder, signals_deferred)

    seq = read_sequence(args.folder, depth_scale=args.depth_scale)
    radius = resolve_radius(args.radius, seq)
    path = features_path(Path(args.out), file_label(args.descriptor))
    finals = [path] if is_h5(path) else [path.with_name(f"{path.stem}-{n}.npz") for n in seq.names]
    # --out naming the sequence folder, or a .npz prefix in it (one file per frame): among its frames.
    # An .h5 file named there is one file of the user's choosing, which no reader takes for a frame's.
    if not (is_h5(path) and path == Path(args.out)):
        refuse_input_folder(path.parent, [seq.folder], "--out",
                            f"extract would write {path.name if is_h5(path) else f'{path.stem}-<frame>.npz'} "
                            "among its frames")
    claim_output(path)  # one claim for the .h5, or for the prefix of the one file per frame
    for final in finals:
        check_out_file(final, args.overwrite, claim=False)
    if not is_h5(path):  # a killed run's half-written .npz files (the .h5's `atomic_file` clears its own)
        clear_stale_partials(*finals)
    profile = sequence_depth_profile(seq, args.depth_profile)
    options = {"device": args.device, "backend": "torch"} if gpu else {}
    try:
        descriptor = make_descriptor(args.descriptor, radius=radius, depth_config=PROFILES[profile], **options)
    except RuntimeError as error:  # no CUDA GPU for torch (`gpu.torch_device`)
        raise ValueError(f"--device {args.device}: {error}") from None
    print(f"{seq.name}: depth profile {profile}, {detection}, "
          f"radius {radius:g} m")
    skipped: list[str] = []
    written: list[tuple[Path, Path]] = []  # (temporary, final) of the .npz files
    counts: list[int] = []  # keypoints of each frame written
    with atomic_file(path) as h5_tmp:
        try:
            for name in tqdm(seq.names, desc=f"extract {args.descriptor}", unit="frame"):
                try:
                    frame, kps = frame_and_keypoints(seq, name, args)
                    features = descriptor.compute_cuda(frame, kps).to_host() if gpu else descriptor.compute(frame, kps)
                except ValueError as error:
                    skip_frame(skipped, name, error)
                    continue
                counts.append(len(features))
                if is_h5(path):
                    save_features(h5_tmp, features, name=name)
                else:
                    final = path.with_name(f"{path.stem}-{name}.npz")
                    tmp = partial_name(final)
                    save_features(tmp, features)
                    written.append((tmp, final))
            status = finish_skipped(skipped, len(seq), "extract")
            with signals_deferred():  # all the frames' files, or none: never this run's beside an earlier one's
                for tmp, final in written:
                    os.replace(tmp, final)
                written.clear()
            # as the .h5 (replaced whole) has no group for it: a skipped frame's file from an earlier run,
            # which --overwrite let replace, would mix that run's features with this one's
            stale = [] if is_h5(path) else [f for f in (path.with_name(f"{path.stem}-{n}.npz") for n in skipped)
                                            if f.exists() or f.is_symlink()]
            for final in stale:
                final.unlink()
            if stale:
                print(f"removed {', '.join(str(f) for f in stale)}: features of an earlier run for the frames "
                      "skipped in this one", file=sys.stderr)
        finally:
            for tmp, _ in written:
                tmp.unlink(missing_ok=True)
    where = path if is_h5(path) else path.with_name(f"{path.stem}-<frame>.npz")
    per_frame = "" if not counts else (f" ({min(counts)}" + (f"-{max(counts)}" if max(counts) != min(counts) else "")
                                       + f" keypoints per frame of --keypoints {args.keypoints})")
    print(f"wrote {args.descriptor} features of {plural(len(seq) - len(skipped), 'frame')} of {seq.folder}{per_frame} to {where}")
    return status


def check_device(device: str, descriptor: str) -> bool:
    """Whether `--device` asks for the GPU path (ValueError naming the flag for a device that is
    neither the CPU nor CUDA, for a descriptor the GPU path does not compute, or when no CUDA GPU
    can be used: `gpu.require_cuda` says what is missing)."""
    from ..gpu import is_cuda_device, require_cuda

    if not is_cuda_device(device):
        if device != "cpu":
            raise ValueError(f"--device: expected cpu, cuda or cuda:N, got {device!r}")
        return False
    base, _, weights = descriptor.partition("=")
    if base != "geopatch" or weights.lower().endswith(".onnx"):
        raise ValueError(f"--device {device}: the GPU path computes GeoPatch with torch weights only (--descriptor "
                         f"geopatch or geopatch=WEIGHTS.pt), not {descriptor}")
    try:
        require_cuda(device)
    except RuntimeError as error:
        raise ValueError(f"--device {device}: {error}") from None
    return True

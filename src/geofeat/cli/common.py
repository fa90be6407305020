"""Helpers shared by `extract` and `match`: file labels, skipped frames, a frame with its keypoints, the
GPU path of `--device`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..outputs import plural


def file_label(descriptor: str) -> str:
    """A descriptor name fit for a file name ("geopatch=runs/a.pt" -> "geopatch-a")."""
    if "=" in descriptor:
        name, path = descriptor.split("=", 1)
        return f"{name}-{Path(path).stem}"
    return descriptor


def is_h5(path: Path) -> bool:
    """True for a .h5 / .hdf5 name in any case, as `geofeat.save_features` reads it."""
    from ..features import file_format

    return file_format(path) == ".h5"


def features_path(out: Path, descriptor: str) -> Path:
    """`out` itself when it names a .h5 / .hdf5 / .npz file (any case, as `geofeat.save_features`
    takes them), else `out/features-<descriptor>.h5`."""
    from ..features import file_format

    return out if file_format(out) is not None else out / f"features-{descriptor}.h5"


def skip_frame(skipped: list[str], name: str, error: Exception) -> None:
    """Report a frame that cannot be processed by name; the run goes on and exits 1 at the end."""
    from tqdm import tqdm

    from ..io import skipped_frame_line

    skipped.append(name)
    tqdm.write(skipped_frame_line(name, error))


def finish_skipped(skipped: list[str], total: int, what: str) -> int:
    """Exit status after a run that skipped `skipped` of `total` frames (1 when any was skipped)."""
    if skipped and len(skipped) >= total:
        raise ValueError(f"{what}: every frame was skipped ({', '.join(skipped[:5])}); nothing written")
    if skipped:
        print(f"{plural(len(skipped), 'frame')} SKIPPED: {', '.join(skipped)}", file=sys.stderr)
        return 1
    return 0


def frame_and_keypoints(seq, name: str, args: argparse.Namespace):
    """(frame, keypoints) of frame `name` with the command's detector options; ValueError when the
    frame cannot be read, differs in size from the reference or has no keypoints (extract and match
    skip such a frame by name)."""
    from ..keypoints import detect

    frame = seq.frame(name)  # a frame of another size than the reference is its ValueError there
    kps = detect(frame, args.keypoints, detector=args.detector, keypoint_set=args.keypoint_set)
    if len(kps) == 0:
        raise ValueError("no keypoints detected")
    return frame, kps


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


def descriptor_for_device(args: argparse.Namespace, gpu: bool, **settings):
    """`make_descriptor(args.descriptor, **settings)`, on `args.device` with the torch backend when
    `gpu` (`check_device`'s answer); ValueError naming --device when torch cannot use that device."""
    from ..descriptors import make_descriptor

    options = {"device": args.device, "backend": "torch"} if gpu else {}
    try:
        return make_descriptor(args.descriptor, **settings, **options)
    except RuntimeError as error:  # no CUDA GPU for torch (`gpu.torch_device`)
        raise ValueError(f"--device {args.device}: {error}") from None


def describe(descriptor, frame, kps, gpu: bool):
    """`Features` of keypoints `kps` on `frame`: the GPU path's (`compute_cuda`, copied to the host)
    when `gpu`, else `descriptor.compute`'s."""
    return descriptor.compute_cuda(frame, kps).to_host() if gpu else descriptor.compute(frame, kps)

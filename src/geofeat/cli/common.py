"""Helpers shared by `extract` and `match`: file labels, skipped frames, a frame with its keypoints, the
GPU path of `--device` (its checks shared with `bench`, `track` and `retrieval`)."""

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


def check_device(device: str, descriptor: str, flag: str = "--descriptor") -> bool:
    """Whether `--device` asks for the GPU path (ValueError naming the flag for a device that is
    neither the CPU nor CUDA, for a descriptor the GPU path does not compute, given by `flag`, or
    when no CUDA GPU can be used: `gpu.require_cuda` says what is missing)."""
    from ..gpu import gpu_computes, is_cuda_device, require_cuda

    if not is_cuda_device(device):
        if device != "cpu":
            raise ValueError(f"--device: expected cpu, cuda or cuda:N, got {device!r}")
        return False
    if not gpu_computes(descriptor):
        raise ValueError(f"--device {device}: the GPU path computes GeoPatch with torch weights only ({flag} "
                         f"geopatch or geopatch=WEIGHTS.pt), not {descriptor}")
    try:
        require_cuda(device)
    except RuntimeError as error:
        raise ValueError(f"--device {device}: {error}") from None
    return True


def check_devices(device: str, descriptors: tuple[str, ...]) -> str | None:
    """`check_device` for the commands that run several descriptors (`bench`, `track`, `retrieval`):
    the device to give their functions, None for the CPU. `--device cuda[:N]` puts the GeoPatch ones
    of `--descriptors` on the GPU path and leaves the others on the CPU; refused, naming the flags, as
    `check_device` refuses, when none of them is GeoPatch or one is GeoPatch from an .onnx file."""
    from ..descriptors import check_descriptor_name
    from ..gpu import is_cuda_device

    if not is_cuda_device(device):
        check_device(device, "")  # "cpu", or the error naming --device
        return None
    names = [check_descriptor_name(d) for d in descriptors]  # "GeoPatch" is geopatch; an unknown name is its error
    geopatch = [d for d in names if d.partition("=")[0] == "geopatch"]
    if not geopatch:
        raise ValueError(f"--device {device}: the GPU path computes GeoPatch only, and --descriptors "
                         f"{','.join(names) or '(none)'} names none; add geopatch, or leave --device out")
    for name in geopatch:  # an .onnx GeoPatch refused by name; CUDA checked as extract checks it
        check_device(device, name, "--descriptors")
    return device


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

"""Helpers shared by `extract` and `match`: file labels, skipped frames, a frame with its keypoints."""

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

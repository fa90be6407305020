"""Features computed elsewhere (DALF, DISK, ALIKED, a user's own method), scored by `geofeat bench
--features NAME=PATH` on our protocol and ground truth, beside geofeat's own descriptors.

PATH is either
- an hloc-style `.h5` file: one group per frame, named `<sequence>/<frame>` or `<frame>` (the frame
  name as in the sequence folder, e.g. `frame-003` for `frame-003-rgb.png`), or
- a folder of `.npz` files: `PATH/<sequence>/<frame>.npz` or `PATH/<frame>.npz`.

Each group or file holds `keypoints` (N, 2) pixels (x, y), `descriptors` (N, ...) and optionally
`scores` (N,) (higher = better: with `n_keypoints` set, the best n are kept, so that no method is
compared at a larger budget than the others), `valid` (N,) bool and `metric` (a string). Without
`metric` it follows the descriptors' dtype: float -> L2, uint8 (N, B) -> Hamming, uint8 (N, R, B) ->
Hamming minimum over R; name `metric` "l2" for integer descriptors that are not packed bits (e.g. SIFT
stored as uint8). Keypoints must lie on the frame's image; float descriptors must be finite.
Float descriptors may also come as hloc's (D, N); an .h5 group without `valid` (as hloc writes them)
is read as (D, N) whenever its second axis has one entry per keypoint, even when D = N.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from ..features import Features, _h5_leaf_groups, descriptors_n_by_d
from ..keypoints import as_keypoints
from ..matching import METRICS, match


def parse_features_option(text: str) -> tuple[str, Path]:
    """'NAME=PATH' -> (NAME, PATH); PATH must exist (an .h5 file or a folder)."""
    name, sep, path = str(text).partition("=")
    if not sep or not name or not path:
        raise ValueError(f"features: expected NAME=PATH (an .h5 file or a folder of .npz files), got {text!r}")
    p = Path(path)
    if not p.exists():
        raise ValueError(f"features: {p} does not exist")
    if p.is_file() and p.suffix.lower() not in (".h5", ".hdf5"):
        raise ValueError(f"features: {p} is neither an .h5 file nor a folder of .npz files")
    return name, p


class ExternalFeatures:
    """Reads one method's features for the frames of a sequence."""

    def __init__(self, name: str, path: Path) -> None:
        self.name, self.path = name, Path(path)
        self._groups: set[str] | None = None
        #: the `metric` the files name (None: chosen from the descriptors' dtype, see `geofeat.match`)
        self.metric: str | None = None

    def _h5_groups(self) -> set[str]:
        if self._groups is None:
            import h5py

            try:
                with h5py.File(str(self.path), "r") as fd:
                    self._groups = set(_h5_leaf_groups(fd))
            except OSError as error:
                raise ValueError(f"features {self.name}: cannot read {self.path} as HDF5 ({error})") from None
        return self._groups

    def load(self, sequence: str, frame: str, n: int | None = None,
             shape: tuple[int, int] | None = None) -> Features:
        """The features of `frame` of `sequence`, best `n` by score when scores are given; with
        `shape` (H, W), every keypoint must lie on the image.

        Raises:
            ValueError naming the method, the frame and the file when they are missing or malformed.
        """
        arrays, source = self._read(sequence, frame)
        try:
            return self._features(arrays, n, shape, hloc_layout=self.path.is_file() and "valid" not in arrays)
        except (TypeError, ValueError) as error:
            raise ValueError(f"features {self.name}: {sequence}/{frame} ({source}): {error}") from None

    def _features(self, arrays: dict[str, np.ndarray], n: int | None, shape: tuple[int, int] | None,
                  hloc_layout: bool = False) -> Features:
        """`hloc_layout`: the group has hloc's layout (`features.descriptors_n_by_d`)."""
        if "keypoints" not in arrays or "descriptors" not in arrays:
            raise ValueError("lacks 'keypoints' or 'descriptors'")
        kp = as_keypoints(arrays["keypoints"], shape=shape, allow_empty=True).xy
        desc = descriptors_n_by_d(arrays["descriptors"], len(kp), hloc_layout)
        if desc.dtype.kind == "f" and not np.isfinite(desc).all():
            raise ValueError("descriptors hold NaN or infinite values; drop those keypoints")
        valid = arrays.get("valid")
        features = Features(kp, desc, np.ones(len(kp), bool) if valid is None else valid)
        self.metric = self._metric(arrays.get("metric"))
        match(features.descriptors, features.descriptors[:0], metric=self.metric)  # match's checks only (no target)
        scores = arrays.get("scores")
        if scores is not None:
            scores = np.asarray(scores, np.float64).reshape(-1)
            if scores.shape != (len(kp),) or not np.isfinite(scores).all():
                raise ValueError(f"scores: expected {len(kp)} finite values, one per keypoint, got shape "
                                 f"{scores.shape}{'' if np.isfinite(scores).all() else ' with NaN or inf'}")
            if n and len(kp) > n:
                keep = np.sort(np.argsort(-scores, kind="stable")[:n])
                features = Features(kp[keep], features.descriptors[keep], features.valid[keep])
        return features

    def _metric(self, value) -> str | None:
        """The `metric` a file names (None when it names none), one of `geofeat.matching.METRICS` and
        the same in every file of the method."""
        if value is None:
            return self.metric
        value = np.asarray(value)
        text = value.item() if value.size == 1 else value
        text = text.decode() if isinstance(text, bytes) else str(text)
        if text not in METRICS:
            raise ValueError(f"metric: {text!r} is not a metric geofeat matches with; expected one of "
                             f"{', '.join(METRICS)} (for cosine similarity, store L2-normalised descriptors "
                             "with metric 'l2')")
        if self.metric is not None and text != self.metric:
            raise ValueError(f"metric: {text!r} differs from the {self.metric!r} of frames read before")
        return text

    def _read(self, sequence: str, frame: str) -> tuple[dict[str, np.ndarray], str]:
        """The arrays of `frame` and where they come from (for messages)."""
        if self.path.is_file():
            groups = self._h5_groups()
            for key in (f"{sequence}/{frame}", frame):
                if key in groups:
                    import h5py

                    with h5py.File(str(self.path), "r") as fd:
                        return {k: np.asarray(v[()]) for k, v in fd[key].items()}, f"{self.path}, group {key}"
            raise ValueError(f"features {self.name}: no group '{sequence}/{frame}' or '{frame}' in {self.path}")
        for candidate in (self.path / sequence / f"{frame}.npz", self.path / f"{frame}.npz"):
            if candidate.is_file():
                try:
                    with np.load(candidate, allow_pickle=False) as data:
                        return {k: data[k] for k in data.files}, str(candidate)
                except (OSError, ValueError, zipfile.BadZipFile) as error:
                    raise ValueError(f"features {self.name}: cannot read {candidate} ({error})") from None
        raise ValueError(f"features {self.name}: no {sequence}/{frame}.npz or {frame}.npz under {self.path}")

"""Features computed elsewhere (DALF, DISK, ALIKED, a user's own method), scored by `geofeat bench
--features NAME=PATH` on our protocol and ground truth, beside geofeat's own descriptors.

PATH is either
- an hloc-style `.h5` file: one group per frame, named `<sequence>/<frame>` or `<frame>` (the frame
  name as in the sequence folder, e.g. `frame-003` for `frame-003-rgb.png`), or
- a folder of `.npz` files: `PATH/<sequence>/<frame>.npz` or `PATH/<frame>.npz`.

Each group or file holds `keypoints` (N, 2) pixels (x, y), `descriptors` (N, ...) and optionally
`scores` (N,) (higher = better: with `n_keypoints` set, the best n are kept, so that no method is
compared at a larger budget than the others) and `valid` (N,) bool. The metric follows the
descriptors' dtype: float -> L2, uint8 (N, B) -> Hamming, uint8 (N, R, B) -> Hamming minimum over R.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..features import Features, _h5_leaf_groups


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

    def _h5_groups(self) -> set[str]:
        if self._groups is None:
            import h5py

            with h5py.File(str(self.path), "r") as fd:
                self._groups = set(_h5_leaf_groups(fd))
        return self._groups

    def load(self, sequence: str, frame: str, n: int | None = None) -> Features:
        """The features of `frame` of `sequence`, best `n` by score when scores are given.

        Raises:
            ValueError naming the method and the frame when they are missing or malformed.
        """
        arrays = self._read(sequence, frame)
        if "keypoints" not in arrays or "descriptors" not in arrays:
            raise ValueError(f"features {self.name}: {sequence}/{frame} lacks 'keypoints' or 'descriptors'")
        kp = np.asarray(arrays["keypoints"], np.float64)
        if kp.ndim != 2 or kp.shape[1] != 2 or not np.isfinite(kp).all():
            raise ValueError(f"features {self.name}: {sequence}/{frame} keypoints must be a finite (N, 2) array, "
                             f"got shape {kp.shape}")
        desc = np.asarray(arrays["descriptors"])
        if desc.dtype.kind == "f" and desc.ndim == 2 and desc.shape[0] != len(kp) and desc.shape[1] == len(kp):
            desc = desc.T  # hloc stores float descriptors as (D, N)
        valid = arrays.get("valid")
        features = Features(kp, desc, np.ones(len(kp), bool) if valid is None else valid)
        scores = arrays.get("scores")
        if n and scores is not None and len(kp) > n:
            keep = np.sort(np.argsort(-np.asarray(scores, np.float64).reshape(-1), kind="stable")[:n])
            features = Features(kp[keep], features.descriptors[keep], features.valid[keep])
        return features

    def _read(self, sequence: str, frame: str) -> dict[str, np.ndarray]:
        if self.path.is_file():
            groups = self._h5_groups()
            for key in (f"{sequence}/{frame}", frame):
                if key in groups:
                    import h5py

                    with h5py.File(str(self.path), "r") as fd:
                        return {k: np.asarray(v[()]) for k, v in fd[key].items()}
            raise ValueError(f"features {self.name}: no group '{sequence}/{frame}' or '{frame}' in {self.path}")
        for candidate in (self.path / sequence / f"{frame}.npz", self.path / f"{frame}.npz"):
            if candidate.is_file():
                with np.load(candidate, allow_pickle=False) as data:
                    return {k: data[k] for k in data.files}
        raise ValueError(f"features {self.name}: no {sequence}/{frame}.npz or {frame}.npz under {self.path}")

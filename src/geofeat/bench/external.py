"""Features computed elsewhere (DALF, DISK, ALIKED, a user's own method), scored by `geofeat bench
--features NAME=PATH` on our protocol and ground truth, beside geofeat's own descriptors.

PATH is either
- an hloc-style `.h5` file: one group per frame, named `<sequence>/<frame>` or `<frame>` (the frame
  name as in the sequence folder, e.g. `frame-003` for `frame-003-rgb.png`), or by the colour image's
  file name as hloc names them (`<sequence>/frame-003-rgb.png` or `frame-003-rgb.png`), or
- a folder of `.npz` files: `PATH/<sequence>/<frame>.npz` or `PATH/<frame>.npz`, or
- the `.npz` path given to `geofeat extract --out DIR/NAME.npz`, which writes `DIR/NAME-<frame>.npz`
  (read from `DIR/<sequence>/NAME-<frame>.npz` or `DIR/NAME-<frame>.npz`).
A name without the sequence may serve one sequence only: two benched sequences whose frames would be
read from one group or file are refused (`check_one_source_per_frame`), and so is a sequence whose
frames would be read some from names with the sequence and some from names without it.

Each group or file holds `keypoints` (N, 2) pixels (x, y), 0-based with pixel centres at whole numbers
(OpenCV's, hloc's and kornia's convention: the top-left pixel's centre is (0, 0)), `descriptors` (N, ...)
and optionally `scores` (N,) (higher = better: with `n_keypoints` set, the best n are kept, so that no
method is compared at a larger budget than the others; without scores more than n keypoints are
refused), `valid` (N,) bool, `metric` (a string) and hloc's `image_size` (W, H) of the image the
keypoints are in pixels of (it must be the frame's). Without `metric` it follows the descriptors'
dtype: float -> L2, uint8 (N, B) -> Hamming, uint8 (N, R, B) -> Hamming minimum over R; name `metric`
"l2" for integer descriptors that are not packed bits (e.g. SIFT stored as uint8: uint8 descriptors
with many zero bytes and no `metric` are refused as ambiguous). Keypoints must lie on the frame's image
and not all within 1 px of the origin (normalised coordinates); float descriptors must be finite. An
array whose name is close to one of these (`score`, `Metric`) is refused rather than ignored.
Float descriptors may also come as hloc's (D, N); an .h5 group without `valid` (as hloc writes them)
is read as (D, N) whenever its second axis has one entry per keypoint, even when D = N.
"""

from __future__ import annotations

import glob
import hashlib
from pathlib import Path

import numpy as np

from ..features import (Features, _h5_leaf_groups, _h5_read_group, _open_h5, descriptors_n_by_d, float16_step,
                        features_source_record, read_features_source, read_npz, warn_float16_keypoints)
from ..io import RGB_SUFFIX, frame_digest, frame_names, reference_name
from ..keypoints import as_keypoints
from ..matching import METRICS, match, quantised_zero_share


def parse_features_option(text: str) -> tuple[str, Path]:
    """'NAME=PATH' -> (NAME, PATH); PATH must exist (an .h5 file or a folder)."""
    name, sep, path = str(text).partition("=")
    if not sep or not name or not path:
        raise ValueError(f"features: expected NAME=PATH (an .h5 file or a folder of .npz files), got {text!r}")
    p = Path(path)
    if not p.exists() and _is_extract_prefix(p):
        return name, p
    if not p.exists():
        raise ValueError(f"features: {p} does not exist" + (f" (nor any {p.stem}-<frame>.npz beside it, as `geofeat "
                                                             f"extract --out {p}` writes)" if _npz_named(p) else ""))
    if p.is_file() and p.suffix.lower() not in (".h5", ".hdf5"):
        raise ValueError(f"features: {p} is neither an .h5 file nor a folder of .npz files")
    return name, p


def _npz_named(path: Path) -> bool:
    return path.suffix.lower() == ".npz"


def _is_extract_prefix(path: Path) -> bool:
    """Whether `path` (DIR/NAME.npz, not a file) names the files `geofeat extract --out DIR/NAME.npz` writes:
    some `DIR/NAME-<frame>.npz` or `DIR/<sequence>/NAME-<frame>.npz`."""
    if not _npz_named(path) or not path.parent.is_dir():
        return False
    pattern = f"{glob.escape(path.stem)}-*.npz"  # as extract names them whatever the case of --out's suffix
    return any(path.parent.glob(pattern)) or any(path.parent.glob(f"*/{pattern}"))


#: the arrays a group or file may hold that are read (`angles`, `sizes`: as `geofeat extract` writes them)
FIELDS = ("keypoints", "descriptors", "scores", "valid", "metric", "image_size", "angles", "sizes")


def _check_field_names(arrays: dict) -> None:
    """Refuse an array whose name is a near miss of a field that is read (`score`, `Metric`,
    `descriptor`): it would be ignored, and the numbers made without it."""
    import difflib

    for key in arrays:
        if key in FIELDS:
            continue
        near = [f for f in FIELDS if f == key.lower()] or difflib.get_close_matches(key.lower(), FIELDS, 1, 0.75)
        if near:
            raise ValueError(f"holds {key!r}, which is not read; did you mean {near[0]!r}? "
                             f"(the fields read: {', '.join(FIELDS)})")


def _check_pixels(kp: np.ndarray, image_size, shape: tuple[int, int] | None) -> None:
    """Keypoints in pixels of this frame: hloc's `image_size` (W, H), when stored, is the frame's, and
    they are not normalised coordinates (all within 1 px of the origin, which pass the on-image check)."""
    if shape is None:
        return
    H, W = shape
    if image_size is not None:
        size = np.asarray(image_size).reshape(-1)
        if size.shape != (2,) or not np.array_equal(size.astype(np.float64), [W, H]):
            raise ValueError(f"image_size {size.tolist()} (hloc's (W, H)) is not the frame's {[W, H]}: keypoints "
                             "must be pixels of the frame itself (rescale those found on a resized image)")
    if len(kp) >= 5 and max(W, H) > 4 and (np.abs(kp) <= 1.0).all():
        raise ValueError(f"all {len(kp)} keypoints lie within 1 px of the origin: normalised coordinates? "
                         f"expected (x, y) pixels of the {W}x{H} image")


def _check_bytes_are_bits(desc: np.ndarray) -> None:
    """uint8 descriptors without `metric` are matched as packed bits; SIFT or another quantised float
    descriptor stored as uint8 would then be matched by a wrong distance without a word said."""
    zeros = quantised_zero_share(desc)  # the rule `geofeat.match` warns by
    if zeros is not None:
        raise ValueError(f"uint8 descriptors without 'metric', {zeros:.0%} of their bytes 0: packed bits have "
                         "about 0.4 %; store 'metric' 'l2' for a quantised descriptor such as SIFT, or 'hamming' "
                         "for packed bits")


def _check_no_repeats(kp: np.ndarray, desc: np.ndarray) -> None:
    """Refuse a keypoint stored twice with the same descriptor (e.g. a frame's arrays concatenated
    twice): each copy takes a place of the --keypoints budget and the copies tie in matching. Keypoints
    at one position with other descriptors (SIFT's several orientations) are kept."""
    if len(kp) < 2 or np.ndim(desc) < 1 or len(desc) != len(kp):
        return
    rows = np.concatenate([np.ascontiguousarray(kp, np.float64).view(np.uint8).reshape(len(kp), -1),
                           np.ascontiguousarray(desc).view(np.uint8).reshape(len(kp), -1)], axis=1)
    unique = np.unique(rows, axis=0)
    if len(unique) < len(kp):
        raise ValueError(f"{len(kp) - len(unique)} of {len(kp)} keypoints repeat an earlier one, position and "
                         "descriptor alike; store each once (geofeat extract: --keypoint-set unique, which a "
                         "descriptor that ignores the keypoint angle, as GeoBit and GeoPatch do, needs)")


class ExternalFeatures:
    """Reads one method's features for the frames of a sequence."""

    def __init__(self, name: str, path: Path) -> None:
        self.name, self.path = name, Path(path)
        self._groups: set[str] | None = None
        #: the `metric` the files name (None: chosen from the descriptors' dtype, see `geofeat.match`)
        self.metric: str | None = None
        #: the largest float16 rounding step warned about so far (`features.warn_float16_keypoints`)
        self._float16_warned = 0.0

    def _h5_groups(self) -> set[str]:
        if self._groups is None:
            try:
                with _open_h5(self.path, "r") as fd:
                    self._groups = set(_h5_leaf_groups(fd))
            except ValueError as error:  # not HDF5, or truncated: the file named
                raise ValueError(f"features {self.name}: {error}") from None
        return self._groups

    def load(self, sequence: str, frame: str, n: int | None = None,
             shape: tuple[int, int] | None = None) -> Features:
        """The features of `frame` of `sequence`, best `n` by score when scores are given; with
        `shape` (H, W), every keypoint must lie on the image.

        Float16 keypoints (hloc's `as_half`) are read as stored, with a warning naming the file when their
        rounding reaches 0.5 px (`features.warn_float16_keypoints`; once per feature set, again only for a larger step).

        Raises:
            ValueError naming the method, the frame and the file when they are missing or malformed.
        """
        arrays, source = self._read(sequence, frame)
        if float16_step(arrays.get("keypoints")) > self._float16_warned:  # once per feature set and step, not per frame
            self._float16_warned = max(self._float16_warned, warn_float16_keypoints(
                arrays["keypoints"], f"features {self.name}: {sequence}/{frame} ({source})"))
        try:
            return self._features(arrays, n, shape, hloc_layout=self.path.is_file() and "valid" not in arrays)
        except (TypeError, ValueError) as error:
            raise ValueError(f"features {self.name}: {sequence}/{frame} ({source}): {error}") from None

    def _features(self, arrays: dict[str, np.ndarray], n: int | None, shape: tuple[int, int] | None,
                  hloc_layout: bool = False) -> Features:
        """`hloc_layout`: the group has hloc's layout (`features.descriptors_n_by_d`)."""
        _check_field_names(arrays)
        if "keypoints" not in arrays or "descriptors" not in arrays:
            raise ValueError("lacks 'keypoints' or 'descriptors'")
        kp = as_keypoints(arrays["keypoints"], shape=shape, allow_empty=True).xy
        _check_pixels(kp, arrays.get("image_size"), shape)
        desc = descriptors_n_by_d(arrays["descriptors"], len(kp), hloc_layout)
        if desc.dtype.kind == "f" and not np.isfinite(desc).all():
            raise ValueError("descriptors hold NaN or infinite values; drop those keypoints")
        _check_no_repeats(kp, desc)
        valid = arrays.get("valid")
        features = Features(kp, desc, np.ones(len(kp), bool) if valid is None else valid)
        self.metric = self._metric(arrays.get("metric"))
        if self.metric is None:
            _check_bytes_are_bits(features.descriptors)
        match(features.descriptors, features.descriptors[:0], metric=self.metric)  # match's checks only (no target)
        scores = arrays.get("scores")
        if scores is None and n and len(kp) > n:
            raise ValueError(f"{len(kp)} keypoints and no 'scores' to keep the best --keypoints {n} by: store "
                             f"'scores' (higher = better), or at most {n} keypoints")
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

    def source(self, sequence: str, frame: str) -> str | None:
        """The group (.h5) or file (.npz) that `frame` of `sequence` is read from; None when none is."""
        if self.path.is_file():
            groups = self._h5_groups()
            image = f"{frame}{RGB_SUFFIX}"  # hloc names a group by the image file
            for key in (f"{sequence}/{frame}", frame, f"{sequence}/{image}", image):
                if key in groups:
                    return key
            return None
        if self.path.is_dir():
            candidates = (self.path / sequence / f"{frame}.npz", self.path / f"{frame}.npz")
        else:  # `geofeat extract --out DIR/NAME.npz`'s files
            where, file = self.path.parent, f"{self.path.stem}-{frame}.npz"  # extract's names, even for --out NAME.NPZ
            candidates = (where / sequence / file, where / file)
        for candidate in candidates:
            if candidate.is_file():
                return str(candidate)
        return None

    def names_sequence(self, sequence: str, key: str) -> bool:
        """Whether the group or file `key` (from `source`) is named with `sequence`
        ('<sequence>/<frame>' in the .h5, or under PATH/<sequence>/), not by the frame alone."""
        if self.path.is_file():
            return key.startswith(f"{sequence}/")
        base = self.path if self.path.is_dir() else self.path.parent
        return Path(key).parent == base / sequence

    def digest(self, sequence: str, frames: list[str]) -> str:
        """SHA-1 (hex) of what `load` reads for `frames` of `sequence`: each frame's group (.h5: its
        datasets' names, dtypes, shapes and bytes) or file (.npz: its bytes), or that it has none.
        It changes when the features of one of these frames are rewritten in place, and not when
        groups or files of other sequences are added (`geofeat bench` resumes by it)."""
        digest = hashlib.sha1()
        keys = [self.source(sequence, frame) for frame in frames]
        if self.path.is_file() and any(key is not None for key in keys):
            import h5py

            with _open_h5(self.path, "r") as fd:
                for frame, key in zip(frames, keys):
                    digest.update(f"{frame}\0{key}\0".encode())
                    if key is None:
                        continue
                    group = fd[key]
                    for name in sorted(group):
                        if isinstance(group[name], h5py.Dataset):
                            value = np.asarray(group[name][()])
                            digest.update(f"{name}\0{value.dtype.str}\0{value.shape}\0".encode())
                            digest.update(np.ascontiguousarray(value).tobytes() if value.dtype.kind != "O"
                                          else repr(value.tolist()).encode())
            return digest.hexdigest()
        for frame, key in zip(frames, keys):
            digest.update(f"{frame}\0{key is not None}\0".encode())
            if key is not None:
                with open(key, "rb") as fh:
                    for block in iter(lambda: fh.read(1 << 20), b""):
                        digest.update(block)
        return digest.hexdigest()

    def _read(self, sequence: str, frame: str) -> tuple[dict[str, np.ndarray], str]:
        """The arrays of `frame` and where they come from (for messages)."""
        key = self.source(sequence, frame)
        if self.path.is_file():
            if key is not None:  # a group `_h5_groups` listed
                return _h5_read_group(self.path, key), f"{self.path}, group {key}"
            some = sorted(self._h5_groups())[:3]
            raise ValueError(f"features {self.name}: no group '{sequence}/{frame}' or '{frame}' (or "
                             f"'{frame}{RGB_SUFFIX}') in {self.path}; it holds e.g. {some} (names are matched "
                             "exactly, case included)")
        if key is not None:  # an existing file (`source`)
            try:
                return read_npz(key), key
            except ValueError as error:
                raise ValueError(f"features {self.name}: {error}") from None
        if not self.path.is_dir():
            file = f"{self.path.stem}-{frame}.npz"
            raise ValueError(f"features {self.name}: no {sequence}/{file} or {file} in {self.path.parent}")
        raise ValueError(f"features {self.name}: no {sequence}/{frame}.npz or {frame}.npz under {self.path}")


def check_one_source_per_frame(features: list[ExternalFeatures], sequences: dict[str, list[str]]) -> None:
    """Refuse feature sets that would score two sequences' frames with one group or file: names
    without the sequence (`frame-000`) serve any sequence whose frame has that name, so a second
    benched sequence would silently be scored with the first one's features. Also refuse a sequence
    whose frames are read some from names with the sequence and some from names without it: a frame
    missing under the sequence's name would be scored with the features that the bare name holds,
    another sequence's. `sequences`: sequence name -> its frame names."""
    for f in features:
        seen: dict[str, str] = {}
        for sequence, frames in sequences.items():
            named, bare = [], []
            for frame in frames:
                key = f.source(sequence, frame)
                if key is None:
                    continue
                if key in seen and seen[key] != sequence:
                    raise ValueError(f"features {f.name}: {frame} of {seen[key]} and of {sequence} would both be read "
                                     f"from {key!r}; name each frame '<sequence>/<frame>' (.h5) or put the .npz files "
                                     f"in PATH/<sequence>/ when benching several sequences")
                seen[key] = sequence
                (named if f.names_sequence(sequence, key) else bare).append((frame, key))
            if named and bare:
                raise ValueError(f"features {f.name}: {sequence}: {bare[0][0]} would be read from {bare[0][1]!r}, a name "
                                 f"without the sequence, {named[0][0]} from {named[0][1]!r}: are the features of "
                                 f"{sequence}/{bare[0][0]} missing (the name without the sequence may hold another "
                                 "sequence's)? Name every frame of the sequence alike")


def check_extract_sources(features: list[ExternalFeatures], folders: list[str | Path]) -> None:
    """Refuse the `.npz` files of `geofeat extract --out DIR/NAME.npz` for a benched sequence when
    the record extract wrote beside them (`features.features_source_record`) says they are features
    of another sequence: its reference frame's content differs from the benched sequence's (a copy
    of the same sequence elsewhere passes). Frame names alone cannot tell: every simulated sequence
    has `frame-000-master` ... `frame-007`, so another sequence's features were scored without a word.
    Files without a record (written by an older geofeat, or by hand) are read as before."""
    for f in features:
        if f.path.is_file() or f.path.is_dir() or not _npz_named(f.path):  # not extract's one file per frame
            continue
        for folder in folders:
            names, sequence = frame_names(folder), Path(folder).name
            keys = [f.source(sequence, n) for n in names] if names else []
            for where in dict.fromkeys(Path(k).parent for k in keys if k is not None):
                prefix = where / f.path.name
                record = read_features_source(prefix, what=f"features {f.name}")
                if record is None:
                    continue
                reference = reference_name(names)
                if record.get("reference_digest") != frame_digest(folder, reference):
                    raise ValueError(
                        f"features {f.name}: {features_source_record(prefix)} says the {prefix.stem}-<frame>.npz files "
                        f"there are features of {record.get('sequence')} (reference frame {record.get('reference')}), "
                        f"not of {folder}, whose reference frame {reference} differs: they would score {sequence} "
                        f"with another sequence's features; extract {sequence}'s, or put each sequence's files in "
                        f"{f.path.parent}/<sequence>/")

"""Feature records (keypoints + descriptors) and matches, with .npz / .h5 storage.

The .h5 layout follows hloc's ``features.h5`` / ``matches.h5``: one group per image (or per image
pair) holding plain datasets, so files written here can be read by hloc-style tools and back:

- features: ``/<image name>/keypoints`` (N, 2) float32 pixels (x, y), ``descriptors`` (N, ...);
  float (N, D) descriptors are stored as hloc stores them, (D, N), with the dataset attribute
  ``layout = "DxN"`` (files written before it, without the attribute, hold (N, D) and still read
  right), ``valid`` (N,) bool, and optionally ``angles`` (N,), ``sizes`` (N,) and ``scores`` (N,) (the
  detector's, higher = better, as hloc names them).
- matches: ``/<pair name>/matches0`` (N0,) int64 (-1 = no match), ``distances`` (N0,) float64.

Image names may contain ``/`` (nested groups, as in hloc). The .npz layout stores the same arrays
at the top level of one archive per image (or pair).
"""

from __future__ import annotations

import warnings
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .inputs import error_summary
from .outputs import write_npz

__all__ = [
    "Features",
    "Matches",
    "save_features",
    "load_features",
    "save_matches",
    "load_matches",
]


def fields_equal(a, b, names: tuple[str, ...]) -> bool:
    """The fields `names` of records `a` and `b` hold equal arrays (shape and values; NaN equals NaN,
    as the NaN sizes of keypoints given as bare pixels; None only equals None). The `==` of the
    dataclasses `Features`, `Matches` and `Keypoints`: the generated one compared tuples of arrays,
    "The truth value of an array with more than one element is ambiguous" for any two records."""
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        if x is None or y is None:
            if x is not y:
                return False
            continue
        x, y = np.asarray(x), np.asarray(y)
        floats = x.dtype.kind in "fc" and y.dtype.kind in "fc"
        if not np.array_equal(x, y, equal_nan=floats):
            return False
    return True


@dataclass(eq=False)
class Features:
    """Local features of one image.

    Attributes:
        keypoints: (N, 2) float64 image pixel coordinates (x, y), OpenCV convention.
        descriptors: (N, ...) array of numbers, e.g. (N, 16, 64) uint8 for GeoBit, (N, 128) float32 for
            GeoPatch; another dtype (object, str, complex) raises TypeError.
        valid: (N,) bool; False where no descriptor could be computed (such keypoints never match).
            Given as numbers, only 0 and 1 are flags: other values (scores) raise ValueError.
        angles: optional (N,) detector orientation, degrees as OpenCV reports it.
        sizes: optional (N,) detector keypoint diameter, pixels.
        scores: optional (N,) detector score (higher = better; `Keypoints.scores`), so that a set can be
            cut to its best n later (`geofeat bench --features` does).
        method: optional name of the descriptor that computed them ("geopatch", "orb", "brand", ...; every
            geofeat descriptor sets it, files keep it): `geofeat.match` refuses two sets of different
            methods, which may share a shape and dtype (ORB's and BRAND's (N, 32) uint8). Not compared by `==`.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    valid: np.ndarray
    angles: np.ndarray | None = None
    sizes: np.ndarray | None = None
    scores: np.ndarray | None = None
    method: str | None = None

    def __post_init__(self) -> None:
        try:
            kp = np.asarray(self.keypoints, dtype=np.float64)
        except (TypeError, ValueError) as error:  # cv2.KeyPoints: "float() argument must be ...", naming nothing
            what = type(self.keypoints).__name__
            if isinstance(self.keypoints, (list, tuple)) and self.keypoints:
                what = f"a {what} of {type(self.keypoints[0]).__module__}.{type(self.keypoints[0]).__name__}"
            raise TypeError(f"keypoints: expected an (N, 2) array of (x, y) pixels, got {what} (for cv2.KeyPoints: "
                            "geofeat.as_keypoints(keypoints).xy)") from error
        if kp.size == 0:
            kp = kp.reshape(0, 2)
        if kp.ndim != 2 or kp.shape[1] != 2:
            raise ValueError(f"keypoints: expected shape (N, 2), got {kp.shape}")
        if not np.isfinite(kp).all():  # a loaded file's NaN positions went on into matching, pictures and fits
            bad = np.flatnonzero(~np.isfinite(kp).all(axis=1))
            raise ValueError(f"keypoints: {len(bad)} not finite (NaN or inf), e.g. keypoint {bad[0]} at "
                             f"{kp[bad[0]].tolist()}; every keypoint needs a pixel position (mark a keypoint "
                             "without a descriptor with valid=False instead)")
        n = kp.shape[0]
        desc = np.asarray(self.descriptors)
        if desc.dtype.kind not in "biuf":
            # an object array (a pandas column of arrays) was kept: its .npz was written pickled and then
            # refused by load_features, and h5py's "no native HDF5 equivalent" came after the group's old
            # datasets were deleted
            hint = "; for an array of per-keypoint arrays: np.stack(descriptors)" if desc.dtype == object else ""
            raise TypeError(f"descriptors: expected an (N, ...) array of numbers (float, or uint8 bits), got dtype "
                            f"{desc.dtype}{hint}")
        if desc.ndim < 1 or desc.shape[0] != n:
            raise ValueError(f"descriptors: expected first axis N={n}, got shape {desc.shape}")
        valid = np.ones(n, bool) if self.valid is None else np.asarray(self.valid)
        if valid.dtype != bool and valid.size and not np.isin(valid, (0, 1)).all():
            # another tool's scores or visibility codes: 0.1 and 2 were both read as True
            odd = np.unique(valid[~np.isin(valid, (0, 1))])
            raise ValueError(f"valid: expected flags (bool, or 0 and 1), got {valid.dtype} values such as "
                             f"{odd[:3].tolist()}; a score is not a flag")
        valid = valid.astype(bool).reshape(-1)
        if valid.shape != (n,):
            raise ValueError(f"valid: expected shape ({n},), got {valid.shape}")
        self.keypoints, self.descriptors, self.valid = kp, desc, valid
        for name in ("angles", "sizes", "scores"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=np.float64).reshape(-1)
                if value.shape != (n,):
                    raise ValueError(f"{name}: expected shape ({n},), got {value.shape}")
                setattr(self, name, value)
        if self.method is not None:
            if isinstance(self.method, np.ndarray) and self.method.ndim == 0:  # as a file stores it
                self.method = self.method.item()
            if isinstance(self.method, bytes):
                self.method = self.method.decode()
            if not isinstance(self.method, str) or not self.method.strip():
                raise ValueError(f"method: expected a descriptor name or None, got {self.method!r}")

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])

    def __eq__(self, other) -> bool:
        """Equal keypoints, descriptors, valid flags, angles, sizes and scores (`fields_equal`)."""
        if not isinstance(other, Features):
            return NotImplemented
        return fields_equal(self, other, ("keypoints", "descriptors", "valid", "angles", "sizes", "scores"))

    __hash__ = None

    def __repr__(self) -> str:  # the dataclass's printed every array in full
        d = self.descriptors
        extras = "".join(f", {name}" for name in ("angles", "sizes", "scores") if getattr(self, name) is not None)
        of = f" of {self.method}" if self.method else ""
        return (f"Features({len(self)} keypoints{of}, {int(self.valid.sum())} valid, descriptors {tuple(d.shape)} "
                f"{d.dtype}{extras})")


@dataclass(eq=False)
class Matches:
    """Nearest-neighbour matches from the keypoints of image 0 to those of image 1.

    Attributes:
        matches0: (N0,) int64 index into image 1, -1 where keypoint i of image 0 has no match.
        distances0: (N0,) float64 descriptor distance of each match (Hamming bits or L2), inf where
            matches0 is -1.
    """

    matches0: np.ndarray
    distances0: np.ndarray

    def __post_init__(self) -> None:
        m0 = np.asarray(self.matches0)
        # bool flags (m.matches0 >= 0) read as indices 1 and 0, scores in [0, 1) as index 0 (truncated),
        # NaN was "cannot convert float NaN to integer", naming nothing
        if m0.dtype.kind not in "iuf" and m0.size:
            raise ValueError(f"matches0: expected (N0,) whole-number indices into image 1 (-1 = no match), got dtype "
                             f"{m0.dtype}" + ("; a mask of matched keypoints is not an index" if m0.dtype == bool else ""))
        if m0.dtype.kind == "f" and not (np.isfinite(m0) & (m0 == np.round(m0))).all():
            odd = m0[~(np.isfinite(m0) & (m0 == np.round(m0)))]
            raise ValueError(f"matches0: expected whole-number indices into image 1 (-1 = no match), got values such "
                             f"as {odd[:3].tolist()}; a score or distance is not an index")
        m0 = m0.astype(np.int64).reshape(-1)
        if (m0 < -1).any():
            raise ValueError(f"matches0: expected indices into image 1 or -1 (no match), got {int(m0.min())}")
        self.matches0 = m0
        self.distances0 = np.asarray(self.distances0, dtype=np.float64).reshape(-1)
        if self.matches0.shape != self.distances0.shape:
            raise ValueError(
                f"distances0: expected shape {self.matches0.shape} like matches0, got {self.distances0.shape}"
            )

    def __len__(self) -> int:
        return int(self.matches0.shape[0])

    def __eq__(self, other) -> bool:
        """Equal matches0 and distances0 (`fields_equal`)."""
        if not isinstance(other, Matches):
            return NotImplemented
        return fields_equal(self, other, ("matches0", "distances0"))

    __hash__ = None

    def __repr__(self) -> str:
        return f"Matches({len(self)} keypoints of image 0, {int((self.matches0 >= 0).sum())} matched)"

    @property
    def pairs(self) -> np.ndarray:
        """(M, 2) int64 index pairs (i0, i1) of the accepted matches."""
        i0 = np.flatnonzero(self.matches0 >= 0)
        return np.stack([i0, self.matches0[i0]], axis=1)


def file_format(path: str | Path) -> str | None:
    """".h5" for a .h5 / .hdf5 name, ".npz" for a .npz one (any case), None for any other name."""
    suffix = Path(path).suffix.lower()
    if suffix in (".h5", ".hdf5"):
        return ".h5"
    return ".npz" if suffix == ".npz" else None


def _suffix(path: str | Path) -> str:
    """`file_format`, or ValueError for a name that is neither."""
    fmt = file_format(path)
    if fmt is None:
        raise ValueError(f"path: expected a .npz or .h5 file name, got {str(path)!r}")
    return fmt


def _require_name(name: str | None, path: str | Path) -> str:
    if not name:
        raise ValueError(f"name: an image (or pair) name is required to store into the .h5 file {str(path)!r}")
    name = str(name)
    # HDF5 reads '.', '..' and empty parts as paths ('.' wrote into the file's root group, which the
    # name listing then did not show; '/a' and 'a//b' are listed as 'a' and 'a/b')
    if any(part in ("", ".", "..") for part in name.split("/")):
        raise ValueError(f"name: {name!r} has an empty, '.' or '..' part between its slashes; an .h5 name is a "
                         "relative path such as 'dir/image.png'")
    return name


#: Key under which an .npz file keeps the image (or pair) name it was saved with, when one was given.
NPZ_NAME_KEY = "name"


def _npz_with_name(arrays: dict[str, np.ndarray], name: str | None) -> dict[str, np.ndarray]:
    """`arrays` plus the image (or pair) `name` as a 0-d string array, when one is given."""
    return arrays if name is None else {**arrays, NPZ_NAME_KEY: np.array(str(name))}


def _check_npz_name(arrays: dict[str, np.ndarray], name: str | None, path: str | Path) -> None:
    """An .npz file holds one image (or pair): asked for `name`, it must be the name it was saved with
    (ValueError naming both otherwise; a file saved without a name passes). Reading `name` from an
    .npz file returned whatever image the file held, e.g. the last of several saved to one file."""
    stored = arrays.get(NPZ_NAME_KEY)
    if name is None or stored is None or stored.ndim != 0 or str(stored) == str(name):
        return
    raise ValueError(f"name: {str(path)!r} holds {str(stored)!r}, not {str(name)!r}; an .npz file holds one image "
                     "(or pair): save each to its own file, or use an .h5 file for several")


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """The arrays of an .npz archive (no pickled objects). FileNotFoundError for a missing file,
    ValueError naming it for one that is not a whole .npz (truncated, another format, a bare .npy)."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"path: {str(path)!r} does not exist")
    try:
        data = np.load(str(path), allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):  # an .npy under an .npz name
            raise ValueError("a single .npy array, not an .npz archive")
        with data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as error:
        raise ValueError(f"path: cannot read {str(path)!r} as an .npz archive ({error_summary(error)})") from None


def _open_h5(path: str | Path, mode: str):
    """h5py.File(path, mode); ValueError naming the file for one that is truncated or not HDF5 at all
    (h5py's OSError names none)."""
    import h5py

    try:
        return h5py.File(str(path), mode)
    except OSError as error:
        raise ValueError(f"path: cannot read {str(path)!r} as HDF5 ({error_summary(error)})") from None


#: Attribute of an .h5 `descriptors` dataset that `save_features` stored transposed, as hloc does.
LAYOUT_ATTR, LAYOUT_D_BY_N = "layout", "DxN"


def _hloc_descriptors(value: np.ndarray) -> bool:
    """Whether `descriptors` go into an .h5 file transposed, as hloc's (D, N): float and 2-D. Written
    as (N, D), hloc's matchers read N as the descriptor length, which with as many keypoints in both
    images (a fixed `n`) matched garbage without an error."""
    return value.dtype.kind == "f" and value.ndim == 2


def _h5_write_group(path: str | Path, name: str, arrays: dict[str, np.ndarray]) -> None:
    import h5py

    with _open_h5(path, "a") as fd:
        grp = fd.require_group(name)
        for key in [k for k, v in grp.items() if isinstance(v, h5py.Dataset)]:
            del grp[key]  # the datasets of `name` only: a nested name ("name/other") is another image's group
        for key, value in arrays.items():
            value = np.asarray(value)
            if key == "descriptors" and _hloc_descriptors(value):
                grp.create_dataset(key, data=np.ascontiguousarray(value.T)).attrs[LAYOUT_ATTR] = LAYOUT_D_BY_N
            else:
                grp.create_dataset(key, data=value)


def _h5_dataset(ds) -> np.ndarray:
    """A dataset's values; `descriptors` that `save_features` stored as (D, N) come back as (N, D)."""
    value = np.asarray(ds[()])
    layout = ds.attrs.get(LAYOUT_ATTR)
    if isinstance(layout, bytes):
        layout = layout.decode()
    return value.T if layout == LAYOUT_D_BY_N and value.ndim == 2 else value


def _h5_read_group(path: str | Path, name: str | None) -> dict[str, np.ndarray]:
    import h5py

    if not Path(path).exists():
        raise FileNotFoundError(f"path: {str(path)!r} does not exist")
    with _open_h5(path, "r") as fd:
        if name is None:
            names = _h5_leaf_groups(fd)
            if len(names) != 1:
                raise ValueError(
                    f"name: {str(path)!r} holds {len(names)} groups; pass one of them, e.g. {names[:3]}"
                )
            name = names[0]
        name = str(name)
        group = fd.get(name)
        arrays = {} if not isinstance(group, h5py.Group) else \
            {key: _h5_dataset(ds) for key, ds in group.items() if isinstance(ds, h5py.Dataset)}
        if not arrays:  # missing, a dataset, or a folder of other names ("dir" of "dir/img.png")
            held = _h5_leaf_groups(fd)
            listed = ", ".join(map(repr, held[:5])) + (f", ... ({len(held)} in all)" if len(held) > 5 else "")
            raise ValueError(f"name: {str(path)!r} has no group {name!r}; " + (
                f"it holds {listed} (names are matched exactly, case included)" if held else "it holds no group"))
        return arrays


def _h5_leaf_groups(fd) -> list[str]:
    import h5py

    out: list[str] = []

    def visit(name, obj):
        if isinstance(obj, h5py.Group) and any(isinstance(v, h5py.Dataset) for v in obj.values()):
            out.append(name)

    fd.visititems(visit)
    return out


def list_names(path: str | Path) -> list[str]:
    """Image (or pair) names stored in an .h5 features / matches file."""
    with _open_h5(path, "r") as fd:
        return _h5_leaf_groups(fd)


def _checked_again(record, fields: tuple[str, ...]):
    """A `Features` or `Matches` record built again from its `fields`, so checked as its constructor
    checks one: the records are mutable, and one whose fields were replaced or edited after it was made
    (keypoints filtered without their descriptors, a NaN written in place) was saved without a word and
    then refused by the loader. Same error type, naming the record."""
    try:
        return type(record)(*(getattr(record, name) for name in fields))
    except (TypeError, ValueError) as error:
        raise type(error)(f"{type(record).__name__.lower()}: {error} (changed after the record was made? a file "
                          "is written only when it can be read back)") from None


def save_features(path: str | Path, features: Features, name: str | None = None) -> None:
    """Write `features` to an .npz file (one image per file; `name`, when given, is kept with it and
    checked by `load_features`) or into group `name` of an .h5 file (hloc features.h5 layout; other
    groups of the file are kept, an existing `name` is replaced). The record is checked again first (as
    its constructor checks it): one edited after it was made so that it no longer loads is refused."""
    if not isinstance(features, Features):
        raise TypeError(f"features: expected a Features record, got {type(features).__name__}")
    features = _checked_again(features, ("keypoints", "descriptors", "valid", "angles", "sizes", "scores", "method"))
    arrays = {
        "keypoints": features.keypoints.astype(np.float32 if _suffix(path) == ".h5" else np.float64),
        "descriptors": features.descriptors,
        "valid": features.valid,
    }
    if features.angles is not None:
        arrays["angles"] = features.angles
    if features.sizes is not None:
        arrays["sizes"] = features.sizes
    if features.scores is not None:
        arrays["scores"] = features.scores
    if features.method is not None:
        arrays["method"] = np.bytes_(features.method.encode())  # bytes: h5py stores no numpy unicode
    if _suffix(path) == ".npz":
        write_npz(path, _npz_with_name(arrays, name))
    else:
        _h5_write_group(path, _require_name(name, path), arrays)


def _require_arrays(arrays: dict[str, np.ndarray], keys: tuple[str, ...], path, what: str) -> None:
    """ValueError naming the file and what it holds when one of `keys` is missing (e.g. a matches
    file given to `load_features`), rather than a bare KeyError."""
    missing = [key for key in keys if key not in arrays]
    if missing:
        raise ValueError(f"path: {str(path)!r} holds no {' or '.join(map(repr, missing))}, so it is not a {what} "
                         f"file; it holds {sorted(arrays)}")


def descriptors_n_by_d(descriptors: np.ndarray, n_keypoints: int, hloc_layout: bool = False) -> np.ndarray:
    """Float descriptors as (N, D): hloc stores them as (D, N). `hloc_layout` (an .h5 group without
    `valid`: hloc writes none, `save_features` always does): (D, N) whenever the second axis has one
    entry per keypoint, also when D = N; otherwise (D, N) only where (N, D) cannot fit. Other arrays
    are returned as they are."""
    d = np.asarray(descriptors)
    if d.dtype.kind == "f" and d.ndim == 2 and d.shape[1] == n_keypoints and (hloc_layout or d.shape[0] != n_keypoints):
        return d.T
    return d


def features_source_record(path: Path) -> Path:
    """The record that `geofeat extract --out DIR/NAME.npz` writes beside its one `NAME-<frame>.npz`
    per frame: `DIR/NAME.source.json`, naming the sequence they are features of (its folder, its
    reference frame's name and `io.frame_digest`) and listing the files."""
    path = Path(path)
    return path.with_name(f"{path.stem}.source.json")


def read_features_source(path: Path, what: str = "--out") -> dict | None:
    """The source record of the `.npz` prefix `path` (`features_source_record`), None when there is
    none; ValueError naming it (and the option `what`) when it is not one that `extract` wrote."""
    import json

    record = features_source_record(path)
    if not (record.exists() or record.is_symlink()):
        return None
    try:
        data = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        data = None
    if not (isinstance(data, dict) and data.get("generator") == "geofeat extract" and isinstance(data.get("files"), list)):
        raise ValueError(f"{what}: {record} is not the record of the sequence that `geofeat extract` writes beside its "
                         f"{Path(path).stem}-<frame>.npz files; move it away, or choose another path")
    return data


#: Float16 keypoint coordinates this far apart (pixels) or more are warned about (`warn_float16_keypoints`):
#: from 512 px on, where the 3 px protocol starts to score the rounding.
FLOAT16_WARN_STEP_PX = 0.5


def float16_step(keypoints) -> float:
    """The largest gap (pixels) between neighbouring float16 values at the keypoints' coordinates: 0.5 px
    from 512 px, 1 px from 1024 px, 2 px from 2048 px; 0.0 for keypoints of another dtype. hloc's
    `as_half` stores every float32 array as float16, keypoints (N, 2) included."""
    kp = np.asarray(keypoints)
    if kp.dtype != np.float16:
        return 0.0
    finite = np.abs(kp[np.isfinite(kp)])
    return float(np.spacing(finite.max())) if finite.size else 0.0


def warn_float16_keypoints(keypoints, where: str) -> float:
    """Warn, naming `where` (the file, and its group), when float16 `keypoints` (N, 2) have
    coordinates where float16 values lie `FLOAT16_WARN_STEP_PX` or more apart: their positions
    were rounded when stored, and the 3 px protocol scores the rounded ones. The keypoints are
    still read. Returns the largest gap (`float16_step`) when it warned, else 0.0."""
    step = float16_step(keypoints)
    if step < FLOAT16_WARN_STEP_PX:
        return 0.0
    kp = np.abs(np.asarray(keypoints, np.float64))
    far = int((kp.max(axis=-1) >= 1024 * FLOAT16_WARN_STEP_PX).sum()) if kp.ndim == 2 else kp.size
    warnings.warn(f"{where}: keypoints stored as float16 (hloc's as_half), rounded to steps of up to {step:g} px "
                  f"({far} of {len(kp)} keypoints have a coordinate >= {1024 * FLOAT16_WARN_STEP_PX:g} px, where "
                  f"float16 values are {FLOAT16_WARN_STEP_PX:g} px or more apart); they are read as stored, so the "
                  "3 px protocol scores the rounded positions: store keypoints as float32 (hloc: as_half=False)",
                  stacklevel=3)
    return step


def _features_from(arrays: dict[str, np.ndarray], path, hloc: bool = False) -> Features:
    """`hloc`: the group has hloc's layout (`descriptors_n_by_d`)."""
    _require_arrays(arrays, ("keypoints", "descriptors"), path, "features")
    kp = np.asarray(arrays["keypoints"], dtype=np.float64)
    desc = descriptors_n_by_d(arrays["descriptors"], len(kp) if kp.ndim == 2 else -1, hloc)
    valid = arrays.get("valid")
    return Features(
        keypoints=kp,
        descriptors=desc,
        valid=np.ones(len(kp), bool) if valid is None else valid,
        angles=arrays.get("angles"),
        sizes=arrays.get("sizes"),
        scores=arrays.get("scores"),
        method=arrays.get("method"),  # a 0-d bytes array: `Features` reads it
    )


def load_features(path: str | Path, name: str | None = None) -> Features:
    """Read features written by `save_features` (or an hloc features.h5 group: a missing `valid`
    means every keypoint is valid, and float descriptors stored as hloc's (D, N) are read as
    (N, D)). For .h5, `name` may be omitted when the file holds one image; a `name` the file has no
    group of is a ValueError naming the file and the groups it holds. For .npz, a `name` other than
    the one the file was saved with is a ValueError too. Float16 keypoints (hloc's `as_half`) are read
    as stored, with a warning where their rounding reaches 0.5 px (`warn_float16_keypoints`)."""
    if _suffix(path) == ".npz":
        arrays = read_npz(path)
        _check_npz_name(arrays, name, path)
        warn_float16_keypoints(arrays.get("keypoints"), f"path: {str(path)!r}")
        return _features_from(arrays, path)
    arrays = _h5_read_group(path, name)
    where = f"path: {str(path)!r}" + ("" if name is None else f", group {name!r}")
    warn_float16_keypoints(arrays.get("keypoints"), where)
    return _features_from(arrays, path, hloc="valid" not in arrays)


def save_matches(path: str | Path, matches: Matches, name: str | None = None) -> None:
    """Write `matches` (matches0, distances) to an .npz file (one pair per file; `name`, when given, is
    kept with it and checked by `load_matches`) or into group `name` (e.g. "img0.png/img1.png" as
    hloc's names_to_pair would make) of an .h5 file."""
    if not isinstance(matches, Matches):
        raise TypeError(f"matches: expected a Matches record, got {type(matches).__name__}")
    matches = _checked_again(matches, ("matches0", "distances0"))
    arrays = {"matches0": matches.matches0.astype(np.int64), "distances": matches.distances0}
    if _suffix(path) == ".npz":
        write_npz(path, _npz_with_name(arrays, name))
    else:
        _h5_write_group(path, _require_name(name, path), arrays)


def load_matches(path: str | Path, name: str | None = None) -> Matches:
    """Read matches written by `save_matches` (a missing `distances` dataset reads as NaN; for .npz, a
    `name` other than the one the file was saved with is a ValueError)."""
    if _suffix(path) == ".npz":
        arrays = read_npz(path)
        _check_npz_name(arrays, name, path)
    else:
        arrays = _h5_read_group(path, name)
    _require_arrays(arrays, ("matches0",), path, "matches")
    m0 = arrays["matches0"]
    dist = arrays.get("distances", arrays.get("distances0"))
    if dist is None:
        dist = np.full(len(m0), np.nan)
    return Matches(m0, dist)

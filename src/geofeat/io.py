"""Readers for the public RGB-D dataset layout.

A sequence folder holds, per frame `<name>`:
    `<name>-rgb.png`    8-bit colour,
    `<name>-depth.png`  16-bit depth (default unit: millimetres, 0 = missing),
    `<name>.csv`        optional landmarks: a header line, then `id, x, y, valid` (pixels),
and one `intrinsics.xml` (OpenCV FileStorage, node `intrinsics`, 3x3 matrix).
The reference frame is the one whose name holds `master` or `ref` as a whole token (see
`geofeat.inputs.is_reference_name`); the others follow in natural order (`frame-2` before `frame-10`).
Hidden files (`._frame-001-rgb.png`) are not frames. Every reader validates what it reads (`geofeat.inputs`).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

import cv2
import numpy as np

from .constants import DEFAULT_RADIUS_M, DEPTH_SCALE_M, MAX_PLAUSIBLE_DEPTH_M
from .frame import RGBDFrame, _warn_if_dark, check_depth
from .inputs import (check_depth_plausible, check_depth_scale, check_intrinsics_for_image, check_landmarks,
                     check_not_8bit_depth, check_unique_names, is_reference_name, read_config, unmask_depth,
                     warn_depth_units)
from .outputs import atomic_file

RGB_SUFFIX = "-rgb.png"
DEPTH_SUFFIX = "-depth.png"


def natural_key(name: str) -> tuple:
    """Sort key that orders the numbers in a name by their value: `frame-2` before `frame-10` (plain
    string order puts `frame-10` first, and a tracker would jump through the sequence). A number with
    a fractional part is a decimal (a timestamp): `1650000000.0333` before `1650000000.1`, which
    ordering the digits after the point as a whole number (333 > 1) reversed."""
    parts = re.split(r"(\d+(?:\.\d+)?)", name)  # str, number, str, number, ..., str
    return [Decimal(t) if i % 2 else t for i, t in enumerate(parts)], name


def frame_names(folder: str | Path, suffix: str = RGB_SUFFIX) -> list[str]:
    """Names of the frames in `folder` that have a `<name><suffix>` file, in `natural_key` order.
    Hidden files (a leading `.`, such as macOS's `._frame-001-rgb.png` resource forks on a USB disk)
    are not frames."""
    return sorted((p.name[: -len(suffix)] for p in Path(folder).glob(f"*{suffix}") if not p.name.startswith(".")),
                  key=natural_key)


#: Files of a sequence folder that are not per-frame but are read with it (`read_sequence`).
SEQUENCE_FILES = ("intrinsics.xml", "geofeat.json")


def sequence_digest(folder: str | Path) -> str:
    """SHA-1 (hex) of the files a reader of the sequence in `folder` uses: every non-hidden file whose
    name starts with a frame's name (colour, depth, landmark CSV, ground truth), `intrinsics.xml` and
    `geofeat.json`, names and contents in order. It changes when a frame is replaced, added or removed
    in place, and not when the folder is copied or touched (`geofeat bench` resumes by it)."""
    folder = Path(folder)
    prefixes = tuple(f"{n}{sep}" for n in frame_names(folder) for sep in "-.")
    return files_digest(p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")
                        and (p.name in SEQUENCE_FILES or p.name.startswith(prefixes)))


def frame_digest(folder: str | Path, name: str) -> str:
    """SHA-1 (hex) of the contents of frame `name`'s colour and depth files in `folder`: a cheap
    fingerprint of a sequence by its reference frame (contents only, so that a copy under another
    folder name has the same). `geofeat retrieval` refuses two sequences with one reference frame;
    `geofeat extract` records it beside its one `.npz` per frame."""
    digest = hashlib.sha1()
    for path in (Path(folder) / f"{name}{RGB_SUFFIX}", Path(folder) / f"{name}{DEPTH_SUFFIX}"):
        # a missing depth file (reading the frame names it) is hashed as such: the colour file tells apart
        data = path.read_bytes() if path.is_file() else None
        digest.update(b"missing\0" if data is None else str(len(data)).encode() + b"\0" + data)
    return digest.hexdigest()


def reference_name(names: list[str]) -> str:
    """The reference frame among a sequence's frame `names`: the first whose name holds `master` or
    `ref` as a whole token (`inputs.is_reference_name`), else the first name (`read_sequence` refuses
    several)."""
    refs = [n for n in names if is_reference_name(n)]
    return refs[0] if refs else names[0]


def files_digest(paths) -> str:
    """SHA-1 (hex) of files: the name, size and contents of each, in name order (`sequence_digest`, and
    the TPS files of a sequence in `geofeat bench`'s resume check)."""
    digest = hashlib.sha1()
    for path in sorted(Path(p) for p in paths):
        digest.update(path.name.encode() + b"\0" + str(path.stat().st_size).encode() + b"\0")
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


#: What a sequence folder holds, for the errors that find something else there.
LAYOUT = (f"a sequence folder holds <name>{RGB_SUFFIX} (8-bit colour), <name>{DEPTH_SUFFIX} (16-bit, "
          "millimetres unless geofeat.json gives depth_scale) and intrinsics.xml; geofeat.write_frame and "
          "geofeat.write_intrinsics write them from arrays")
#: The file names (lower-case, without extension) a K in memory could have been saved under, beside a
#: missing intrinsics.xml.
_K_STEMS = frozenset(("intrinsics", "camera", "camera_matrix", "k", "calib", "calibration"))
_INTRINSICS_HINT = ("geofeat reads OpenCV FileStorage XML or YAML with the 3x3 matrix under the node 'intrinsics'; "
                    "for a K you have as numbers (np.loadtxt, np.load), write it with geofeat.write_intrinsics(path, K), "
                    "or build the frame with geofeat.RGBDFrame(image, depth_m, K)")


def _listing(paths: list[Path], limit: int = 3) -> str:
    """'a.jpg, b.jpg and 3 more' of the names of `paths` (sorted naturally)."""
    names = sorted((p.name for p in paths), key=natural_key)
    more = f" and {len(names) - limit} more" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _near_misses(folder: Path, suffix: str) -> list[Path]:
    """Non-hidden files of `folder` named like `<name><suffix>` but for the extension's case or kind,
    or an underscore for the hyphen (`frame-0-rgb.jpg`, `frame-0-depth.tiff`, `frame-0-rgb.PNG`,
    `frame_0_rgb.png`): a frame geofeat does not read."""
    word = suffix.rsplit(".", 1)[0].lower().lstrip("-")  # 'rgb'
    return [p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and not p.name.endswith(suffix)
            and p.stem.lower().endswith((f"-{word}", f"_{word}"))]


def _unread_frames(folder: Path, names: list[str]) -> list[Path]:
    """The colour files of `folder` named like a frame but for the extension's case or kind
    (`_near_misses`: `frame-003-rgb.PNG`, `frame-003-RGB.png`, `frame-003-rgb.jpg`, `frame_003_rgb.png`) whose frame is not
    among the frame `names` read: frames `read_sequence` would leave out. A copy of a read frame in
    another format (`frame-001-rgb.jpg` beside `frame-001-rgb.png`) is not one."""
    stem = len(RGB_SUFFIX.rsplit(".", 1)[0])  # '-rgb'
    read = set(names)
    return [p for p in _near_misses(folder, RGB_SUFFIX) if p.stem[:-stem] not in read]


def layout_problem(folder: Path) -> str:
    """Why `folder` holds no `*-rgb.png` frame, from what it holds instead: colour files of another
    type (`-rgb.jpg`), images not named `<name>-rgb.png`, sub-folders (`rgb/`, `depth/`), or nothing;
    then the layout geofeat reads (`LAYOUT`)."""
    entries = [p for p in folder.iterdir() if not p.name.startswith(".")]
    colour = _near_misses(folder, RGB_SUFFIX)
    images = [p for p in entries if p.is_file() and p.suffix.lower() in (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")]
    subs = [p for p in entries if p.is_dir()]
    sequences = [p for p in subs if frame_names(p)]
    if sequences:  # a folder of sequences where one sequence is read
        return (f"it holds the sequence folders {_listing(sequences)}: name one of them (extract, match and "
                "read_sequence read one sequence; bench, track, retrieval and groundtruth also take a folder of them)")
    if colour:
        found = f"found {_listing(colour)}: colour frames must be PNG files named exactly <name>{RGB_SUFFIX}"
    elif images:
        found = f"found images not named <name>{RGB_SUFFIX} ({_listing(images)})"
    elif subs:
        found = f"found sub-folders ({_listing(subs)}) but no sequence one level down"
    else:
        found = "the folder is empty" if not entries else f"found {_listing(entries)}"
    return f"{found}; {LAYOUT}"


def _existing(path: str | Path, what: str) -> Path:
    if not isinstance(path, (str, os.PathLike)):  # an array for a path: pathlib's TypeError names nothing
        hint = "" if what == "landmarks" else "; for an image, depth or K in memory, use RGBDFrame(image, depth, K)"
        raise TypeError(f"{what}: expected a file path, got {type(path).__name__}{hint}")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{what}: file not found: {path}")
    return path


def read_intrinsics(path: str | Path, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read the (3, 3) camera matrix from an OpenCV FileStorage `intrinsics.xml` (node `intrinsics`).
    ValueError naming the file when the node is missing (naming the nodes it has) or holds no 3x3
    opencv-matrix (saying what it holds: a 3x4 matrix, nine plain numbers, ...), or one stored in an
    integer type (`dt` u, c, s, w, i) that changed the file's numbers (8 bits clip fx = 525 to 255).
    Non-zero lens distortion coefficients in the file (a node named `D`, `kc` or `*dist*`, or single
    numbers `k1`..`k6`, `p1`, `p2`: `_distortion`) warn: geofeat projects as a pinhole and does not
    apply them.

    `shape`: (H, W) pixels of the frames the matrix is for (`read_frame` and `read_sequence` pass it);
    an image size the file records (`image_width` / `image_height`, as OpenCV's calibration writes, or
    `width` / `height`, `image_cols` / `image_rows`, `image_size` / `resolution` as [W, H]) that differs
    is a ValueError: a K of 1280x960 frames on 640x480 ones sizes every geodesic patch wrongly."""
    if isinstance(path, (str, os.PathLike)) and not Path(path).is_file() and Path(path).parent.is_dir():
        # a K saved as text, NumPy or YAML beside the intrinsics.xml a sequence needs
        others = [p for p in Path(path).parent.iterdir()
                  if p.is_file() and not p.name.startswith(".") and p.stem.lower() in _K_STEMS]
        if others:
            raise ValueError(f"intrinsics_path: file not found: {path} (found {_listing(others)}); {_INTRINSICS_HINT}")
    path = _existing(path, "intrinsics_path")
    try:  # a malformed or truncated file makes OpenCV raise cv2.error (or a SystemError that says nothing)
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):
        fs = None
    if fs is None or not fs.isOpened():
        raise ValueError(f"intrinsics_path: cannot parse {path} as OpenCV FileStorage; {_INTRINSICS_HINT}")
    try:
        node = fs.getNode("intrinsics")
        K, held, written, dt = None, None, None, ""
        if not node.empty():
            try:
                K = node.mat()
            except (cv2.error, SystemError):
                K = None
            held = _node_contents(node, K)
            if node.isMap():  # the numbers as the file writes them, before OpenCV casts them to its dt
                written, dt = _node_numbers(node.getNode("data")), node.getNode("dt").string()
        nodes = list(fs.root().keys())
        distortion = _distortion(fs, nodes)
        recorded = _recorded_size(fs, nodes)
        pinhole = _pinhole_numbers(fs, nodes)
    finally:
        fs.release()
    if K is not None and np.asarray(K).shape == (3, 3):
        _check_stored_exactly(np.asarray(K), written, dt, path)
        if shape is not None and recorded is not None:
            _check_recorded_size(recorded, shape, path)
        if distortion:  # every projection in geofeat is a pinhole's: the coefficients were dropped without a word
            name, values = next(iter(distortion.items()))
            where = f"node{'s' if ', ' in name else ''} '{name}'"  # single numbers: "nodes 'k1, k2'"
            warnings.warn(f"intrinsics_path: {path} holds lens distortion coefficients ({where}: "
                          f"{np.round(values, 4).tolist()}), which geofeat does not apply: it reads frames as pinhole "
                          "images. Undistort the colour and depth first (cv2.undistort; nearest-neighbour for depth) "
                          "and drop the node, or drop it if the frames are undistorted already", UserWarning,
                          stacklevel=2)
        return np.asarray(K, dtype=np.float64)
    if held is not None:  # "rename the camera matrix's node to 'intrinsics'" was the advice for it too
        raise ValueError(f"intrinsics_path: {path}: its node 'intrinsics' holds {held}, not a 3x3 opencv-matrix; "
                         f"{_INTRINSICS_HINT}")
    if pinhole is not None:  # "rename the camera matrix's node" was the advice, and there is no matrix to rename
        fx, fy, cx, cy = pinhole
        raise ValueError(f"intrinsics_path: {path} holds fx, fy, cx, cy as single numbers, not the 3x3 matrix under the "
                         "node 'intrinsics' that geofeat reads; write it with geofeat.write_intrinsics(path, "
                         f"[[{fx:g}, 0, {cx:g}], [0, {fy:g}, {cy:g}], [0, 0, 1]])")
    holds = f" (its nodes: {', '.join(nodes[:5])}; rename the camera matrix's to 'intrinsics')" if nodes else ""
    raise ValueError(f"intrinsics_path: {path} has no 3x3 matrix under the node 'intrinsics'{holds}")


def _pinhole_numbers(fs, nodes: list[str]) -> tuple[float, float, float, float] | None:
    """(fx, fy, cx, cy) pixels where an open OpenCV FileStorage `fs` holds them as single numbers in its
    top-level `nodes` (any case; ORB-SLAM's `Camera.fx` too), None otherwise."""
    named = {name.lower().rsplit(".", 1)[-1]: fs.getNode(name) for name in nodes}
    found = [named.get(key) for key in ("fx", "fy", "cx", "cy")]
    if not all(node is not None and (node.isReal() or node.isInt()) for node in found):
        return None
    return tuple(float(node.real()) for node in found)


#: The name of a top-level node holding one lens distortion coefficient (`k1`, `p2`; ORB-SLAM's `Camera.k1`).
_COEFFICIENT_NODE = re.compile(r"(?:.*\.)?(?:k[1-6]|p[12])")


def _distortion(fs, nodes: list[str]) -> dict[str, np.ndarray]:
    """{node name(s): non-zero coefficients} of the lens distortion an open OpenCV FileStorage `fs`
    records in its top-level `nodes`: a matrix or list named `D`, `kc` (the MATLAB calibration toolbox)
    or `*dist*` (`distortion_coefficients`, `dist_coeffs`, `RadialDistortion`), and single numbers named
    `k1`..`k6`, `p1`, `p2` (gathered under one key, `"k1, k2, p1"`). Zero ones (undistorted frames) are
    left out."""
    found = {}
    for name in nodes:
        key = name.lower()
        if key in ("d", "kc") or "dist" in key:
            values = _node_numbers(fs.getNode(name))
            if values is not None and values.any():
                found[name] = values
    single = [n for n in nodes if _COEFFICIENT_NODE.fullmatch(n.lower())
              and (fs.getNode(n).isReal() or fs.getNode(n).isInt())]
    values = np.array([fs.getNode(n).real() for n in single])
    if values.any():
        found[", ".join(single)] = values
    return found


def _check_stored_exactly(K: np.ndarray, written: np.ndarray | None, dt: str, path: Path) -> None:
    """ValueError naming `path` when the camera matrix `K`, as OpenCV read it, is of an integer type
    (its `dt`: u, c, s, w, i) and differs from the numbers `written` in the file (its `data`,
    flattened; None when unreadable: then an 8-bit type is refused alone). OpenCV saturates to the
    type's range and rounds: with `<dt>u</dt>` fx = 525 reads as 255, with `<dt>i</dt>` cx = 319.5
    as 320, and nothing said so."""
    if K.dtype.kind not in "iu":
        return
    readable = written is not None and written.shape == (K.size,)
    if (np.array_equal(written, K.ravel()) if readable else K.dtype.itemsize > 1):
        return  # whole numbers within the type's range (or nothing to compare with, in 16 bits or more)
    limits = np.iinfo(K.dtype)
    clips = not readable or ((written < limits.min) | (written > limits.max)).any()
    shown = f" (the file has {np.round(written, 4).tolist()})" if readable else ""
    raise ValueError(f"intrinsics_path: {path}: its node 'intrinsics' is stored as {K.dtype} (dt '{dt}'), which "
                     f"{'clips' if clips else 'rounds'} the camera matrix: read as {K.ravel().tolist()}{shown}; "
                     "write it with <dt>d</dt> (64-bit float), as geofeat.write_intrinsics does")


#: Names (lower case, without '_') of the top-level nodes a calibration file records its image size
#: under: pairs of (width, height) nodes, and single nodes holding [width, height] (a cv::Size).
_SIZE_PAIRS = (("imagewidth", "imageheight"), ("width", "height"), ("imagecols", "imagerows"), ("cols", "rows"))
_SIZE_NODES = ("imagesize", "resolution", "imageresolution")


def _recorded_size(fs, nodes: list[str]) -> tuple[int, int, str] | None:
    """(W, H, the node names) of the image size an open OpenCV FileStorage `fs` records in its
    top-level `nodes` (`_SIZE_PAIRS`, `_SIZE_NODES`); None when it records none as whole numbers > 0."""
    named = {name.lower().replace("_", ""): name for name in nodes}

    def whole(values) -> bool:
        return values is not None and all(v > 0 and v == int(v) for v in values)

    for w, h in _SIZE_PAIRS:
        if w in named and h in named:
            values = [fs.getNode(named[k]) for k in (w, h)]
            if all(v.isInt() or v.isReal() for v in values) and whole([v.real() for v in values]):
                return int(values[0].real()), int(values[1].real()), f"{named[w]}, {named[h]}"
    for key in _SIZE_NODES:
        if key in named:
            values = _node_numbers(fs.getNode(named[key]))
            if values is not None and values.shape == (2,) and whole(values):
                return int(values[0]), int(values[1]), named[key]
    return None


def _check_recorded_size(recorded: tuple[int, int, str], shape: tuple[int, int], path: Path) -> None:
    """ValueError naming `path` and both sizes when the image size (W, H, node names) an intrinsics
    file records differs from the (H, W) of the frames it is read with."""
    W, H, where = recorded
    height, width = shape
    if (W, H) != (width, height):
        raise ValueError(f"intrinsics_path: {path} records an image size of {W}x{H} ({where}), but the frames are "
                         f"{width}x{height}: the intrinsics are for another resolution. Scale K to the frames (fx and cx "
                         f"by {width}/{W}, fy and cy by {height}/{H}: geofeat.depth.scale_intrinsics) and write it with "
                         f"geofeat.write_intrinsics, or use a calibration made at {width}x{height}")


def _node_numbers(node) -> np.ndarray | None:
    """The numbers of an OpenCV FileStorage `node` that is a matrix or a sequence of numbers, flattened;
    None for any other node (a single number, a string, a map)."""
    try:
        if node.isSeq():  # a YAML or JSON list, of numbers or of rows of numbers
            items = [node.at(i) for i in range(node.size())]
            parts = [_node_numbers(item) if item.isSeq() else np.array([item.real()]) for item in items]
            return None if any(part is None for part in parts) else np.concatenate(parts + [np.zeros(0)])
        matrix = node.mat() if node.isMap() else None
    except (cv2.error, SystemError):
        return None
    return None if matrix is None else np.asarray(matrix, dtype=np.float64).ravel()


def _node_contents(node, matrix: np.ndarray | None) -> str:
    """What an OpenCV FileStorage `node` holds, in words, given its `matrix` (None where OpenCV could not
    read it as one): "a 3x4 matrix", "a plain sequence of 9 values", ..."""
    if matrix is not None:
        return f"a {'x'.join(map(str, np.shape(matrix)))} matrix"
    if node.isSeq():
        items = "rows" if node.size() and node.at(0).isSeq() else "values"
        return f"a plain sequence of {node.size()} {items}"
    if node.isMap():
        keys = list(node.keys())
        if {"rows", "cols", "dt", "data"} <= set(keys):
            return "an opencv-matrix whose data does not match its rows, cols and dt (it needs rows x cols numbers)"
        return f"a map of {', '.join(keys[:5])} (an opencv-matrix has rows, cols, dt and data)"
    return "a single value" if node.isReal() or node.isInt() or node.isString() else "no matrix"


def write_intrinsics(path: str | Path, K: np.ndarray) -> None:
    """Write a (3, 3) camera matrix as OpenCV FileStorage XML under the node `intrinsics`."""
    path = Path(path)
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):  # read_intrinsics refuses anything else
        raise ValueError(f"K: expected a (3, 3) camera matrix, got shape {K.shape}")
    if not path.parent.is_dir():  # OpenCV would log an error and raise a bare cv2.error
        raise ValueError(f"intrinsics_path: cannot write {path}: folder not found")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        if not fs.isOpened():
            raise ValueError(f"intrinsics_path: cannot write {path}")
        fs.write("intrinsics", K)
    finally:
        fs.release()


def read_image(path: str | Path, what: str = "rgb_path") -> np.ndarray:
    """Read a colour image as (H, W, 3) uint8 BGR (grey and RGBA files too). A 16-bit file is read as
    0-65535 and kept to its high byte; one that uses under 1/16 of that range (8-bit values stored
    in 16 bits: read back nearly black) warns, naming the file. The stored pixels, whatever an EXIF
    orientation tag says (OpenCV would turn the image by it, away from its depth, K and landmarks)."""
    path = _existing(path, what)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None:
        raise ValueError(f"{what}: cannot decode image {path}")
    if image.dtype == np.uint16:
        _warn_if_dark(image, float(image.max()) / 65535.0, f"{what}: {path}", stacklevel=3)
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ValueError(f"{what}: {path} holds {image.dtype} values; expected an 8-bit (or 16-bit) colour image")
    return image


#: The largest 16-bit value: in a depth PNG a sensor's no-data code (or a saturated reading), never a
#: depth (65.5 m in millimetres); `read_depth` reads it as missing.
DEPTH_NO_DATA = 65535
_warned_no_data: set[str] = set()


#: A uint16 depth map whose byte-swapped values step between neighbouring pixels this many times less
#: than its own is byte-swapped (`read_depth`): a smooth surface's steps are a few units, and swapping
#: the bytes makes each unit a step of 256.
BYTE_SWAP_SMOOTHER = 10.0


def _neighbour_steps(raw: np.ndarray) -> tuple[float, float] | None:
    """(as stored, byte-swapped): the mean absolute difference, in depth-PNG units, between
    horizontally neighbouring pixels that both hold a depth (not 0, not `DEPTH_NO_DATA`), on every
    4th row of the (H, W) uint16 `raw`; None when fewer than 100 such pairs are there."""
    rows = raw[::4].astype(np.int32)
    known = (rows > 0) & (rows != DEPTH_NO_DATA)
    pairs = known[:, 1:] & known[:, :-1]
    if pairs.sum() < 100:
        return None
    swapped = raw[::4].byteswap().astype(np.int32)
    # the mean, not the median: most neighbours of a quantised depth map are equal, swapped or not
    return tuple(float(np.mean(np.abs(np.diff(a, axis=1))[pairs])) for a in (rows, swapped))


def read_depth(path: str | Path, depth_scale: float = DEPTH_SCALE_M) -> np.ndarray:
    """Read a 16-bit depth PNG as (H, W) float32 metres (value * depth_scale; 0 = missing). Pixels
    holding 65535 (`DEPTH_NO_DATA`) are read as missing too, with a warning once per folder: read as
    65.5 m they passed the median check and the smoothing mixed them into the surface beside them.
    A depth map whose two bytes are swapped (`_neighbour_steps`: far smoother swapped back) is a
    ValueError: read as stored, its depths were noise with a plausible median (48.6 m for the Kinect
    frame's 0.7-1.1 m), which only warned."""
    path = _existing(path, "depth_path")
    # ANYCOLOR keeps the channels: IMREAD_ANYDEPTH alone turns a 3-channel 16-bit PNG into its luminance;
    # the stored pixels, not turned by an EXIF orientation tag (`read_image`)
    raw = None if path.suffix.lower() == ".npy" else cv2.imread(
        str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if raw is None:
        hint = ("; for depth as an array (np.load), build the frame with geofeat.RGBDFrame(image, depth_m, K), or write "
                "16-bit PNGs with geofeat.write_frame") if path.suffix.lower() in (".npy", ".npz", ".exr") else ""
        raise ValueError(f"depth_path: cannot decode image {path}{hint}")
    if raw.ndim != 2:
        raise ValueError(f"depth_path: {path} has {raw.shape[2]} channels; depth must be a single-channel 16-bit PNG")
    if raw.dtype == np.uint8:
        raise ValueError(f"depth_path: {path} is 8-bit; depth must be a 16-bit PNG")
    check_depth_scale(depth_scale, "depth_scale")
    if raw.dtype == np.uint16:
        steps = _neighbour_steps(raw)
        if steps is not None and steps[1] * BYTE_SWAP_SMOOTHER < steps[0]:
            raise ValueError(f"depth_path: {path}: its 16-bit values are a depth map only with their two bytes swapped "
                             f"(neighbouring pixels differ by {steps[0]:.0f} units on average as stored, {steps[1]:.0f} "
                             "swapped): written least significant byte first, where PNG stores the most significant "
                             "first? Write it again from the native uint16 array (array.byteswap() of the one read) with "
                             "cv2.imwrite, or with geofeat.write_frame from metres")
    no_data = raw == DEPTH_NO_DATA if raw.dtype == np.uint16 else None
    if no_data is not None and no_data.any():
        raw = np.where(no_data, 0, raw)
        if str(path.parent) not in _warned_no_data:
            _warned_no_data.add(str(path.parent))
            warnings.warn(f"depth_path: {path}: {int(no_data.sum())} pixels ({no_data.mean():.1%}) hold {DEPTH_NO_DATA}, the "
                          "largest 16-bit value: a sensor's no-data code (or a saturated reading), not a depth of "
                          f"{DEPTH_NO_DATA * depth_scale:.4g} m; read as missing, as 0 is (said once for the depth PNGs "
                          f"of {path.parent})", UserWarning, stacklevel=2)
    return raw.astype(np.float32) * np.float32(depth_scale)


def read_frame(
    rgb_path: str | Path,
    depth_path: str | Path,
    intrinsics_path: str | Path,
    depth_scale: float | None = None,
) -> RGBDFrame:
    """Read one frame of the public layout. `depth_scale` is metres per depth-PNG unit (None: the
    `geofeat.json` beside the depth PNG, as `read_sequence` reads it, else 0.001, millimetres). The
    frame is checked as `read_sequence` checks one: colour and depth of one size, a plausible median
    depth, intrinsics plausible for the image size and made for it where the file records a size
    (`read_intrinsics`)."""
    image = read_image(rgb_path)
    if depth_scale is None:  # the simulator's 0.1 mm PNGs were read in millimetres: depth 10x too far, no word
        depth_scale = float(read_config(_existing(depth_path, "depth_path").parent).get("depth_scale", DEPTH_SCALE_M))
    depth = read_depth(depth_path, depth_scale)
    if depth.shape != image.shape[:2]:
        raise ValueError(f"depth_path: {depth_path} is {depth.shape[1]}x{depth.shape[0]}, the colour image {rgb_path} "
                         f"{image.shape[1]}x{image.shape[0]}; they must have one size")
    try:
        check_depth(depth)
    except ValueError as error:
        raise ValueError(f"depth_path: {depth_path}: {error}") from None
    check_depth_plausible(depth, depth_scale, f"depth_path: {depth_path}")
    warn_depth_units(depth, depth_scale, f"depth_path: {depth_path}", key=str(Path(depth_path).resolve()))
    K = check_intrinsics_for_image(read_intrinsics(intrinsics_path, image.shape[:2]), image.shape[:2],
                                   f"intrinsics_path: {intrinsics_path}")
    return RGBDFrame._from_reader(image, depth, K)  # the depth units were warned of above, once per file


def write_frame(folder: str | Path, name: str, color: np.ndarray, depth: np.ndarray,
                depth_scale: float = DEPTH_SCALE_M) -> None:
    """Write one frame in the public layout: `<name>-rgb.png` (8-bit, (H, W, 3) BGR or (H, W)) and
    `<name>-depth.png` (16-bit, depth in metres / depth_scale, rounded; 0 = missing; at most 65534
    units, as 65535 reads as missing). A `depth_scale` other than the one the folder's depth PNGs are
    read at (its geofeat.json's, else 0.001) is recorded in its geofeat.json, so that `read_sequence`
    reads the frame back in metres; ValueError when other depth PNGs there are read at that other
    scale. Everything is checked before any file is written."""
    folder = Path(folder)
    check_depth_scale(depth_scale, "depth_scale")
    config = _depth_scale_config(folder, name, depth_scale)
    color, depth = np.asarray(color), np.asarray(unmask_depth(depth))  # masked pixels: missing depth (0)
    if depth.ndim != 2 or depth.dtype.kind not in "fiu":
        raise ValueError(f"depth: expected an (H, W) array of metres, got shape {depth.shape}, dtype {depth.dtype}")
    check_not_8bit_depth(depth)  # written as 2-4 mm
    if color.shape[:2] != depth.shape or color.ndim not in (2, 3) or (color.ndim == 3 and color.shape[2] not in (1, 3, 4)):
        raise ValueError(f"color: expected shape (H, W, 3) or (H, W) with the depth's (H, W) = {depth.shape}, "
                         f"got {color.shape}")
    if color.dtype != np.uint8:  # OpenCV would write floats in [0, 1] as a black image, 16-bit as 16-bit
        if color.dtype.kind not in "iu" or (color.size and (color.min() < 0 or color.max() > 255)):
            raise ValueError(f"color: expected 8-bit values (uint8, or integers 0-255), got {color.dtype}"
                             + (f" in [{color.min():.3g}, {color.max():.3g}]" if color.dtype.kind in "iuf" and color.size else ""))
        color = color.astype(np.uint8)
    depth = depth.astype(np.float64)
    if not np.isfinite(depth).all() or (depth < 0).any():  # a negative depth would wrap to 65 m in uint16
        raise ValueError("depth: NaN, infinite or negative values; use 0 for missing depth")
    median = float(np.median(depth[depth > 0])) if (depth > 0).any() else 0.0
    if median > MAX_PLAUSIBLE_DEPTH_M:  # "1098.0 m does not fit a 16-bit PNG" sent one to a coarser depth_scale
        raise ValueError(f"depth: median {median:.4g} is not in metres (at most {MAX_PLAUSIBLE_DEPTH_M:g} m expected); "
                         "write_frame takes metres: divide millimetres by 1000")
    units = np.rint(depth / depth_scale)
    if units.max(initial=0) >= DEPTH_NO_DATA:
        raise ValueError(f"depth: {units.max() * depth_scale:.1f} m does not fit a 16-bit PNG at {depth_scale} m per unit")
    for path, image in ((folder / f"{name}{RGB_SUFFIX}", color), (folder / f"{name}{DEPTH_SUFFIX}", units.astype(np.uint16))):
        if not cv2.imwrite(str(path), image):
            raise ValueError(f"folder: cannot write {path}")
    if config is not None:
        with atomic_file(folder / "geofeat.json") as tmp:
            tmp.write_text(json.dumps(config, indent=1), encoding="utf-8")


def _depth_scale_config(folder: Path, name: str, depth_scale: float) -> dict | None:
    """The geofeat.json `write_frame` writes into `folder` so that frame `name`'s depth PNG, written at
    `depth_scale`, is read back at it: None when the folder's depth PNGs are read at it already. Written
    at 0.1 mm without one, a frame was read back in millimetres, 10x too far, without a word. ValueError
    when the folder's geofeat.json, or its other depth PNGs (read as millimetres without one), say
    another scale: a sequence folder has one."""
    config = read_config(folder) if folder.is_dir() else {}
    current = float(config.get("depth_scale", DEPTH_SCALE_M))
    if depth_scale == current:
        return None
    others = [n for n in frame_names(folder, DEPTH_SUFFIX) if n != name] if folder.is_dir() else []
    if "depth_scale" in config or others:
        source = ("its geofeat.json's depth_scale" if "depth_scale" in config else
                  f"millimetres, as its depth PNGs {_listing([folder / f'{n}{DEPTH_SUFFIX}' for n in others])} are "
                  "read without a geofeat.json")
        raise ValueError(f"depth_scale: {depth_scale:g} m per unit, but the depth PNGs of {folder} are read at "
                         f"{current:g} ({source}); a sequence folder has one depth scale: write at {current:g}, or into "
                         "another folder")
    return {**config, "depth_scale": depth_scale}


def _csv_fields(line: str) -> list[str]:
    """The fields of one landmark csv line: comma-separated (empty fields kept, so a missing value is not
    filled by the next column; trailing commas dropped), else whitespace-separated."""
    line = line.strip()
    if "," in line:
        return [t.strip() for t in line.rstrip(", \t").split(",")]
    return line.split()


#: Landmark csv header names that mean a coordinate: a row is y, a column x; u, v are x, y (image
#: coordinates as OpenCV and ROS name them), as px, py are.
_HEADER_SYNONYMS = {"row": "y", "rows": "y", "r": "y", "col": "x", "cols": "x", "column": "x", "columns": "x",
                    "c": "x", "u": "x", "v": "y", "px": "x", "py": "y"}


#: A coordinate's name in a landmark csv header, after `_column_name` took off its decorations.
_AXIS = r"(x|y|u|v|r|c|rows?|cols?|columns?)"


def _column_name(field: str) -> str:
    """What a landmark csv header `field` names, in geofeat's words (`id`, `x`, `y`, or the field in
    lower case): quotes, a leading `#`, a unit (`x_px`, `x (pixels)`), a word before a coordinate's
    name (`pixel_x`, `kp_row`) and one after it (`x_coord`, `y_pos`) left out, then `_HEADER_SYNONYMS`
    (`row` is y, `u` is x)."""
    name = field.strip(" #\"'").lower()
    if name in _HEADER_SYNONYMS:  # 'px' is x, not a unit
        return _HEADER_SYNONYMS[name]
    name = re.sub(r"[\s_-]*[(\[]?(px|pixels?)[)\]]?$", "", name)  # a unit after the name
    name = re.sub(rf"^[a-z]+[\s_-]+(?={_AXIS}$)", "", name)  # 'pixel_x', 'image u', 'kp-row'
    name = re.sub(rf"^{_AXIS}[\s_-]*(coord(inate)?s?|pos(ition)?)$", r"\1", name)  # 'x_coord', 'y pos'
    return _HEADER_SYNONYMS.get(name, name)


#: Names of a last csv column that flags hidden landmarks, the opposite of `valid`.
_HIDDEN_FLAGS = ("occlu", "hidden", "invisib", "not_visible", "notvisible", "missing")


def read_landmarks(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a landmark csv (`id, x, y, valid` after one header line; exactly these four fields a row,
    valid 0 or 1). A header that names `id`, `x` or `y` (or `col`, `row`) in another column, or a last
    column of the opposite sense (`occluded`, `hidden`), is refused.

    Returns:
        ids (N,) int64, xy (N, 2) float64 pixels, visible (N,) bool (valid flag set and x, y >= -0.5, on the
        image: pixel centres at integers; -1 marks a missing landmark).
    """
    path = _existing(path, "landmarks")
    try:
        text = Path(path).read_text(encoding="utf-8-sig")  # a spreadsheet's byte-order mark is not part of the first field
    except UnicodeDecodeError:
        raise ValueError(f"landmarks: {path}: not a text csv ('id, x, y, valid' after one header line)") from None
    if not text.strip():  # a file cut to nothing (a failed copy) was read as a frame whose landmarks are all hidden
        raise ValueError(f"landmarks: {path}: the file is empty; expected a header line such as 'id,x,y,valid', "
                         "then one landmark a line (a frame without landmarks: the header line alone)")
    lines = text.splitlines()
    if lines:  # a file without its header line would lose its first landmark
        try:
            first = [float(t) for t in _csv_fields(lines[0])]
        except ValueError:
            first = None
        if first is not None and len(first) == 4:
            raise ValueError(f"landmarks: {path}: the first line {lines[0].strip()!r} is a landmark, not a header; "
                             "the csv needs a header line such as 'id,x,y,valid'")
        # a header in rows and columns names y first: 'id,row,col,valid' is 'id,y,x,valid'; 'id,v,u,valid' too
        columns = [_column_name(t) for t in _csv_fields(lines[0])]
        if any(name in columns and columns.index(name) != i for i, name in enumerate(("id", "x", "y"))):
            # the header is not otherwise read: 'id,y,x,valid' swapped x and y without a word
            raise ValueError(f"landmarks: {path}: the header {lines[0].strip()!r} names the columns in another "
                             "order; geofeat reads them as 'id, x, y, valid'")
        if len(columns) == 4 and columns[3].startswith(_HIDDEN_FLAGS):
            # 'id,x,y,occluded': 1 means hidden there, and every visible landmark was read as invisible
            raise ValueError(f"landmarks: {path}: the header {lines[0].strip()!r} names a flag that is 1 where the "
                             "landmark is hidden; geofeat reads the last column as valid (1 = visible): write 1 - flag")
    rows = []
    for line in lines[1:]:
        tokens = _csv_fields(line)
        if not any(tokens):
            continue
        if len(tokens) != 4:
            raise ValueError(f"landmarks: {path}: expected the 4 fields 'id, x, y, valid', got {len(tokens)} in {line!r}")
        try:
            rows.append([float(t) for t in tokens])
        except ValueError:
            raise ValueError(f"landmarks: {path}: expected numbers 'id, x, y, valid', got {line!r}") from None
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
    if not np.isfinite(data[:, 0]).all() or (data[:, 0] != np.round(data[:, 0])).any() or (np.abs(data[:, 0]) > 2**53).any():
        raise ValueError(f"landmarks: {path}: ids must be integers")
    ids = data[:, 0].astype(np.int64)
    xy = data[:, 1:3]
    odd = ~np.isin(data[:, 3], (0.0, 1.0))  # NaN, 0.5, 2 (a COCO "visible"), -1: no guessing which is meant
    if odd.any():
        raise ValueError(f"landmarks: {path}: valid must be 0 or 1, got {data[odd, 3][:5].tolist()} for ids "
                         f"{ids[odd][:10].tolist()}")
    flagged = data[:, 3] > 0
    if (flagged & ~np.isfinite(xy).all(axis=1)).any():
        raise ValueError(f"landmarks: {path}: landmarks marked valid need finite coordinates, ids "
                         f"{ids[flagged & ~np.isfinite(xy).all(axis=1)][:10].tolist()}")
    # pixel centres at integers, so the image starts at -0.5: a landmark flagged valid at y = -0.2 lies on
    # the first row (the simulator writes such ones); -1, the usual "missing", stays invisible
    visible = flagged & (xy[:, 0] >= -0.5) & (xy[:, 1] >= -0.5)
    return ids, xy, visible


def write_landmarks(path: str | Path, ids: np.ndarray, xy: np.ndarray, visible: np.ndarray) -> None:
    """Write landmarks in the public csv layout (`id,x,y,valid`, coordinates with 2 decimals).
    ids (N,) integers, xy (N, 2) pixels, visible (N,)."""
    ids, xy, visible = np.asarray(ids), np.asarray(xy, dtype=np.float64), np.asarray(visible)
    if xy.size == 0:
        xy = xy.reshape(0, 2)
    if ids.ndim != 1 or xy.shape != (len(ids), 2) or visible.shape != (len(ids),):
        raise ValueError(f"landmarks: {path}: expected ids (N,), xy (N, 2) and visible (N,), got shapes "
                         f"{ids.shape}, {xy.shape} and {visible.shape}")
    if ids.dtype.kind not in "iu" and not (ids.dtype.kind == "f" and np.isfinite(ids).all() and (ids == np.round(ids)).all()):
        raise ValueError(f"landmarks: {path}: ids must be integers, got {ids[:5].tolist()}")
    lines = ["id,x,y,valid"]
    for i, (x, y), v in zip(ids, xy, visible):
        lines.append(f"{int(i)},{x:.2f},{y:.2f},{int(bool(v))}")
    Path(path).write_text("\n".join(lines) + "\n")


@dataclass
class Sequence:
    """A folder of frames in the public layout.

    Attributes:
        folder: the sequence folder.
        names: frame names, reference first, then in natural order (`frame-2` before `frame-10`).
        K: (3, 3) intrinsics shared by all frames.
        depth_scale: metres per depth-PNG unit.
        depth_profile: the depth profile asked for by the folder's geofeat.json ("auto" when it
            names none: chosen from the measured depth noise, see `geofeat.depth_profile`).
        radius: geodesic radius for this sequence, metres (geofeat.json `radius`, else 0.075).
        shape: (H, W) of the frames (the reference's), None when unknown.
    """

    folder: Path
    names: list[str]
    K: np.ndarray
    depth_scale: float = DEPTH_SCALE_M
    depth_profile: str = "auto"
    radius: float = DEFAULT_RADIUS_M
    shape: tuple[int, int] | None = None

    @property
    def name(self) -> str:
        return self.folder.name

    @property
    def reference(self) -> str:
        """Name of the reference frame (the name holds `master` or `ref` as a whole token)."""
        return self.names[0]

    @property
    def targets(self) -> list[str]:
        return self.names[1:]

    def frame_name(self, key: str | int) -> str:
        """The name of a frame given by name or by index into `names` (Python or numpy int; negative
        counts from the end); ValueError for a name or index the sequence does not have."""
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            if not -len(self.names) <= int(key) < len(self.names):
                raise ValueError(f"frame index {key} out of range for a sequence of {len(self.names)} frames")
            return self.names[int(key)]
        if not isinstance(key, str) or key not in self.names:
            raise ValueError(f"frame {key!r} is not in the sequence {self.folder} (frames: {self.names[:5]}...)")
        return key

    def frame(self, name: str | int) -> RGBDFrame:
        """The frame `name` (a name or an index, see `frame_name`) as an RGBDFrame."""
        name = self.frame_name(name)
        image = read_image(self.folder / f"{name}{RGB_SUFFIX}")
        if self.shape is not None and image.shape[:2] != tuple(self.shape):  # K is the reference's
            raise ValueError(f"frame {name}: colour {image.shape[1]}x{image.shape[0]} differs in size from the reference "
                             f"{self.reference} ({self.shape[1]}x{self.shape[0]}), whose intrinsics.xml the sequence "
                             f"shares ({self.folder})")
        depth = read_depth(self.folder / f"{name}{DEPTH_SUFFIX}", self.depth_scale)
        if depth.shape != image.shape[:2]:
            raise ValueError(f"frame {name}: depth {depth.shape[1]}x{depth.shape[0]} and colour "
                             f"{image.shape[1]}x{image.shape[0]} differ in size ({self.folder})")
        check_depth_plausible(depth, self.depth_scale, f"frame {name} of {self.folder}")
        try:  # RGBDFrame's own checks (an all-zero depth map) name no file
            return RGBDFrame._from_reader(image, depth, self.K)  # its depth units warned of once, by read_sequence
        except ValueError as error:
            raise ValueError(f"frame {name} of {self.folder}: {error}") from None

    def landmarks(self, name: str | int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids, xy, visible) of the frame's csv, see `read_landmarks`, checked by
        `geofeat.inputs.check_landmarks` (unique ids, visible landmarks on the image)."""
        name = self.frame_name(name)
        ids, xy, visible = read_landmarks(self.folder / f"{name}.csv")
        if self.shape is not None:
            check_landmarks(ids, xy, visible, self.shape, f"{name}.csv")
        return ids, xy, visible

    def correspondences(self, i: str | int, j: str | int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact ground truth of a simulated sequence: map (N, 2) pixels of frame i to frame j.

        Returns mapped (N, 2) pixels of frame j and visible (N,) bool (on the surface in frame i and
        seen, unoccluded, in frame j). Raises ValueError for sequences without simulator ground truth."""
        from .groundtruth.simulator import correspondences

        return correspondences(self, i, j, points)

    def has_ground_truth(self) -> bool:
        """True when the sequence carries the simulator's dense ground truth."""
        from .groundtruth.simulator import has_ground_truth

        return has_ground_truth(self)

    def without_landmarks(self) -> list[str]:
        """The frames that have no `<name>.csv`."""
        return [n for n in self.names if not (self.folder / f"{n}.csv").is_file()]

    def has_landmarks(self) -> bool:
        """True when every frame has its landmark csv (the thin-plate-spline ground truth needs them all)."""
        return not self.without_landmarks()

    def __len__(self) -> int:
        return len(self.names)


def skipped_frame_line(name: str, error: Exception, sequence: str = "") -> str:
    """'SKIPPED frame NAME[ of SEQUENCE]: reason' for a frame a command leaves out, with the error's
    first line as the reason; an error that already names the frame (`Sequence.frame`'s: "frame NAME
    of FOLDER: ...") is not prefixed again."""
    reason = str(error).splitlines()[0] if str(error) else type(error).__name__
    if reason.startswith(f"frame {name} of "):
        return f"SKIPPED {reason}"
    return f"SKIPPED frame {name}{f' of {sequence}' if sequence else ''}: {reason}"


def read_sequence(folder: str | Path, depth_scale: float | None = None) -> Sequence:
    """Open a sequence folder of the public layout (see module docstring).

    `depth_scale` (metres per depth unit) defaults to the folder's optional `geofeat.json`
    (`{"depth_scale": ...}`) and otherwise to 0.001 (millimetres). The same file may name a
    `depth_profile` ("auto", "kinect", "quantised" or "clean"); without it the profile is "auto".
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"folder: not a directory: {folder}")
    names = frame_names(folder)
    if not names:
        raise ValueError(f"folder: no '*{RGB_SUFFIX}' frames in {folder}: {layout_problem(folder)}")
    missing = [n for n in names if not (folder / f"{n}{DEPTH_SUFFIX}").is_file()]
    if missing:
        others = [p for p in _near_misses(folder, DEPTH_SUFFIX) if p.name.startswith(tuple(missing))]
        found = (f" (found {_listing(others)}: depth must be a 16-bit PNG, millimetres unless geofeat.json gives "
                 "depth_scale; geofeat.write_frame(folder, name, color, depth_m) writes one from metres)") if others else ""
        raise ValueError(f"folder: frames without '{DEPTH_SUFFIX}' in {folder}: {missing[:5]}{found}")
    colourless = sorted(set(frame_names(folder, DEPTH_SUFFIX)) - set(names), key=natural_key)
    if colourless:  # such a frame was left out without a word
        raise ValueError(f"folder: frames without '{RGB_SUFFIX}' in {folder}: {colourless[:5]}")
    unread = _unread_frames(folder, names)
    if unread:  # `frame-003-rgb.PNG` beside `frame-002-rgb.png`: the sequence was read without it, no word said
        raise ValueError(f"folder: {folder} holds colour frames geofeat does not read ({_listing(unread)}) beside "
                         f"its '*{RGB_SUFFIX}' frames: colour frames must be PNG files named exactly <name>{RGB_SUFFIX}; "
                         "rename them (and their depth PNGs), or move them out of the sequence folder")
    refs = [n for n in names if is_reference_name(n)]
    if len(refs) > 1:
        raise ValueError(f"folder: {folder} has several reference frames ({', '.join(refs[:5])}); "
                         "exactly one frame name may hold 'master' or 'ref'")
    reference = reference_name(names)
    names = [reference] + [n for n in names if n != reference]
    config = read_config(folder)
    if depth_scale is None:
        depth_scale = float(config.get("depth_scale", DEPTH_SCALE_M))
    check_depth_scale(depth_scale, "depth_scale")  # the Python argument: geofeat.json's is checked by read_config
    profile = config.get("depth_profile", "auto")
    radius = float(config.get("radius", DEFAULT_RADIUS_M))
    image = read_image(folder / f"{reference}{RGB_SUFFIX}")
    shape = (int(image.shape[0]), int(image.shape[1]))
    K = read_intrinsics(folder / "intrinsics.xml", shape)
    K = check_intrinsics_for_image(K, shape, f"intrinsics_path: {folder / 'intrinsics.xml'}")
    seq = Sequence(folder=folder, names=names, K=K, depth_scale=depth_scale, depth_profile=profile.strip().lower(),
                   radius=radius, shape=shape)
    depth = read_depth(folder / f"{reference}{DEPTH_SUFFIX}", depth_scale)
    check_depth_plausible(depth, depth_scale, f"frame {reference} of {folder}")
    # once per sequence, on its reference frame: a scale 10x off passes the check above
    warn_depth_units(depth, depth_scale, f"sequence {folder} (reference frame {reference})", key=str(folder.resolve()))
    return seq


def demo_data_dir() -> Path:
    """Folder of the real Kinect v1 frame shipped with geofeat (`cloud_1`, 51 landmarks)."""
    return Path(__file__).parent / "data" / "kinect_example"


def read_demo_frame() -> RGBDFrame:
    """The shipped real Kinect v1 frame (640x480, depth in mm on disk)."""
    d = demo_data_dir()
    return read_frame(d / "cloud_1-rgb.png", d / "cloud_1-depth.png", d / "intrinsics.xml")


def _looks_like_sequence(folder: Path) -> bool:
    """Whether `folder`, which has no `*-rgb.png` frame, holds what only a sequence folder holds: depth
    frames (`<name>-depth.png`), an `intrinsics.xml`, or colour frames geofeat does not read
    (`<name>-rgb.jpg`, `<name>-rgb.PNG`; `_near_misses`)."""
    return ((folder / "intrinsics.xml").is_file() or bool(frame_names(folder, DEPTH_SUFFIX))
            or bool(_near_misses(folder, RGB_SUFFIX)))


def path_list(paths) -> list[Path]:
    """The folders a command was given (one path, or an iterable of them) as a list of paths."""
    return [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]


def find_sequences(paths, unique_names: bool = False, what: str = "dataset") -> list[Path]:
    """Sequence folders under the given paths: a path that holds `*-rgb.png` frames is a sequence,
    otherwise its sub-folders that do are (one level down, hidden ones left out), sorted by name; a
    sub-folder that looks like a sequence but has no such frame (`_looks_like_sequence`) is refused
    rather than passed over. A folder reached twice is
    listed once; with `unique_names`, two different folders with one name are refused (commands key
    their results by the sequence name). ValueError naming `what` (an option such as --data) for a
    path that is no folder or holds no sequence."""
    found: list[Path] = []
    for p in path_list(paths):
        if not p.is_dir():
            raise ValueError(f"{what}: not a directory: {p}")
        if frame_names(p):
            # a folder of sequences with loose frames beside them was read as one sequence of the loose
            # frames, the sequence folders left out without a word
            inner = sorted(d for d in p.iterdir() if d.is_dir() and not d.name.startswith(".") and frame_names(d))
            if inner:
                raise ValueError(f"{what}: {p} holds both frames ({_listing(list(p.glob(f'*{RGB_SUFFIX}')))}) and the "
                                 f"sequence folders {_listing(inner)}: move the loose frames into a sequence folder of "
                                 "their own, or name the sequence folders")
            found.append(p)
            continue
        # a hidden sub-folder (as hidden frame files, `frame_names`) is not a sequence: above all the
        # temporary folder of a `simulate` or a result still being written, or left by a killed run,
        # which was read as a sequence, half-written and without its geofeat.json (its depth scale)
        subs = sorted(d for d in p.iterdir() if d.is_dir() and not d.name.startswith(".") and frame_names(d))
        if not subs:
            raise ValueError(f"{what}: no sequence (folder of '*{RGB_SUFFIX}' frames) in {p}: {layout_problem(p)}")
        # a sequence folder whose colour frames are not read (JPEG, upper-case .PNG) was left out without
        # a word, and the others were scored as the whole dataset
        broken = sorted(d for d in p.iterdir() if d.is_dir() and not d.name.startswith(".") and d not in subs
                        and _looks_like_sequence(d))
        if broken:
            raise ValueError(f"{what}: {broken[0]} holds no '*{RGB_SUFFIX}' frames, though it looks like a sequence "
                             f"folder of {p} (one of {len(broken)}): {layout_problem(broken[0])}; fix its files, or "
                             "move it out of the folder of sequences")
        found.extend(subs)
    seen: set[Path] = set()
    unique = [f for f in found if not (f.resolve() in seen or seen.add(f.resolve()))]
    if unique_names:
        check_unique_names(unique)
    return unique

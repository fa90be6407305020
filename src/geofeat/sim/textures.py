"""Cloth textures: the packaged training photographs, image files, and procedural generators.

A texture is an (Ht, Wt, 3) float32 BGR albedo in [0, 1], cropped to the cloth's aspect ratio and
resized so that one texel is about the size of one pixel of the closest view (no aliasing).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


def packaged_texture_dir() -> Path:
    """Folder of the training photographs shipped with geofeat (credits in its SOURCES.md)."""
    return Path(__file__).resolve().parent.parent / "data" / "textures"


def list_textures(folder: str | Path) -> list[Path]:
    """Image files of a folder (sorted, non-recursive)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"texture_dir: not a directory: {folder}")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if not files:
        raise ValueError(f"texture_dir: no image files ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    return files


def read_texture(path: str | Path) -> np.ndarray:
    """Read an image file as (H, W, 3) uint8 BGR; ValueError if it is missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"texture: file not found: {path}")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        raise ValueError(f"texture: cannot decode image {path}")
    if min(image.shape[:2]) < 8:
        raise ValueError(f"texture: image {path} is too small ({image.shape[1]}x{image.shape[0]} px)")
    return image


def prepare_texture(image: np.ndarray, aspect: float, max_width: int) -> np.ndarray:
    """Centre-crop a uint8 BGR image to `aspect` = width / height, resize to <= `max_width` texels
    wide (area filter), return (Ht, Wt, 3) float32 in [0, 1]."""
    h, w = image.shape[:2]
    if w / h > aspect:
        cw, ch = int(round(h * aspect)), h
    else:
        cw, ch = w, int(round(w / aspect))
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    crop = image[y0 : y0 + ch, x0 : x0 + cw]
    tw = max(8, min(max_width, cw))
    th = max(8, int(round(tw / aspect)))
    if (tw, th) != (cw, ch):
        interp = cv2.INTER_AREA if tw < cw else cv2.INTER_LINEAR
        crop = cv2.resize(crop, (tw, th), interpolation=interp)
    return np.ascontiguousarray(crop, dtype=np.float32) / 255.0


def procedural_texture(rng: np.random.Generator, width: int = 512, height: int = 384) -> np.ndarray:
    """A random (height, width, 3) uint8 BGR texture: multi-octave coloured noise overlaid with
    random filled shapes, lines and text, so that it has corners and blobs at many scales."""
    image = np.zeros((height, width, 3), dtype=np.float32)
    for octave in range(5):
        cells = 2 ** (octave + 2)
        small = rng.random((cells, max(2, int(cells * width / height)), 3)).astype(np.float32)
        image += cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC) * (0.6 ** octave)
    image -= image.min()
    image = (image / max(float(image.max()), 1e-6) * 255).astype(np.uint8)
    for _ in range(int(rng.integers(25, 60))):
        color = tuple(int(c) for c in rng.integers(0, 256, 3))
        kind = rng.integers(0, 4)
        x, y = int(rng.integers(0, width)), int(rng.integers(0, height))
        size = int(rng.integers(4, max(5, width // 6)))
        if kind == 0:
            cv2.circle(image, (x, y), size, color, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(image, (x, y), (x + size, y + int(rng.integers(4, size + 5))), color, -1)
        elif kind == 2:
            x2, y2 = int(rng.integers(0, width)), int(rng.integers(0, height))
            cv2.line(image, (x, y), (x2, y2), color, int(rng.integers(1, 6)), cv2.LINE_AA)
        else:
            text = "".join(chr(int(c)) for c in rng.integers(65, 91, int(rng.integers(2, 6))))
            cv2.putText(image, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, size / 40, color, 2, cv2.LINE_AA)
    return image


def choose_texture(
    rng: np.random.Generator,
    texture: str | Path | np.ndarray | None = None,
    texture_dir: str | Path | None = None,
    procedural_fraction: float = 0.25,
) -> tuple[np.ndarray, str]:
    """Pick the texture of a sequence: an explicit file or array, one drawn at random from
    `texture_dir`, or (both None) a packaged photograph or, with probability `procedural_fraction`,
    a procedural texture. Returns ((H, W, 3) uint8 BGR, description)."""
    if texture is not None and texture_dir is not None:
        raise ValueError("texture, texture_dir: give at most one of them")
    if isinstance(texture, np.ndarray):
        arr = np.asarray(texture)
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
            raise ValueError(f"texture: expected an (H, W, 3) uint8 BGR array, got {arr.shape} {arr.dtype}")
        return arr, "array"
    if texture is not None:
        if str(texture) == "procedural":
            return procedural_texture(rng), "procedural"
        return read_texture(texture), Path(texture).name
    if texture_dir is not None:
        files = list_textures(texture_dir)
        path = files[int(rng.integers(len(files)))]
        return read_texture(path), path.name
    if rng.random() < procedural_fraction:
        return procedural_texture(rng), "procedural"
    files = list_textures(packaged_texture_dir())
    path = files[int(rng.integers(len(files)))]
    return read_texture(path), path.name

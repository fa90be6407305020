"""Cloth textures: the packaged training photographs, image files, and procedural generators.

A texture is an (Ht, Wt, 3) float32 BGR albedo in [0, 1], cropped to the cloth's aspect ratio and
resized so that one texel is about the size of one pixel of the closest view (no aliasing).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
#: The formats of `IMAGE_SUFFIXES` that can hold an alpha channel (`_warn_if_transparent`).
ALPHA_SUFFIXES = (".png", ".bmp", ".tif", ".tiff", ".webp")


def packaged_texture_dir() -> Path:
    """Folder of the training photographs shipped with geofeat (credits in its SOURCES.md)."""
    return Path(__file__).resolve().parent.parent / "data" / "textures"


def list_textures(folder: str | Path) -> list[Path]:
    """Image files of a folder (sorted, non-recursive; hidden files left out: the `._photo.jpg` that macOS
    writes beside each photo on a foreign disk is no image, and drawn for a seed it failed that seed)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"texture_dir: not a directory: {folder}")
    files = sorted(p for p in folder.iterdir()
                   if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") and p.is_file())
    if not files:
        raise ValueError(f"texture_dir: no image files ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    return files


def read_texture(path: str | Path) -> np.ndarray:
    """Read an image file as (H, W, 3) uint8 BGR (`geofeat.io.read_image`: grey, RGBA and 16-bit files
    too, a 16-bit file of 8-bit values warned of); ValueError if it is missing or unreadable."""
    from ..io import read_image

    path = Path(path)
    if path.is_dir():  # "file not found" for a folder that exists misled
        raise ValueError(f"texture: {path} is a folder, not an image file; pass a folder of images as --texture-dir")
    if not path.is_file():
        # a bare word that is no file ("Procedural", "fabrics") is likelier a misspelt choice than a lost file
        choices = "" if path.suffix or len(path.parts) > 1 else (
            "; the generated textures are 'procedural', 'fabric' or 'fabric:KIND' (lower case)")
        raise ValueError(f"texture: file not found: {path}{choices}")
    image = read_image(path, "texture")  # ValueError "texture: cannot decode image ..." for a foreign file
    if min(image.shape[:2]) < 8:
        raise ValueError(f"texture: image {path} is too small ({image.shape[1]}x{image.shape[0]} px)")
    _warn_if_transparent(path)
    return image


def _warn_if_transparent(path: Path) -> None:
    """Warn when the image file has an alpha channel with transparent pixels: the cloth shows the colour
    stored under them (black, in most files: a logo on a transparent background became a logo on black).
    The file is decoded a second time (`read_image` drops the alpha), so only in formats that can hold
    one: the packaged JPEG photographs, and every seed that draws one, are not read twice."""
    import warnings

    if path.suffix.lower() not in ALPHA_SUFFIXES:
        return
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if raw is None or raw.ndim != 3 or raw.shape[2] != 4:
        return
    alpha = raw[..., 3]
    if alpha.min() < np.iinfo(alpha.dtype).max:
        warnings.warn(f"texture: {path} has transparent pixels ({(alpha < np.iinfo(alpha.dtype).max).mean():.0%}); "
                      "the cloth shows the colour stored under them, not what the image shows over a background: "
                      "flatten the image onto a background first", stacklevel=3)


#: Most texels a prepared texture holds: 4096 x 4096, 192 MiB as float32 BGR.
MAX_TEXELS = 4096 * 4096


def texture_width(px_width: float, aspect: float) -> int:
    """Texels across the texture of a cloth `px_width` pixels wide at its closest view (`aspect` = width /
    height): 1.5 per pixel up to 1024 texels, and never under one per pixel, within MAX_TEXELS in all.

    A flat cap of 1024 texels stretched a texel over four pixels of a 4096 px wide frame (a blurred cloth).
    Where the cloth spans at most 1008 px (every preset at 640 x 480) the width is that cap's. The texture
    gets this width only from an image at least as wide (`prepare_texture` never enlarges one)."""
    texels = max(min(1.5 * px_width + 16, 1024), px_width + 16)
    return int(min(texels, np.sqrt(MAX_TEXELS * aspect)))


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
    a procedural texture (half the time a `fabric_texture`; texture="fabric" or "fabric:KIND" asks for
    one). Returns ((H, W, 3) uint8 BGR, description: the file name, "procedural", "fabric" or
    "fabric:KIND" as asked for, or "array")."""
    if texture is not None and texture_dir is not None:
        raise ValueError("texture, texture_dir: give at most one of them")
    if isinstance(texture, np.ndarray):
        arr = np.asarray(texture)
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
            raise ValueError(f"texture: expected an (H, W, 3) uint8 BGR array, got {arr.shape} {arr.dtype}")
        if arr.size == 0:  # a zero side crashed later (ZeroDivisionError, cv2.error)
            raise ValueError(f"texture: the array is empty ({arr.shape})")
        return arr, "array"
    if texture is not None:
        if str(texture) == "procedural":
            return procedural_texture(rng), "procedural"
        if str(texture) == "fabric" or str(texture).startswith("fabric:"):
            kind = str(texture).partition(":")[2] or None
            if kind is not None and kind not in FABRIC_KINDS:
                raise ValueError(f"texture: expected 'fabric' or 'fabric:KIND' with KIND one of {', '.join(FABRIC_KINDS)}, "
                                 f"got {texture!r}")
            img = fabric_texture(rng, kind)
            # the family asked for is part of what was simulated: recorded as plain "fabric", a "fabric:plaid"
            # sequence passed `recorded_difference(texture="fabric")` (a random family, other draws) as the same
            return img, "fabric" if kind is None else f"fabric:{kind}"
        return read_texture(texture), Path(texture).name
    if texture_dir is not None:
        files = list_textures(texture_dir)
        path = files[int(rng.integers(len(files)))]
        try:
            return read_texture(path), path.name
        except ValueError as error:  # it named --texture, which was not given, and only some seeds hit it
            raise ValueError(f"texture_dir: {path.name}, the file this seed draws from {texture_dir}, is no usable "
                             f"texture ({error}); remove it from the folder") from None
    if rng.random() < procedural_fraction:
        if rng.random() < 0.5:
            return procedural_texture(rng), "procedural"
        return fabric_texture(rng), "fabric"
    files = list_textures(packaged_texture_dir())
    path = files[int(rng.integers(len(files)))]
    return read_texture(path), path.name


#: Families of `fabric_texture` (printed and woven fabric patterns, generated in code).
FABRIC_KINDS = ("stripes", "plaid", "gingham", "dots", "houndstooth", "herringbone", "floral", "paisley",
                "camouflage", "knit", "lettering", "geometric", "denim")


def _palette(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) float32 BGR colours in [0, 1]: random hues, mixed saturation and value."""
    hsv = np.stack([rng.integers(0, 180, n), rng.integers(40, 256, n), rng.integers(40, 256, n)], axis=1)
    return cv2.cvtColor(hsv.astype(np.uint8)[None], cv2.COLOR_HSV2BGR)[0].astype(np.float32) / 255.0


def _noise(rng: np.random.Generator, h: int, w: int, cells: int) -> np.ndarray:
    """(h, w) float32 smooth noise in [0, 1] with about `cells` blobs across."""
    small = rng.random((max(2, cells * h // max(w, 1)), max(2, cells))).astype(np.float32)
    n = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    return (n - n.min()) / max(float(np.ptp(n)), 1e-6)


def _bands(rng: np.random.Generator, coord: np.ndarray, period: float) -> np.ndarray:
    """Index (0..k-1) of a band of random widths repeating every 3 periods along `coord`."""
    widths = rng.uniform(0.1, 1.0, int(rng.integers(2, 6)))
    edges = np.cumsum(widths) / widths.sum()
    phase = (coord / (period * 3)) % 1.0
    return np.searchsorted(edges, phase).clip(0, len(widths) - 1)


def _stripes(rng, kind, img, pal, xr, yr, period):
    return pal[1:][_bands(rng, xr, period) % 5]


def _checks(rng, kind, img, pal, xr, yr, period):  # plaid, gingham: two crossing band sets
    a, b = _bands(rng, xr, period), _bands(rng, yr, period)
    alpha = 0.5 if kind == "gingham" else rng.uniform(0.3, 0.7)
    return alpha * pal[1:][a % 5] + (1 - alpha) * pal[1:][(b + 2) % 5]


def _dots(rng, kind, img, pal, xr, yr, period):
    gx, gy = (xr / period) % 1.0 - 0.5, (yr / period) % 1.0 - 0.5
    img[np.hypot(gx, gy) < rng.uniform(0.15, 0.4)] = pal[1]
    return img


_HOUNDSTOOTH = np.array([[1, 1, 0, 1], [1, 1, 1, 0], [0, 1, 1, 0], [1, 0, 0, 0]], bool)


def _houndstooth(rng, kind, img, pal, xr, yr, period):
    u, v = (xr / period * 4).astype(np.int64) % 4, (yr / period * 4).astype(np.int64) % 4
    img[_HOUNDSTOOTH[v, u]] = pal[1]
    return img


def _twill(rng, kind, img, pal, xr, yr, period):  # herringbone, denim: diagonal weaves
    col = ((xr / period * 3).astype(np.int64) % 2) * 2 - 1
    if kind == "herringbone":
        diag = ((yr + col * xr) / (period / 4)) % 1.0 < 0.5
    else:
        diag = ((yr + xr) / 4) % 1.0 < 0.5
        pal[:2] = _palette(rng, 1) * np.array([1.0, 0.5, 0.3], np.float32) + np.array([0.3, 0.1, 0.0], np.float32)
        pal[1] = np.clip(pal[0] * 1.8 + 0.2, 0, 1)
    img[diag] = pal[1]
    return img


def _camouflage(rng, kind, img, pal, xr, yr, period):
    h, w = img.shape[:2]
    levels = np.stack([_noise(rng, h, w, int(rng.integers(4, 12))) for _ in range(3)])
    return pal[1:4][np.argmax(levels + rng.uniform(0, 0.2, (3, 1, 1)), axis=0)]


def _knit(rng, kind, img, pal, xr, yr, period):
    h, w = img.shape[:2]
    wave = np.sin(2 * np.pi * xr / (period / 3)) * np.sin(2 * np.pi * yr / (period / 2))
    img = pal[0] + (pal[1] - pal[0]) * (0.5 + 0.5 * wave[..., None])
    return img * (0.7 + 0.3 * _noise(rng, h, w, 20)[..., None])


def _bgr(colour: np.ndarray) -> tuple:
    return tuple(int(c) for c in colour * 255)


def _floral(canvas, rng, pal, cx, cy, s, col):
    for k in range(int(rng.integers(4, 8))):
        t = k * 2 * np.pi / 6 + rng.uniform(-0.2, 0.2)
        cv2.ellipse(canvas, (int(cx + s * np.cos(t)), int(cy + s * np.sin(t))), (s, max(1, s // 3)),
                    np.degrees(t), 0, 360, col, -1, cv2.LINE_AA)
    cv2.circle(canvas, (cx, cy), max(1, s // 3), _bgr(pal[5]), -1, cv2.LINE_AA)


def _paisley(canvas, rng, pal, cx, cy, s, col):
    cv2.ellipse(canvas, (cx, cy), (s, max(1, s // 2)), rng.uniform(0, 180), 0, 360, col, -1, cv2.LINE_AA)
    cv2.ellipse(canvas, (cx, cy), (max(1, s // 2), max(1, s // 4)), rng.uniform(0, 180), 0, 360,
                _bgr(pal[0]), 2, cv2.LINE_AA)


def _lettering(canvas, rng, pal, cx, cy, s, col):
    text = "".join(chr(int(c)) for c in rng.integers(65, 91, int(rng.integers(1, 5))))
    cv2.putText(canvas, text, (cx, cy), int(rng.choice([0, 2, 3, 4])), s / 25, col, 2, cv2.LINE_AA)


def _geometric(canvas, rng, pal, cx, cy, s, col):
    pts = (np.array([cx, cy]) + rng.uniform(-s, s, (int(rng.integers(3, 7)), 2))).astype(np.int32)
    cv2.fillPoly(canvas, [cv2.convexHull(pts)], col, cv2.LINE_AA)


#: Motif families: one drawer per motif, scattered at random over the base colour.
_MOTIFS = {"floral": _floral, "paisley": _paisley, "lettering": _lettering, "geometric": _geometric}


def _motifs(rng, kind, img, pal, xr, yr, period):
    h, w = img.shape[:2]
    canvas = (img * 255).astype(np.uint8)
    for _ in range(int(w * h / period**2 * rng.uniform(0.3, 0.8))):
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        col = _bgr(pal[int(rng.integers(1, 6))])
        s = int(rng.uniform(0.3, 0.7) * period)
        _MOTIFS[kind](canvas, rng, pal, cx, cy, s, col)
    return canvas.astype(np.float32) / 255.0


#: kind -> pattern function (rng, kind, base image, palette, rotated x, rotated y, period) -> image.
_PATTERNS = {
    "stripes": _stripes, "plaid": _checks, "gingham": _checks, "dots": _dots, "houndstooth": _houndstooth,
    "herringbone": _twill, "denim": _twill, "camouflage": _camouflage, "knit": _knit,
    **{kind: _motifs for kind in _MOTIFS},
}


def fabric_texture(rng: np.random.Generator, kind: str | None = None, width: int = 512, height: int = 384) -> np.ndarray:
    """A random (height, width, 3) uint8 BGR fabric pattern of family `kind` (one of FABRIC_KINDS;
    None = drawn at random): printed or woven repeats with random colours, scale and angle, plus
    fine weave grain and smooth dye variation, so that there is structure at every scale."""
    if kind is None:
        kind = FABRIC_KINDS[int(rng.integers(len(FABRIC_KINDS)))]
    if kind not in FABRIC_KINDS:
        raise ValueError(f"kind: expected one of {', '.join(FABRIC_KINDS)}, got {kind!r}")
    h, w = height, width
    pal = _palette(rng, 6)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    angle = rng.uniform(0, np.pi)
    xr = x * np.cos(angle) + y * np.sin(angle)
    yr = -x * np.sin(angle) + y * np.cos(angle)
    period = float(rng.uniform(12, 60))
    img = np.empty((h, w, 3), np.float32)
    img[:] = pal[0]
    img = np.asarray(_PATTERNS[kind](rng, kind, img, pal, xr, yr, period), np.float32).reshape(h, w, 3)
    # dye variation and weave grain
    img = img * (0.85 + 0.3 * _noise(rng, h, w, int(rng.integers(2, 6))))[..., None]
    img = img + rng.normal(0, rng.uniform(0.01, 0.04), (h, w, 1)).astype(np.float32)
    return np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)


def jitter_colours(image: np.ndarray, rng: np.random.Generator, strength: float = 1.0) -> np.ndarray:
    """Colour / contrast augmentation of an (H, W, 3) uint8 BGR texture: hue rotation, saturation
    and contrast scaling, gamma, and a per-channel gain (`strength` scales all ranges)."""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV).astype(np.float32)
    hsv[..., 0] = (hsv[..., 0] + rng.uniform(-30, 30) * strength) % 180
    hsv[..., 1] = np.clip(hsv[..., 1] * (1 + rng.uniform(-0.5, 0.5) * strength), 0, 255)
    img = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2BGR).astype(np.float32) / 255.0
    mean = img.mean()
    img = (img - mean) * (1 + rng.uniform(-0.4, 0.4) * strength) + mean
    img = np.clip(img, 0, 1) ** np.exp(rng.uniform(-0.4, 0.4) * strength)
    img = img * (1 + rng.uniform(-0.15, 0.15, 3) * strength)
    return np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)

"""The GPU path from frame to matches (`device="cuda"`): geodesic walk -> patch sampling -> GeoPatch
CNN -> matching, every intermediate array staying on the GPU.

Per frame, the host detects the keypoints and fills the depth's small holes (`depth.fill_holes`, a
connected-component labelling) and uploads the filled depth, the gray image and the keypoints once.
Then on the GPU:

0. the mesh (`build_mesh_cuda`, cached on the frame like the host's `frame_mesh`): the depth's
   smoothing pyramid on tensors, back-projection, and one thread per face for the faces, normals
   and the walk's tables (the CPU's kernel sources, `walk_cuda.mesh_faces_cuda`); a host
   `GridMesh` passed as `mesh=` is uploaded instead (its tables cached on it);
1. the walk (`geodesic.walk_cuda`: the CPU walk's kernel source compiled by numba.cuda), writing
   into torch tensors;
2. the sampling blur (separable Gaussian, OpenCV's kernel) and the bilinear read of the patches
   in OpenCV `remap`'s form, with border replication (`sample_bilinear_torch`);
3. the GeoPatch CNN in torch (fp32, TF32 off; float16 autocast with `compute_cuda(..., half=True)`);
4. matching as matrix products: L2 for GeoPatch, min-over-rotations Hamming for GeoBit
   (`matching._hamming_search_torch`); only the (N0,) matches and distances come back.

Results equal the CPU path's within stated tolerances (tests/test_gpu.py, tests/test_walk_cuda.py):
the smoothed depth within two float32 ulp of OpenCV's (the same depth, bit for bit, in the "clean"
profile, which does not smooth), the same faces on the tested frames,
walk coordinates within 1e-4 px (the GPU's cos/sin and fused multiply-adds may differ from the CPU's
in the last bits of float64; on an H100 the Kinect pair's coordinates and rings reached were
identical), patch values within 1e-5 where the coordinates agree, descriptors within 1e-4 (of the CPU's
torch backend, `GeoPatch(backend="torch")`; the CPU's default int8 / bfloat16 backends differ from
both by their rounding), the same matches on the tested frames. Nothing here is imported by `import geofeat`;
torch and numba.cuda load on first use.

Under numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1, no GPU needed) the same code runs with torch
CPU tensors and the walk kernel simulated: that is how the tests run the whole path without a GPU.
"""

from __future__ import annotations

import contextlib
import functools
import os
from dataclasses import dataclass

import numpy as np

from .constants import DEFAULT_RADIUS_M, MAX_EDGE_STRETCH, N_ANGLES, N_RINGS, SAMPLING_BLUR_PX, SMOOTH_WINDOW_PX
from .depth import DepthConfig, mean_focal
from .features import Features, Matches
from .matching import check_match_options
from .frame import RGBDFrame
from .geodesic.mesh import GridMesh, frame_fingerprint, frame_mesh, image_to_mesh
from .geodesic.polar import MIN_DIRECTION_SHARE, check_blur_px, check_mesh_shape, check_patch_request, walk_starts

#: Attribute of a GridMesh under which its device tables are kept, per device.
_MESH_ATTR = "_geofeat_device_tables"


def is_cuda_device(device) -> bool:
    """Whether `device` ("cuda", "cuda:1", a torch.device) names a CUDA device."""
    return device is not None and str(device).split(":")[0] == "cuda"


def wants_gpu(device) -> bool:
    """Whether `device`, as geofeat's functions take it, asks for the GPU path: True for "cuda",
    "cuda:N" (or a CUDA torch.device), False for None and "cpu" (the CPU path); ValueError naming
    `device` for anything else."""
    if is_cuda_device(device):
        return True
    if device is not None and str(device) != "cpu":
        raise ValueError(f"device: expected None, 'cpu' or 'cuda[:N]', got {device!r}")
    return False


def gpu_computes(name: str) -> bool:
    """Whether the GPU path computes the descriptor of (checked, `check_descriptor_name`) name
    `name`: GeoPatch with torch weights ("geopatch", "geopatch=WEIGHTS.pt"), not from an .onnx
    model, nor another descriptor."""
    base, _, weights = name.partition("=")
    return base == "geopatch" and not weights.lower().endswith(".onnx")


def gpu_descriptors(names, device) -> tuple[str, ...]:
    """The descriptors of `names` (checked names) that a run of several descriptors (the bench,
    tracking, retrieval) describes and matches on the GPU path when given `device`: for "cuda" /
    "cuda:N" the GeoPatch ones with torch weights (`gpu_computes`), the others staying on the CPU;
    none for None or "cpu". ValueError naming `device` for another value (`wants_gpu`), and for a
    CUDA device when a GeoPatch of .onnx weights is named, or no GeoPatch at all: the device would
    be ignored for it, or for every descriptor."""
    if not wants_gpu(device):
        return ()
    onnx = [n for n in names if n.partition("=")[0] == "geopatch" and not gpu_computes(n)]
    on_gpu = tuple(n for n in names if gpu_computes(n))
    if onnx or not on_gpu:
        raise ValueError(f"device: {str(device)!r} describes GeoPatch with torch weights (geopatch or "
                         "geopatch=WEIGHTS.pt) on the GPU path and the other descriptors on the CPU; "
                         + (f"{onnx[0]} is an ONNX model (torch weights only)" if onnx else
                            f"none of {', '.join(names) or 'no descriptor'} is GeoPatch"))
    return on_gpu


def simulated() -> bool:
    """Whether numba's CUDA simulator is on (then torch tensors live on the CPU)."""
    return os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0")


def torch_device(device):
    """The torch.device for `device` ("cpu", "cuda", "cuda:N" or a torch.device) for work that needs torch
    only (the GeoPatch network, `match(..., device=...)`): ValueError for a name torch does not know
    or a GPU index it does not see, and `require_cuda`'s RuntimeError for a CUDA device without a CUDA GPU (torch's own is an
    AssertionError). Another device type torch knows ("mps", "xpu", "meta") is a ValueError too: geofeat
    runs on the CPU and CUDA only (torch failed later, with "Torch not compiled with XPU enabled" or "Cannot
    copy out of meta tensor"). The GPU walk needs `require_cuda`."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device: expected None, 'cpu' or 'cuda[:N]', got {device!r}") from None
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device: expected None, 'cpu' or 'cuda[:N]', got {device!r} (geofeat runs on the CPU "
                         "and CUDA GPUs only)")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise RuntimeError(f"device={str(device)!r}: no CUDA GPU is available to torch (torch {torch.__version__}, "
                           f"built for CUDA {torch.version.cuda}); use device='cpu' or None")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        count = torch.cuda.device_count()  # torch's own error comes later: "CUDA error: invalid device ordinal"
        raise ValueError(f"device: {str(device)!r}, but torch sees {count} CUDA GPU{'s' if count != 1 else ''} "
                         f"(cuda:0 to cuda:{count - 1}; CUDA_VISIBLE_DEVICES renumbers them)")
    return dev


def require_cuda(device="cuda"):
    """The torch.device for `device`, or a RuntimeError saying what is missing: a CUDA build of
    torch with a visible GPU, and numba's CUDA target (built into numba <= 0.60, else the
    numba-cuda package: pip install 'geofeat[cuda]'). A device that is not CUDA ("cpu", a typo) is a
    ValueError naming `device`. Under the simulator: the CPU, whatever `device`."""
    import importlib.util

    if simulated():
        import torch

        return torch.device("cpu")
    if importlib.util.find_spec("torch") is None:
        raise RuntimeError("device='cuda': torch is not installed")
    import torch

    dev = torch_device(device)  # ValueError for a name torch does not know, RuntimeError without a GPU
    if dev.type != "cuda":
        raise ValueError(f"device: the GPU path needs 'cuda' or 'cuda:N', got {device!r}")
    try:
        from numba import cuda
    except ImportError as exc:  # pragma: no cover - depends on the numba build
        raise RuntimeError("device='cuda': numba's CUDA target is missing; pip install 'geofeat[cuda]' "
                           f"(numba-cuda) ({exc})") from exc
    if not cuda.is_available():
        raise RuntimeError("device='cuda': numba cannot use the GPU (numba.cuda.is_available() is False; "
                           "pip install 'geofeat[cuda]' for the numba-cuda target)")
    if dev.index is None:
        dev = torch.device("cuda", torch.cuda.current_device())
    return dev


def mesh_device(device="cuda") -> str:
    """The device under which `frame_mesh` keeps the GPU path's mesh for `device`: "cuda:N" (the
    index resolved, so that "cuda" and "cuda:0" share it), "cuda" under the simulator."""
    dev = require_cuda(device)
    return str(dev) if dev.type == "cuda" else "cuda"


def _as_numba(t):
    """A numba device array viewing torch CUDA tensor `t` (no copy, no synchronisation); anything
    that is not a torch tensor (a view made before, e.g. outside a CUDA graph's capture) as it is."""
    if not hasattr(t, "detach"):
        return t
    if simulated():
        return t.detach().numpy()
    from numba import cuda

    return cuda.as_cuda_array(t.detach(), sync=False)


def _numba_on(dev):
    """A context manager that makes torch device `dev`'s GPU numba's current one: numba launches its
    kernels, and views torch's memory, in its current context, which is the first GPU unless told;
    torch's tensors of "cuda:1" live on the second."""
    if simulated():
        return contextlib.nullcontext()
    import torch
    from numba import cuda

    return cuda.gpus[dev.index if dev.index is not None else torch.cuda.current_device()]


def _numba_stream(dev):
    if simulated():
        return 0
    import torch
    from numba import cuda

    return cuda.external_stream(torch.cuda.current_stream(dev).cuda_stream)


def smooth_depth_torch(depth, levels: int, out_scale: float, window: int = SMOOTH_WINDOW_PX):
    """`geofeat.depth.smooth` of an (H, W) float32 depth tensor (metres, 0 = missing) on its device:
    `levels` rounds of masked `window` box mean and 2x2 halving, then the masked bilinear resize to
    `out_scale` times the input size. Equal to the OpenCV version within float32 rounding (box sums
    in float64 as OpenCV's, the resize in float32 with the same half-pixel convention; two ulp on the
    Kinect frame with the shipped profiles: tested). A resize by a factor that is not a power of two
    differs a little more (measured: up to 5.7e-6 m at a factor of 0.37 on that frame).

    Returns (max(2, round(H * out_scale)), max(2, round(W * out_scale))) float32 metres, 0 = missing
    (all 0 for a map under 2 pixels high or wide, as the CPU's: `depth.too_thin_for_surface`)."""
    import torch
    import torch.nn.functional as F

    from . import depth as host  # the CPU pyramid's rules, read at call time: HALVE_MIN_VALID, RESIZE_MIN_WEIGHT

    H, W = depth.shape
    size = (max(2, int(round(H * out_scale))), max(2, int(round(W * out_scale))))
    if host.too_thin_for_surface((H, W)):
        return torch.zeros(size, dtype=torch.float32, device=depth.device)
    d = depth.float()
    area = float(window * window)
    halvings = 0
    for _ in range(levels):
        if min(d.shape) < 2 * window:
            break
        halvings += 1
        valid = d > 0
        v = valid.double()
        both = torch.stack([d.double() * v, v])[:, None]  # (2, 1, H, W): depth sum and count
        sums = F.avg_pool2d(both, window, stride=1, padding=window // 2, count_include_pad=True)[:, 0] * area
        num, den = sums[0].float(), torch.round(sums[1]).float()
        d = torch.where(valid, num / torch.clamp(den, min=1e-12), torch.zeros((), device=d.device))
        h, w = d.shape[0] // 2 * 2, d.shape[1] // 2 * 2
        a, b, c, e = d[0:h:2, 0:w:2], d[0:h:2, 1:w:2], d[1:h:2, 0:w:2], d[1:h:2, 1:w:2]
        count = (a > 0).double() + (b > 0).double() + (c > 0).double() + (e > 0).double()
        total = (a + b) + (c + e)
        zero = torch.zeros((), dtype=torch.float64, device=d.device)
        d = torch.where(count >= host.HALVE_MIN_VALID, total.double() / torch.clamp(count, min=1.0), zero).float()
    matrices = _resampling_tensors((H, W), tuple(d.shape), halvings, size[::-1], d.device)
    if matrices is not None:  # a frame the pyramid does not cover: the CPU's exact resampling
        Ry, Rx = matrices
        valid = (d > 0).double()
        num, den = Ry @ (d.double() * valid) @ Rx.T, Ry @ valid @ Rx.T
        zero = torch.zeros((), dtype=torch.float64, device=d.device)
        return torch.where(den >= host.RESIZE_MIN_WEIGHT, num / torch.clamp(den, min=1e-12), zero).float()
    if tuple(d.shape) == size:
        return d
    valid = (d > 0).float()
    both = torch.stack([d * valid, valid])[:, None]
    num, den = F.interpolate(both, size=size, mode="bilinear", align_corners=False)[:, 0]
    return torch.where(den >= host.RESIZE_MIN_WEIGHT, num / torch.clamp(den, min=1e-12), torch.zeros((), device=d.device))


@functools.lru_cache(maxsize=8)
def _resampling_tensors(shape: tuple[int, int], smoothed: tuple[int, int], halvings: int, size: tuple[int, int],
                        device) -> tuple | None:
    """`depth.pyramid_resampling`'s matrices as float64 tensors on `device`, made once per frame size: a
    copy from the host on every frame would be refused inside a CUDA graph's capture (`FrameGraph`
    captures after warm-up calls, which fill this cache)."""
    import torch

    from .depth import pyramid_resampling

    matrices = pyramid_resampling(shape, smoothed, halvings, size)
    if matrices is None:
        return None
    return tuple(torch.as_tensor(m, dtype=torch.float64, device=device) for m in matrices)


def backproject_torch(depth, K: np.ndarray):
    """`geofeat.depth.backproject` on a tensor: (H, W) depth (metres) -> (H, W, 3) float64 points,
    NaN where depth is missing."""
    import torch

    H, W = depth.shape
    dev = depth.device
    z = torch.where(depth > 0, depth.double(), torch.full((), float("nan"), dtype=torch.float64, device=dev))
    u = torch.arange(W, dtype=torch.float64, device=dev)[None, :]
    v = torch.arange(H, dtype=torch.float64, device=dev)[:, None]
    y_over_z = (v - float(K[1, 2])) / float(K[1, 1])
    x = (u - float(K[0, 2]) - float(K[0, 1]) * y_over_z) / float(K[0, 0]) * z
    return torch.stack([x, y_over_z * z, z], dim=-1)


@dataclass
class DeviceMesh:
    """A `GridMesh` with its walk tables, built and kept on a GPU (`build_mesh_cuda`).

    Attributes:
        tensors: torch tensors on the device: points (Hm, Wm, 3) float64 metres (NaN = missing),
            face_ok (Hm-1, Wm-1, 2) bool, normals (Hm-1, Wm-1, 2, 3) float64, local (Hm-1, Wm-1, 2, 3)
            and edges (Hm-1, Wm-1, 2, 3, 2) float64 (`GridMesh.walk_tables`).
        tables: the same five as numba device arrays (views, no copy), the walk kernel's inputs.
        K: (3, 3) intrinsics of the mesh grid. scale: (sx, sy) mesh pixels per image pixel.
        image_shape: (H, W) of the frame. device: the torch device.
        source: `mesh.frame_fingerprint` of that frame (None when unknown), as `GridMesh.source`:
            `polar_patches_cuda` refuses the mesh for another frame, as the CPU path does.
        config: the `DepthConfig` its depth was preprocessed with (None when unknown), as
            `GridMesh.config`.
    """

    tensors: tuple
    tables: tuple
    K: np.ndarray
    scale: tuple[float, float]
    image_shape: tuple[int, int]
    device: object
    source: tuple | None = None
    config: DepthConfig | None = None

    def image_to_mesh(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) image pixel coordinates -> (N, 2) mesh pixel coordinates."""
        return image_to_mesh(xy, self.scale)

    def __repr__(self) -> str:  # the dataclass's printed every tensor and numba view
        Hm, Wm = self.tensors[0].shape[:2]
        return f"DeviceMesh({Wm}x{Hm} grid for a {self.image_shape[1]}x{self.image_shape[0]} frame, on {self.device})"

    def to_host(self) -> GridMesh:
        """The `GridMesh` (walk tables included) on the host."""
        points, face_ok, normals, local, edges = (t.cpu().numpy() for t in self.tensors)
        mesh = GridMesh(points=points, face_ok=face_ok, normals=normals, K=self.K, scale=self.scale,
                        image_shape=self.image_shape, source=self.source, config=self.config)
        mesh.__dict__["walk_tables"] = (local, edges)
        return mesh


def build_mesh_cuda(frame: RGBDFrame, config: DepthConfig | str = "auto", max_edge_stretch: float = MAX_EDGE_STRETCH,
                    device="cuda", fingerprint: tuple | None = None) -> DeviceMesh:
    """`geodesic.mesh.build_mesh` and its walk tables on the GPU. The host fills the depth's small
    holes (`depth.fill_holes`: a connected-component labelling, serial work) and uploads the filled
    (H, W) float32 depth; then on the GPU: the smoothing pyramid (`smooth_depth_torch`), the
    back-projection, and one thread per face for the faces, normals and walk tables (the CPU's
    kernel sources, `walk_cuda.mesh_faces_cuda`). Equal to the host mesh within float rounding
    (tested): the same faces exist on the tested frames.

    `config`: a DepthConfig or a profile name; "auto" measures the frame on the host each call
    (`depth.depth_profile`: 6.2 ms on the Kinect frame, 4.6-6.3 ms on simulated depth, BENCHMARKS.md "Millimetre
    depth: the quantised profile"), so a stream should resolve it once
    (`depth.sequence_depth_profile`) and pass the profile. `fingerprint`: the frame's
    `mesh.frame_fingerprint`, when the caller has just computed it."""
    import torch

    from .depth import filled_depth, resolve_depth_config

    dev = require_cuda(device)
    config = resolve_depth_config(config, frame)
    depth = filled_depth(frame.depth, config)  # on the host
    source = fingerprint if fingerprint is not None else frame_fingerprint(frame)
    return mesh_from_depth(torch.from_numpy(depth).to(dev, non_blocking=False), config, frame.K, max_edge_stretch,
                           source=source)


def mesh_from_depth(depth, config: DepthConfig, K: np.ndarray, max_edge_stretch: float = MAX_EDGE_STRETCH,
                    out: DeviceMesh | None = None, source: tuple | None = None) -> DeviceMesh:
    """The device part of `build_mesh_cuda`: the (H, W) float32 depth tensor (metres, holes already
    filled: `depth.filled_depth`) -> `DeviceMesh`, with nothing read back to the host (a CUDA graph
    can hold it, `gpu_graph.FrameGraph`). `K`: the frame's (3, 3) intrinsics. `out`: a DeviceMesh of
    the same mesh grid size to write into, its tensors and numba views kept (as a graph needs), its
    intrinsics, scale, frame size and `source` this frame's; by default a new one."""
    import torch

    from .depth import scale_intrinsics
    from .geodesic.walk_cuda import mesh_faces_cuda
    from .inputs import check_positive

    max_edge_stretch = check_positive(max_edge_stretch, "max_edge_stretch")  # as `mesh_from_points`

    dev = depth.device
    smoothed = smooth_depth_torch(depth, config.smooth_levels, config.mesh_scale)
    H, W = depth.shape
    Hm, Wm = smoothed.shape
    scale = (Wm / W, Hm / H)
    K_mesh = scale_intrinsics(K, *scale)
    if out is None:
        points = backproject_torch(smoothed, K_mesh).contiguous()
        cells = (Hm - 1, Wm - 1, 2)
        face_ok = torch.zeros(cells, dtype=torch.bool, device=dev)
        normals = torch.zeros(cells + (3,), dtype=torch.float64, device=dev)
        local = torch.zeros(cells + (3,), dtype=torch.float64, device=dev)
        edges = torch.zeros(cells + (3, 2), dtype=torch.float64, device=dev)
        tensors = (points, face_ok, normals, local, edges)
        with _numba_on(dev):
            tables = tuple(_as_numba(t) for t in tensors)
        out = DeviceMesh(tensors, tables, K_mesh, scale, (H, W), dev, source, config)
    else:
        if tuple(out.tensors[0].shape[:2]) != (Hm, Wm):
            raise ValueError(f"out: a {tuple(out.tensors[0].shape[:2])} mesh, not {(Hm, Wm)}")
        out.tensors[0].copy_(backproject_torch(smoothed, K_mesh))
        for t in out.tensors[1:]:
            t.zero_()
        # this frame's
        out.K, out.scale, out.image_shape, out.source, out.config = K_mesh, scale, (H, W), source, config
    with _numba_on(dev):
        tables = out.tables
        mesh_faces_cuda(tables[0], mean_focal(K_mesh), float(max_edge_stretch), out=tables[1:],
                        stream=_numba_stream(dev))
    return out


def device_mesh_tables(mesh, dev) -> tuple:
    """The walk's per-mesh arrays on device `dev` as numba device arrays (points, face_ok, normals,
    local, edges): a `DeviceMesh`'s own, or a host `GridMesh`'s, uploaded on first use and kept with
    the mesh (the tensors that own them too)."""
    import torch

    if isinstance(mesh, DeviceMesh):
        if str(mesh.device) != str(dev):
            raise ValueError(f"mesh: built on {mesh.device}, not on {dev}")
        return mesh.tables
    cache = mesh.__dict__.setdefault(_MESH_ATTR, {})
    hit = cache.get(str(dev))
    if hit is None:
        local, edges = mesh.walk_tables
        tensors = [torch.from_numpy(np.ascontiguousarray(a)).to(dev)
                   for a in (mesh.points, mesh.face_ok, mesh.normals, local, edges)]
        with _numba_on(dev):
            hit = (tensors, tuple(_as_numba(t) for t in tensors))
        cache[str(dev)] = hit
    return hit[1]


def gaussian_blur_torch(image, sigma: float):
    """cv2.GaussianBlur(image, (0, 0), sigma) of an (H, W) float32 tensor: the same kernel
    (OpenCV's size rule for float images, cv2.getGaussianKernel) and border (reflect-101), rows then
    columns; equal to OpenCV's up to float32 summation order (1e-6).

    The two passes are sums of shifted slices in float32, not torch's conv2d: on CUDA, cuDNN's
    convolutions default to TF32 (about 1e-4 off, measured on an H100), and this keeps the result
    independent of such settings."""
    import cv2
    import torch.nn.functional as F

    if sigma <= 0:
        return image
    ksize = int(round(sigma * 4 * 2 + 1)) | 1
    weights = [float(w) for w in cv2.getGaussianKernel(ksize, sigma, cv2.CV_32F)[:, 0]]
    r = ksize // 2
    H, W = image.shape
    if r < W:
        x = F.pad(image[None, None], (r, r, 0, 0), mode="reflect")[0, 0]
    else:  # torch's reflection needs a pad under the side; OpenCV reflects again (a large blur, a small frame)
        x = image[:, _reflect101_index(W, r, image.device)]
    rows = x[:, 0:W] * weights[0]
    for i in range(1, ksize):
        rows = rows + x[:, i:i + W] * weights[i]
    if r < H:
        y = F.pad(rows[None, None], (0, 0, r, r), mode="reflect")[0, 0]
    else:
        y = rows[_reflect101_index(H, r, rows.device)]
    out = y[0:H] * weights[0]
    for i in range(1, ksize):
        out = out + y[i:i + H] * weights[i]
    return out


def _reflect101_index(n: int, r: int, device):
    """(n + 2 r,) int64 indices of a side of `n` pixels padded by `r` on both ends with OpenCV's
    BORDER_REFLECT_101 (`cv2.borderInterpolate`: reflected again and again while off the side, 0 for
    n = 1): periodic with period 2 n - 2 and even. Made on the device (no copy from the host, which a
    CUDA graph's capture would refuse)."""
    import torch

    index = torch.arange(-r, n + r, dtype=torch.int64, device=device)
    if n == 1:
        return torch.zeros_like(index)
    period = 2 * n - 2
    index = index.abs() % period
    return torch.where(index >= n, period - index, index)


@functools.cache
def remap_subpixel_steps() -> int | None:
    """How finely the installed OpenCV's `cv2.remap` (INTER_LINEAR, float32 maps) places a sample
    between pixels: None when it interpolates at the float coordinates themselves (OpenCV 5), else
    the number of positions per pixel it rounds them to (32, OpenCV 4's INTER_TAB_SIZE: the
    coordinates rounded to 1/32 pixel). Measured once per process, on a 2-pixel ramp."""
    import cv2

    ramp = np.array([[0.0, 1.0], [0.0, 1.0]], np.float32)
    x = (np.arange(1024, dtype=np.float32) / 1024)[None, :]
    got = cv2.remap(ramp, x, np.full_like(x, 0.5), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    levels = len(np.unique(got))  # 1024 distinct values, or steps + 1 (0, 1/32, ..., 1)
    return None if levels > 256 else levels - 1


def sample_bilinear_torch(image, coords, steps: int | None | str = "opencv"):
    """`geodesic.polar.sample_bilinear` (cv2.remap, INTER_LINEAR, BORDER_REPLICATE) on torch tensors:
    (H, W) float32 image, (..., 2) float32 pixel coordinates (x, y) -> (...) float32.

    Float32 bilinear interpolation in OpenCV 5's form (two lerps along x, then one along y, on the
    fractional parts of the coordinates), neighbours off the image clamped to the border: equal to
    cv2.remap's values within 1e-6 (OpenCV's SIMD code fuses some multiply-adds). NaN coordinates
    give 0 (the caller masks them).

    `steps`: "opencv" follows the installed OpenCV (`remap_subpixel_steps`): OpenCV 4's remap rounds
    the coordinates to 1/32 pixel (round half to even) and weighs the four neighbours with products
    of those fractions, and so does this then; without it the GPU's patch values differed from the
    CPU's by up to 4.6e-3 on the Kinect frame under OpenCV 4.10 (pyproject allows >= 4.8).
    None: no rounding; a number: that many positions per pixel."""
    import torch

    if steps == "opencv":
        steps = remap_subpixel_steps()
    H, W = image.shape
    ok = torch.isfinite(coords).all(-1)
    c = torch.where(ok[..., None], coords, torch.zeros((), dtype=coords.dtype, device=coords.device)).float()
    flat = image.reshape(-1)
    if steps:  # OpenCV 4: fixed-point positions, a weight table of float products
        q = torch.round(c * float(steps)).to(torch.int64)
        f = torch.div(q, steps, rounding_mode="floor")
        frac = (q - f * steps).float() * (1.0 / steps)
        x0, y0 = f[..., 0], f[..., 1]
        fx, fy = frac[..., 0], frac[..., 1]
    else:
        f = torch.floor(c)
        fx, fy = c[..., 0] - f[..., 0], c[..., 1] - f[..., 1]
        x0, y0 = f[..., 0].to(torch.int64), f[..., 1].to(torch.int64)
    xa, xb = x0.clamp(0, W - 1), (x0 + 1).clamp(0, W - 1)
    ya, yb = y0.clamp(0, H - 1), (y0 + 1).clamp(0, H - 1)
    s00, s01 = flat[ya * W + xa], flat[ya * W + xb]
    s10, s11 = flat[yb * W + xa], flat[yb * W + xb]
    if steps:
        gx, gy = 1.0 - fx, 1.0 - fy
        v = ((s00 * (gy * gx) + s01 * (gy * fx)) + s10 * (fy * gx)) + s11 * (fy * fx)
    else:
        top = s00 + fx * (s01 - s00)
        v = top + fy * ((s10 + fx * (s11 - s10)) - top)
    return torch.where(ok, v, torch.zeros((), dtype=v.dtype, device=v.device))


@dataclass
class DevicePatches:
    """`geodesic.polar.PolarPatches` with its arrays as torch tensors on the GPU (keypoints, radius,
    sampling blur and depth config on the host, as `PolarPatches` records them)."""

    keypoints: np.ndarray
    values: object
    coords: object
    valid: object
    rings_reached: object
    points: object
    radius: float
    blur_px: float | None = None
    depth_config: DepthConfig | None = None

    def __len__(self) -> int:
        return len(self.keypoints)

    def __repr__(self) -> str:  # the dataclass's printed every tensor
        return (f"DevicePatches({len(self)} keypoints on {self.values.device}, {self.values.shape[1]} rings x "
                f"{self.values.shape[2]} angles, radius {self.radius:g} m)")

    def to_host(self):
        """The `PolarPatches` on the host (one copy per array)."""
        from .geodesic.polar import PolarPatches

        return PolarPatches(self.keypoints, self.values.cpu().numpy(), self.coords.cpu().numpy(),
                            self.valid.cpu().numpy(), self.rings_reached.cpu().numpy(), self.points.cpu().numpy(),
                            self.radius, blur_px=self.blur_px, depth_config=self.depth_config)


def polar_patches_cuda(frame: RGBDFrame, keypoints, radius: float = DEFAULT_RADIUS_M, n_angles: int = N_ANGLES,
                       n_rings: int = N_RINGS, depth_config: DepthConfig | str = "auto", mesh: GridMesh | DeviceMesh | None = None,
                       blur_px: float = SAMPLING_BLUR_PX, device="cuda", image=None) -> DevicePatches:
    """`geofeat.polar_patches` on the GPU: same arguments (plus `device`), same results within the
    tolerances of the module docstring, as `DevicePatches` (torch tensors on `device`).

    `image`: the frame's sampling image (`geodesic.polar.sampling_image`, blurred) already on the
    device, to skip the upload and blur when several calls share a frame."""
    import torch

    dev = require_cuda(device)
    kp = check_patch_request(frame, keypoints, radius, n_angles, n_rings)
    check_blur_px(blur_px)  # as the CPU's `sampling_image` (a negative one was no blur, one over 20 px ran)
    if mesh is None:  # built on the GPU (the simulator's "GPU" is the CPU), cached on the frame
        mesh = frame_mesh(frame, depth_config, device=mesh_device(dev))
    else:  # of this frame (a host GridMesh also knows its frame's depth and intrinsics)
        check_mesh_shape(mesh, frame)
    starts = walk_starts(mesh, kp)
    host = torch.from_numpy(np.concatenate([starts.ravel(), np.asarray(frame.K, np.float64).ravel()]))
    upload = host.to(dev, non_blocking=False)
    starts_t, K_t = upload[:starts.size].view(-1, 2), upload[starts.size:].view(3, 3)
    if image is None:
        # a copy: torch warns of the frame's read-only array ("not writable"); it is uploaded next anyway
        image = gaussian_blur_torch(torch.from_numpy(np.array(frame.image, np.float32)).to(dev), float(blur_px))
    walk = WalkBuffers(len(kp), n_rings, n_angles, dev)
    values, valid = walk_and_sample(device_mesh_tables(mesh, dev), starts_t, K_t, image, radius, walk)
    return DevicePatches(kp, values, walk.coords, valid, walk.reached, walk.samples, float(radius),
                         blur_px=float(blur_px), depth_config=getattr(mesh, "config", None))


class WalkBuffers:
    """The walk's output tensors for N keypoints on device `dev`, with their numba views (made once:
    a CUDA graph replays the same memory): samples (N, R, A, 3) float32, coords (N, R, A, 2) float32
    (NaN where the patch is invalid, after `walk_and_sample`), reached (N, A) int32, and the
    per-keypoint scratch of the tangent frames (faces, centre, frames)."""

    def __init__(self, n: int, n_rings: int, n_angles: int, dev) -> None:
        import torch

        self.n_rings, self.n_angles = n_rings, n_angles
        self.samples = torch.empty((n, n_rings, n_angles, 3), dtype=torch.float32, device=dev)
        self.coords = torch.empty((n, n_rings, n_angles, 2), dtype=torch.float32, device=dev)
        self.reached = torch.empty((n, n_angles), dtype=torch.int32, device=dev)
        self.faces = torch.empty((n, 3), dtype=torch.int64, device=dev)
        self.centre = torch.empty((n, 3), dtype=torch.float64, device=dev)
        self.frames = torch.empty((n, 3, 3), dtype=torch.float64, device=dev)
        with _numba_on(dev):
            self.views = tuple(_as_numba(t) for t in (self.samples, self.coords, self.reached, self.faces,
                                                      self.centre, self.frames))


def walk_and_sample(tables: tuple, starts, K, image, radius: float, walk: WalkBuffers, mask=None):
    """The device part of `polar_patches_cuda`, with nothing read back to the host (a CUDA graph can
    hold it): the walk from the (N, 2) float64 mesh-pixel `starts` tensor over the mesh `tables`
    (`device_mesh_tables`) with the frame's (3, 3) float64 intrinsics tensor `K` (either may be its
    numba view already), into `walk`; the
    patches' validity (`patch_validity`), and `image` (the (H, W) float32 sampling image, blurred)
    read at the valid patches' sample points. `mask`: optional (N,) bool tensor; False marks a
    keypoint invalid whatever its walk (padding). Returns (values (N, R, A) float32, valid (N,) bool)
    and leaves the NaN-masked coordinates in `walk.coords`."""
    from .geodesic.walk import MAX_CROSSINGS
    from .geodesic.walk_cuda import walk_polar_cuda

    dev = walk.samples.device
    walk.faces.fill_(-1)  # `walk.tangent_frames`' start values
    walk.centre.fill_(float("nan"))
    walk.frames.zero_()
    with _numba_on(dev):
        points, face_ok, normals, local, edges = tables
        walk_polar_cuda(points, face_ok, normals, local, edges, _as_numba(starts), _as_numba(K), float(radius),
                        int(walk.n_angles), int(walk.n_rings), MAX_CROSSINGS, out=walk.views,
                        stream=_numba_stream(dev))
    valid = (walk.reached >= 1).double().mean(1) >= MIN_DIRECTION_SHARE  # patch_validity, the same float64 mean
    if mask is not None:
        valid = valid & mask
    walk.coords.masked_fill_(~valid[:, None, None, None], float("nan"))
    return sample_bilinear_torch(image, walk.coords), valid


@dataclass
class DeviceFeatures:
    """`Features` whose descriptors and valid flags are torch tensors on the GPU (keypoints,
    angles, sizes and scores on the host)."""

    keypoints: np.ndarray
    descriptors: object
    valid: object
    angles: np.ndarray | None = None
    sizes: np.ndarray | None = None
    scores: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.keypoints)

    def __repr__(self) -> str:  # the dataclass's printed every tensor
        d = self.descriptors
        return f"DeviceFeatures({len(self)} keypoints, descriptors {tuple(d.shape)} {d.dtype} on {d.device})"

    def to_host(self) -> Features:
        return Features(self.keypoints, self.descriptors.cpu().numpy(), self.valid.cpu().numpy(), self.angles,
                        self.sizes, self.scores)


def check_gpu_descriptor(descriptor) -> None:
    """ValueError unless `descriptor` is a GeoPatch with the torch backend on a CUDA device (any
    device under the simulator)."""
    on_gpu = simulated() or is_cuda_device(getattr(descriptor, "device", None))
    if not on_gpu or getattr(descriptor, "backend", None) != "torch":
        raise ValueError("descriptor: the GPU path needs a GeoPatch on a CUDA device "
                         "(GeoPatch(device='cuda', backend='torch'))")


def compute_cuda(descriptor, frame: RGBDFrame, keypoints, mesh: GridMesh | DeviceMesh | None = None,
                 half: bool = False) -> DeviceFeatures:
    """GeoPatch features of `keypoints` on the GPU: `GeoPatch.compute` with the walk, the sampling
    and the CNN on `descriptor.device` (a GeoPatch with the torch backend on CUDA). `half`: the CNN
    under float16 autocast (`GeoPatch.describe_tensor`)."""
    from .frame import check_frame, too_thin_to_describe
    from .geodesic.polar import check_depth_config
    from .keypoints import as_keypoints

    check_gpu_descriptor(descriptor)
    kps = as_keypoints(keypoints, check_frame(frame).shape)  # TypeError naming `frame`, as `GeoPatch.compute`
    too_thin_to_describe(frame, descriptor.name)  # a warning, as `GeoPatch.compute`: the mesh has no face
    if mesh is not None:  # of the descriptor's depth config, as `GeoPatch.compute` checks it
        check_depth_config(getattr(mesh, "config", None), descriptor.depth_config, frame, "mesh")
    patches = polar_patches_cuda(frame, kps, radius=descriptor.radius, depth_config=descriptor.depth_config,
                                 mesh=mesh, blur_px=descriptor.blur_px, device=descriptor.device)
    desc = descriptor.describe_tensor(patches.values, patches.valid, half=half)
    return DeviceFeatures(patches.keypoints, desc, patches.valid, angles=kps.angles, sizes=kps.sizes,
                          scores=kps.scores)


def features_on(features, which: str, dev) -> tuple:
    """(descriptors (N, ...), valid (N,) bool) of `DeviceFeatures` or host `Features` as tensors on
    `dev` (uploaded when on the host), checked as `geofeat.match` checks them; `which` names them in
    the errors."""
    import torch

    def up(x):
        if isinstance(x, torch.Tensor):
            return x.to(dev)
        return torch.from_numpy(np.ascontiguousarray(x)).to(dev)

    if not (hasattr(features, "descriptors") and hasattr(features, "valid")):
        raise TypeError(f"{which}: expected DeviceFeatures or Features, got {type(features).__name__}")
    d, v = up(features.descriptors), up(features.valid).bool()
    if d.ndim < 2 or tuple(v.shape) != tuple(d.shape[:1]):
        raise ValueError(f"{which}: expected (N, ...) descriptors and (N,) valid flags, got shapes "
                         f"{tuple(d.shape)} and {tuple(v.shape)}")
    keypoints = getattr(features, "keypoints", None)  # as `matching._unpack`: a field replaced after construction
    if keypoints is not None and np.shape(keypoints)[:1] != tuple(d.shape[:1]):
        raise ValueError(f"{which}: keypoints, descriptors and valid must have one entry per keypoint, got shapes "
                         f"{np.shape(keypoints)}, {tuple(d.shape)} and {tuple(v.shape)}")
    return d, v


def valid_descriptors_finite(d, v):
    """Whether every valid descriptor of `d` (valid flags `v`) is finite, as a 0-d bool tensor on the
    device (no wait for the GPU)."""
    import torch

    if not d.dtype.is_floating_point:
        return torch.ones((), dtype=torch.bool, device=d.device)
    return (torch.isfinite(d).flatten(1).all(1) | ~v).all()


def valid_squared_norm(d, v):
    """The largest squared L2 norm of a valid float (N, D) descriptor of `d` (valid flags `v`), in
    float64, as a 0-d tensor on the device (0 for integer descriptors or none valid; inf or NaN where a
    value is not finite, which `valid_descriptors_finite` reports)."""
    import torch

    if not d.dtype.is_floating_point or d.ndim != 2 or d.shape[0] == 0:
        return torch.zeros((), dtype=torch.float64, device=d.device)
    rows = torch.where(v.bool()[:, None], d.double(), 0.0)
    return (rows * rows).sum(1).max()


def match_cuda(features0, features1, mutual: bool = False, ratio: float | None = None, device="cuda") -> Matches:
    """`geofeat.match` on the GPU for `DeviceFeatures` (or host `Features`, uploaded): L2 for float
    descriptors (GeoPatch), min-over-rotations Hamming for uint8 (N, R, B) ones (GeoBit), Hamming
    for (N, B). Only the (N0,) matches and distances come back to the host."""
    import torch

    from .matching import _finish_matches, _hamming_search_torch, _l2_search_torch, check_same_method

    check_same_method(features0, features1)  # host Features of two descriptors (ORB's and BRAND's)
    dev = require_cuda(device)
    unpack, finite = functools.partial(features_on, dev=dev), valid_descriptors_finite

    def check_finite():  # one read back for both features
        flags = finite_flags.tolist()
        for which, ok in zip(("features0", "features1"), flags[:2]):
            if not ok:
                raise ValueError(f"descriptors: {which} has NaN or infinite values at valid keypoints; mark them "
                                 "invalid or drop them")
        # `check_l2_range`'s bound: the squared distances overflowed the search's float type to inf (no match)
        largest = float(torch.finfo(torch.float64 if torch.float64 in (d0.dtype, d1.dtype) else torch.float32).max)
        norm, which = max(zip(flags[2:], ("features0", "features1")))
        if not 16.0 * norm < largest:
            raise ValueError(f"descriptors: {which} has a row of squared norm {norm:.3g}: its squared L2 distances "
                             f"(up to 16 times that) overflow the GPU search's float type; scale the descriptors "
                             "down (divide them by their largest norm)")

    d0, v0 = unpack(features0, "features0")
    d1, v1 = unpack(features1, "features1")
    finite_flags = torch.stack([finite(d0, v0).double(), finite(d1, v1).double(),  # on the device: read after
                                valid_squared_norm(d0, v0), valid_squared_norm(d1, v1)])  # the search, whose
    # results come back anyway, so that the check adds no wait of its own
    check_match_options(ratio, mutual)  # as `geofeat.match` checks them
    if d0.shape[1:] != d1.shape[1:]:
        raise ValueError(f"descriptors: trailing shapes differ: features0 {tuple(d0.shape)} vs features1 "
                         f"{tuple(d1.shape)}")
    if d0.dtype.is_floating_point != d1.dtype.is_floating_point or (
            not d0.dtype.is_floating_point and d0.dtype != d1.dtype):  # e.g. GeoPatch against GeoBit
        raise ValueError(f"descriptors: features0 ({d0.dtype}) and features1 ({d1.dtype}) are of different kinds; "
                         "match descriptors of one type")
    if d0.dtype.is_floating_point and d0.ndim != 2:  # as `geofeat.match`; (N, R, D) ran as a batched product
        raise ValueError(f"descriptors: metric 'l2' expects (N, D) arrays, got shape {tuple(d0.shape)}")
    n0 = d0.shape[0]
    if n0 == 0 or d1.shape[0] == 0:
        check_finite()
        return Matches(np.full(n0, -1, np.int64), np.full(n0, np.inf))
    if d0.dtype.is_floating_point:
        res = _l2_search_torch(d0, d1, v0, v1, mutual)
    elif d0.dtype == torch.uint8 and d0.ndim in (2, 3):
        if d0.ndim == 2:
            d0, d1 = d0[:, None, :], d1[:, None, :]
        res = _hamming_search_torch(d0, d1, v0, v1, mutual, dev)
    else:
        raise ValueError(f"descriptors: expected float (N, D) or uint8 (N, B) / (N, R, B), got {d0.dtype} "
                         f"{tuple(d0.shape)}")
    check_finite()
    return _finish_matches(*res, ratio=ratio, mutual=mutual)

"""The geodesic walk on a CUDA GPU: the kernel source of `geofeat.geodesic.walk`, compiled by
`numba.cuda`.

Nothing here is written twice: every device function is the code object of a shared source in
`walk.DEVICE_SOURCES` (the same Python function that `walk` compiles with `numba.njit` for the CPU),
rebuilt with its global names bound to the CUDA versions and compiled with
`numba.cuda.jit(device=True)`. Kernels drive them: one thread per keypoint for the tangent
frames, one thread per (keypoint, direction) ray for the walk, exactly the loop bodies of
`walk.tangent_frames` and `walk.walk_polar`; and one thread per face for a fresh frame's mesh and walk
tables (`mesh_faces_cuda`).

This module imports `numba.cuda` and is imported only on demand (`geofeat.gpu`); without a GPU it
runs under numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1, set before numba.cuda is imported), which
is how the tests compare it with the CPU walk.

Arrays may be numba device arrays or any object with `__cuda_array_interface__` (torch CUDA tensors).
"""

from __future__ import annotations

import math
import types

import numpy as np

if not hasattr(np, "row_stack"):  # pragma: no cover - depends on the installed versions
    # numba-cuda releases before 0.30 register an overload of np.row_stack when they first compile,
    # and fail on NumPy 2.4, which removed it (an alias of np.vstack since NumPy 2.0)
    np.row_stack = np.vstack

from numba import cuda  # noqa: E402

from . import mesh as _mesh  # noqa: F401  (registers the mesh's shared source, `_face_one`)
from . import walk as _walk

#: Threads per block of both kernels.
THREADS = 128


def _compile_device_functions() -> dict:
    """name -> CUDA device function of every shared walk source, resolved against each other."""
    namespace = dict(vars(_walk))  # math, np, _SWAP, MAX_CROSSINGS, ...
    for name, fn in _walk.DEVICE_SOURCES.items():
        clone = types.FunctionType(fn.__code__, namespace, name, fn.__defaults__, fn.__closure__)
        clone.__doc__ = fn.__doc__
        namespace[name] = cuda.jit(device=True)(clone)
    return namespace


_DEVICE = _compile_device_functions()
_tangent_frame_one = _DEVICE["_tangent_frame_one"]
_ray_one = _DEVICE["_ray_one"]
_face_one = _DEVICE["_face_one"]
_face_frame_one = _DEVICE["_face_frame_one"]
_edge_directions_one = _DEVICE["_edge_directions_one"]


@cuda.jit
def _tangent_frames_kernel(points, face_ok, normals, starts, faces, centre, frames):
    k = cuda.grid(1)
    if k < starts.shape[0]:
        _tangent_frame_one(points, face_ok, normals, starts[k, 0], starts[k, 1], faces, centre, frames, k)


@cuda.jit
def _walk_kernel(points, face_ok, normals, local, edges, faces, centre, frames, K, ring_step, n_angles, n_rings,
                 max_crossings, samples, coords, reached):
    job = cuda.grid(1)
    if job >= faces.shape[0] * n_angles:
        return
    k = job // n_angles
    a = job % n_angles
    r = _ray_one(points, face_ok, normals, local, edges, faces, centre, frames, K, ring_step, n_angles, n_rings,
                 max_crossings, samples, coords, k, a)
    if r < 0:  # no surface under the keypoint
        for i in range(n_rings):
            for c in range(3):
                samples[k, i, a, c] = math.nan
            for c in range(2):
                coords[k, i, a, c] = math.nan
        reached[k, a] = 0
    else:
        reached[k, a] = r


@cuda.jit
def _mesh_faces_kernel(points, fx, max_edge_stretch, ok, normals, local, edges):
    """One thread per face: the face and its normal (`mesh._face_one`), then the walk's tables of the
    same face (`walk._face_frame_one`, `walk._edge_directions_one`), which read only what this
    thread has just written. One launch instead of three: on a GPU the launches, not the work, are
    the cost of a fresh frame's mesh."""
    job = cuda.grid(1)
    Wc = points.shape[1] - 1
    if job < (points.shape[0] - 1) * Wc * 2:
        cell, t = job // 2, job % 2
        x, y = cell % Wc, cell // Wc
        _face_one(points, fx, max_edge_stretch, ok, normals, x, y, t)
        _face_frame_one(points, ok, normals, local, x, y, t)
        _edge_directions_one(local, ok, edges, x, y, t)


def mesh_faces_cuda(points, fx: float, max_edge_stretch: float, out, stream=0) -> None:
    """`mesh._faces`, `walk.face_frames` and `walk.edge_directions` on the GPU, one thread per face:
    the mesh's faces and normals and the walk's tables from the (Hm, Wm, 3) float64 grid points
    (NaN = missing), written into `out` = (face_ok (Hm-1, Wm-1, 2) bool, normals (Hm-1, Wm-1, 2, 3),
    local (Hm-1, Wm-1, 2, 3), edges (Hm-1, Wm-1, 2, 3, 2) float64), all zero on entry."""
    ok, normals, local, edges = out
    n = max(0, (points.shape[0] - 1) * (points.shape[1] - 1) * 2)
    if n == 0:
        return
    _mesh_faces_kernel[_blocks(n), THREADS, stream](points, float(fx), float(max_edge_stretch), ok, normals, local,
                                                    edges)


def _blocks(n: int) -> int:
    return max(1, (n + THREADS - 1) // THREADS)


def walk_polar_cuda(points, face_ok, normals, local, edges, starts, K, radius: float, n_angles: int, n_rings: int,
                    max_crossings: int = _walk.MAX_CROSSINGS, out=None, stream=0):
    """`walk.walk_polar` on the GPU, same arguments and results, as device arrays.

    Inputs are device arrays (or `__cuda_array_interface__` objects) of the dtypes `walk_polar`
    takes: points, normals, local, edges, starts, K float64, face_ok bool. `out`: optional
    (samples, coords, reached, faces, centre, frames) device arrays to write into (e.g. torch
    tensors, so that torch owns the results); by default they are allocated here. `stream`: the
    CUDA stream to launch on (0: the default stream).

    Returns (samples (N, R, A, 3) float32, coords (N, R, A, 2) float32, reached (N, A) int32,
    centre (N, 3) float64), as `walk_polar`.
    """
    N = starts.shape[0]
    if out is None:
        samples = cuda.device_array((N, n_rings, n_angles, 3), np.float32, stream=stream)
        coords = cuda.device_array((N, n_rings, n_angles, 2), np.float32, stream=stream)
        reached = cuda.device_array((N, n_angles), np.int32, stream=stream)
        faces = cuda.to_device(np.full((N, 3), -1, np.int64), stream=stream)
        centre = cuda.to_device(np.full((N, 3), np.nan), stream=stream)
        frames = cuda.to_device(np.zeros((N, 3, 3)), stream=stream)
    else:  # faces must hold -1, centre NaN and frames 0 on entry, as in `walk.tangent_frames`
        samples, coords, reached, faces, centre, frames = out
    if N == 0:
        return samples, coords, reached, centre
    _tangent_frames_kernel[_blocks(N), THREADS, stream](points, face_ok, normals, starts, faces, centre, frames)
    _walk_kernel[_blocks(N * n_angles), THREADS, stream](
        points, face_ok, normals, local, edges, faces, centre, frames, K, float(radius) / n_rings, int(n_angles),
        int(n_rings), int(max_crossings), samples, coords, reached)
    return samples, coords, reached, centre

"""`geofeat.extract`: the whole job in one call, keypoints and GeoPatch descriptors of one frame."""

from __future__ import annotations

import threading
from contextlib import contextmanager

from .constants import N_KEYPOINTS
from .features import Features
from .frame import RGBDFrame
from .keypoints import Keypoints, detect, detector_for


def extract(frame: RGBDFrame, n: int = N_KEYPOINTS, detector: str | None = None, descriptor: str = "geopatch",
            radius: float | None = None, depth_config="auto", device: str | None = None) -> Features:
    """Detect up to `n` keypoints on `frame` and describe them.

    Args:
        frame: the RGB-D frame.
        n: keypoints wanted (>= 1).
        detector: "sift", "geokey" or "geokey=WEIGHTS"; None = the descriptor's own
            (`geofeat.keypoints.detector_for`: GeoKey for GeoPatch and GeoBit, SIFT for the others).
        descriptor: a `geofeat.make_descriptor` name (default the shipped GeoPatch).
        radius: geodesic radius, metres (None: the descriptor's default, 0.075); GeoBit and GeoPatch
            only (ValueError for another descriptor, which has none).
        depth_config: depth profile name or `DepthConfig` (default "auto"); another one than "auto"
            is for GeoBit and GeoPatch only, as `radius`.
        device: None or "cpu": the CPU path. "cuda" (or "cuda:N"): GeoPatch only; the walk, patch
            sampling and CNN run on the GPU (`geofeat.gpu`), the descriptors come back once at the
            end. The GPU runs GeoPatch's torch network in fp32: its descriptors equal the CPU path's
            with `GeoPatch(backend="torch")` within the tolerances stated in `geofeat.gpu` (1e-4),
            not those of the CPU's default backend (int8 or bfloat16, `GeoPatch`'s `backend`),
            which differ from both by that backend's rounding (3.7e-3 at most, cosine >= 0.9999,
            openvino-bf16 on the demo frame; the same matching scores). A RuntimeError
            says what is missing when no CUDA GPU can be used. For descriptors that stay on the
            GPU (to match there), see `geofeat.gpu.compute_cuda` and `geofeat.gpu.match_cuda`.

    Returns:
        `Features`: keypoints (N, 2) pixels, descriptors ((N, 128) float32 for GeoPatch), valid (N,).

    A frame on which the detector finds no keypoint (no texture, or no depth under it) is a
    ValueError naming the frame (`detect` itself warns and returns an empty set).

    Descriptors on geodesic patches (GeoPatch, GeoBit; on the CPU and with device="cuda") have the
    frame's mesh built in a background thread while the detector runs (`_mesh_prefetch`); the
    results are the same as detecting first and describing after.
    """
    from .descriptors import GEODESIC_DESCRIPTORS, check_descriptor_name, make_descriptor

    base = check_descriptor_name(descriptor).partition("=")[0]
    given = [name for name, value in (("radius", radius), ("depth_config", depth_config))
             if value is not None and not (name == "depth_config" and isinstance(value, str) and value.lower() == "auto")]
    if given and base not in GEODESIC_DESCRIPTORS:
        # `make_descriptor` passes them to the descriptors that have them (the commands name several at once):
        # extract(frame, descriptor="orb", radius=0.05) described at ORB's own size without a word
        raise ValueError(f"{given[0]}: {base} has no geodesic patch (only {' and '.join(GEODESIC_DESCRIPTORS)} have); "
                         f"leave {' and '.join(given)} out")

    from .gpu import wants_gpu  # a light module: torch and numba.cuda load only on use

    if wants_gpu(device):  # ValueError for a device that is neither None, "cpu" nor CUDA
        from .descriptors import check_descriptor_name
        from .gpu import mesh_device, require_cuda

        base, _, weights = check_descriptor_name(descriptor).partition("=")
        if base != "geopatch":
            raise ValueError(f"device: the GPU path computes GeoPatch descriptors only, not {descriptor!r}")
        require_cuda(device)
        from .descriptors.geopatch import GeoPatch

        # None: GeoPatch's own, as `make_descriptor` takes it on the CPU path (depth_config=None was refused here)
        kwargs = {k: v for k, v in (("radius", radius), ("depth_config", depth_config)) if v is not None}
        net = GeoPatch(weights=weights or None, device=device, backend="torch", **kwargs)
        # the mesh is built on the GPU (its hole filling on the host) while the host detects
        with _mesh_prefetch(frame, net.depth_config, device=mesh_device(device)):
            keypoints = _detect(frame, n, detector_for(descriptor, detector))
        return net.compute_cuda(frame, keypoints).to_host()
    describer = make_descriptor(descriptor, radius=radius, depth_config=depth_config)
    with _mesh_prefetch(frame, getattr(describer, "depth_config", None)):
        keypoints = _detect(frame, n, detector_for(descriptor, detector))
    return describer.compute(frame, keypoints)


def _detect(frame: RGBDFrame, n: int, detector: str) -> Keypoints:
    """`detect(frame, n, detector=detector)`; a ValueError naming the frame when it gives no keypoint
    (a frame without texture or depth: the detector warns, and there is nothing to describe)."""
    keypoints = detect(frame, n, detector=detector)
    if len(keypoints) == 0:
        raise ValueError(f"frame: no keypoints detected by {detector} (no texture, or no depth under it); "
                         "nothing to describe")
    return keypoints


@contextmanager
def _mesh_prefetch(frame: RGBDFrame, depth_config, device=None):
    """Build the frame's mesh and walk tables (`geofeat.geodesic.mesh.frame_mesh`, cached on the
    frame) in a background thread while the body runs (detection, which does not need them), and
    wait for it on exit; the descriptor's `polar_patches` then finds them cached. The depth
    preprocessing is mostly serial numpy and OpenCV work, and the detector leaves a core free
    often enough, so this hides part of it. The same mesh is built either way: results are
    unchanged. depth_config None (a descriptor without geodesic patches): nothing is prefetched.
    The thread has ended when the call returns or raises (KeyboardInterrupt included).
    `device` "cuda[:N]": the GPU path's mesh (`frame_mesh(..., device=device)`) is built instead."""
    if depth_config is None:
        yield
        return
    from .geodesic.mesh import frame_mesh

    built = threading.Event()

    def build() -> None:
        try:
            mesh = frame_mesh(frame, depth_config, device=device)
            if device is None:
                mesh.walk_tables
        except Exception:  # noqa: BLE001 - the describer's own frame_mesh call raises it again, in the caller's thread
            pass
        finally:
            built.set()

    worker = threading.Thread(target=build, name="geofeat-mesh", daemon=True)
    worker.start()
    try:
        yield
    finally:
        try:
            worker.join()
        except KeyboardInterrupt:
            # Ctrl-C while waiting for the mesh: the build cannot be stopped, so wait for it before
            # the interrupt goes on, and no work of this call outlives it (a second Ctrl-C leaves at
            # once). On `built`: Python before 3.13 marks a thread whose join was interrupted as
            # ended, while it runs on, and a second join returns at once
            built.wait()
            worker.join()
            raise

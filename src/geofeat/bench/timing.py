"""Timing of f(.), extraction and matching per descriptor on one frame (`geofeat bench --timing`)."""

from __future__ import annotations

import time

from ..depth import check_profile, depth_profile as measured_profile, resolve_depth_config
from ..descriptors import make_descriptor
from ..geodesic.mesh import build_mesh
from ..geodesic.polar import polar_patches
from ..keypoints import detect
from ..matching import match


def timing_table(frame, descriptors: tuple[str, ...], radius: float, counts=(250, 2048), repeat: int = 3,
                 depth_profile: str = "auto", device: str | None = None) -> str:
    """Markdown timing table on one frame: the depth mesh (once per frame, whatever the count), map
    f(.) (polar patches on that mesh), extraction and matching per descriptor for each keypoint count
    (best of `repeat`; counts above the number of keypoints the frame has are lowered to it, and the
    header says the count used). A geodesic descriptor's extraction is timed on the patches given,
    so a frame costs it the mesh, f(.) and its extraction, as the rows say. A line under the table
    names the detector and the depth profile the mesh was built with ("auto" resolved on `frame`).
    `device` "cuda" / "cuda:N": GeoPatch (torch weights, `geofeat.gpu.gpu_computes`) on the GPU path,
    its extraction timed whole there (its own mesh, f(.) and CNN, the features copied back) and its
    matching with `match(..., device=)`; the other descriptors on the CPU, as without it."""
    from ..gpu import build_mesh_cuda, gpu_computes, wants_gpu

    gpu = str(device) if wants_gpu(device) else None
    profile = None  # the profile's name, measured once when "auto" (a DepthConfig has none)
    if isinstance(depth_profile, str):
        profile = check_profile(depth_profile)
        profile = measured_profile(frame) if profile == "auto" else profile
    config = resolve_depth_config(profile or depth_profile, frame)

    def best(fn):
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            result = fn()
            times.append(time.perf_counter() - t)
        return min(times), result

    kps_all = detect(frame, max(counts), detector="sift")
    counts = sorted({min(n, len(kps_all)) for n in counts})  # a frame may have fewer keypoints
    lines = ["| step | " + " | ".join(f"{n} kps (s)" for n in counts) + " |", "|---|" + "---|" * len(counts)]
    cells: dict[str, list[str]] = {}
    t_mesh, mesh = best(lambda: build_mesh(frame, config))
    cells["depth mesh (once per frame)"] = [f"{t_mesh:.3f}"] * len(counts)
    for n in counts:
        kps = kps_all[:n]
        t_map, patches = best(lambda: polar_patches(frame, kps, radius=radius, mesh=mesh))
        cells.setdefault("map f(.) (polar patches, mesh above reused)", []).append(f"{t_map:.3f}")
        for name in descriptors:
            on_gpu = gpu is not None and gpu_computes(name)
            d = make_descriptor(name, radius=radius, depth_config=config,
                                **({"device": gpu, "backend": "torch"} if on_gpu else {}))
            if on_gpu:  # as `Describer` describes it: a mesh of its own, built on the GPU
                t_ext, f = best(lambda: d.compute_cuda(frame, kps, mesh=build_mesh_cuda(frame, config, device=gpu)).to_host())
            elif d.geodesic:
                t_ext, f = best(lambda: d.compute(frame, kps, patches=patches))
            elif getattr(d, "slow", False):  # e.g. DaLI: one run, not the best of `repeat`
                t = time.perf_counter()
                f = d.compute(frame, kps)
                t_ext = time.perf_counter() - t
            else:
                t_ext, f = best(lambda: d.compute(frame, kps))
            t_match, _ = best(lambda: match(f, f, device=gpu if on_gpu else None))
            step = f"{name} extraction" + (f" on {gpu} (its mesh, f(.) and CNN there)" if on_gpu else
                                           " (patches given: mesh and f(.) above)" if d.geodesic else "")
            cells.setdefault(step, []).append(f"{t_ext:.3f}")
            cells.setdefault(f"{name} matching (N x N)" + (f" on {gpu}" if on_gpu else ""), []).append(f"{t_match:.3f}")
    for step, values in cells.items():
        if len(values) < len(counts):
            values = values + ["-"] * (len(counts) - len(values))
        lines.append(f"| {step} | " + " | ".join(values) + " |")
    lines += ["", "Keypoints: OpenCV SIFT; depth profile: " + (profile or "a DepthConfig given") + "."]
    return "\n".join(lines) + "\n"

"""A retrieval set that tells descriptors apart (`geofeat retrieval`, the paper's setting).

--objects objects, each simulated in --sequences sequences that differ in everything but the
object's texture: preset (mild / paper / hard, cycled), scenario (deform / rotate / scale,
cycled with an offset per object), seed (cloth, wind, pins, lighting and camera path) and field of
view; plus --distractors objects seen in one sequence each (their frames sit in the database, their
own queries are skipped: no other sequence of their class). Textures: one per object, from
--texture-dir (photographs, in name order) or, by default, a procedural fabric pattern
(`geofeat.sim.fabric_texture`) drawn from the object's seed, written to <out>/textures/.

Writes <out>/<object>-s<k>/ sequences, <out>/distractor-<i>/ and <out>/classes.csv, then:

    geofeat retrieval <out> --classes <out>/classes.csv --descriptors geopatch,geobit,sift --out RESULTS

Run (60 x 3 + 20 sequences of 6 frames at 640 x 480: 2 minutes to simulate on 2 cores, and
`geofeat retrieval` on GeoPatch and SIFT about 7 minutes more):
    .venv/bin/python benchmarks/make_retrieval_set.py --out out/retrieval_set [--objects 60 --sequences 3
        --distractors 20 --frames 6 --jobs 2]

60 objects by default: with 20 (60 queries, 30 of them for the test half) the 95 % interval of a
difference between two descriptors was +-0.15 wide and the two halves of the queries disagreed on
its sign (BENCHMARKS.md, "Retrieval").
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

PRESETS = ("mild", "paper", "hard")
SCENARIOS = ("deform", "rotate", "scale")
#: Vertical fields of view cycled over an object's sequences, degrees (None: the Kinect-like default).
FOVS = (None, 60.0, 75.0)


def plan(objects: int, sequences: int, distractors: int, seed: int) -> list[dict]:
    """One dict of `simulate_sequence` settings per sequence: name, cls, texture index, preset,
    scenario, seed, fov. Object i's sequence k: preset k, scenario (i + k) mod 3, fov k (cycled)."""
    jobs = []
    for i in range(objects):
        for k in range(sequences):
            jobs.append(dict(name=f"object-{i:02d}-s{k}", cls=f"object-{i:02d}", texture=i,
                             preset=PRESETS[k % len(PRESETS)], scenario=SCENARIOS[(i + k) % len(SCENARIOS)],
                             seed=seed + 100 * i + k, fov=FOVS[k % len(FOVS)]))
    for j in range(distractors):
        jobs.append(dict(name=f"distractor-{j:02d}", cls=f"distractor-{j:02d}", texture=objects + j,
                         preset=PRESETS[j % len(PRESETS)], scenario=SCENARIOS[j % len(SCENARIOS)],
                         seed=seed + 100 * (objects + j), fov=None))
    return jobs


def textures(out: Path, count: int, seed: int, texture_dir: Path | None) -> list[Path]:
    """`count` texture files, one per object and distractor: from `texture_dir` (in name order,
    needs that many), else procedural fabric patterns written to <out>/textures/."""
    from geofeat.sim import fabric_texture
    from geofeat.sim.textures import list_textures

    if texture_dir is not None:
        files = list_textures(texture_dir)
        if len(files) < count:
            raise SystemExit(f"--texture-dir: need {count} textures (objects + distractors), found {len(files)}")
        return files[:count]
    folder = out / "textures"
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for i in range(count):
        path = folder / f"texture-{i:02d}.png"
        cv2.imwrite(str(path), fabric_texture(np.random.default_rng(seed + 7919 * (i + 1))))
        files.append(path)
    return files


def _simulate(job: dict) -> str:
    from geofeat.sim import simulate_sequence

    simulate_sequence(job["out"], scenario=job["scenario"], preset=job["preset"], n_frames=job["frames"],
                      seed=job["seed"], texture=job["texture_path"], width=job["width"], height=job["height"],
                      fov=job["fov"], progress=False, overwrite=True)
    return job["name"]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("out/retrieval_set"))
    p.add_argument("--objects", type=int, default=60)
    p.add_argument("--sequences", type=int, default=3, help="sequences per object (>= 2)")
    p.add_argument("--distractors", type=int, default=20)
    p.add_argument("--frames", type=int, default=6, help="frames per sequence, reference included")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--seed", type=int, default=5000)
    p.add_argument("--texture-dir", type=Path, default=None, help="photographs, one per object (default: procedural fabrics)")
    p.add_argument("--jobs", type=int, default=1, help="sequences simulated in parallel")
    args = p.parse_args()
    if args.sequences < 2 or args.objects < 1:
        raise SystemExit("--sequences: at least 2 per object (a query needs another sequence of its object); --objects >= 1")
    jobs = plan(args.objects, args.sequences, args.distractors, args.seed)
    tex = textures(args.out, args.objects + args.distractors, args.seed, args.texture_dir)
    for job in jobs:
        job.update(out=args.out / job["name"], texture_path=str(tex[job["texture"]]), frames=args.frames,
                   width=args.width, height=args.height)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "classes.csv").write_text("sequence,class\n" + "".join(f"{j['name']},{j['cls']}\n" for j in jobs))
    with ProcessPoolExecutor(max(args.jobs, 1)) as pool:
        for k, name in enumerate(pool.map(_simulate, jobs), start=1):
            print(f"[{k}/{len(jobs)}] {name}", flush=True)
    print(f"wrote {len(jobs)} sequences and {args.out / 'classes.csv'}; run:\n  geofeat retrieval {args.out} "
          f"--classes {args.out / 'classes.csv'} --descriptors geopatch,geobit,sift --out RESULTS")


if __name__ == "__main__":
    main()

"""Simulated datasets for training and evaluating GeoPatch (and for `geofeat bench`).

train/: sequences textured with the packaged training photographs (geofeat/data/textures, each in
turn) and procedural / fabric textures (every fourth sequence), presets cycling through
--train-presets (default paper, hard, mild);
val/ and test/: sequences of --val-presets / --test-preset (default hard) textured with held-out
photographs that training never sees (from --heldout-dir, default shared/data/textures minus the
packaged ones; val cycles through the first N_VAL_TEXTURES of them, whatever --val is, and test
through the rest, so that no validation texture ever textures a test sequence of
`sim_difficulty.py`, which skips the same N_VAL_TEXTURES). Half of the sequences have
Kinect-like depth noise and holes. Scenarios cycle deform/rotate/scale.
(`benchmarks/sim_difficulty.py` writes the per-preset test sequences with the test textures.)
A sequence folder already there is reused when its groundtruth.json records this run's settings and
the simulator's current revision; any other stops the run (an earlier simulator's sequence is not
this run's).

Run: .venv/bin/python benchmarks/make_sim_datasets.py --out out/sim [--train 30 --val 4 --test 6 --frames 8 --seed 1000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from tqdm import tqdm

from geofeat.sim import simulate_sequence
from geofeat.sim.writer import recorded_difference
from sim_difficulty import N_VAL_TEXTURES, TEST_SEEDS
from geofeat.sim.textures import list_textures, packaged_texture_dir

SCENARIOS = ("deform", "rotate", "scale")
#: Each split's seeds start at --seed plus its offset; a split holds at most SPLIT_BLOCK sequences,
#: so that the three splits of one run never share a seed.
SPLIT_OFFSET = {"train": 0, "val": 1000, "test": 2000}
SPLIT_BLOCK = 1000


def split_seeds(split: str, count: int, seed0: int) -> range:
    """Seeds of the `count` sequences of `split` (train, val or test) for --seed `seed0`:
    seed0 + SPLIT_OFFSET[split] + i. ValueError when count exceeds SPLIT_BLOCK (the split would run
    into the next one's seeds) or when a train or val seed is one of sim_difficulty.py's reserved
    TEST_SEEDS (that sequence would replay a test scene: same cloth, wind, lights and camera path)."""
    if count > SPLIT_BLOCK:
        raise ValueError(f"--{split} {count}: at most {SPLIT_BLOCK} sequences per split (the next split's seeds "
                         f"start {SPLIT_BLOCK} later)")
    seeds = range(seed0 + SPLIT_OFFSET[split], seed0 + SPLIT_OFFSET[split] + count)
    if split != "test" and count and seeds.start < TEST_SEEDS.stop and TEST_SEEDS.start < seeds.stop:
        raise ValueError(f"--seed {seed0}: the {split} seeds {seeds.start}-{seeds.stop - 1} meet the seeds reserved "
                         f"for test scenes, {TEST_SEEDS.start}-{TEST_SEEDS.stop - 1} (sim_difficulty.py); pick a "
                         "--seed whose train and val blocks avoid them")
    return seeds


def heldout_textures(folder: Path) -> list[Path]:
    """Photographs of `folder` that are not packaged (never trained on), in name order."""
    packaged = {p.stem for p in list_textures(packaged_texture_dir())}
    return [p for p in list_textures(folder) if p.stem not in packaged]


def make(split: str, count: int, out: Path, frames: int, seed0: int, textures: list[Path] | None,
         presets: tuple[str, ...] = ("mild",)) -> None:
    """Simulate the `count` sequences of `split` under out/split/, seeds `split_seeds(split, count, seed0)`
    (the first seed also shuffles the packaged photographs of a training split)."""
    seeds = split_seeds(split, count, seed0)
    packaged = list_textures(packaged_texture_dir())
    photos = [packaged[k] for k in np.random.default_rng(seeds.start).permutation(len(packaged))]
    for i in tqdm(range(count), desc=split, unit="seq"):
        preset = presets[(i // 3) % len(presets)]
        folder = out / split / f"{split}{i:03d}-{preset}-{SCENARIOS[i % 3]}"
        if textures:
            texture = str(textures[i % len(textures)])
        elif i % 4 == 3:
            texture = "procedural" if i % 8 == 3 else "fabric"
        else:  # every packaged photograph in turn, in an order shuffled by the first seed
            texture = str(photos[(i - i // 4) % len(photos)])
        settings = dict(scenario=SCENARIOS[i % 3], n_frames=frames, seed=seeds[i], preset=preset,
                        kinect_noise=bool(i % 2), texture=texture, width=640, height=480)
        if folder.is_dir() and any(folder.iterdir()):  # reused only when it is this run's sequence
            stale = recorded_difference(folder, **settings)
            if stale:
                raise SystemExit(f"{stale}: not this run's sequence; remove it or choose another --out")
            continue
        simulate_sequence(folder, progress=False, **settings)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/sim"))
    parser.add_argument("--train", type=int, default=30)
    parser.add_argument("--val", type=int, default=4)
    parser.add_argument("--test", type=int, default=6)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1000,
                        help="first training seed (val starts at seed + 1000, test at seed + 2000); "
                             "a new seed gives new scenes; train and val seeds may not meet the test seeds "
                             "5000-5999 that sim_difficulty.py reserves")
    shared = next((p / "shared/data/textures" for p in Path(__file__).resolve().parents
                   if (p / "shared/data/textures").is_dir()), Path("shared/data/textures"))
    parser.add_argument("--heldout-dir", type=Path, default=shared)
    parser.add_argument("--train-presets", default="paper,hard,mild", help="comma-separated, cycled every 3 sequences")
    parser.add_argument("--val-presets", default="hard", help="comma-separated, cycled every 3 sequences")
    parser.add_argument("--test-preset", default="hard")
    args = parser.parse_args()
    held = heldout_textures(args.heldout_dir)
    if len(held) <= N_VAL_TEXTURES:
        raise SystemExit(f"need more than {N_VAL_TEXTURES} held-out textures in {args.heldout_dir}, found {len(held)}")
    try:  # every split's seeds checked before the first simulation
        for split in SPLIT_OFFSET:
            split_seeds(split, getattr(args, split), args.seed)
    except ValueError as error:
        raise SystemExit(str(error)) from None
    make("train", args.train, args.out, args.frames, args.seed, None, tuple(args.train_presets.split(",")))
    make("val", args.val, args.out, args.frames, args.seed, held[:N_VAL_TEXTURES], tuple(args.val_presets.split(",")))
    make("test", args.test, args.out, args.frames, args.seed, held[N_VAL_TEXTURES:], (args.test_preset,))
    print(f"datasets in {args.out}: train {args.train}, val {args.val}, test {args.test} sequences of {args.frames} frames")


if __name__ == "__main__":
    main()

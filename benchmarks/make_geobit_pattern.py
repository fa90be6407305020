"""Generate the shipped GeoBit test pattern: src/geofeat/data/geobit_pattern.npz.

Run once: python benchmarks/make_geobit_pattern.py [--check]
The file is committed so every machine uses the same pattern, whatever its numpy version; --check
only verifies that the shipped file equals a fresh draw from PATTERN_SEED (numpy's Generator
streams are stable across versions in practice, but only the shipped file is the reference).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from geofeat.constants import N_ANGLES, N_RINGS
from geofeat.descriptors.geobit import (
    DEFAULT_N_BITS,
    DEFAULT_SIGMA_ROWS,
    PATTERN_FILE,
    PATTERN_SEED,
    generate_pattern,
)

TARGET = Path(__file__).resolve().parents[1] / "src" / "geofeat" / "data" / PATTERN_FILE


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare with the shipped file, write nothing")
    args = parser.parse_args()
    tests = generate_pattern(DEFAULT_N_BITS, DEFAULT_SIGMA_ROWS, PATTERN_SEED, N_RINGS, N_ANGLES)
    if args.check:
        with np.load(TARGET) as data:
            same = np.array_equal(data["tests"], tests)
        print(f"{TARGET}: {'identical to' if same else 'DIFFERS from'} a fresh draw")
        raise SystemExit(0 if same else 1)
    np.savez(
        TARGET,
        tests=tests,
        sigma=np.float64(DEFAULT_SIGMA_ROWS),
        seed=np.int64(PATTERN_SEED),
        n_rings=np.int64(N_RINGS),
        n_angles=np.int64(N_ANGLES),
    )
    print(f"wrote {TARGET}: {len(tests)} tests, sigma {DEFAULT_SIGMA_ROWS} rings, seed {PATTERN_SEED}")


if __name__ == "__main__":
    main()

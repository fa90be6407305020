"""Merge the results.csv of several `geofeat bench` runs on the same sequences (e.g. the slow DaLI
run and a later run of retrained nets) into one table, MMA / MS orderings and the rotation / scale
curves.

Run: PYTHONPATH=src python benchmarks/merge_bench.py out/bench11/a/results.csv out/bench11/b/results.csv --out out/bench11
"""

from __future__ import annotations

import argparse
from pathlib import Path

from geofeat.bench.report import markdown_table, plot_curves, read_results, summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    rows = [r for path in args.results for r in read_results(path)]
    args.out.mkdir(parents=True, exist_ok=True)
    table = markdown_table(rows)
    (args.out / "table.md").write_text(table)
    print(table)
    s = summary(rows)
    print("MMA:", ", ".join(f"{n} {s[n]['mma']:.3f}" for n in sorted(s, key=lambda n: -s[n]["mma"])))
    print("MS order:", " > ".join(f"{n} {s[n]['ms']:.3f}" for n in sorted(s, key=lambda n: -s[n]["ms"])))
    for path in plot_curves(rows, args.out):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()

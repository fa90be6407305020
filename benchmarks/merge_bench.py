"""Merge the results.csv of several `geofeat bench` runs on the same sequences (e.g. the slow DaLI
run and a later run of retrained nets) into one table, MMA / MS orderings and the rotation / scale
curves.

The tables give a descriptor one column per detector (`geofeat.bench.report.result_labels`), and the
landmarks protocol's rows their own ("landmarks" as detector); results.csv has no keypoint-count
column, so runs of the protocol detect made at different `--keypoints` (or, on one detector, with
different `--keypoint-set`), which would be averaged into one column, are refused by name, as read
from the config.json that each run wrote beside its results.csv.

Run: PYTHONPATH=src python benchmarks/merge_bench.py out/bench11/a/results.csv out/bench11/b/results.csv --out out/bench11
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from geofeat.bench.report import markdown_table, plot_curves, read_results, summary


def run_settings(results: Path) -> dict:
    """The settings of the bench run that wrote `results` (a results.csv): the config.json beside it.
    ValueError naming the file when there is none or it is not a bench run's."""
    path = Path(results).parent / "config.json"
    try:
        settings = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise ValueError(f"results: cannot read {path}, the settings of the run that wrote {results} "
                         f"({type(error).__name__}), so its keypoint count is unknown; merge results.csv files "
                         "in the output folders `geofeat bench` wrote them to") from None
    if not isinstance(settings, dict) or "n_keypoints" not in settings:
        raise ValueError(f"results: {path} holds no n_keypoints: not the config.json of a `geofeat bench` run")
    return settings


def check_mergeable(results: list[Path]) -> None:
    """ValueError, naming the runs and their values, when runs of the protocol detect differ in their
    keypoint count (`--keypoints`), or runs on one detector in their keypoint set (`--keypoint-set`):
    their rows would be averaged into one column; or when runs ran on different devices (`--device`:
    their timings would be mixed). Runs of the landmarks protocol describe the
    annotated landmarks, whatever these were."""
    settings = {str(r): run_settings(r) for r in results}
    detect = {r: s for r, s in settings.items() if s.get("protocol", "detect") == "detect"}
    counts = {r: s["n_keypoints"] for r, s in detect.items()}
    if len(set(map(str, counts.values()))) > 1:
        raise ValueError("results: runs made at different --keypoints would be averaged into one column: "
                         + ", ".join(f"{r} {n} keypoints" for r, n in counts.items())
                         + "; merge the runs of one keypoint count")
    devices = {r: s.get("device") or "cpu" for r, s in settings.items()}  # None or unrecorded: a CPU run
    if len(set(devices.values())) > 1:  # one table would average CPU and GPU extraction and matching times
        raise ValueError("results: runs on different devices would mix their timings in one table: "
                         + ", ".join(f"{r} {d}" for r, d in devices.items()) + "; merge the runs of one device")
    for detector in dict.fromkeys(s.get("detector") for s in detect.values()):
        sets = {r: s["keypoint_set"] for r, s in detect.items()
                if s.get("detector") == detector and s.get("keypoint_set") is not None}  # recorded: not by older runs
        if len(set(map(str, sets.values()))) > 1:
            raise ValueError(f"results: runs on detector {detector} with different --keypoint-set would be averaged "
                             "into one column: " + ", ".join(f"{r} {k}" for r, k in sets.items())
                             + "; merge the runs of one keypoint set")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:
        check_mergeable(args.results)
    except ValueError as error:
        parser.error(str(error))
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

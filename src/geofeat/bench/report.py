"""Tables and plots from `results.csv` of `geofeat bench`. It reads results only; it never extracts
(timing lives in bench/timing.py)."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..descriptors.baselines import USES_GIVEN_ANGLE
from ..outputs import atomic_file, plural


def read_results(path: str | Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for key in ("ms", "mma", "repeatability", "seconds_extract", "seconds_match", "angle_deg", "scale"):
            if key in r:
                r[key] = float(r[key])
        for key in ("hits", "n_gt", "n_ref", "n_tgt"):
            if key in r:
                r[key] = int(r[key])
    return rows


def detail_table(rows: list[dict]) -> str:
    """Per descriptor and sequence, and in total (mean over sequences of per-sequence means): MS, MMA,
    repeatability (the MS of a perfect descriptor on the same keypoints), reference keypoints per
    frame, target keypoints kept per pair (those whose surface point is visible in the reference:
    the protocol drops the others, so with n_ref they set the denominator min(n_ref, n_tgt) of MS and
    repeatability, and a detector whose points fall off the surface is not charged for them) and
    correct matches (hits) per pair. A descriptor with rows from several detectors (runs merged by
    benchmarks/merge_bench.py) gets one block per detector (`result_labels`). Markdown."""
    lines = ["| descriptor | detector | sequence | MS | MMA | repeatability | reference keypoints / frame "
             "| target keypoints kept / pair | correct matches / pair |",
             "|---|---|---|---|---|---|---|---|---|"]
    keys = ("ms", "mma", "repeatability", "n_ref", "n_tgt", "hits")
    label_of = result_labels(rows)
    for label in dict.fromkeys(label_of(r) for r in rows):
        mine = [r for r in rows if label_of(r) == label]
        name = mine[0]["descriptor"]
        detector = ", ".join(dict.fromkeys(_detector(r) for r in mine))
        per_seq = {}
        for r in mine:
            per_seq.setdefault(r["sequence"], []).append([float(r.get(k, "nan")) for k in keys])
        means = {seq: np.mean(v, axis=0) for seq, v in per_seq.items()}
        for seq, m in list(means.items()) + [("**all**", np.mean(list(means.values()), axis=0))]:
            lines.append(f"| {name} | {detector} | {seq} | {m[0]:.3f} | {m[1]:.3f} | {m[2]:.3f} | {m[3]:.0f} | {m[4]:.0f} | {m[5]:.0f} |")
    return "\n".join(lines) + "\n"


def _detector(row: dict) -> str:
    return row.get("detector") or "sift"


def result_labels(rows: list[dict]) -> Callable[[dict], str]:
    """The name a row's result goes by in the tables: its descriptor, or "detector + descriptor" when
    `rows` hold that descriptor from several detectors (runs merged by benchmarks/merge_bench.py, e.g.
    `--detector geokey` and `--detector sift`), so that two detectors' pairs are never averaged together."""
    detectors: dict[str, set[str]] = {}
    for r in rows:
        detectors.setdefault(r["descriptor"], set()).add(_detector(r))
    return lambda r: f"{_detector(r)} + {r['descriptor']}" if len(detectors[r["descriptor"]]) > 1 else r["descriptor"]


def summary(rows: list[dict], label_of: Callable[[dict], str] | None = None) -> dict[str, dict[str, float]]:
    """Per descriptor (`result_labels`: per detector and descriptor where a descriptor comes from several
    detectors; `label_of` to give the labels): mean over sequences of the per-sequence mean MS and MMA
    (the paper's rule)."""
    label_of = result_labels(rows) if label_of is None else label_of
    out: dict[str, dict[str, float]] = {}
    for name in dict.fromkeys(label_of(r) for r in rows):
        per_seq = {}
        for r in rows:
            if label_of(r) == name:
                per_seq.setdefault(r["sequence"], []).append((r["ms"], r["mma"]))
        means = np.array([np.mean(v, axis=0) for v in per_seq.values()])
        out[name] = {"ms": float(means[:, 0].mean()), "mma": float(means[:, 1].mean()), "sequences": len(per_seq)}
    return out


#: Scenario words that name a group of sequences wherever they stand in the name ("deform-0", "a-rotate").
SCENARIO_WORDS = ("deform", "rotate", "scale")


def _words(name: str) -> list[str]:
    return name.replace("_", "-").split("-")


def sequence_group(name: str) -> str:
    """The group of a sequence in `markdown_table`: a scenario word of its name (`SCENARIO_WORDS`),
    else the part after its last "-", else "all"."""
    parts = _words(name)
    for word in SCENARIO_WORDS:
        if word in parts:
            return word
    return parts[-1] if len(parts) > 1 else "all"


def scenario_groups(folders) -> Callable[[str], str]:
    """A `group_of` for `markdown_table` and `plot_curves`: the scenario a sequence folder was
    simulated with (its groundtruth.json), else `sequence_group` of its name. Keyed by folder name,
    as the results' "sequence" column."""
    from ..groundtruth.simulator import GT_JSON, read_metadata

    scenarios = {}
    for folder in folders:
        if (Path(folder) / GT_JSON).is_file():
            try:
                scenario = read_metadata(folder).get("scenario")
            except (OSError, ValueError):  # unreadable: the name decides
                continue
            if scenario in SCENARIO_WORDS:
                scenarios[Path(folder).name] = scenario
    return lambda name: scenarios.get(name) or sequence_group(name)


def markdown_table(rows: list[dict], group_of=sequence_group) -> str:
    """Table 1 style: matching score per descriptor (columns; per detector and descriptor where a
    descriptor comes from several detectors, `result_labels`) for each group of sequences (rows, e.g.
    the scenario suffix of simulated sequence names) and overall; best of each row in bold (every cell
    that shows the best value as printed, so that equal numbers are marked alike). A cell
    whose descriptor has results on fewer of the row's sequences than the row counts says so
    ("(1 of 2)"): its mean is over those only, so it is never bold (a mean over the easier sequences
    alone is no better descriptor); the best is of the cells over all the row's sequences. The notes
    under the table name the detectors, keypoint sets and depth profiles, and the device of each
    descriptor where any ran on a GPU (`geofeat bench --device`)."""
    groups = {}
    for r in rows:
        groups.setdefault(group_of(r["sequence"]), []).append(r)
    groups["all"] = rows
    label_of = result_labels(rows)  # one descriptor from two merged runs' detectors: two columns
    names = list(dict.fromkeys(label_of(r) for r in rows))
    lines = ["| sequences | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for group, grows in groups.items():
        s = summary(grows, label_of)
        n_seq = len({r["sequence"] for r in grows})
        complete = [float(f"{s[n]['ms']:.3f}") for n in names if n in s and s[n]["sequences"] == n_seq]
        best = max(complete, default=None)  # as printed: 0.4144 and 0.4141 tie
        cells = []
        for n in names:
            if n not in s:
                cells.append("-")
                continue
            text = f"{s[n]['ms']:.3f}"
            text = f"**{text}**" if float(text) == best and s[n]["sequences"] == n_seq else text
            cells.append(text + (f" ({s[n]['sequences']} of {n_seq})" if s[n]["sequences"] < n_seq else ""))
        lines.append(f"| {group} ({n_seq}) | " + " | ".join(cells) + " |")
    # protocol landmarks describes the annotated positions: no keypoint set applies (its rows still record one)
    kp_sets = sorted({r.get("keypoint_set", "") for r in rows if r.get("protocol") != "landmarks"} - {""})
    detectors = sorted({r.get("detector", "") for r in rows} - {""})
    profiles: dict[str, set] = {}
    for r in rows:
        profiles.setdefault(r.get("depth_profile", "") or "?", set()).add(r["sequence"])
    notes = "Matching score (MS, mean over sequences of the per-sequence mean over pairs)."
    if detectors:
        notes += f" Detector: {', '.join(detectors)}."
    upright = sorted({r["descriptor"] for r in rows if str(r.get("detector", "")).startswith("geokey")
                      and str(r["descriptor"]).lower() in USES_GIVEN_ANGLE})
    if upright:  # their warning scrolls by inside the progress bar
        notes += (f" {', '.join(upright)} on GeoKey's keypoints: described upright (GeoKey gives no orientation), "
                  "so not rotation-invariant; use --detector sift for them.")
    if kp_sets:
        notes += f" Keypoints: {', '.join(kp_sets)}."
    notes += " Depth profile: " + ", ".join(f"{p} ({plural(len(v), 'sequence')})" for p, v in sorted(profiles.items())) + "."
    devices: dict[str, dict[str, None]] = {}  # device -> its descriptors, in order (an older results.csv has none)
    for r in rows:
        devices.setdefault(r.get("device") or "cpu", {})[r["descriptor"]] = None
    if set(devices) != {"cpu"}:  # GPU rows (`geofeat bench --device`): their seconds are not the CPU's
        notes += " Device: " + "; ".join(f"{d} ({', '.join(names)})" for d, names in sorted(devices.items())) + "."
    return "\n".join(lines) + "\n\n" + notes + "\n"


def unscored_pairs_note(rows: list[dict], targets: dict[str, list[str]]) -> str:
    """A note for table.md and details.md naming the pairs of the scored sequences that have no row
    in `rows` (skipped by the run: no ground truth on the target, no landmark in common), so that a
    mean over fewer pairs than the sequence has is said there, not only in the run's scrolled output
    (a resumed run does not print it again). `targets`: {sequence: its target frame names}; a pair
    missing for some descriptors only names them. Empty when every pair has its rows."""
    scored: dict[str, dict[str, set[str]]] = {}
    for r in rows:
        scored.setdefault(r["sequence"], {}).setdefault(r["descriptor"], set()).add(r["target"])
    missing = []
    for seq, per_descriptor in scored.items():
        for target in targets.get(seq, []):
            without = [d for d, done in per_descriptor.items() if target not in done]
            if without:
                missing.append(f"{seq}/{target}" + ("" if len(without) == len(per_descriptor)
                                                    else f" ({', '.join(without)})"))
    if not missing:
        return ""
    return (f"\nNot scored, so in no mean above: {plural(len(missing), 'pair')} (skipped by the run, which said why): "
            + ", ".join(missing) + ".\n")


CURVES = (  # (row column, sequence kind, axis label, bin edges)
    ("angle_deg", "rotate", "camera roll (degrees)", np.arange(0, 200, 20)),
    ("scale", "scale", "scale (reference depth / target depth)", np.linspace(0.4, 1.05, 8)),
)


def curve_series(rows: list[dict], key: str, kind: str, bins: np.ndarray,
                 group_of=sequence_group) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Mean MS per bin of `key` over the rows of `kind` sequences ("rotate" or "scale": the group
    `group_of` gives the sequence name, by default a word of the name as `sequence_group` reads it;
    "grayscale-deform" is no scale sequence).

    Returns {label: (bin centres (B,), mean MS (B,))}, centres ascending. The label is the
    descriptor, or "detector + descriptor" when the rows come from several detectors."""
    sel = [r for r in rows if group_of(r["sequence"]) == kind and np.isfinite(r[key])]
    detectors = list(dict.fromkeys(r.get("detector") or "sift" for r in sel))
    series = {}
    for name, det in dict.fromkeys((r["descriptor"], r.get("detector") or "sift") for r in sel):
        mine = [r for r in sel if r["descriptor"] == name and (r.get("detector") or "sift") == det]
        x = np.array([r[key] for r in mine], dtype=float)
        y = np.array([r["ms"] for r in mine], dtype=float)
        idx = np.digitize(x, bins)
        groups = np.unique(idx)
        centres = np.array([x[idx == b].mean() for b in groups])
        means = np.array([y[idx == b].mean() for b in groups])
        order = np.argsort(centres)
        series[name if len(detectors) == 1 else f"{det} + {name}"] = (centres[order], means[order])
    return series


def plot_curves(rows: list[dict], path: str | Path, group_of=sequence_group) -> list[Path]:
    """MS against camera roll (rotate sequences) and against scale (scale sequences, as `group_of`
    tells them): PNG files.

    One line per descriptor; when the rows come from several detectors, one line per
    (detector, descriptor) pair, with one line style per detector."""
    from ..viz import plot_figure

    written = []
    styles = ("o-", "s--", "^:", "d-.")
    for key, kind, axis_label, bins in CURVES:
        series = curve_series(rows, key, kind, bins, group_of)
        if not series:
            continue
        detectors = list(dict.fromkeys(lab.split(" + ")[0] for lab in series if " + " in lab))
        fig, ax = plot_figure((6, 4))
        descriptors = list(dict.fromkeys(lab.split(" + ")[-1] for lab in series))
        for lab, (x, y) in series.items():
            style = styles[detectors.index(lab.split(" + ")[0]) % len(styles)] if " + " in lab else "o-"
            colour = f"C{descriptors.index(lab.split(' + ')[-1]) % 10}"  # one colour per descriptor
            ax.plot(x, y, style, color=colour, label=lab)
        ax.set_xlabel(axis_label)
        ax.set_ylabel("matching score (MS)")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend()
        ax.set_title(curve_title(rows, kind, group_of, key), fontsize=10)
        fig.tight_layout()
        out = Path(path) / f"ms_vs_{kind}.png"
        with atomic_file(out) as tmp:  # whole or not at all
            fig.savefig(tmp, dpi=100, format="png")
        written.append(out)
    return written


def curve_title(rows: list[dict], kind: str, group_of=sequence_group, key: str | None = None) -> str:
    """The title of `plot_curves`' plot of the `kind` sequences: how many sequences and pairs the
    points average, and the detector (its keypoints decide the MS as much as the descriptor does;
    the legend names it only when there are several). With `key` (the x column), pairs without a
    value there (NaN: no simulator pose, e.g. real data named "rotate") are not drawn
    (`curve_series`), so they are not counted, and the title says how many were left out."""
    def pairs(selected):
        return dict.fromkeys((r["sequence"], r.get("reference"), r.get("target")) for r in selected)

    sel = [r for r in rows if group_of(r["sequence"]) == kind]
    drawn = sel if key is None else [r for r in sel if np.isfinite(r[key])]
    detectors = list(dict.fromkeys(r.get("detector") or "sift" for r in drawn))
    n_seq = len(dict.fromkeys(r["sequence"] for r in drawn))
    n_pairs, n_left = len(pairs(drawn)), len(pairs(sel)) - len(pairs(drawn))
    title = f"MS on {plural(n_seq, f'{kind} sequence')}, {plural(n_pairs, 'pair')}"
    if n_left:
        title += f" ({n_left} without a {'camera roll' if kind == 'rotate' else kind} left out)"
    if len(detectors) == 1:
        title += f"; keypoints: {detectors[0]}"
    return title

"""Package the training photographs: copy the shared texture set (shared/data/textures, licences in
its SOURCES.md) into geofeat/data/textures as JPEGs of at most 512 px per side, holding back every
third photograph (in name order, among those not packaged before) for validation / test sequences.

    .venv/bin/python benchmarks/package_textures.py [--shared ../shared/data/textures] [--extra DIR]

--extra: a folder of further photographs with their own SOURCES.md (the ones taken from PyPI
packages, see that file); all of them are training textures (the held-out split of the shared set
stays as it was, so test sequences made before never see a training photograph).

Writes the images and SOURCES.md (which files ship, how they were processed, then the shared
SOURCES.md with every licence and credit). Run once; the result is committed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from geofeat.sim.textures import FABRIC_KINDS, list_textures, packaged_texture_dir

#: Photographs packaged before this script (always training textures).
ORIGINAL = {
    "budgie_canyon-wren", "budgie_casa-mila", "budgie_fragrant-chamomile", "budgie_roman-colosseum",
    "budgie_singaporean-cityscape", "budgie_solaris-grapes", "budgie_the-spices-of-life", "kodak_kodim01",
    "kodak_kodim03", "kodak_kodim07", "kodak_kodim08", "kodak_kodim14", "kodak_kodim19", "kodak_kodim23",
    "kodak_kodim24", "wuffs_harvesters",
}
MAX_SIDE = 512
QUALITY = 85


def split(shared: Path) -> tuple[list[Path], list[Path]]:
    """(training, held-out) photographs of the shared folder."""
    files = list_textures(shared)
    others = [p for p in files if p.stem not in ORIGINAL]
    held = others[::3]
    return [p for p in files if p not in held], held


def main() -> None:
    default = next((p / "shared/data/textures" for p in Path(__file__).resolve().parents
                    if (p / "shared/data/textures").is_dir()), Path("shared/data/textures"))
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shared", type=Path, default=default)
    ap.add_argument("--extra", type=Path, default=None, help="folder of further training photographs + SOURCES.md")
    a = ap.parse_args()
    train, held = split(a.shared)
    extra = [p for p in list_textures(a.extra) if p.stem != "contact"] if a.extra else []
    if a.extra and not (a.extra / "SOURCES.md").is_file():
        raise SystemExit(f"--extra: {a.extra} has no SOURCES.md with the photographs' licences")
    n_shared = len(train)
    train = train + extra
    out = packaged_texture_dir()
    for p in out.glob("*.jpg"):
        p.unlink()
    for p in train:
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        s = MAX_SIDE / max(img.shape[:2])
        if s < 1:
            img = cv2.resize(img, (round(img.shape[1] * s), round(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(out / f"{p.stem}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, QUALITY])
    shared_sources = (a.shared / "SOURCES.md").read_text()
    lines = [
        "# Training textures shipped with geofeat",
        "",
        f"{len(train)} photographs: {n_shared} of the {n_shared + len(held)} photographs of the project's "
        f"`shared/data/textures` set and {len(extra)} photographs taken from PyPI packages (both described below), "
        "downscaled with OpenCV's area filter so that the longer side is at most "
        f"{MAX_SIDE} px and saved as JPEG quality {QUALITY} by `benchmarks/package_textures.py`; no other edits. "
        "They are used only as cloth textures for simulated training sequences. The other "
        f"{len(held)} photographs are held back for validation and test sequences (never trained on) and are "
        "not shipped. None of scikit-image's sample images is included (reserved for evaluation).",
        "",
        "Besides the photographs, `geofeat.sim.textures` generates textures in code (geofeat's own licence): "
        "`procedural_texture` (coloured multi-octave noise with shapes and letters) and `fabric_texture`, "
        f"{len(FABRIC_KINDS)} families of printed / woven fabric patterns ({', '.join(FABRIC_KINDS)}), each with "
        "random colours, scale, angle, dye variation and weave grain. Training sequences also jitter the colours "
        "and contrast of every texture (`jitter_colours`).",
        "",
        "Shipped: " + ", ".join(f"`{p.stem}.jpg`" for p in train) + ".",
        "",
        "Held out: " + ", ".join(f"`{p.name}`" for p in held) + ".",
        "",
        "---",
        "",
        shared_sources.replace("# Texture photographs: sources and licences", "## Sources and licences (full list)"),
    ]
    if extra:
        lines += ["", "---", "", (a.extra / "SOURCES.md").read_text().replace("# ", "## ", 1)]
    (out / "SOURCES.md").write_text("\n".join(lines))
    size = sum(p.stat().st_size for p in out.iterdir())
    print(f"packaged {len(train)} photographs ({size / 1e6:.1f} MB) in {out}; held out {len(held)}")


if __name__ == "__main__":
    main()

"""Every code block of README.md, BENCHMARKS.md (included in the site) and docs/*.md runs, in the order of its page.

- ```python blocks run in one namespace per page (a later block may use what an earlier one made);
- ```bash blocks run with `bash -e` in the same folder (a fresh temporary folder per page), with
  this interpreter's `bin/` first on PATH (so `geofeat` is the command line of this checkout);
- ```text blocks are not code (synopses, printed output) and do not run;
- a block that is too long to run here (training, full benchmarks, `make test` itself) carries the
  visible marker line `<!-- no-test: reason -->` right above it and is skipped;
- a block in any other language, or with none, fails: label it.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", ROOT / "BENCHMARKS.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```(\S*)\s*$")
NO_TEST = re.compile(r"^<!--\s*no-test:\s*(\S.*?)\s*-->$")
RUN = ("python", "bash")
NOT_CODE = ("text",)


def code_blocks(path: Path) -> list[dict]:
    """The fenced blocks of a Markdown page: language, first line number, code, no-test reason."""
    blocks, lines, i = [], path.read_text().splitlines(), 0
    while i < len(lines):
        start = FENCE.match(lines[i])
        if not start:
            i += 1
            continue
        prev = next((line.strip() for line in reversed(lines[:i]) if line.strip()), "")
        skip = NO_TEST.match(prev)
        end = next((j for j in range(i + 1, len(lines)) if lines[j].strip() == "```"), None)
        assert end is not None, f"{path.name}:{i + 1}: code block never closed"
        blocks.append({"lang": start.group(1), "line": i + 1, "code": "\n".join(lines[i + 1:end]),
                       "skip": skip.group(1) if skip else None})
        i = end + 1
    return blocks


def test_every_page_has_blocks_and_every_block_is_labelled():
    assert (ROOT / "docs").is_dir() and len(PAGES) > 5
    for page in PAGES:
        for block in code_blocks(page):
            where = f"{page.relative_to(ROOT)}:{block['line']}"
            assert block["lang"] in RUN + NOT_CODE, f"{where}: label the block python, bash or text"
            if block["skip"] is not None:
                assert block["lang"] in RUN, f"{where}: a no-test marker on a block that does not run"


def test_a_missing_marker_reason_is_not_a_marker(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("<!-- no-test: -->\n```bash\nfalse\n```\n\n<!-- no-test: slow -->\n\n```bash\nsleep 600\n```\n")
    assert [b["skip"] for b in code_blocks(page)] == [None, "slow"]


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_page_examples_run(page, tmp_path, monkeypatch):
    blocks = [b for b in code_blocks(page) if b["lang"] in RUN and b["skip"] is None]
    if not blocks:
        pytest.skip("no runnable block")
    env = dict(os.environ, MPLBACKEND="Agg",
               PATH=str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""),
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")])))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__docs__"}
    for block in blocks:
        where = f"{page.relative_to(ROOT)}:{block['line']}"
        if block["lang"] == "python":
            exec(compile(block["code"], where, "exec"), namespace)
        else:
            run = subprocess.run(["bash", "-e", "-c", block["code"]], cwd=tmp_path, env=env,
                                 capture_output=True, text=True, timeout=300)
            assert run.returncode == 0, f"{where} exited {run.returncode}:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}"


def test_readme_stays_short():
    """The README is a front page (what, one picture, two commands, an example, results, links);
    the manual lives in docs/."""
    assert len((ROOT / "README.md").read_text()) <= 8000

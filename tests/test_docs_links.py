"""The documentation holds together without mkdocs installed: every relative link of README.md and
docs/*.md points to a file and heading that exist, and docs/api.md documents every name of
`geofeat.__all__`.

`mkdocs build --strict` (`make docs`) checks the links of docs/ too, but not README.md, which GitHub
renders; this runs with the test suite. Anchors are slugs of a page's headings: mkdocs' (Python-Markdown's
toc) for links between docs/ pages, GitHub's for links from README.md. docs/benchmarks.md includes
BENCHMARKS.md (`--8<-- "BENCHMARKS.md"`), so its anchors are that file's headings too.
"""

import importlib
import inspect
import re
import unicodedata
from pathlib import Path

import pytest

import geofeat

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```.*?^```[ \t]*$", re.S | re.M)
CODE_SPAN = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#{1,6}[ \t]+(.+?)[ \t]*#*[ \t]*$", re.M)
INCLUDE = re.compile(r'^--8<--\s+"([^"]+)"\s*$', re.M)


def prose(text: str) -> str:
    """A Markdown page without its fenced code blocks (whose `#` comments are no headings)."""
    return FENCE.sub("", text)


def heading_texts(page: Path) -> list[str]:
    """The page's heading texts as rendered (code spans lose their backticks), snippets included."""
    text = prose(page.read_text())
    for name in INCLUDE.findall(text):
        text += "\n" + prose((ROOT / name).read_text())
    return [h.replace("`", "") for h in HEADING.findall(text)]


def mkdocs_slug(text: str) -> str:
    """Python-Markdown's toc slugify (mkdocs' default): ASCII, word characters, '-' between words."""
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    return re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", text).strip().lower())


def github_slug(text: str) -> str:
    """GitHub's heading anchors: lower case, punctuation but '-' and '_' dropped, each space a '-'."""
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def anchors(page: Path, slug) -> set[str]:
    """Every anchor of `page` under `slug`, repeated headings numbered as mkdocs and GitHub do."""
    seen: dict[str, int] = {}
    out = set()
    for text in heading_texts(page):
        base = slug(text)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}_{n}" if slug is mkdocs_slug else f"{base}-{n}")
    return out


def shown(path: Path) -> str:
    """`path` relative to the repository where it lies inside it."""
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def broken_links(page: Path) -> list[str]:
    """The relative links of `page` whose file or anchor does not exist, as 'LINK: why'."""
    slug = github_slug if page.name == "README.md" and page.parent == ROOT else mkdocs_slug
    broken = []
    for target in LINK.findall(CODE_SPAN.sub("", prose(page.read_text()))):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            broken.append(f"{target}: no file {shown(file)}")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file, slug):
            broken.append(f"{target}: no heading with that anchor in {shown(file)}")
    return broken


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_every_relative_link_points_to_an_existing_file_and_heading(page):
    assert broken_links(page) == []


def test_a_link_to_a_missing_file_or_heading_is_found(tmp_path):
    (tmp_path / "other.md").write_text("# Other page\n\n## The walk's first compile (2026-11-28) — `x.py`\n"
                                       "\n```bash\n# a comment, not a heading\n```\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](other.md#the-walks-first-compile-2026-11-28-xpy) [ok](other.md) [web](https://x.org/a)\n"
                    "[gone](missing.md) [bad](other.md#a-comment-not-a-heading) `[code](missing.md)`\n")
    assert [b.split(":")[0] for b in broken_links(page)] == ["missing.md", "other.md#a-comment-not-a-heading"]


def test_slugs_follow_mkdocs_and_github():
    heading = "Rerun in the fourteenth session, against 05a3f34 (2026-11-27, 07:50 UTC)"
    assert mkdocs_slug(heading) == "rerun-in-the-fourteenth-session-against-05a3f34-2026-11-27-0750-utc"
    assert github_slug(heading) == "rerun-in-the-fourteenth-session-against-05a3f34-2026-11-27-0750-utc"
    assert mkdocs_slug("GeoPatch — `bench_geopatch.py`".replace("`", "")) == "geopatch-bench_geopatchpy"
    assert github_slug("GeoPatch — bench_geopatch.py") == "geopatch--bench_geopatchpy"


def documented_objects(api_page: Path) -> set[int]:
    """ids of the objects that docs/api.md renders: each `::: path`, or its `members: [...]`."""
    text = api_page.read_text()
    found = set()
    for m in re.finditer(r"^::: (\S+)\n((?:[ \t]+\S.*\n)*)", text, re.M):
        parts = m.group(1).split(".")
        for i in range(len(parts), 0, -1):  # the longest importable module, then attributes
            try:
                obj = importlib.import_module(".".join(parts[:i]))
            except ImportError:
                continue
            for attr in parts[i:]:
                obj = getattr(obj, attr)
            break
        members = re.search(r"members: \[(.*?)\]", m.group(2))
        if members:
            found.update(id(getattr(obj, name.strip())) for name in members.group(1).split(","))
        else:
            found.add(id(obj))
            if inspect.ismodule(obj):  # a whole module: its public names too
                found.update(id(value) for name, value in vars(obj).items() if not name.startswith("_"))
    return found


def test_the_api_page_documents_every_public_name():
    documented = documented_objects(ROOT / "docs" / "api.md")
    assert [name for name in geofeat.__all__ if id(getattr(geofeat, name)) not in documented] == []

"""Build the user guide (docs/*.md) into a static HTML site.

    .venv/bin/python scripts/build_docs.py [--out site]     (or scripts/build_docs.sh)

Each page becomes ``site/NAME.html`` with a navigation bar ordered by role (technician,
criminalist, analyst, reference); links between pages point at the HTML pages, ``docs/images``
is copied to ``site/images``, and links that leave docs/ (``../packaging/WINDOWS.md``) keep
working from site/, which sits beside docs/ at the top of the repository. Headings get the same
anchors as on GitHub, so ``troubleshooting.md#video`` works in both. Needs the ``markdown``
package (the ``docs`` extra: ``pip install -c constraints.txt -e .[docs]``).
"""

from __future__ import annotations

import argparse
import html
import re
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: the navigation: (section, [(page stem, label)]). Pages not named here go under "More".
NAV = [
    ("Start", [("index", "The guide")]),
    ("Technician", [("technician-guide", "Rig and scanning"), ("motor", "The rail motor")]),
    (
        "Criminalist",
        [
            ("target", "The L target"),
            ("calibration-guide", "Calibrating a scan"),
            ("camera-calibration", "Camera intrinsics"),
        ],
    ),
    (
        "Analyst",
        [
            ("measuring-guide", "Processing and measuring"),
            ("validation", "Validation"),
            ("accuracy", "Accuracy"),
        ],
    ),
    (
        "Reference",
        [
            ("cli", "Command line"),
            ("formats", "File formats"),
            ("troubleshooting", "Troubleshooting"),
        ],
    ),
]

CSS = """
body { margin: 0; font: 16px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif;
       color: #1d2327; background: #fff; }
nav { position: fixed; top: 0; bottom: 0; left: 0; width: 15rem; overflow-y: auto;
      background: #1f2a33; color: #cfd8dc; padding: 1rem 1rem 2rem; box-sizing: border-box; }
nav .brand { display: flex; align-items: center; gap: .5rem; color: #fff; font-weight: 600;
             text-decoration: none; margin-bottom: 1rem; }
nav .brand img { width: 2rem; height: 2rem; }
nav h2 { font-size: .75rem; text-transform: uppercase; letter-spacing: .08em; color: #8fa3b0;
         margin: 1.2rem 0 .3rem; }
nav a { color: #e0e6ea; text-decoration: none; display: block; padding: .1rem 0; }
nav a:hover { color: #fff; text-decoration: underline; }
nav a.current { color: #7ee08a; font-weight: 600; }
main { margin-left: 15rem; padding: 1.5rem 2.5rem 4rem; max-width: 60rem; }
h1, h2, h3 { line-height: 1.25; } h2 { border-bottom: 1px solid #e3e7ea; padding-bottom: .2rem; }
a { color: #0b66c3; }
code { background: #f1f3f5; padding: .05rem .25rem; border-radius: 3px; font-size: .92em; }
pre { background: #f6f8fa; border: 1px solid #e3e7ea; padding: .7rem 1rem; overflow-x: auto;
      border-radius: 4px; }
pre code { background: none; padding: 0; }
table { border-collapse: collapse; margin: 1rem 0; font-size: .95em; }
th, td { border: 1px solid #d5dbe0; padding: .3rem .6rem; vertical-align: top; text-align: left; }
th { background: #f1f3f5; }
img { max-width: 100%; border: 1px solid #d5dbe0; }
td:first-child code { white-space: nowrap; }
footer { margin-top: 3rem; color: #6b7780; font-size: .85em; }
@media (max-width: 50rem) { nav { position: static; width: auto; } main { margin-left: 0; } }
@media print { nav { display: none; } main { margin: 0; } }
"""

PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title} - IMPREsS workstation</title>
<link rel="stylesheet" href="style.css">
<link rel="icon" href="images/impress.svg">
</head>
<body>
<nav>
<a class="brand" href="index.html"><img src="images/impress.svg" alt="">IMPREsS workstation</a>
{nav}
</nav>
<main>
{body}
<footer>IMPREsS workstation {version} - generated from docs/{source} by scripts/build_docs.py</footer>
</main>
</body>
</html>
"""


def slugify(value: str, separator: str = "-") -> str:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    value = re.sub(r"<[^>]+>", "", value)  # markup the toc extension may pass
    value = html.unescape(value).strip().lower()
    value = re.sub(r"[^\w\- ]", "", value)
    return value.replace(" ", separator)


def _plain_heading(text: str) -> str:
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)  # links -> their text
    text = re.sub(r"(`+)(.+?)\1", r"\2", text)
    return re.sub(r"[*_]{1,3}(\S.*?\S|\S)[*_]{1,3}", r"\1", text)


def anchors_of(markdown_text: str) -> set[str]:
    """The anchors of a page's headings (code blocks already removed), GitHub's way:
    a repeated heading gets -1, -2, ..."""
    seen: dict[str, int] = {}
    out = set()
    for m in re.finditer(r"^#{1,6}[ \t]+(.+?)[ \t]*#*[ \t]*$", markdown_text, re.M):
        base = slugify(_plain_heading(m.group(1)))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def _heading_ids(body: str) -> str:
    """Give every heading GitHub's anchor as its id (repeated headings -1, -2, ...)."""
    seen: dict[str, int] = {}

    def add(m: re.Match) -> str:
        base = slugify(m.group(3))
        n = seen.get(base, 0)
        seen[base] = n + 1
        id_ = base if n == 0 else f"{base}-{n}"
        return f'<h{m.group(1)}{m.group(2)} id="{id_}">{m.group(3)}</h{m.group(1)}>'

    return re.sub(r"<h([1-6])((?:\s[^>]*)?)>(.*?)</h\1>", add, body, flags=re.S)


def _rewrite_links(body: str) -> str:
    """href="page.md#x" -> href="page.html#x" for pages inside docs/."""

    def fix(m: re.Match) -> str:
        attr, target = m.group(1), m.group(2)
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/", "..")):
            return m.group(0)
        path, sep, anchor = target.partition("#")
        if path.endswith(".md") and "/" not in path:
            path = path[:-3] + ".html"
        return f'{attr}="{path}{sep}{anchor}"'

    return re.sub(r'(href)="([^"]+)"', fix, body)


def _title(text: str, fallback: str) -> str:
    m = re.search(r"^#[ \t]+(.+)$", text, re.M)
    return _plain_heading(m.group(1)).strip() if m else fallback


def _nav(pages: dict[str, str], current: str) -> str:
    named = {stem for _, items in NAV for stem, _ in items}
    sections = [(s, [(stem, label) for stem, label in items if stem in pages]) for s, items in NAV]
    more = sorted(stem for stem in pages if stem not in named)
    if more:
        sections.append(("More", [(stem, pages[stem]) for stem in more]))
    out = []
    for section, items in sections:
        if not items:
            continue
        out.append(f"<h2>{html.escape(section)}</h2>")
        for stem, label in items:
            cls = ' class="current"' if stem == current else ""
            out.append(f'<a href="{stem}.html"{cls}>{html.escape(label)}</a>')
    return "\n".join(out)


def build(docs: Path = ROOT / "docs", out: Path = ROOT / "site") -> list[Path]:
    """Write the site; return the HTML pages written."""
    import markdown

    from impress_gui import __version__

    sources = sorted(docs.glob("*.md"))
    if not sources:
        raise SystemExit(f"no pages in {docs}")
    texts = {p.stem: p.read_text(encoding="utf-8") for p in sources}
    titles = {stem: _title(text, stem) for stem, text in texts.items()}
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    # the site is a build output: keep it out of git without touching the top .gitignore
    (out / ".gitignore").write_text("*\n", encoding="utf-8")
    (out / "style.css").write_text(CSS.lstrip(), encoding="utf-8")
    images = docs / "images"
    if images.is_dir():
        shutil.copytree(images, out / "images")
    else:
        (out / "images").mkdir()
    icon = ROOT / "packaging" / "impress.svg"
    if icon.is_file():
        shutil.copy2(icon, out / "images" / "impress.svg")
    written = []
    for p in sources:
        md = markdown.Markdown(
            extensions=["tables", "fenced_code", "sane_lists"], output_format="html"
        )
        body = _heading_ids(md.convert(texts[p.stem]))
        body = _rewrite_links(body)
        page = PAGE.format(
            title=html.escape(titles[p.stem]),
            nav=_nav(titles, p.stem),
            body=body,
            version=html.escape(__version__),
            source=p.name,
        )
        dest = out / f"{p.stem}.html"
        dest.write_text(page, encoding="utf-8")
        written.append(dest)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="build docs/*.md into a static HTML site")
    ap.add_argument("--docs", type=Path, default=ROOT / "docs", help="source folder (docs/)")
    ap.add_argument("--out", type=Path, default=ROOT / "site", help="output folder (site/)")
    args = ap.parse_args(argv)
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    try:
        import markdown  # noqa: F401
    except ModuleNotFoundError:
        print(
            "build_docs: the markdown package is missing: "
            ".venv/bin/python -m pip install -c constraints.txt markdown",
            file=sys.stderr,
        )
        return 1
    pages = build(args.docs, args.out)
    print(f"wrote {len(pages)} pages to {args.out} (open {args.out / 'index.html'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

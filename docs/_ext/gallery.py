"""The gallery: every figure of docs/figures.toml with the commands that make it.

``{flocking-gallery}`` in a page becomes one section per committed figure, in the
manifest's order: the figure, what it shows, the commands that make it again (as
``tools/figures.py make`` runs them), how long they took, and a link to the section of
the page that quotes its numbers (found by the page's own reference to the picture).
"""

from __future__ import annotations

import os
import re
import tomllib

from docutils import nodes
from docutils.parsers.rst import Directive
from docutils.statemachine import StringList

DOCS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(DOCS)
MANIFEST = os.path.join(DOCS, "figures.toml")

#: pages of the site that show figures: (source file, the page's name on the site)
PAGES = [(os.path.join(DOCS, name), name[:-3]) for name in sorted(os.listdir(DOCS)) if name.endswith(".md")]
PAGES.append((os.path.join(ROOT, "examples", "README.md"), "examples"))


def slug(heading: str) -> str:
    """MyST's anchor of a heading (``myst_heading_anchors``)."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def where_shown(path: str):
    """(page, heading) of the first page section that shows the figure, or None."""
    name = os.path.basename(path)
    # an example's numbers are on the examples page; the rest on the page that shows it
    pages = sorted(PAGES, key=lambda entry: entry[1] != "examples") if path.startswith("examples/") else PAGES
    for source, page in pages:
        if page in ("gallery", "index") or not os.path.exists(source):
            continue
        heading = None
        with open(source, encoding="utf-8") as f:
            for line in f:
                if line.startswith("#"):
                    heading = line.lstrip("#").strip()
                if re.search(r"!\[[^\]]*\]\((\.\./)*([\w/]+/)?" + re.escape(name) + r"\)", line):
                    return page, heading
    return None


def figures() -> list[dict]:
    with open(MANIFEST, "rb") as f:
        return tomllib.load(f)["figure"]


def title(about: str) -> str:
    """The figure's description without the trailing page reference."""
    return re.sub(r"\s*\([^()]*\.md\)\s*$", "", about)


class Gallery(Directive):
    has_content = False

    def run(self):
        env = self.state.document.settings.env
        env.note_dependency(MANIFEST)
        lines: list[str] = []
        for fig in figures():
            path = fig["path"]
            env.note_dependency(os.path.join(ROOT, path))
            rel = os.path.relpath(os.path.join(ROOT, path), DOCS).replace(os.sep, "/")
            lines += [f"## {os.path.basename(path)}", "", f"```{{image}} {rel}", f":alt: {title(fig['about'])}",
                      ":width: 100%", "```", "", title(fig["about"]) + ".", ""]
            shown = where_shown(path)
            if shown:
                page, heading = shown
                anchor = f"#{slug(heading)}" if heading else ""
                lines += [f"Its numbers and what they mean: [{heading or page}]({page}.md{anchor}).", ""]
            work = "work"
            lines += [f"Made by these commands, run from a clone (`{work}` is a scratch folder; "
                      f"`python tools/figures.py make {path}` runs them and records the figure):", "",
                      "```bash", *[cmd.replace("{work}", work) for cmd in fig["make"]], "```", "",
                      f"Time: {fig['time']}.", ""]
        holder = nodes.Element()
        self.state.nested_parse(StringList(lines, MANIFEST), 0, holder, match_titles=True)
        return holder.children


def setup(app):
    app.add_directive("flocking-gallery", Gallery)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}

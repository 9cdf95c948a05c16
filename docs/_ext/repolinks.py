"""Links from the Markdown pages to files of the repository outside docs/.

The pages link to ``../README.md``, ``../examples/README.md``, ``../ARCHITECTURE.md`` and
to example files, so that they read on a clone as they do on the site. On the site, a link
to a Markdown file that the site includes goes to that page; a link to any other file of
the repository (a config file, a script) keeps its text without a link. A link to a file
that does not exist still fails the build.
"""

from __future__ import annotations

import os

from sphinx import addnodes
from sphinx.transforms.post_transforms import SphinxPostTransform

DOCS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(DOCS)

#: repository files (without .md) -> the site's page that includes them
INCLUDED = {"README": "index", "examples/README": "examples", "ARCHITECTURE": "architecture",
            "CHANGELOG": "changelog"}


class RepositoryLinks(SphinxPostTransform):
    default_priority = 8  # before MyST resolves its references (9)

    def run(self, **kwargs):
        for node in list(self.document.findall(addnodes.pending_xref)):
            if node.get("reftype") != "myst":
                continue
            target = node["reftarget"]
            if node.get("refdomain") == "doc":
                rel = os.path.relpath(os.path.join(self.env.srcdir, target), ROOT).replace(os.sep, "/")
                if rel in INCLUDED:
                    node["reftarget"] = INCLUDED[rel]
                    if rel == "README":
                        node["reftargetid"] = None
                continue
            base = os.path.dirname(self.env.doc2path(node.get("refdoc", self.env.docname)))
            source = node.source or ""
            for folder in {base, os.path.dirname(source)}:
                path = os.path.normpath(os.path.join(folder, target))
                if folder and os.path.isfile(path) and path.startswith(ROOT) and not path.endswith(".md"):
                    node.replace_self(node[0].deepcopy())
                    break


def setup(app):
    app.add_post_transform(RepositoryLinks)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}

"""The rules' compiled functions in numba's cache: a change to a rule is compiled again,
never loaded stale from the cache (numba itself checks only the stamp of the file that
defines a cached function)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import flocking
from flocking.backends import cpu_graph, cpu_kernels
from flocking.backends.features import Features
from flocking.rules import source_digest

#: in a copy of the package: the digests, then a wrap by flocking.space (the ufunc compiled
#: from flocking.rules.geometry.wrap, cached on disk)
PROBE = """
import json
from flocking.backends import cpu_graph, cpu_kernels
from flocking.rules import source_digest
from flocking.space import Space
print(json.dumps([source_digest(), cpu_kernels.SOURCES, cpu_graph.SOURCES,
                  Space((4.0, 4.0)).wrap([[5.0, 1.0]]).tolist()]))
"""


def probe(src: Path, cache: Path) -> list:
    env = {**os.environ, "PYTHONPATH": str(src), "NUMBA_CACHE_DIR": str(cache)}
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.splitlines()[-1])


def test_a_changed_rule_is_compiled_again_and_renames_the_kernels(tmp_path):
    """Run, change ``wrap`` in the copy's rules (nothing else), run again on the same
    cache: the new rule's result, and new names for every kernel compiled from it."""
    package = Path(flocking.__file__).parent
    src = tmp_path / "src"
    shutil.copytree(package, src / "flocking", ignore=shutil.ignore_patterns("__pycache__"))
    before = probe(src, tmp_path / "cache")
    assert before[3] == [[1.0, 1.0]]
    geometry = src / "flocking" / "rules" / "geometry.py"
    text = geometry.read_text()
    fold = "    x = x - length * REAL(math.floor(x / length))\n"
    assert text.count(fold) == 1
    geometry.write_text(text.replace(fold, fold.rstrip("\n") + " + ONE\n"))
    after = probe(src, tmp_path / "cache")
    assert after[3] == [[2.0, 2.0]]  # 5 - 4 + 1: compiled from the new text, not loaded
    assert all(a != b for a, b in zip(before[:3], after[:3]))
    assert probe(src, tmp_path / "cache") == after  # and then loaded as it is


def test_the_kernels_are_cached_under_the_digest_of_what_they_compile_in():
    kernels = cpu_kernels.build(Features(), 2)
    assert kernels.lines.py_func.__qualname__ == f"lines_2d_00000_{cpu_kernels.SOURCES}"
    assert kernels.search.py_func.__qualname__ == f"search_2d_00000_{cpu_kernels.SOURCES}"
    assert cpu_graph.build(Features(), 3).py_func.__qualname__ == f"graph_3d_00000_{cpu_graph.SOURCES}"
    from flocking.backends import cells, delaunay, intrinsics, voronoi_cells

    assert cpu_kernels.SOURCES == source_digest(cells, intrinsics)
    assert cpu_graph.SOURCES == source_digest(cells, intrinsics, cpu_kernels, delaunay, voronoi_cells)
    assert len({source_digest(), cpu_kernels.SOURCES, cpu_graph.SOURCES}) == 3

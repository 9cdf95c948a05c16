"""Run the benchmark suite from a checkout: ``python benchmarks/run.py [--full] [--out DIR]``.

The same as ``flocking bench`` (all options pass through), with this folder as the
reference folder. It times flocking's CPU backend against the kd-tree + sparse-matrix
reference (``kdtree_reference.py`` here) and against pyvicsek's C++ kernel when
``pip install pyvicsek`` has been run in this environment, in one process, and writes
``results.md``, ``results.json`` and ``throughput.png``. See docs/performance.md.
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, os.pardir, "src"))

from flocking.cli import main  # noqa: E402

if __name__ == "__main__":
    args = sys.argv[1:]
    if "--refs" not in args:
        args += ["--refs", HERE]
    sys.exit(main(["bench", *args]))

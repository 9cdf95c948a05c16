"""A script of the repository (an example, a tool) loaded as a module, for tests to call
its functions."""

from __future__ import annotations

import importlib.util
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def load_script(relative: str):
    """The module of ``ROOT / relative`` (``"examples/chate2008.py"``), executed afresh."""
    path = ROOT / relative
    spec = importlib.util.spec_from_file_location(f"script_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

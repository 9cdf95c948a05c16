"""Writing files so that a reader, or a crash, sees the old file or the new one, never half.

>>> import os, tempfile
>>> path = os.path.join(tempfile.mkdtemp(), "notes.txt")
>>> with replace_atomically(path) as f:
...     _ = f.write("complete")
>>> open(path).read(), sorted(os.listdir(os.path.dirname(path)))
('complete', ['notes.txt'])
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import IO


@contextlib.contextmanager
def replace_atomically(path: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a temporary file beside ``path``; when the block ends, flush it to disk and
    rename it over ``path``. If the block fails (a full disk, an interrupt), the temporary
    is removed and ``path`` keeps its old content."""
    path = os.fspath(path)
    tmp = f"{path}.{os.getpid()}.tmp"  # one per process: concurrent writers never share it
    if "b" not in mode:
        kwargs.setdefault("encoding", "utf-8")
    try:
        with open(tmp, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    """``text`` into ``path``, atomically."""
    with replace_atomically(path) as f:
        f.write(text)

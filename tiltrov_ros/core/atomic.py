"""Files replaced whole: a reader sees the old file or the new one, never a part."""

from __future__ import annotations

import os
from pathlib import Path


def replace_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through a hidden sibling written first and
    renamed into place (``os.replace``, atomic on POSIX): a reader of ``path`` meanwhile
    (a node reading its parameter file, a bag reader, a supervisor's status) sees the
    previous content or the new one whole."""
    partial = path.with_name(f'.{path.name}.partial')
    partial.write_text(text, encoding='utf-8')
    os.replace(partial, path)

"""Reading a YAML file the user gave or edited (one-line errors naming the file), and
flattening a nested document into dotted keys."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from tiltrov_ros.core.errors import UnreadableFileError


def read_yaml(path: str | Path) -> Any:
    """The YAML document of ``path`` (``yaml.safe_load``: aliases stay shared, so an
    alias bomb costs nothing). Raises :class:`UnreadableFileError`, one line naming
    the file: missing or unreadable, not UTF-8 text, or not YAML."""
    try:
        with Path(path).open(encoding='utf-8') as stream:
            return yaml.safe_load(stream)
    except OSError as exc:
        raise UnreadableFileError(f'cannot read {path}: {exc.strerror or exc}') from None
    except UnicodeDecodeError:
        raise UnreadableFileError(f'cannot read {path}: not UTF-8 text') from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise UnreadableFileError(f'cannot read {path}: not valid YAML: {problem}{where}') \
            from None


def flatten(document: Mapping[Any, Any], prefix: str = '') -> dict[str, Any]:
    """Nested mappings as one level, keys joined by dots:
    ``{robot: {length: 0.6}}`` -> ``{'robot.length': 0.6}``."""
    out: dict[str, Any] = {}
    for key, value in document.items():
        if isinstance(value, Mapping):
            out.update(flatten(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out

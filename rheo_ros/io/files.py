"""Output files written whole or not at all, and never through a link planted at their path."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any


def write_json_atomic(path: str | Path, data: Any) -> Path:
    """``data`` as indented JSON (numpy floats as floats), ``write_text_atomic``."""
    return write_text_atomic(path, json.dumps(data, indent=2, default=float) + "\n")


def write_text_atomic(path: str | Path, text: str) -> Path:
    """``write_bytes_atomic`` of ``text`` in UTF-8."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` by a temporary file in the same folder renamed over it: a
    reader sees the old file or the new one, never half of one, and a symlink at ``path``
    is replaced, not followed (another local user cannot aim the output at a file of
    yours). The file gets the usual mode (0666 less the umask)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path

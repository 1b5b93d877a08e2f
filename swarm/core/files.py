"""Files that readers may open at any moment: written whole or not at all."""

from __future__ import annotations

import os
from pathlib import Path


def write_atomically(path: Path, text: str) -> None:
    """``path`` holds ``text`` whole or keeps what it held: the text goes to ``<path>.tmp`` first, which
    then replaces ``path`` in one step (``os.replace``), so a reader or an interrupt never sees half a
    file; the temporary file is removed if the write fails."""
    temporary = path.with_name(path.name + ".tmp")
    try:
        temporary.write_text(text)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)

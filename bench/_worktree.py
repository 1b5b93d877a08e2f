"""A detached git worktree of another commit, for benchmarks that alternate it with this working tree
(``floor_ab.py``, ``alone_probe.py --base``)."""

from __future__ import annotations

import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def short_commit(rev: str) -> str | None:
    """``rev``'s short hash in this repository, or None if it names no commit."""
    done = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", rev], capture_output=True, text=True
    )
    return done.stdout.strip() if done.returncode == 0 else None


@contextmanager
def base_worktree(base: str, prefix: str) -> Iterator[Path]:
    """A worktree of commit ``base`` (checked with :func:`short_commit` first) in a new temporary
    directory named ``prefix...``; removed on exit. Its parent directory is scratch space for the runs."""
    tree = Path(tempfile.mkdtemp(prefix=prefix)) / "base"
    subprocess.run(
        ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), base],
        check=True,
        capture_output=True,
    )
    try:
        yield tree
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)

"""swarm.core.files.write_atomically: a file is replaced whole, or keeps what it held."""

from __future__ import annotations

import pytest

from swarm.core.files import write_atomically


def test_a_write_replaces_the_file_whole_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "stats.json"
    write_atomically(path, "first\n")
    write_atomically(path, "second\n")
    assert path.read_text() == "second\n"
    assert [entry.name for entry in tmp_path.iterdir()] == ["stats.json"]


def test_a_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    path = tmp_path / "stats.json"
    write_atomically(path, "kept\n")
    with pytest.raises(UnicodeEncodeError):  # a lone surrogate: fails once the temporary is open
        write_atomically(path, "half \udc80 written")
    assert path.read_text() == "kept\n"
    assert [entry.name for entry in tmp_path.iterdir()] == ["stats.json"]

"""Atomic writes: nothing half-written, and the mode the umask gives."""

from __future__ import annotations

import os
import stat

import pytest

from posevote._io import atomic_open, atomic_write_text, atomic_write_with


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_new_files_get_the_umask_mode_and_old_ones_keep_theirs(tmp_path, umask_022):
    path = tmp_path / "a.txt"
    atomic_write_text(path, "one")
    assert path.read_text() == "one" and stat.S_IMODE(path.stat().st_mode) == 0o644
    os.chmod(path, 0o600)
    atomic_write_text(path, "two")
    assert path.read_text() == "two" and stat.S_IMODE(path.stat().st_mode) == 0o600
    png = tmp_path / "b.png"
    atomic_write_with(png, lambda tmp: tmp.write_bytes(b"x"))
    assert stat.S_IMODE(png.stat().st_mode) == 0o644


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "m.bin"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError), atomic_open(path) as fh:
        fh.write(b"half")
        raise RuntimeError("crash")
    assert path.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.bin"]

"""Atomic file writing: a crash never leaves half a file behind.

The temporary file is given the mode the file would have had if written
directly: an overwritten file keeps its mode, a new one gets ``0666`` less
the process's umask (0644 under umask 022), not ``mkstemp``'s private 0600.
Its name holds the writing process's id (``.NAME.PID.XXXX.tmp``), so that the
next write of the same file removes the temporaries of writers that died
(killed mid-write) and leaves those of live ones.

Results folders (``evaluate --out``, ``estimate --out``) are held by one run
at a time (:func:`folder_lock`) and keep their records as JSON lines,
appended and synced one at a time (:func:`read_records`, :func:`repair_records`).
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import stat
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _target_mode(path: Path) -> int:
    """The mode ``path`` has, or that a new file there would get."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        return 0o666 & ~_umask()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # another user's live process
        return True
    return True


def _clean_stale(parent: Path, prefix: str, suffix: str) -> None:
    """Remove the temporaries ``prefix PID. ... suffix`` in ``parent`` whose writer is gone."""
    for tmp in parent.glob(f"{glob.escape(prefix)}*{glob.escape(suffix)}"):
        pid_text = tmp.name[len(prefix):].split(".", 1)[0]
        if pid_text.isdigit() and int(pid_text) != os.getpid() and not _alive(int(pid_text)):
            with contextlib.suppress(OSError):
                tmp.unlink()


def _temporary(path: Path, suffix: str) -> tuple[int, str]:
    path.parent.mkdir(parents=True, exist_ok=True)
    prefix = f".{path.name}."
    _clean_stale(path.parent, prefix, suffix)
    return tempfile.mkstemp(prefix=f"{prefix}{os.getpid()}.", suffix=suffix, dir=path.parent)


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file beside ``path``; rename it onto ``path`` on success.

    On any exception the temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    fd, tmp = _temporary(path, ".tmp")
    try:
        os.chmod(tmp, _target_mode(path))
        with os.fdopen(fd, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_open(path, "w") as fh:
        fh.write(text)


def atomic_write_with(path: str | Path, writer: Callable[[Path], None]) -> None:
    """Let ``writer`` write a temporary file, then rename it onto ``path``.

    For libraries that insist on writing to a file name themselves
    (``cv2.imwrite``, ``Figure.savefig``). The temporary name keeps the
    suffix of ``path`` so that the format is chosen the same way.
    """
    path = Path(path)
    fd, tmp = _temporary(path, f".tmp{path.suffix}")
    os.close(fd)
    try:
        os.chmod(tmp, _target_mode(path))
        writer(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def folder_lock(out: Path) -> Iterator[None]:
    """Hold the results folder for this run: a second run on it at once is refused.

    The lock is the kernel's (``flock`` on ``out/.lock``): it is released
    when the process ends, however it ends, so a killed run leaves none.
    """
    out.mkdir(parents=True, exist_ok=True)
    path = out / ".lock"
    fh = path.open("a+")
    try:
        try:
            import fcntl
        except ImportError:   # not POSIX: no lock
            yield
            return
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "?"
            raise ValueError(f"{out}: another posevote evaluate (pid {holder}) is writing to "
                             "this results folder; wait for it to finish or use another --out"
                             ) from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        yield
    finally:
        fh.close()


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key {key!r} appears twice in one object")
        out[key] = value
    return out


def parse_json(text: str, where: str, *, kind: str = "JSON") -> Any:
    """JSON ``text``, refused with a ValueError naming ``where`` when it is not JSON (``kind``
    says what it should be), holds a key twice in one object, or nests deeper than the
    parser can follow."""
    try:
        return json.loads(text, object_pairs_hook=_unique_keys)
    except RecursionError:
        raise ValueError(f"{where}: the JSON nests too deep") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{where}: not {kind} ({exc})") from None
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def read_records(path: Path) -> list[dict[str, Any]]:
    """The complete records of a JSON-lines file, one an image (a cut-short last line is dropped)."""
    if not path.is_file():
        return []
    out = []
    seen: set[str] = set()
    with path.open("r", encoding="utf-8") as fh:
        for line in fh:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            # One record an image: a second (from a run that overlapped) is ignored.
            if isinstance(rec, dict) and "image" in rec and rec["image"] not in seen:
                seen.add(rec["image"])
                out.append(rec)
    return out


def repair_records(path: Path) -> None:
    """Cut a records file back to its last complete line (after an interruption)."""
    if not path.is_file():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        os.truncate(path, data.rfind(b"\n") + 1)

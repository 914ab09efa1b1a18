"""The result files of the benchmarks: the command that made them, then what it printed."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from posevote._io import atomic_write_text


def write_markdown(path: str | Path, script: str, argv: list[str] | None, text: str, *,
                   fenced: bool = True) -> None:
    """Write ``text`` under the command line that reproduces it (atomically).

    ``script`` is the benchmark's ``__file__``; ``argv`` its arguments (None:
    the process's own). ``fenced=False`` leaves ``text`` outside the code block
    (Markdown tables that should render).
    """
    args = sys.argv[1:] if argv is None else argv
    command = shlex.join(["python", f"benchmarks/{Path(script).name}", *args])
    body = f"```\n$ {command}\n{text}```\n" if fenced else f"```\n$ {command}\n```\n\n{text}"
    atomic_write_text(path, body)


def emit(text: str, markdown: str | None, script: str, argv: list[str] | None, *,
         fenced: bool = True) -> int:
    """Print a benchmark's report and, if ``markdown`` names a file, write it there too
    (:func:`write_markdown`); 0."""
    print(text, end="")
    if markdown:
        write_markdown(markdown, script, argv, text, fenced=fenced)
    return 0

"""numba's on-disk cache of posevote's compiled kernels, kept in step with their sources.

numba keys a cached function by its own file's time stamp, not by the files of
the compiled functions it calls: after a change to a callee in another module
(a checkout that leaves the caller's file untouched), the caller's cached
machine code still holds the old callee, and runs it. The sources that define
kernels are therefore hashed together; when the hash differs from the one
stamped beside the cache, posevote's cache files are dropped (recompiled on
first use) and the new hash is stamped.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

#: What marks a source file that defines compiled kernels.
KERNEL_MARK = b"numba.njit"
#: The stamp's name, in the package's own ``__pycache__``.
STAMP = "kernel-sources.sha256"


def kernel_sources_hash(package: Path) -> str:
    """The SHA-256 of the package's source files that define kernels, in path order."""
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        text = path.read_bytes()
        if KERNEL_MARK in text:
            digest.update(path.relative_to(package).as_posix().encode() + b"\0" + text)
    return digest.hexdigest()


def refresh_kernel_cache(package: Path) -> bool:
    """Drop the package's cached kernels if the kernel sources changed since they were stamped.

    Only the cache numba keeps beside the modules (``__pycache__/*.nbi``, ``*.nbc``);
    with ``NUMBA_CACHE_DIR`` set, the cache is the user's to manage. A folder that
    cannot be written (an installed, read-only package) is left as it is.

    Returns
    -------
    bool
        True when cache files were dropped (or the stamp was first written).
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return False
    stamp = package / "__pycache__" / STAMP
    current = kernel_sources_hash(package)
    try:
        if stamp.read_text().strip() == current:
            return False
    except OSError:
        pass
    try:
        for pattern in ("*.nbi", "*.nbc"):
            for path in package.rglob(f"__pycache__/{pattern}"):
                path.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        # Written whole or not at all: several workers may start at once.
        partial = stamp.with_name(f"{STAMP}.{os.getpid()}")
        partial.write_text(current + "\n")
        os.replace(partial, stamp)
    except OSError:
        return False
    return True

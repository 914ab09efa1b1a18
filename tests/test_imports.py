"""Every module of posevote imports on its own, first: no import cycle hides behind the order
in which the package's own ``__init__`` happens to load them."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import importlib, pkgutil, sys
import posevote
names = sorted(m.name for m in pkgutil.walk_packages(posevote.__path__, "posevote."))
failed = []
for name in names:
    for loaded in [m for m in sys.modules if m == "posevote" or m.startswith("posevote.")]:
        del sys.modules[loaded]
    try:
        importlib.import_module(name)
    except ImportError as exc:
        failed.append(f"{name}: {exc}")
print(len(names))
print("\\n".join(failed))
"""


def test_every_module_imports_first():
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    count, *failed = done.stdout.strip().split("\n")
    assert int(count) > 50 and not [f for f in failed if f], failed

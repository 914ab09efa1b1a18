import os

from posevote._kernels import STAMP, kernel_sources_hash, refresh_kernel_cache


def _package(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub" / "__pycache__").mkdir(parents=True)
    (pkg / "__pycache__").mkdir()
    (pkg / "kernel.py").write_text("import numba\n@numba.njit(cache=True)\ndef f(x):\n    return x\n")
    (pkg / "sub" / "caller.py").write_text("import numba\n@numba.njit(cache=True)\ndef g(x):\n"
                                           "    return x\n")
    (pkg / "plain.py").write_text("x = 1\n")
    cached = [pkg / "sub" / "__pycache__" / "caller.g-2.py311.nbi",
              pkg / "sub" / "__pycache__" / "caller.g-2.py311.1.nbc"]
    for path in cached:
        path.write_bytes(b"machine code")
    return pkg, cached


def test_a_changed_kernel_source_drops_every_cached_kernel(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    pkg, cached = _package(tmp_path)
    # The first import stamps the sources (and drops what no stamp vouches for).
    assert refresh_kernel_cache(pkg)
    assert (pkg / "__pycache__" / STAMP).read_text().strip() == kernel_sources_hash(pkg)
    for path in cached:
        path.write_bytes(b"machine code")
    # Unchanged sources keep the cache; a change to a plain module does too.
    (pkg / "plain.py").write_text("x = 2\n")
    assert not refresh_kernel_cache(pkg)
    assert all(p.exists() for p in cached)
    # A change to a kernel's file elsewhere than the caller's drops the caller's cache.
    (pkg / "kernel.py").write_text("import numba\n@numba.njit(cache=True)\ndef f(x):\n"
                                   "    return 2 * x\n")
    assert refresh_kernel_cache(pkg)
    assert not any(p.exists() for p in cached)
    assert not refresh_kernel_cache(pkg)


def test_a_cache_folder_of_the_users_is_left_alone(tmp_path, monkeypatch):
    pkg, cached = _package(tmp_path)
    monkeypatch.setenv("NUMBA_CACHE_DIR", os.fspath(tmp_path / "elsewhere"))
    assert not refresh_kernel_cache(pkg)
    assert all(p.exists() for p in cached)
    assert not (pkg / "__pycache__" / STAMP).exists()

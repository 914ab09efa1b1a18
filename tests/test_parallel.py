"""Worker processes and the Dask cluster: the same results, in order, as one process."""

from __future__ import annotations

import numpy as np
import pytest

from posevote._parallel import ordered_map, thread_map


def _square(x: int, offset: int) -> int:
    return x * x + offset


def test_local_pool_keeps_the_order():
    tasks = [(i, 1) for i in range(7)]
    assert list(ordered_map(_square, tasks)) == list(ordered_map(_square, tasks, jobs=2)) == [
        i * i + 1 for i in range(7)]
    assert list(ordered_map(_square, [], jobs=2)) == []


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, host="127.0.0.1")
    with distributed.Client(cluster) as c:
        yield c
    cluster.close()


@pytest.mark.filterwarnings("ignore")
def test_a_dask_cluster_gives_the_local_results(client, fitted_estimator, draw, tmp_path):
    import cv2

    from posevote.batch import estimate_images

    model = tmp_path / "m.npz"
    fitted_estimator.save(model)
    paths = []
    for i, az in enumerate((30, 140, 260)):
        paths.append(tmp_path / f"t{i}.png")
        cv2.imwrite(str(paths[-1]), (draw(np.radians(az)) * 255).astype(np.uint8))
    assert list(ordered_map(_square, [(i, 0) for i in range(5)], scheduler=client)) == [
        0, 1, 4, 9, 16]
    local = list(estimate_images(model, paths))
    remote = list(estimate_images(model, paths, scheduler=client))
    assert [r["best"] for r in remote] == [r["best"] for r in local]
    # The address form: a client of its own, closed afterwards.
    by_address = list(ordered_map(_square, [(3, 0)], scheduler=client.scheduler.address))
    assert by_address == [9]


@pytest.mark.filterwarnings("ignore")
def test_an_evaluation_on_dask_equals_the_local_one(client, tiny_protocol, tmp_path):
    from posevote._io import read_records
    from posevote.evaluation.runner import run_protocol, slug

    quiet = {"log": lambda m: None, "rows": ["weights + fitting"]}
    run_protocol(tiny_protocol, tmp_path / "local", **quiet)
    run_protocol(tiny_protocol, tmp_path / "dask", scheduler=client, **quiet)
    key = f"{slug('weights + fitting')}__only.jsonl"
    a, b = (sorted(read_records(tmp_path / d / "records" / key), key=lambda r: r["image"])
            for d in ("local", "dask"))
    assert [r["estimate_deg"] for r in a] == [r["estimate_deg"] for r in b]


@pytest.mark.parametrize("threads", [1, 3])
def test_thread_map_keeps_the_order_and_raises_in_place(threads):
    import time

    def slow(i: int) -> int:
        time.sleep(0.002 * (i % 3))
        if i == 7:
            raise ValueError("item 7")
        return i * i

    got = []
    with pytest.raises(ValueError, match="item 7"):
        for value in thread_map(slow, range(20), threads, ahead=2):
            got.append(value)
    assert got == [i * i for i in range(7)]
    assert list(thread_map(lambda i: -i, range(50), threads)) == [-i for i in range(50)]


def test_two_interrupts_end_the_parent_and_its_workers(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    started = tmp_path / "started"
    script = ("import time, pathlib\n"
              "from posevote._parallel import ordered_map\n"
              "for i, _ in enumerate(ordered_map(time.sleep, [(0.5,)] * 200, jobs=2)):\n"
              f"    pathlib.Path({str(started)!r}).write_text(str(i))\n")
    proc = subprocess.Popen([sys.executable, "-c", script], start_new_session=True,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not started.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert started.exists()
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        assert proc.wait(timeout=20) != 0
    finally:
        leftover = subprocess.run(["pgrep", "-g", str(proc.pid)], capture_output=True,
                                  text=True).stdout.split()
        for pid in leftover:
            os.kill(int(pid), signal.SIGKILL)
    assert not leftover   # no worker outlives its parent


def test_a_consumer_that_stops_early_leaves_no_worker():
    import multiprocessing
    import time

    before = set(multiprocessing.active_children())     # a Dask cluster's, from other tests
    results = ordered_map(time.sleep, [(0.2,)] * 50, jobs=2)
    next(results)
    results.close()
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        left = [p for p in multiprocessing.active_children()
                if p.is_alive() and p not in before and "Dask" not in p.name]
        if not left:
            break
        time.sleep(0.1)
    assert not left


@pytest.mark.parametrize("address", ["not a url", "http://127.0.0.1:80", "tcp://host"])
def test_a_malformed_scheduler_address_is_refused_at_once(address):
    pytest.importorskip("distributed")
    import time

    start = time.monotonic()
    with pytest.raises(ValueError, match="cannot use the Dask scheduler"):
        list(ordered_map(abs, [(1,), (2,)], scheduler=address))
    assert time.monotonic() - start < 10


def test_a_server_that_answers_nonsense_is_refused_at_once():
    pytest.importorskip("distributed")
    import socket
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)

    def answer() -> None:
        conn, _ = server.accept()
        with conn:
            conn.recv(1024)
            conn.sendall(b"HTTP/1.0 400 Bad Request\r\nContent-Length: 0\r\n\r\n")

    threading.Thread(target=answer, daemon=True).start()
    try:
        with pytest.raises(ValueError, match="does not answer as one"):
            list(ordered_map(abs, [(1,), (2,)],
                             scheduler=f"tcp://127.0.0.1:{server.getsockname()[1]}"))
    finally:
        server.close()


def test_a_server_that_is_not_a_scheduler_times_out(monkeypatch):
    pytest.importorskip("distributed")
    import socket

    import posevote._parallel as parallel

    monkeypatch.setattr(parallel, "CONNECT_SECONDS", 2.0)
    # A listening socket that never answers, as a web server does to a Dask handshake.
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(8)
        with pytest.raises(TimeoutError, match="no Dask scheduler answered"):
            list(ordered_map(abs, [(1,), (2,)],
                             scheduler=f"tcp://127.0.0.1:{server.getsockname()[1]}"))


@pytest.mark.filterwarnings("ignore")
def test_a_scheduler_given_by_its_address_is_used(client):
    address = client.scheduler.address
    assert list(ordered_map(abs, [(-1,), (-2,), (3,)], scheduler=address)) == [1, 2, 3]

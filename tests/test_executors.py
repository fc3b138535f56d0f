"""Executors: the same outcomes in this process, on a local pool and on dask; worker deaths retried (bounded), raised
errors recorded, Ctrl-C frees the cluster, and a clear error when the cluster extra is missing.

The functions the workers run live at module level so that spawned processes can import them by name. Every test
that starts worker processes is marked slow (a cluster or a pool takes seconds to start on a loaded 2-core machine).
"""

import math
import os
import sys
from pathlib import Path

import distributed
import psutil
import pytest

from lightcurve_gp.sweep import executors
from lightcurve_gp.sweep.executors import (
    CLUSTER_EXTRA,
    DaskExecutor,
    ExecutorError,
    LocalPoolExecutor,
    SerialExecutor,
    make_executor,
)


def series(payload: dict) -> float:
    """A deterministic float result: a partial sum of the Leibniz series; raises for a negative length."""
    n = payload["n"]
    if n < 0:
        raise ValueError(f"negative length {n}")
    return 4 * math.fsum((-1) ** k / (2 * k + 1) for k in range(n))


def die_once(payload: dict) -> int:
    """Kill the worker process the first time a payload runs (a marker file remembers), then return ``10 n``."""
    marker = Path(payload["marker"])
    if not marker.exists():
        marker.touch()
        os._exit(1)
    return payload["n"] * 10


def die_always(payload: dict) -> int:
    """Kill the worker process every time; count the attempts in a file."""
    counter = Path(payload["counter"])
    with counter.open("a") as fh:
        fh.write("x")
    os._exit(1)


def payloads(*ns: int) -> dict[str, dict]:
    return {f"n{n}": {"n": n} for n in ns}


@pytest.fixture(scope="module")
def scheduler():
    """A running 2-worker cluster (one thread each) whose scheduler retries a task on a died worker once."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  scheduler_kwargs={"allowed_failures": 1}) as cluster:
        yield cluster.scheduler_address


def by_key(outcomes) -> dict:
    return {o.key: (o.value, o.error) for o in outcomes}


@pytest.mark.slow
def test_dask_local_pool_and_serial_give_the_same_outcomes_and_record_a_raising_case(scheduler):
    work = payloads(10, 200, -1, 3000, 7)
    serial = by_key(SerialExecutor().run(series, work, progress=False))
    with make_executor("local", workers=2) as pool:
        assert isinstance(pool, LocalPoolExecutor)
        local = by_key(pool.run(series, work, progress=False))
    with make_executor("dask", address=scheduler) as cluster:
        dask = by_key(cluster.run(series, work, progress=False))
    assert serial == local == dask
    assert serial["n-1"] == (None, "ValueError: negative length -1")
    assert serial["n200"][0] == pytest.approx(math.pi, abs=1 / 200) and serial["n200"][1] is None


@pytest.mark.slow
def test_running_scheduler_streams_outcomes_and_keeps_the_traceback(scheduler):
    with DaskExecutor(address=scheduler) as ex:
        outcomes = list(ex.run(series, payloads(5, -2, 50), progress=False))
        assert ex.slots == 2
    assert sorted(o.key for o in outcomes) == ["n-2", "n5", "n50"]
    failed = [o for o in outcomes if not o.ok]
    assert [o.key for o in failed] == ["n-2"]
    assert "in series" in failed[0].traceback and failed[0].value is None


@pytest.mark.slow
def test_dask_case_that_kills_its_worker_is_retried_and_the_run_completes(scheduler, tmp_path):
    work = {f"n{n}": {"n": n, "marker": str(tmp_path / f"marker{n}")} for n in range(4)}
    work["n2"]["marker"] = str(tmp_path / "fresh")  # only this one finds no marker: it dies once
    for n in (0, 1, 3):
        Path(work[f"n{n}"]["marker"]).touch()
    with DaskExecutor(address=scheduler) as ex:
        outcomes = by_key(ex.run(die_once, work, progress=False))
    assert outcomes == {f"n{n}": (10 * n, None) for n in range(4)}
    assert (tmp_path / "fresh").exists()  # it did die once


@pytest.mark.slow
def test_dask_worker_deaths_are_bounded_and_the_others_finish(scheduler, tmp_path):
    with DaskExecutor(address=scheduler) as ex:  # its scheduler allows one retry
        counter = tmp_path / "attempts"
        outcomes = list(ex.map_unordered(die_always, {"doomed": {"counter": str(counter)}}))
        rest = by_key(ex.map_unordered(series, payloads(1, 2)))
    assert len(outcomes) == 1 and not outcomes[0].ok
    assert outcomes[0].error.startswith("worker died 2 time(s) while running it (KilledWorker")
    assert counter.read_text() == "xx"  # the first run and one retry
    assert rest == {"n1": (4.0, None), "n2": (4 * (1 - 1 / 3), None)}


@pytest.mark.slow
def test_local_pool_retries_a_died_worker_and_gives_up_after_the_bound(tmp_path):
    once = {"a": {"n": 1, "marker": str(tmp_path / "a")}}
    with LocalPoolExecutor(1, retries=1) as pool:  # one process: each rebuild spawns one
        assert by_key(pool.map_unordered(die_once, once)) == {"a": (10, None)}
        counter = tmp_path / "attempts"
        doomed = list(pool.map_unordered(die_always, {"doomed": {"counter": str(counter)}}))
    assert doomed[0].error.startswith("worker died 2 time(s) while running it (BrokenProcessPool")
    assert counter.read_text() == "xx"


@pytest.mark.slow
def test_interrupt_in_the_consumer_cancels_the_rest_and_shuts_the_local_cluster_down():
    ex = DaskExecutor(workers=2)
    assert ex.slots == 2
    pids = list(ex.client.run(os.getpid).values())
    assert len(pids) == 2 and all(psutil.pid_exists(p) for p in pids)
    seen = []
    with pytest.raises(KeyboardInterrupt), ex:
        for outcome in ex.run(series, payloads(*range(1, 40)), progress=False):
            seen.append(outcome.key)
            raise KeyboardInterrupt
    assert len(seen) == 1
    assert ex.client.status == "closed"
    assert not any(psutil.pid_exists(p) for p in pids)


def test_missing_cluster_extra_is_an_error_naming_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed now raises ImportError
    with pytest.raises(ExecutorError) as exc:
        make_executor("dask", workers=2)
    assert str(exc.value) == ("--executor dask needs dask.distributed, which is not installed: install the cluster "
                              f"extra with {CLUSTER_EXTRA}")
    assert CLUSTER_EXTRA == 'pip install -e ".[cluster]"'


def test_bad_executor_settings_are_errors_naming_the_option(monkeypatch):
    with pytest.raises(ExecutorError, match=r"^--executor: unknown executor 'ray'; choose from local, dask$"):
        make_executor("ray")
    with pytest.raises(ExecutorError, match=r"^--scheduler: a scheduler address needs --executor dask$"):
        make_executor("local", address="tcp://127.0.0.1:8786")
    with pytest.raises(ExecutorError, match=r"^workers: 0 must be >= 1$"):
        make_executor("local", workers=0)
    assert isinstance(make_executor("local", workers=1), SerialExecutor)
    monkeypatch.setattr(executors, "CONNECT_TIMEOUT_S", 0.5)
    with pytest.raises(ExecutorError, match=r"^--scheduler tcp://127.0.0.1:9: cannot connect to a dask scheduler"):
        make_executor("dask", address="tcp://127.0.0.1:9")

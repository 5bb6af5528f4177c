"""The studies on a Dask cluster as a cluster user runs one: its scheduler and workers are separate
processes started outside this checkout, with the installed package but without ``scenes/`` or
``comparisons/`` on their path (comparisons.executors.ship_checkout uploads them).

The records must be the ones the same configurations give in this process: a shipped study runs
the same code, so its figures are bit for bit the same.
"""
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

distributed = pytest.importorskip("dask.distributed")

from comparisons import energy_loss as el  # noqa: E402
from comparisons import grasp  # noqa: E402

START_TIMEOUT = 120.0  # s, for the scheduler file and both workers (cold imports of dartpy, numba)


def _clean_env():
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["DASK_DISTRIBUTED__WORKER__DAEMON"] = "False"
    return env


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A scheduler and two single-threaded workers, each its own process, cwd outside the checkout."""
    home = tmp_path_factory.mktemp("cluster")
    scheduler_file = home / "scheduler.json"
    env = _clean_env()
    probe = subprocess.run([sys.executable, "-c", "import scenes"], cwd=home, env=env, capture_output=True)
    assert probe.returncode != 0, "the cluster's processes must not see the checkout"
    common = dict(cwd=home, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(scheduler_file)], **common)]
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while not scheduler_file.exists():
            if time.monotonic() > deadline or procs[0].poll() is not None:
                pytest.fail("the Dask scheduler did not start")
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address,
                                       "--nworkers", "2", "--nthreads", "1", "--no-dashboard",
                                       "--local-directory", str(home / "workers")], **common))
        with distributed.Client(address) as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT)
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()


def test_energy_loss_grid_runs_on_workers_without_the_checkout(cluster):
    configs = [el.RunConfig("implicit", "", None, 0.01, 0.2), el.RunConfig("dart_native", "fcl", 40, 0.01, 0.2),
               el.RunConfig("exact", "", 40, 1e-3, 0.2)]
    records = el.execute([("N", c) for c in configs], scheduler=cluster, progress=False)
    assert set(records) == set(configs)
    for config in configs:
        assert records[config].applicable, records[config].note
        np.testing.assert_array_equal(records[config].kinetic, el.run(config).kinetic)


def test_grasp_grid_runs_on_workers_without_the_checkout(cluster, tmp_path):
    cells = dict(xs=(0, 19), ys=(-1,), trials=1, out=tmp_path, progress=False, plot=False)
    shipped = grasp.study(scheduler=cluster, **cells)
    assert shipped.ran == 2
    assert all(r["kind"] != "run error" for r in shipped.rows), [r["reason"] for r in shipped.rows]
    here = {(c.x_mm, c.y_mm): grasp.run_trial(c) for c in grasp.plan(xs=(0, 19), ys=(-1,), trials=1)}
    for row in shipped.rows:
        local = here[(int(row["x_mm"]), int(row["y_mm"]))]
        assert row["kind"] == local["kind"] and int(row["steps"]) == local["steps"]
        assert float(row["part_x_mm"]) == local["part_x_mm"] and float(row["part_y_mm"]) == local["part_y_mm"]

"""Where a study's independent runs execute: in this process, a local process pool, or Dask.

A study is a list of small frozen configs and a top-level ``run(config) -> record`` function, so
that both executors can pickle them. ``completed`` yields (config, record) as runs finish; a run
that raises becomes ``failed(config, error)`` (one failed configuration must not discard the
others). A user who outgrows one machine passes a Dask scheduler address instead of rewriting.

On Dask, the scheduler (it unpickles the task graph) and the workers need to import the study's
modules, which live in this checkout (``scenes/``, ``comparisons/``), not in the installed package.
``completed`` ships them: their sources are uploaded to the scheduler and to every worker's nanny
(distributed's ``UploadDirectory`` plugin, which also reaches workers that join later) and the
workers are restarted with the upload on their path. A cluster needs only ``pip install
'.[cluster]'`` of this project on its machines.
"""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import shutil
import tempfile
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[1]
SHIPPED = ("scenes", "comparisons")  # the checkout's packages a study's runs import


def completed(run, configs, failed, scheduler=None, max_workers=None):
    """Yield (config, record) as runs finish.

    scheduler: a Dask scheduler address ("tcp://host:8786"), else local. max_workers: local
    processes (default os.cpu_count(); 0 runs in this process). The pool uses "spawn" so workers
    start clean of the parent's dartpy state."""
    if scheduler:
        try:
            from dask.distributed import Client, as_completed
        except ImportError as error:
            raise ImportError("--scheduler needs dask.distributed: pip install '.[cluster]'") from error
        with Client(scheduler) as client:
            ship_checkout(client)
            futures = {client.submit(run, c, pure=False): c for c in configs}
            for future in as_completed(futures):
                yield futures[future], _result(future, futures[future], failed)
        return
    workers = (os.cpu_count() or 1) if max_workers is None else int(max_workers)
    if workers < 0:
        raise ValueError(f"max_workers must be >= 0 (0: run in this process), got {max_workers!r}")
    if workers == 0:
        for config in configs:
            try:
                record = run(config)
            except Exception as error:  # noqa: BLE001 - reported as a failed record
                record = failed(config, error)
            yield config, record
        return
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        futures = {pool.submit(run, c): c for c in configs}
        for future in concurrent.futures.as_completed(futures):
            yield futures[future], _result(future, futures[future], failed)


def ship_checkout(client) -> None:
    """Upload the sources of SHIPPED to the client's scheduler and workers, on their sys.path.

    The workers restart (once per call) so that their processes start with the upload on their
    path; a worker that joins later gets it from its nanny. Nothing but .py sources is sent."""
    from distributed.diagnostics.plugin import UploadDirectory

    with tempfile.TemporaryDirectory() as tmp:
        stage = Path(tmp) / "implicit_contact_checkout"
        for name in SHIPPED:
            shutil.copytree(CHECKOUT / name, stage / name,
                            ignore=shutil.ignore_patterns("__pycache__", "out", "*.pyc"))
        plugin = UploadDirectory(str(stage), mode="all", update_path=True, restart_workers=True)
    client.register_plugin(plugin)


def _result(future, config, failed):
    try:
        return future.result()
    except Exception as error:  # noqa: BLE001 - reported as a failed record
        return failed(config, error)

"""Shared pieces of the fleet tests: a real ``dask scheduler`` + ``dask worker`` pair."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def dask_command() -> list[str]:
    """The ``dask`` command of this interpreter's environment."""
    exe = Path(sys.executable).with_name("dask")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "dask"]


def start_scheduler_and_worker(folder: Path) -> tuple[str, list[Any]]:
    """Start ``dask scheduler`` (127.0.0.1, a free port) and one ``dask worker`` process
    as subprocesses; return the scheduler address and the processes.

    The address comes from the scheduler file the scheduler writes; the client waits
    for the worker (``Client.wait_for_workers``), so nothing here sleeps blindly.
    """
    from distributed import Client

    sched_file = folder / "scheduler.json"
    procs = [subprocess.Popen(
        [*dask_command(), "scheduler", "--host", "127.0.0.1", "--port", "0",
         "--no-dashboard", "--scheduler-file", str(sched_file)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    deadline = time.monotonic() + 60
    while not sched_file.is_file():
        if procs[0].poll() is not None or time.monotonic() > deadline:
            stop(procs)
            raise RuntimeError("dask scheduler did not start")
        time.sleep(0.05)
    address = json.loads(sched_file.read_text())["address"]
    procs.append(subprocess.Popen(
        [*dask_command(), "worker", address, "--nworkers", "1", "--nthreads", "1",
         "--no-nanny", "--no-dashboard", "--host", "127.0.0.1"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    with Client(address, timeout=60, set_as_default=False) as c:
        c.wait_for_workers(1, timeout=120)
    return address, procs


def stop(procs: list[Any]) -> None:
    """Terminate the processes (worker first), then wait for them."""
    for p in reversed(procs):
        if p.poll() is None:
            p.terminate()
    for p in reversed(procs):
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()

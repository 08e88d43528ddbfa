"""Studies on Ray: a two-node cluster on 127.0.0.1 started with the documented ``ray start``
commands, a worker killed mid-study, and a final table equal to an undisturbed run's."""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import pandas as pd
import pytest
import yaml

from ebus_env.study import load_study, read_results
from ebus_env.study.backends import run_study

try:
    import ray  # noqa: F401
except ImportError:
    if os.environ.get("EBUS_REQUIRE_RAY"):
        raise  # CI installs the 'scale' extra: a missing Ray is a failure there
    pytest.skip("ray not installed (pip install -e '.[scale]')", allow_module_level=True)
TESTS = Path(__file__).parent
RAY = str(Path(sys.executable).parent / "ray")
from tests.test_study import small  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def two_node_cluster(env: dict):
    """A head node and a second node joining it at 127.0.0.1, one CPU each (the commands of
    docs/study.md, with both nodes on loopback); both stopped, by their own process groups, on
    exit."""
    port = _free_port()
    address = f"127.0.0.1:{port}"
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths
    head = ["--head", f"--port={port}", f"--temp-dir={temp}", "--node-ip-address=127.0.0.1",
            "--include-dashboard=false"]
    procs = []
    try:
        for n, args in enumerate((head, [f"--address={address}", "--node-ip-address=127.0.0.1"]),
                                 start=1):
            procs.append(subprocess.Popen([RAY, "start", *args, "--num-cpus=1", "--block"],
                                          env=env, start_new_session=True,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            _wait(lambda n=n: _active_nodes(address, env) == n, f"node {n}")
        yield address
    finally:
        for p in reversed(procs):
            os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        shutil.rmtree(temp, ignore_errors=True)


def _active_nodes(address: str, env: dict) -> int:
    out = subprocess.run([RAY, "status", f"--address={address}"], env=env, capture_output=True,
                         text=True)
    if out.returncode != 0 or "Active:" not in out.stdout:
        return 0
    return out.stdout.split("Active:")[1].split("Pending:")[0].count(" node_")


def _wait(ready, what: str, limit_s: float = 120.0) -> None:
    t0 = time.monotonic()
    while not ready():
        if time.monotonic() - t0 > limit_s:
            raise TimeoutError(f"the Ray {what} did not come up within {limit_s:.0f} s")
        time.sleep(1.0)


@pytest.mark.slow
def test_a_worker_killed_mid_study_is_retried_and_the_table_is_complete(tmp_path,
                                                                       monkeypatch):
    data = small(**{"infrastructure.terminal_chargers": [1, 2, 3],
                    "infrastructure.site_limit_kw": [400, 600], "days.count": 1})
    data["strategies"] = [{"name": "held", "policy": "study_faults:die_once"}]
    study = tmp_path / "study.yaml"
    study.write_text(yaml.safe_dump(data))
    monkeypatch.syspath_prepend(str(TESTS))  # study_faults, also when this test runs alone
    undisturbed = run_study(load_study(study), tmp_path / "in_process", say=lambda _: None)
    marker = tmp_path / "killed"
    # the cluster's own token for every node and the driver: the machine may have none in
    # ~/.ray/auth_token, and a test must not write one there
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS.parent), str(TESTS)]),
           "EBUS_STUDY_KILL_MARKER": str(marker), "RAY_USAGE_STATS_ENABLED": "0",
           "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    with two_node_cluster(env) as address:
        run = subprocess.run([sys.executable, "-c", "from ebus_env.cli import app; app()",
                              "study", str(study), "--out", str(tmp_path / "on_ray"),
                              "--address", address], env=env, capture_output=True, text=True,
                             timeout=400)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert marker.exists()  # a worker did die, at the study's second policy build
    on_ray = read_results(tmp_path / "on_ray")
    assert len(on_ray) == len(undisturbed) == 6
    pd.testing.assert_frame_equal(on_ray.drop(columns="site_load_kw"),
                                  undisturbed.drop(columns="site_load_kw"))
    for a, b in zip(on_ray["site_load_kw"], undisturbed["site_load_kw"], strict=True):
        assert a.tolist() == b.tolist()
    assert (tmp_path / "on_ray" / "report.html").exists()

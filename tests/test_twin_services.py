"""The twin with real services: PostgreSQL, a Mosquitto broker that checks credentials, the
twin killed with SIGKILL mid-replay and restarted, and ``ebus twin serve`` with its jobs on a
two-node Ray cluster. Each service runs on 127.0.0.1 in a temporary folder. (The dashboard
in headless Chromium: tests/test_twin_pipeline.py, with the alarms the pipeline raised.)"""

from __future__ import annotations

import json
import os
import secrets
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa

if not os.environ.get("EBUS_REQUIRE_TWIN_SERVICES"):  # CI: missing fails, not skips
    pytest.importorskip("fastapi")
from ebus_env import paths  # noqa: E402
from ebus_env.twin import Twin, open_store  # noqa: E402
from ebus_env.twin.ingest import from_log_file  # noqa: E402
from ebus_env.twin.store import batches, samples  # noqa: E402
from ebus_env.twin.tokens import create  # noqa: E402
from tests.twin_services import free_port, mosquitto, postgres, serve  # noqa: E402

FLEET = paths.here_or_shipped("data/twin_fleet")
T0 = 1_746_424_800.0


def batch(n: int, t0: float = T0, batch_id: str | None = None) -> dict:
    rows = [{"t": t0 + i, "speed_kmh": 10.0, "soc_pct": 80.0 - 0.01 * i} for i in range(n)]
    return {"samples": rows, **({"batch_id": batch_id} if batch_id else {})}


def test_the_same_schema_and_semantics_on_postgresql(tmp_path):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext
    from fastapi.testclient import TestClient

    from ebus_env.twin.server import create_app
    from ebus_env.twin.store import metadata

    with postgres(tmp_path) as url:
        store = open_store(url)
        open_store(url)  # a second process's start: the migration is there, nothing to do
        with store.engine.connect() as conn:
            assert compare_metadata(MigrationContext.configure(conn), metadata) == []
        token = create(store, fleet="north", bus="bus-01")
        twin = Twin(store)
        client = TestClient(create_app(twin))
        head = {"Authorization": f"Bearer {token}"}
        # the same batch from two senders at once: stored once
        answers = []
        threads = [threading.Thread(target=lambda: answers.append(client.post(
            "/v1/buses/bus-01/samples", json=batch(50, batch_id="x"), headers=head).json()))
            for _ in range(4)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        assert sorted(a["status"] for a in answers) == ["duplicate"] * 3 + ["stored"]
        bad = client.post("/v1/buses/bus-01/samples", headers=head,
                          json={"samples": [{"t": T0 + 60, "speed_kmh": 1, "soc_pct": -3}]})
        assert bad.status_code == 422 and bad.json()["row"] == 1
        assert len(twin.samples("bus-01")) == 50
        store.engine.dispose()


def test_loggers_publish_over_mqtt_to_a_broker_that_checks_them(tmp_path):
    from ebus_env.twin.mqtt_bridge import Subscriber, publish

    users = {"twin": secrets.token_hex(8), "bus-01": secrets.token_hex(8),
             "bus-02": secrets.token_hex(8)}
    store = open_store(tmp_path / "twin.sqlite")
    for bus in ("bus-01", "bus-02"):
        create(store, fleet="north", bus=bus)
    twin = Twin(store)
    with mosquitto(tmp_path, users) as address:
        sub = Subscriber(twin, address, "twin", users["twin"])
        sub.start()
        assert sub.connected.wait(30)
        publish(address, "bus-01", json.dumps(batch(10, batch_id="m1")), "bus-01",
                users["bus-01"])
        csv = "t,speed_kmh,soc_pct\n" + "".join(f"{T0 + 10 + i},5,79\n" for i in range(5))
        publish(address, "bus-01", csv, "bus-01", users["bus-01"])
        publish(address, "bus-01", json.dumps(batch(10, batch_id="m1")), "bus-01",
                users["bus-01"])  # a logger's resend: stored once
        publish(address, "bus-01", '{"samples": [{"t": 1746424900, "speed_kmh": -4}]}',
                "bus-01", users["bus-01"])
        # the broker's ACL: bus-01's credentials cannot write bus-02's topic
        publish(address, "bus-02", json.dumps(batch(10, T0 + 500)), "bus-01", users["bus-01"])
        with pytest.raises(Exception):  # noqa: B017 - the broker refuses a wrong password
            publish(address, "bus-01", json.dumps(batch(3, T0 + 900)), "bus-01", "wrong",
                    timeout_s=5)
        _until(lambda: len(sub.refused) == 1 and len(twin.samples("bus-01")) == 15)
        sub.stop()
        # the twin away: the broker keeps its messages (persistent session, QoS 1)
        publish(address, "bus-02", json.dumps(batch(20, T0 + 1000)), "bus-02",
                users["bus-02"])
        again = Subscriber(twin, address, "twin", users["twin"])
        again.start()
        _until(lambda: len(twin.samples("bus-02")) == 20)
        again.stop()
    assert len(twin.samples("bus-01")) == 15
    assert sub.refused[0]["field"] == "speed_kmh" and sub.refused[0]["row"] == 1
    assert twin.samples("bus-02")["t"].min() == T0 + 1000  # not bus-01's forged batch


def _until(ready, limit_s: float = 30.0) -> None:
    t0 = time.monotonic()
    while not ready():
        if time.monotonic() - t0 > limit_s:
            raise TimeoutError("condition not met")
        time.sleep(0.1)


@pytest.mark.slow
def test_kill_9_mid_replay_of_20_buses_loses_no_acknowledged_sample(tmp_path):
    """20 loggers stream batches as fast as the twin takes them; the twin is killed with
    SIGKILL mid-stream and started again; the loggers re-send what was not acknowledged.
    The stored samples are exactly the acknowledged ones, and every stored batch is whole."""
    from ebus_env.twin.replay import Sender, batches_of

    db = tmp_path / "twin.sqlite"
    store = open_store(db)
    logs = sorted(FLEET.glob("bus-*/*.csv.gz"))[:20]
    assert len(logs) == 20
    tokens = {f"r{i:02d}": create(store, fleet="f", bus=f"r{i:02d}") for i in range(20)}
    store.engine.dispose()
    port = free_port()
    proc = serve(str(db), port, "--no-jobs")
    acked: dict[str, list] = {bus: [] for bus in tokens}
    retries = []
    stop = threading.Event()

    def logger(bus: str, log: Path):
        sender = Sender(f"http://127.0.0.1:{port}", bus, tokens[bus], give_up_s=180)
        frame = from_log_file(log).iloc[:3000]
        for part in batches_of(frame, 10.0):
            if stop.is_set():
                break
            answer = sender.batch(f"{bus}:{part['t'].iloc[0]:.0f}", part)
            acked[bus].append((answer["batch_id"], part["t"].to_numpy()))
        retries.append(sender.retries)
        sender.close()

    threads = [threading.Thread(target=logger, args=(bus, log))
               for bus, log in zip(tokens, logs, strict=True)]
    for th in threads:
        th.start()
    _until(lambda: sum(map(len, acked.values())) > 300, 120)
    os.killpg(proc.pid, signal.SIGKILL)  # mid-batch: 20 loggers are sending
    proc.wait()
    killed_at = sum(map(len, acked.values()))
    time.sleep(1.0)
    proc = serve(str(db), port, "--no-jobs")
    try:
        for th in threads:
            th.join(timeout=300)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)
    assert sum(retries) > 0  # answers were lost in the kill, and re-sent
    assert sum(map(len, acked.values())) == 20 * 300 > killed_at
    store = open_store(db)
    with store.engine.connect() as conn:
        ids = dict(conn.execute(sa.text("select name, id from buses")).all())
        per_batch = conn.execute(sa.select(samples.c.bus_id, samples.c.batch_id,
                                           sa.func.count()).group_by(
            samples.c.bus_id, samples.c.batch_id)).all()
        rows = {(r.bus_id, r.batch_id): r.n_new for r in conn.execute(sa.select(batches))}
    for bus, sent in acked.items():
        got = np.sort(Twin(store).samples(bus, columns=())["t"].to_numpy())
        want = np.sort(np.concatenate([t for _, t in sent]))
        np.testing.assert_array_equal(got, want)
    # no partial batch: each stored batch has all the samples its row says it brought
    assert all(rows[(bus_id, batch_id)] == count for bus_id, batch_id, count in per_batch)
    assert len(rows) == 20 * 300 and set(ids) == set(tokens)


@pytest.mark.slow
def test_the_twin_serves_with_its_jobs_on_a_two_node_ray_cluster(tmp_path):
    """``ebus twin serve --ray --address`` on a two-node cluster on 127.0.0.1 (the twin in a
    process of its own with the cluster's token, as a deployment runs it): a bus's logger
    streams a little over an hour of its day (one window re-fit's worth: ``refit_every_min``
    is 60); the bus's window re-fit runs as a Ray task and is stored."""

    import httpx

    if not os.environ.get("EBUS_REQUIRE_RAY") and not os.environ.get(
            "EBUS_REQUIRE_TWIN_SERVICES"):
        pytest.importorskip("ray")
    from ebus_env.twin.replay import Sender, batches_of
    from tests.test_study_ray import two_node_cluster

    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(root / "tests")]),
           "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token",
           "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    db = tmp_path / "twin.sqlite"
    store = open_store(db)
    token = create(store, fleet="f", bus="bus-01")
    store.engine.dispose()
    day = from_log_file(FLEET / "bus-01" / "2025-05-05.csv.gz").iloc[:3700]
    with two_node_cluster(env) as address:
        port = free_port()
        proc = serve(str(db), port, "--ray", "--address", address, env=env)
        try:
            sender = Sender(f"http://127.0.0.1:{port}", "bus-01", token)
            for part in batches_of(day, 600.0):
                sender.batch(f"b{part['t'].iloc[0]:.0f}", part)
            sender.close()
            health = {}

            def fitted():
                health.update(httpx.get(f"http://127.0.0.1:{port}/healthz").json())
                return health["jobs"]["ray"]["tasks"] >= 1 and health["jobs"]["waiting"] == 0

            _until(fitted, 600)
        finally:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=60)
    assert health["jobs"]["ray"]["nodes"] == 2 and health["jobs"]["failed"] == 0, health
    assert health["jobs"]["workers"] == 2  # one per CPU of the cluster
    fit = Twin(open_store(db)).bus("bus-01")["fits"]
    assert [f["kind"] for f in fit] == ["window"]
    assert fit[0]["t_to"] == pytest.approx(float(day["t"].iloc[-1]))
    assert fit[0]["nrmse"] < 0.05
    assert set(fit[0]["values"]) >= {"auxiliaries.base_power_w", "passenger_load.load_frac"}

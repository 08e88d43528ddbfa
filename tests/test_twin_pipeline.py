"""The twin end to end on the shipped made-up fleet: days replayed through the whole pipeline
(ingest in 10-minute batches, the jobs after each: day closing, re-fits, predictions,
diagnoses), and the alarms it raises by itself, read where an operator reads them (the API
and the dashboard in headless Chromium). Slow: each test replays whole service days."""

from __future__ import annotations

import json
import os
import threading
import time

import numpy as np
import pytest

if not os.environ.get("EBUS_REQUIRE_TWIN_SERVICES"):  # CI: missing fails, not skips
    pytest.importorskip("fastapi")
from ebus_env import paths  # noqa: E402
from ebus_env.twin import Twin, open_store  # noqa: E402
from ebus_env.twin.ingest import from_log_file  # noqa: E402
from ebus_env.twin.jobs import Jobs, JobSettings  # noqa: E402
from ebus_env.twin.replay import batches_of  # noqa: E402
from ebus_env.twin.tokens import create  # noqa: E402
from tests.twin_services import free_port, need  # noqa: E402

FLEET = paths.here_or_shipped("data/twin_fleet")
RESERVE_PCT = 30.0


def replay_days(twin: Twin, jobs: Jobs, bus: str, days: list[str]) -> None:
    """``bus``'s logs of ``days`` through the pipeline: its block first, then its samples in
    10-minute batches, the bus's jobs run after each (as the jobs thread would)."""
    for day in days:
        twin.store.put_schedule(bus, day, json.loads(
            (FLEET / bus / f"{day}.block.json").read_text()))
        for part in batches_of(from_log_file(FLEET / bus / f"{day}.csv.gz"), 600.0):
            twin.ingest(bus, part)
            jobs.run_bus(bus)
    assert not jobs.errors, jobs.errors


@pytest.fixture(scope="module")
def reserve_days(tmp_path_factory):
    """bus-05's last two days through the pipeline (no diagnosis): on 2025-05-07 it ends at
    38 %, on 2025-05-08 it runs below its 30 % reserve before its block ends."""
    store = open_store(tmp_path_factory.mktemp("reserve") / "twin.sqlite")
    create(store, fleet="north", bus="bus-05", reserve_soc_pct=RESERVE_PCT)
    twin = Twin(store)
    jobs = Jobs(twin, JobSettings(diagnose=False, predict_every_s=900.0))
    replay_days(twin, jobs, "bus-05", ["2025-05-07", "2025-05-08"])
    return twin


def first_below(bus: str, day: str) -> float | None:
    """When the logged SoC first went below the reserve [UTC epoch s], within the block."""
    log = from_log_file(FLEET / bus / f"{day}.csv.gz")
    below = log["t"][log["soc_pct"] < RESERVE_PCT]
    return None if below.empty else float(below.iloc[0])


@pytest.mark.slow
def test_the_pipeline_raises_the_reserve_alarm_before_the_bus_runs_below_it(reserve_days):
    twin = reserve_days
    alarms = [a for a in twin.alarms("bus-05") if a["kind"] == "reserve"]
    assert first_below("bus-05", "2025-05-07") is None  # the day it makes it: no alarm
    assert [a["day"] for a in alarms] == ["2025-05-08"], alarms
    alarm = alarms[0]
    crossed = first_below("bus-05", "2025-05-08")
    assert crossed is not None
    # known before it happened, by the lead it says (within the 10-s prediction grid)
    assert alarm["data_t"] < crossed and alarm["lead_s"] > 0
    assert abs(alarm["data_t"] + alarm["lead_s"] - crossed) < 3600.0
    assert "will run below its 30 % reserve" in alarm["message"]
    # the bus was fitted by then, and predicted along its block, stored for the dashboard
    page = twin.bus("bus-05")
    assert {f["kind"] for f in page["fits"]} == {"window", "cross-day"}
    assert page["prediction"] is not None


@pytest.mark.slow
def test_the_dashboard_shows_the_alarm_the_pipeline_raised_and_a_bus_going_live(
        reserve_days, tmp_path):
    """In headless Chromium: the fleet page lists the replayed bus with the reserve alarm the
    pipeline raised; a second bus's logger starts and the page shows it live without a
    reload; the bus page draws its measured SoC and lists the alarm."""
    import uvicorn

    from ebus_env.twin.replay import replay
    from ebus_env.twin.server import create_app

    browser = need("chromium", "/usr/bin/chromium")
    driver_path = need("chromedriver", "/usr/bin/chromedriver")
    if not os.environ.get("EBUS_REQUIRE_TWIN_SERVICES"):
        pytest.importorskip("selenium")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    twin = Twin(reserve_days.store)
    write = create(twin.store, fleet="north", bus="bus-02")
    read = create(twin.store, fleet="north")
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(twin), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"):
        options.add_argument(flag)
    chrome = webdriver.Chrome(service=Service(driver_path), options=options)
    try:
        t0 = time.monotonic()
        while not server.started:
            assert time.monotonic() - t0 < 30
            time.sleep(0.1)
        chrome.get(f"http://127.0.0.1:{port}/?fleet=north&token={read}")
        waiter = WebDriverWait(chrome, 30)

        def wait(ready):
            try:
                return waiter.until(ready)
            except Exception:  # the page as it was, when a wait fails
                raise AssertionError(chrome.find_element(By.TAG_NAME, "body").text[:2000]) \
                    from None

        def text(css: str) -> str:
            """An element's text read in one script call: the page rebuilds its rows on every
            update, so an element found in one call may be gone by the next."""
            return chrome.execute_script(
                "const e = document.querySelector(arguments[0]); return e ? e.innerText : '';",
                css)

        wait(lambda d: "2 buses" in text("#status"))
        wait(lambda d: "below its 30 % reserve" in text("tr[data-bus=bus-05] .latest-alarm"))
        assert text("tr[data-bus=bus-02] .state") == "no data"
        counts = replay([FLEET / "bus-02" / "2025-05-08.csv.gz"], "bus-02",
                        f"http://127.0.0.1:{port}", write, speed=1e5, limit_s=3.0)
        assert counts["samples"] > 0, counts
        wait(lambda d: text("tr[data-bus=bus-02] .state") in ("live", "stale"))
        soc = text("tr[data-bus=bus-02] .soc")
        assert soc.endswith("%") and 0 < float(soc.split()[0]) <= 100
        chrome.get(f"http://127.0.0.1:{port}/bus/bus-05")
        wait(lambda d: int(chrome.execute_script(
            "return document.getElementById('soc').getAttribute('data-points')") or 0) > 0)
        wait(lambda d: "reserve" in text("#alarms"))
    finally:
        chrome.quit()
        server.should_exit = True
        thread.join(timeout=30)


@pytest.mark.slow
def test_a_fault_that_starts_on_a_day_raises_the_diagnosis_alarm(tmp_path):
    """bus-03's brake-air system starts leaking on 2025-05-07 (data/twin_fleet/SOURCE.md):
    its days replayed through the pipeline with diagnoses; the alarm comes for that day, not
    for the sound day before it, and says what changed."""
    store = open_store(tmp_path / "twin.sqlite")
    create(store, fleet="north", bus="bus-03")
    twin = Twin(store)
    jobs = Jobs(twin, JobSettings(predict_every_s=np.inf))
    replay_days(twin, jobs, "bus-03", ["2025-05-05", "2025-05-06", "2025-05-07"])
    page = twin.bus("bus-03")
    assert [d["day"] for d in page["diagnoses"]] == ["2025-05-05", "2025-05-06", "2025-05-07"]
    # the first day is the bus's normal day: measured, what the model misses there said
    assert page["diagnoses"][0]["finding"] == "normal day"
    assert "held-out NRMSE" in page["diagnoses"][0]["why"]
    alarms = [a for a in page["alarms"] if a["kind"] == "diagnosis"]
    assert [a["day"] for a in alarms] == ["2025-05-07"], (alarms, page["diagnoses"])
    assert "changed on 2025-05-07" in alarms[0]["message"]

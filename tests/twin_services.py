"""Real services for the twin's tests, each on 127.0.0.1 in a temporary folder, stopped after:
a PostgreSQL cluster (initdb, pg_ctl), a Mosquitto broker with a password file and an ACL,
and the twin itself (``ebus twin serve`` as a subprocess, to be killed with SIGKILL).

Where a service is missing the test is skipped, or fails where CI requires it
(``EBUS_REQUIRE_TWIN_SERVICES``: ``.ci/run`` installs them)."""

from __future__ import annotations

import glob
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def need(tool: str, *candidates: str) -> str:
    found = shutil.which(tool) or next((c for c in candidates if Path(c).exists()), None)
    if found:
        return found
    if os.environ.get("EBUS_REQUIRE_TWIN_SERVICES"):
        pytest.fail(f"{tool} is required here (EBUS_REQUIRE_TWIN_SERVICES) but not installed")
    pytest.skip(f"{tool} not installed")


def wait_port(port: int, limit_s: float = 60.0, proc=None) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit_s:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"the service exited with {proc.returncode}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {limit_s:.0f} s")


def _open_dir(prefix: str) -> Path:
    """A temporary folder under /tmp that a service's own user can use."""
    folder = Path(tempfile.mkdtemp(prefix=prefix, dir="/tmp"))
    folder.chmod(0o777)
    return folder


def _pg_bin(name: str) -> str:
    return need(name, *sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"), reverse=True))


@contextmanager
def postgres(tmp: Path):
    """A PostgreSQL cluster of its own; yields its URL. Run as a non-root user where the
    tests run as root (PostgreSQL refuses root)."""
    initdb, pg_ctl = _pg_bin("initdb"), _pg_bin("pg_ctl")
    tmp = _open_dir("twin-pg-")  # the server's user must reach it (pytest's are 0700)
    data = tmp / "pg"
    port = free_port()
    as_user: list[str] = []
    if os.geteuid() == 0:
        import pwd

        user = "postgres"
        try:
            pwd.getpwnam(user)
        except KeyError:
            subprocess.run(["useradd", "--system", "--no-create-home", user], check=True)
        as_user = ["runuser", "-u", user, "--"]
    data.mkdir()
    if as_user:
        shutil.chown(data, "postgres")
    subprocess.run([*as_user, initdb, "-D", str(data), "-U", "twin", "--auth=trust", "-E",
                    "UTF8"], check=True, capture_output=True)
    log = tmp / "pg.log"
    log.touch()
    if as_user:
        shutil.chown(log, "postgres")
    subprocess.run([*as_user, pg_ctl, "-D", str(data), "-l", str(log), "-w", "-o",
                    f"-c listen_addresses=127.0.0.1 -p {port} -k {data}", "start"], check=True,
                   capture_output=True)
    try:
        subprocess.run([*as_user, shutil.which("createdb") or _pg_bin("createdb"), "-h",
                        "127.0.0.1", "-p", str(port), "-U", "twin", "twin"], check=True,
                       capture_output=True)
        yield f"postgresql://twin@127.0.0.1:{port}/twin"
    finally:
        subprocess.run([*as_user, pg_ctl, "-D", str(data), "-m", "immediate", "-w", "stop"],
                       capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def mosquitto(tmp: Path, users: dict[str, str]):
    """A Mosquitto broker on 127.0.0.1 that checks credentials: ``users`` (name ->
    password); the user ``twin`` reads every bus's topic, any other user writes only
    ``fleet/<its name>/telemetry``. Yields ``host:port``."""
    broker = need("mosquitto", "/usr/sbin/mosquitto")
    passwd = need("mosquitto_passwd", "/usr/bin/mosquitto_passwd")
    port = free_port()
    tmp = _open_dir("twin-mqtt-")  # mosquitto started as root runs as its own user
    pw = tmp / "passwd"
    for i, (user, password) in enumerate(users.items()):
        subprocess.run([passwd, *(["-c"] if i == 0 else []), "-b", str(pw), user, password],
                       check=True, capture_output=True)
    acl = tmp / "acl"
    acl.write_text("user twin\ntopic read fleet/+/telemetry\n\n"
                   "pattern write fleet/%u/telemetry\n")
    conf = tmp / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous false\n"
                    f"password_file {pw}\nacl_file {acl}\npersistence true\n"
                    f"persistence_location {tmp}/\nmax_queued_messages 100000\n")
    for f in (pw, acl, conf):
        f.chmod(0o644)
    proc = subprocess.Popen([broker, "-c", str(conf)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        wait_port(port, proc=proc)
        yield f"127.0.0.1:{port}"
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
        shutil.rmtree(tmp, ignore_errors=True)


def serve(db: str, port: int, *extra: str, env: dict | None = None) -> subprocess.Popen:
    """``ebus twin serve`` as a subprocess in its own process group."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "from ebus_env.cli import app; app()", "twin", "serve", "--db",
         db, "--port", str(port), *extra], cwd=ROOT, start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env={**os.environ, **(env or {})})
    try:
        wait_port(port, 120.0, proc)
    except Exception:
        proc.kill()
        raise RuntimeError(proc.stderr.read().decode()[-3000:]) from None
    return proc

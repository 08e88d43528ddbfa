"""A policy for the Ray fault test (a helper module, not a test).

It holds the baseline settings. Built while ``$EBUS_STUDY_KILL_AFTER`` names a rows folder that
already holds a finished scenario and ``$EBUS_STUDY_KILL_MARKER`` names a file that does not
exist yet, it creates that file and kills its own process with SIGKILL, as a crashed worker
would: exactly once per study, in the middle of it.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np

from ebus_env.envs.spec import ACTION_LOW, ACTION_SPAN, ACTIONS
from ebus_env.study.spec import BASELINE


class Hold:
    """The baseline's settings at every decision, as normalised actions."""

    def predict(self, obs, deterministic=True):
        values = np.array([BASELINE[a.name] for a in ACTIONS])
        return np.tile(2.0 * (values - ACTION_LOW) / ACTION_SPAN - 1.0, (len(obs), 1)), None


def die_once() -> Hold:
    rows, marker = os.environ.get("EBUS_STUDY_KILL_AFTER"), os.environ.get(
        "EBUS_STUDY_KILL_MARKER")
    if rows and marker and any(Path(rows).glob("*.parquet")):
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return Hold()
        os.kill(os.getpid(), signal.SIGKILL)
    return Hold()

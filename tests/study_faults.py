"""A policy for the Ray fault test (a helper module, not a test).

It holds the baseline settings. Built for the second time in a study (``$EBUS_STUDY_KILL_MARKER``
names a file that does not exist yet; a first build leaves ``<marker>.first``), it creates that
file and kills its own process with SIGKILL, as a crashed worker would: exactly once per study,
in the middle of it, however the scenarios are scheduled (waiting for a finished scenario's rows
raced with a loaded machine starting every scenario first).
"""

from __future__ import annotations

import os
import signal

import numpy as np

from ebus_env.envs.common import ACTION_LOW, ACTION_SPAN, ACTIONS
from ebus_env.study.study_file import BASELINE


class Hold:
    """The baseline's settings at every decision, as normalised actions."""

    def predict(self, obs, deterministic=True):
        values = np.array([BASELINE[a.name] for a in ACTIONS])
        return np.tile(2.0 * (values - ACTION_LOW) / ACTION_SPAN - 1.0, (len(obs), 1)), None


def _created(path: str) -> bool:
    """Create ``path`` if it does not exist (atomically); whether this call created it."""
    try:
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


def die_once() -> Hold:
    marker = os.environ.get("EBUS_STUDY_KILL_MARKER")
    if marker and not _created(marker + ".first") and _created(marker):
        os.kill(os.getpid(), signal.SIGKILL)
    return Hold()

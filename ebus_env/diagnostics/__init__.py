"""Diagnostics: compare the model with measurements, see where it fails, learn which physical
effect is missing, add it and watch the error fall.

1. :mod:`~ebus_env.diagnostics.residual`: the battery power the model misses, window by window,
   the model restarted from the measured SoC at each window; by operating mode and by bins.
2. :mod:`~ebus_env.diagnostics.quality`: deviations the log cannot have physically (data
   problems, not model problems); their windows are left out.
3. :mod:`~ebus_env.diagnostics.candidates`: what each registered effect the model lacks, and
   each parameter of the effects it has, would add along the trip (its signature).
4. :mod:`~ebus_env.diagnostics.attribution`: which signature explains the missing power on
   held-out windows (robust, cross-validated, sparse), and the verdict, decided by a block
   bootstrap over the windows; the strength with its interval
   (:func:`~ebus_env.diagnostics.candidates.estimate_strength`). With a calibration, a
   strength at a bound, a tie of two effects and a day no effect explains are settled by
   re-calibrating the bus with the effect (:mod:`~ebus_env.diagnostics.stage07_bound`,
   :mod:`~ebus_env.diagnostics.stage09_tie`, :mod:`~ebus_env.diagnostics.stage10_outside`).
5. :mod:`~ebus_env.diagnostics.clues`: what the missing power moves with, for effects the
   library lacks.
6. :mod:`~ebus_env.diagnostics.ladder`: NRMSE before and after each added effect, re-calibrated
   (the paper's parameters, the bus-to-bus ones and the effect's strength free together), on
   calibration and held-out blocks.

:func:`diagnose` runs them all, in the named stages ``stage01_intake`` ... ``stage11_ladder``
that :mod:`~ebus_env.diagnostics.pipeline` lists, each passed one run context
(:class:`~ebus_env.diagnostics.diagnosis_run.DiagnosisRun`), and returns a
:class:`~ebus_env.diagnostics.diagnosis_result.Diagnosis` (:func:`diagnose_logs` on log files,
as ``ebus diagnose``);
:mod:`~ebus_env.diagnostics.report` writes the console, JSON and HTML report;
:mod:`~ebus_env.diagnostics.hidden` makes service days with a hidden effect.
"""

from ebus_env.diagnostics.diagnose_logs import LogDiagnosis, diagnose_logs
from ebus_env.diagnostics.diagnosis_result import Diagnosis
from ebus_env.diagnostics.pipeline import diagnose

__all__ = ["Diagnosis", "LogDiagnosis", "diagnose", "diagnose_logs"]

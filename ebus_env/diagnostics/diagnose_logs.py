"""``ebus diagnose`` as one function: a thin layer over :func:`~ebus_env.diagnostics.diagnose`
that reads the logs and the reference day, holds the values the user knows, and writes the
report (HTML, JSON)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from ebus_env.bus_choice import BusChoice, input_files, split_names
from ebus_env.calibration.settings import calibration_config_file, load_calibration_config
from ebus_env.diagnostics.diagnosis_result import Diagnosis
from ebus_env.diagnostics.ladder import Freedom, as_effect, check_known
from ebus_env.diagnostics.pipeline import diagnose
from ebus_env.diagnostics.residual import PACK_SIGNALS
from ebus_env.errors import LogError
from ebus_env.inputs import check
from ebus_env.io.log_reading import LogReading, logs_in, refuse_same_log, refuse_twice
from ebus_env.outputs import HTML_SUFFIXES, JSON_SUFFIXES, check_outputs, write_with

if TYPE_CHECKING:
    from rich.console import Console


@dataclass
class LogDiagnosis:
    """What :func:`diagnose_logs` found and wrote: the diagnosis (``.result``), and the report
    files written (None: not asked for)."""

    result: Diagnosis
    html: Path | None = None
    json_path: Path | None = None


def diagnose_logs(logs, bus: str | Path | BusChoice = "12m", *, calibrate: bool = False,
                  add=(), known: dict[str, float] | None = None, reference=(),
                  window_s: float | None = None, soc_only: bool = False, domain: str = "soc",
                  config: str | Path | None = None, seed: int = 0,
                  reading: LogReading | None = None, html: str | Path | None = None,
                  json_path: str | Path | None = None,
                  console: Console | None = None) -> LogDiagnosis:
    """Where the model fails against measured logs, and which effect is missing
    (``ebus diagnose``): :func:`~ebus_env.diagnostics.diagnose` on the logs read from files,
    its report written.

    Parameters
    ----------
    logs
        Measured logs with SoC (CSV or Parquet), or folders of them: several days of one bus
        (each keeps its date where the log has date-times).
    bus
        Config name or path, or a :class:`~ebus_env.bus_choice.BusChoice`.
    calibrate
        Calibrate on the calibration blocks first (the paper's parameters and the bus-to-bus
        ones).
    add
        Effects for the error ladder, added and re-calibrated in turn: registry names or
        ``my_effects.py:Name``.
    known
        Values the user knows, by qualified name: held in every calibration (a parameter of
        an effect of ``add`` too).
    reference
        Logs of a normal day of the same bus: calibrated first, the diagnosis then says what
        the day misses beyond it (implies ``calibrate``).
    window_s
        Window length [s] (default: the diagnosis's).
    soc_only
        Diagnose from SoC alone where the logs have the pack's current too.
    domain
        ``soc`` (SoC windows), ``power`` (BMS logs second by second) or ``auto`` (the power
        domain on logs with the pack's current and voltage): see
        :func:`~ebus_env.diagnostics.diagnose`.
    config, seed
        Calibration config (its params, ranges, fixed values, iSOPT settings) and iSOPT's
        seed.
    reading
        How the logs are read (:class:`~ebus_env.io.log_reading.LogReading`).
    html, json_path
        The report as one HTML file, and as JSON.
    console
        A rich Console told what happens (the loader's changes, the stage running); None:
        nothing is said.

    Returns
    -------
    LogDiagnosis
        The :class:`~ebus_env.diagnostics.diagnosis_result.Diagnosis` and the files written.
    """
    choice, reading = BusChoice.of(bus), reading or LogReading()
    logs, reference = logs_in(logs), logs_in(reference or (), "--reference")
    html, json_path = (None if p is None else Path(p) for p in (html, json_path))
    if window_s is not None:
        check("window_s", window_s, "--window-s")
    cfg = load_calibration_config(config)
    config_bus = choice.load()
    overrides = dict(known or {})
    # unknown names and values out of bounds fail here (a --set value may be one of an
    # effect --add adds)
    check_known(config_bus, [as_effect(a) for a in split_names(add)], Freedom(fixed=overrides))
    present = {n.partition(".")[0] for n in config_bus.build().param_names}
    params: dict = {}
    for key, value in overrides.items():
        effect_name, param = key.split(".", 1)
        if effect_name in present:  # the added effects take theirs when they are added
            params.setdefault(effect_name, {})[param] = value
    if params:  # as an overlay, so that every model the diagnosis builds has them
        config_bus = config_bus.overlay({"params": params}, "--set")
    check_outputs([(html, "--html", HTML_SUFFIXES), (json_path, "--json", JSON_SUFFIXES)],
                  choice.files(config_bus) + input_files(
                      [*logs, *reference], [calibration_config_file(config)], effects=add))
    refuse_twice(logs)
    refuse_same_log("--reference", reference, logs, "the log being diagnosed", "the "
                    "reference is a normal day of the same bus, which the model is compared "
                    "against")
    model = config_bus.build()
    notes: list[str] = []
    profiles = reading.load(logs, model, model.params, console, notes)
    normal = reading.load(reference, model, model.params, console) if reference else []
    if soc_only:
        profiles = [p.without_measured(*PACK_SIGNALS) for p in profiles]
        normal = [p.without_measured(*PACK_SIGNALS) for p in normal]
    without_soc = sorted({p.name for p in [*profiles, *normal] if "soc_frac" not in p.measured})
    if without_soc:
        raise LogError(f"diagnose compares simulated with measured SoC, and the log(s) "
                       f"{', '.join(without_soc)} have none", fix="give logs with a soc_pct "
                       "(or soc_frac) column, or map it with --columns")
    with _status(console) as say:
        result = diagnose(config_bus, profiles, calibrate=calibrate, add=split_names(add),
                          window_s=window_s, settings=replace(cfg.isopt, seed=seed),
                          polish_starts=cfg.polish_starts, loader_notes=notes, progress=say,
                          freedom=Freedom.of(cfg, overrides), reference=normal or None,
                          domain=domain)
    if html:
        write_with(html, result.write_html)
    if json_path:
        write_with(json_path, result.write_json)
    return LogDiagnosis(result, html, json_path)


@contextlib.contextmanager
def _status(console: Console | None):
    """The stage running on ``console``'s status line, as a callback (None: no callback)."""
    if console is None:
        yield None
        return
    with console.status("diagnosing") as status:
        yield lambda text: status.update(text)

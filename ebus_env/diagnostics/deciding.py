"""What would decide a diagnosis the log leaves open: for each library effect that a SoC log
confuses with something else, the log columns that tell them apart, and whether this log
already has them.

Read off the truth bench (docs/validation.md, "Pairs that SoC alone cannot separate"): a
calibrated model takes up the mean of a passenger load in its curb mass and of a cold pack's
loss in its resistance; a load the model lacks looks like base load in 5-min SoC windows.
Each entry below names only what the diagnosis then uses: a logged load is replayed
(``replayed_load`` becomes a candidate, and its ``scale`` says how much of it the pack
supplies), a logged current and voltage give the pack's resistance over the day and free the
brake-blending share, passenger counts drive the passenger mass, altitude gives the grade.
Where the log has them all, nothing is asked. A weighed curb mass is not asked for: held, it
leaves the mean passenger load to the rolling resistance and drivetrain efficiency instead
(docs/validation.md).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Decider:
    """How to tell an effect from what a SoC log confuses it with: where the log lacks any of
    ``columns``, ``log`` says what to log and what the diagnosis does with it."""

    confused_with: str
    columns: tuple[str, ...]
    log: str


def _replay(what: str) -> str:
    return (f"log {what} as `logged_load_kw` (a submeter or the CAN signal): the effect "
            "`replayed_load` then tests whether it explains the missing power")


DECIDERS = {
    "cabin_hvac": Decider("a steady auxiliary load or a cold pack", ("logged_load_kw",),
                          _replay("the HVAC's electric power")),
    "aux_schedule": Decider("the cabin HVAC or the pack's temperature as the evening cools",
                            ("logged_load_kw",),
                            _replay("the switched loads' (lights, heaters) electric power")),
    "passenger_mass": Decider(
        "a heavier bus (the calibrated curb mass takes up the mean load)", ("passengers",),
        "log the passenger counts as `passengers` (automatic passenger counters): the "
        "passenger mass then follows them"),
    "ambient_battery": Decider(
        "a pack of higher resistance or a larger base load",
        ("battery_current_a", "battery_voltage_v"),
        "log the pack's current and voltage (`battery_current_a`, `battery_voltage_v`): the "
        "diagnosis then measures the resistance hour by hour, and a cold pack's falls as it "
        "warms"),
    "regen_soc_limit": Decider(
        "less regenerative braking at every SoC (the brake blending)", ("battery_current_a",),
        "log the pack's current (`battery_current_a`): the calibration then fits the bus's "
        "brake-blending share, which a SoC log leaves at its configured value"),
    "road_grade": Decider("a heavier bus or more rolling resistance", ("altitude_m",),
                          "log the altitude (`altitude_m`, GPS) or the grade (`grade_pct`): "
                          "the grade is then an input, not a guess"),
}
"""The library effects a SoC log confuses, by name."""

COLUMN_KEYS = {"passengers": "passenger_count", "logged_load_kw": "logged_load_w",
               "altitude_m": "grade_frac", "grade_pct": "grade_frac",
               "battery_current_a": "battery_current_a",
               "battery_voltage_v": "battery_voltage_v"}
"""Where a log column lands in a :class:`~ebus_env.profile.Profile` (an input channel or a
measured signal)."""

OPEN = ("tie", "outside library", "implausible")
"""The ends of a diagnosis that leave the question open."""


def logged(profiles, column: str) -> bool:
    """Whether every profile has the log column ``column``."""
    key = COLUMN_KEYS[column]
    return all(key in p.channels or key in p.measured for p in profiles)


def to_decide(status: str, effects: list[str], profiles) -> str:
    """What would decide a diagnosis that ended with ``status`` among ``effects`` (best
    first): for the effects it weighed (both of a tie, the best otherwise) the columns this
    log lacks and what the diagnosis does with them; for a load outside the library, how to
    measure it. "" where the verdict is named, or the log has it all."""
    if status not in OPEN:
        return ""
    parts, asked = [], set()
    for name in effects[:2] if status == "tie" else effects[:1]:
        decider = DECIDERS.get(name)
        if decider is not None and not all(logged(profiles, c) for c in decider.columns):
            parts.append(f"to tell {name} from {decider.confused_with}, {decider.log}")
            asked.update(decider.columns)
    if status == "outside library" and not logged(profiles, "logged_load_kw"):
        replay = ("log its electric power the same way" if "logged_load_kw" in asked
                  else _replay("its electric power"))
        parts.append(f"for a load the library lacks, {replay}, or write it as an effect of "
                     "your own (`--add file.py:Name`)")
    return "; ".join(parts) + "." if parts else ""

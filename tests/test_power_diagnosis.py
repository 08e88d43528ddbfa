"""The diagnosis of BMS logs in the power domain: the held-out test, the bus fit, and whole
days made by the project's own model with an effect hidden (in-family: the out-of-family
checks are the truth bench's)."""

from __future__ import annotations

import datetime
from dataclasses import replace

import numpy as np
import pytest

from ebus_env.diagnostics import hidden
from ebus_env.diagnostics.heldout import HeldOut, Nuisance, fit_all, margin
from ebus_env.diagnostics.power import (
    MODES,
    TRACE,
    Bins,
    _logged_seconds,
    _steps,
    anchored_runs,
    log_power,
    log_voltage,
    logger_lag,
    logs_power,
    make_bins,
)
from ebus_env.diagnostics.power_candidates import Form, switched_on
from ebus_env.diagnostics.power_fit import (
    _dead,
    _signatures,
    counted_capacity_ah,
    fit_bus,
    search_box,
    sensor_columns,
)
from ebus_env.diagnostics.power_path import (
    BEYOND_SURE,
    MIN_OUTSIDE_KW,
    bound_reached,
    decide,
    diagnose_power,
    needed,
    outside_kw,
    pack_resistance,
    scaled,
    separated,
    strength_of,
    strength_read,
)
from ebus_env.io.measured import load_log
from ebus_env.synthetic import synthetic_log


def linear_problem(seed=0, n=3000, beta=1.0):
    """y = X a + beta s + noise, in 60-unit blocks, with a known signature s."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    x = np.column_stack([np.ones(n), np.sin(t / 300.0), rng.normal(size=n)])
    s = np.where((t // 200) % 3 == 0, 1.0, 0.0) * (1.0 + 0.5 * np.cos(t / 50.0))
    y = x @ np.array([0.3, -0.2, 0.1]) + beta * s + rng.normal(0.0, 0.5, n)
    nuisance = Nuisance(["a", "b", "c"], x, np.full(3, -5.0), np.full(3, 5.0))
    return y, np.full(n, 4.0), nuisance, t // 60, s


def test_a_candidate_that_is_in_the_data_passes_the_held_out_test_and_noise_does_not():
    y, w, nuisance, block, s = linear_problem()
    held = HeldOut(y, w, nuisance, block)
    right = held.test("right", s[None, :])
    rng = np.random.default_rng(1)
    placebo = held.test("placebo", rng.normal(size=(1, len(y))))
    assert right.chi2 > needed(2) and right.beta == pytest.approx(1.0, abs=0.05)
    assert placebo.chi2 < needed(2) and margin(right, placebo) > 100
    # the strength is chosen on the training folds from the signatures at several strengths
    scaled = held.test("scaled", np.array([0.5 * s, 1.0 * s, 3.0 * s]))
    assert scaled.choice == 0 or scaled.beta * [0.5, 1.0, 3.0][scaled.choice] == pytest.approx(
        1.0, abs=0.05)
    # nothing there: the same test on data without it finds nothing
    y0, *_ = linear_problem(beta=0.0)
    assert HeldOut(y0, w, nuisance, block).test("right", s[None, :]).chi2 < needed(2)


def test_the_bus_parameters_take_up_what_they_can_so_a_candidate_is_credited_only_beyond():
    """A candidate that is one of the bus's own columns gains nothing held out."""
    y, w, nuisance, block, s = linear_problem()
    held = HeldOut(y, w, nuisance, block)
    assert held.test("same as c", nuisance.x[:, 2][None, :]).chi2 < 1.0


def test_each_day_has_its_own_current_sensor_gain_and_offset():
    """On two days logged through sensors of different gain and offset, the per-day sensor
    columns take up the logged power to the watt; one gain and offset for both days would
    leave a day-shaped missing power (what a weather-borne effect would take for itself)."""
    rng = np.random.default_rng(4)
    n = 400
    day = np.repeat([0, 1], n // 2)
    share = np.zeros((n, len(MODES)))
    share[:, MODES.index("cruising")] = 1.0
    bins = Bins(profile=day, first=np.arange(n) * 10, day=day, block=np.arange(n) // 60,
                hour=np.full(n, 12.0), fit=np.ones(n, bool), mode_share=share, seconds=10)
    power_w = rng.uniform(-80e3, 200e3, n)
    volts = rng.uniform(600.0, 680.0, n)
    gain, offset_a = np.where(day == 0, 0.008, -0.008), np.where(day == 0, 0.4, -0.3)
    logged_w = (1.0 + gain) * power_w + offset_a * volts
    split = sensor_columns(bins, power_w, volts)
    assert split.names == ["current sensor gain, day 0", "current sensor gain, day 1",
                           "current sensor offset [A], day 0", "current sensor offset [A], day 1",
                           "drivetrain loss while moving [kW]"]
    w = np.ones(n)
    _, _, coef, _, loss = fit_all(logged_w - power_w, w, split)
    assert loss / n < 1.0  # W^2: exact
    assert coef[:4] == pytest.approx([0.008, -0.008, 0.4, -0.3], abs=1e-6)
    one_day = replace(bins, day=np.zeros(n, int))
    shared = sensor_columns(one_day, power_w, volts)
    assert len(shared.names) == 3
    *_, loss_shared = fit_all(logged_w - power_w, w, shared)
    assert np.sqrt(loss_shared / n) > 300.0  # W: each day's 0.8 % of the power is left


def test_a_load_from_a_day_on_must_split_the_days_where_it_starts():
    """A bus meets another driver most days, and its power while accelerating spreads by
    some tenths of a kW from day to day: days 3-5 may lie higher on average without a change
    on day 3 (day 5 lies below day 1), and a load from day 3 is then no change from that day.
    A load of 1 kW that starts on day 3 lifts every later day above every earlier one."""
    rng = np.random.default_rng(8)
    day = np.repeat(np.arange(6), 500)
    n = len(day)
    share = np.zeros((n, len(MODES)))
    share[:, MODES.index("accelerating")] = 1.0
    bins = Bins(profile=day, first=np.tile(np.arange(500) * 10, 6), day=day,
                block=np.arange(n) // 60, hour=np.full(n, 12.0), fit=np.ones(n, bool),
                mode_share=share, seconds=10)
    load = 1e3 * share[:, MODES.index("accelerating")]  # a load while accelerating, 1 kW
    drivers_kw = np.array([0.3, 0.9, -0.5, 1.3, 0.9, 0.2])  # a truth-simulator control bus
    w = np.ones(n)
    for change_kw, split in ((0.0, False), (1.0, True)):
        y = 1e3 * (drivers_kw + change_kw * (np.arange(6) >= 3))[day] + rng.normal(
            0.0, 300.0, n)
        assert separated(load, 3, y, w, bins, bins.fit) == split
        assert separated(load, 0, y, w, bins, bins.fit)  # every day: nothing to split


def test_a_load_outside_the_library_too_small_for_a_workshop_is_not_reported():
    """A load while charging of 0.1 kW stands far above the noise of a steady charger, yet is
    a few lamps: the diagnosis reports nothing; one of 2 kW is a load outside the library."""
    rng = np.random.default_rng(2)
    n = 3000
    on = ((np.arange(n) // 100) % 10 == 0).astype(float)  # a tenth of the time on a charger
    constant = Nuisance(["c"], np.ones((n, 1)), np.array([-1e4]), np.array([1e4]))
    form = Form("load while charging", "outside", 1e3 * on[None, :], "an unknown load")
    for load_kw, status in ((0.1, "noise"), (2.0, "outside library")):
        y = 1e3 * load_kw * on + rng.normal(0.0, 50.0, n)
        held = HeldOut(y, np.full(n, 1.0 / 50.0**2), constant, np.arange(n) // 60)
        test = held.test(form.name, form.signatures_w)
        assert test.chi2 > needed(1)
        size = outside_kw(test, form.signatures_w[0], held.null_fitted)
        assert size == pytest.approx(load_kw, rel=0.05)  # whatever the constant took
        assert decide({form.name: test}, {form.name: form}, {form.name: size})[0] == status
    assert 0.1 < MIN_OUTSIDE_KW < 2.0


def test_a_strength_at_an_end_of_its_range_is_told_from_one_inside_it():
    """The regen limit's signatures span its declared range (50 to 99.9 % SoC) beside its
    default: a fit at 50 % is at the lower bound, at 99.9 % at the upper, inside is neither;
    a form without strengths (a load outside the library) has no bound."""
    grid = np.concatenate([[90.0], np.linspace(50.0, 99.9, 9)])
    form = Form("regen_soc_limit", "missing effect", np.zeros((len(grid), 4)), strengths=grid,
                strength_param="regen_soc_limit.derate_soc_pct")
    assert bound_reached(form, 1) == "lower" and bound_reached(form, 9) == "upper"
    assert bound_reached(form, 0) is None and bound_reached(form, 5) is None
    assert bound_reached(replace(form, strengths=None), 1) is None


def test_a_strength_that_only_scales_its_signature_is_read_from_the_fitted_size():
    """A load's scale (0 to 5, default 1) only scales its signature: fitted on the scale-5
    signature with coefficient 0.3 it is a scale of 1.5, inside its range (not at the upper
    bound the signature alone would say); only a size beyond the largest signature's is at a
    bound. A form whose shape changes with its strength keeps the chosen signature's value."""
    shape = np.array([1.0, 0.0, 2.0, 1.0])
    grid = np.array([1.0, 0.0, 1.25, 2.5, 3.75, 5.0])
    form = Form("aux_schedule", "missing effect", grid[:, None] * shape[None, :],
                strengths=grid, strength_param="aux_schedule.scale")
    assert scaled(form, 5, 0.3) == (pytest.approx(1.5), None)
    assert bound_reached(form, 5, 0.3) is None and bound_reached(form, 5, 1.2) == "upper"
    assert scaled(form, 3, 1.0) == (pytest.approx(2.5), None)
    bent = replace(form, signatures_w=np.array([shape * (1.0 + 0.5 * k * np.arange(4))
                                                for k in range(len(grid))]))
    assert scaled(bent, 5, 0.3) is None and bound_reached(bent, 5, 0.3) == "upper"


def test_a_cabin_whose_best_shape_is_its_top_conductance_at_part_size_is_read_inside_range():
    """A cabin's power: the fans and the sun, which stay, plus a part its conductance UA
    scales. Its signatures across UA are near parallel (cosine 0.98-0.99 here, as on a hot
    day), so a fit on the top UA's signature at 0.65 of its size reads a UA inside the range
    from the size, not the upper bound; beyond the top's size it is at the bound. A shape
    inside the range at a size below the least UA's is read from its shape; at an end only
    where both readings are."""
    stays = np.array([5.0, 5.0, 6.0, 5.0])
    per_ua = np.array([2.0, 1.0, 6.0, 3.0]) / 1500.0
    grid = np.array([400.0, 10.0, 382.5, 755.0, 1127.5, 1500.0])
    form = Form("cabin_hvac", "missing effect", stays + grid[:, None] * per_ua[None, :],
                strengths=grid, strength_param="cabin_hvac.ua_w_per_k")
    sig = form.signatures_w
    cos = sig @ sig[5] / (np.linalg.norm(sig, axis=1) * np.linalg.norm(sig[5]))
    assert 0.98 < cos.min() < 0.99  # the regime of the cabin, near parallel
    value, side = scaled(form, 5, 0.65)
    assert side is None and 10.0 < value < 400.0
    assert strength_read(form, 5, 0.65) == (value, None)
    assert bound_reached(form, 5, 0.65) is None and bound_reached(form, 5, 1.1) == "upper"
    # a shape inside the range at a size below the least conductance's: the shape reads it
    assert scaled(form, 3, 0.5)[1] == "lower" and strength_read(form, 3, 0.5) == (755.0, None)
    assert scaled(form, 1, 0.5)[1] == "lower" and bound_reached(form, 1, 0.5) == "lower"


def test_an_effect_without_a_strength_has_an_energy_interval_that_reaches_its_own_size():
    """A grade read from a noisy altitude: its signature is the true one plus noise of the
    same size, so the fit's coefficient is about 0.5 (regression dilution) and its energy
    half the truth's. The effect has no strength parameter: its energy's interval reaches
    the energy of its own size and covers the truth; the estimate stays the fitted one. A
    load with a scale keeps its interval."""
    rng = np.random.default_rng(4)
    n = 2400
    true_w = 3e3 * np.sin(np.arange(n) / 40.0) + 1.5e3 * rng.normal(0.0, 1.0, n) + 400.0
    noise_w = rng.normal(0.0, float(np.std(true_w - 400.0)), n)
    seen_w = true_w + noise_w - noise_w.mean()  # an altitude error does not climb over a day
    y = true_w + rng.normal(0.0, 100.0, n)
    constant = Nuisance(["c"], np.ones((n, 1)), np.array([-1e4]), np.array([1e4]))
    w, block = np.full(n, 1e-4), np.arange(n) // 100
    grade = Form("road_grade", "missing effect", seen_w[None, :])
    test = HeldOut(y, w, constant, block).test(grade.name, grade.signatures_w)
    assert 0.35 < test.beta < 0.65
    truth_kwh, fitted_kwh = (x * seen_w.sum() * 60.0 / 3.6e6 for x in (1.0, test.beta))
    got = strength_of(test, grade, grade.signatures_w, y, w, constant, block, 60.0)
    assert got["energy_kwh"] == pytest.approx(fitted_kwh)
    low, high = got["energy_interval_kwh"]
    assert low < fitted_kwh < truth_kwh < high
    scaled_load = replace(grade, strengths=np.array([1.0]), strength_param="load.scale")
    kept = strength_of(test, scaled_load, grade.signatures_w, y, w, constant, block, 60.0)
    assert kept["energy_kwh"] == pytest.approx(fitted_kwh)
    assert kept["energy_interval_kwh"][1] < truth_kwh  # the fit's own noise alone


@pytest.mark.parametrize("true_scale, beyond", [(5.05, False), (8.0, True)])
def test_a_strength_is_withdrawn_only_where_the_data_ask_beyond_its_range(true_scale, beyond):
    """A load of scale 0-5 whose log holds it at ``true_scale``: at 5.05 the fit ends at the
    top of the range, but the block resamples put it beyond in fewer than 95 % of draws (the
    data do not ask for more than the load can be: named, :data:`BEYOND_SURE`); at 8 in
    every draw (withdrawn)."""
    rng = np.random.default_rng(0)
    n = 2400
    shape_w = 1e3 * (1.2 + np.sin(np.arange(n) / 50.0))
    grid = np.array([1.0, 0.0, 1.25, 2.5, 3.75, 5.0])
    form = Form("aux_schedule", "missing effect", grid[:, None] * shape_w[None, :],
                strengths=grid, strength_param="aux_schedule.scale")
    y = true_scale * shape_w + rng.normal(0.0, 2e3, n)
    none = Nuisance(["c"], np.zeros((n, 1)), np.array([-1.0]), np.array([1.0]))
    w, block = np.full(n, 1e-6), np.arange(n) // 100
    test = HeldOut(y, w, none, block).test(form.name, form.signatures_w)
    assert bound_reached(form, test.choice, test.beta) == "upper"
    share = strength_of(test, form, form.signatures_w, y, w, none, block, 60.0)["beyond_share"]
    assert share["lower"] == 0.0
    assert (share["upper"] >= BEYOND_SURE) is beyond
    assert beyond or share["upper"] > 0.5


def bms_day(effect: str | None, hours: float = 3.0, seed: int = 3, plain: bool = False,
            params=None, **case_changes):
    """A BMS log of a hidden-effect case (the project's model), its first ``hours``: current
    and voltage kept, with a current sensor's gain and offset (``plain``: made by the
    baseline bus, the effect not there; ``params``: the logged bus's own values)."""
    name = {None: "control", "cabin_hvac": "cabin_heating"}.get(effect, effect)
    case = replace(hidden.case(name), hours=hours, **case_changes)
    profile, _ = hidden.day_profile(case)
    truth = hidden.baseline_bus(case) if plain else hidden.true_bus(case)
    frame = synthetic_log(truth.build(hidden.DT_S), profile, params=params,
                          soc_start=case.soc_start, soc_step_pct=0.1, seed=seed)
    rng = np.random.default_rng(seed)
    frame["battery_current_a"] = frame["battery_current_a"] * 1.006 + 0.3 + rng.normal(
        0.0, 0.5, len(frame))
    start = datetime.datetime(2026, 1, 14) + datetime.timedelta(hours=case.start_h)
    frame.insert(0, "timestamp", [(start + datetime.timedelta(seconds=float(t))).isoformat()
                                  for t in frame["time_s"]])
    return case, frame.drop(columns=["time_s", "grade_frac"], errors="ignore")


def load(frame, tmp_path, name):
    path = tmp_path / f"{name}.csv"
    frame.to_csv(path, index=False)
    return load_log(path).profiles


def test_a_bms_log_gives_the_pack_its_counted_capacity(tmp_path):
    case, frame = bms_day(None, hours=4.0)
    profiles = load(frame, tmp_path, "control")
    assert all(map(logs_power, profiles))
    model = hidden.true_bus(case).build(hidden.DT_S)
    pack_ah = 3 * model.params[model.param_index("rint_battery.cell_capacity_ah")]
    # the sensor's gain error (0.6 %) is what separates the count from the truth
    assert counted_capacity_ah(profiles) == pytest.approx(pack_ah, rel=0.02)


def bus_bins(model, profiles):
    """The power path's bins of ``profiles`` (one day), the logged power and voltage in them."""
    first = anchored_runs(model, profiles, model.params[None, :], TRACE)
    bins = make_bins(profiles, [r[0] for r in first], [0] * len(profiles))
    return bins, bins.means(log_power(profiles)), bins.means(log_voltage(profiles))


def test_a_threshold_the_log_never_reaches_where_it_starts_is_still_fitted(tmp_path):
    """The logged bus's motor brakes alone only up to 0.5 m/s^2 (the friction brakes take
    the rest); the model starts at 5 m/s^2, a deceleration no bus reaches, where a step of
    the parameter moves no bin's power and a Gauss-Newton step has no slope to follow. The
    grid across its range finds it, and the motor's share of braking stays the logged bus's
    (all of it) instead of standing in for the threshold. A bus that brakes up to 5 m/s^2
    but stops regenerating below 3 m/s keeps its 5: the grid comes after the cutoff speed
    has been fitted, which a lower deceleration would otherwise stand in for."""
    decel, cutoff = "regen_cutoff.max_decel_mps2", "regen_cutoff.cutoff_speed_mps"
    case = bms_day(None, hours=0.1)[0]
    model = hidden.baseline_bus(case).build(hidden.DT_S)
    fitted = {}
    for logged in ({decel: 0.5}, {cutoff: 3.0}):
        _, frame = bms_day(None, hours=2.0, params=logged)
        profiles = load(frame, tmp_path, "-".join(logged))
        bins, power_w, voltage = bus_bins(model, profiles)
        box = search_box(model)
        names = list(box)
        _, columns, change = _signatures(model, profiles, model.params, names, box)
        assert decel in [names[j] for j in _dead(bins.means(columns).T[bins.fit], change)]
        fitted[next(iter(logged))] = fit_bus(model, profiles, bins, power_w, voltage,
                                             np.ones(len(bins))).values
    assert fitted[decel][decel] == pytest.approx(0.5, abs=0.1)
    assert fitted[decel]["regen_cutoff.max_share"] > 0.95
    assert fitted[cutoff][cutoff] == pytest.approx(3.0, abs=0.4)
    assert fitted[cutoff][decel] > 4.0


def test_a_charger_that_delivers_less_than_its_stated_rating_is_fitted_not_taken_for_a_load(
        tmp_path):
    """The log states the charger's rating on its grid side: the bus gets 93 % of it. Fitted,
    the share leaves the bins at the charger's rating to the sensor's noise; held at a DC
    rating's 1, they miss what the charger does not deliver (tens of kW), which a load while
    charging would take for itself. A log with too few bins at the rating does not fit it."""
    name = "grid_charger.delivered_frac"
    case, frame = bms_day(None, hours=2.0, plain=True, params={name: 0.93})
    model = hidden.baseline_bus(case).build(hidden.DT_S)
    profiles = load(frame, tmp_path, "grid-side")
    bins, power_w, voltage = bus_bins(model, profiles)
    rated = bins.fit & (bins.mode_share[:, MODES.index("charging")] > 0.5)
    assert rated.sum() >= 5
    fits = {fixed: fit_bus(model, profiles, bins, power_w, voltage, np.ones(len(bins)),
                           fixed=fixed) for fixed in ((), (name,))}
    missing = {k: np.mean(f.missing(power_w, bins.fit)[rated]) for k, f in fits.items()}
    assert fits[()].values[name] == pytest.approx(0.93, abs=0.01)
    assert abs(missing[()]) < 500.0  # W
    assert missing[(name,)] > 10e3
    # the report's table of the bus as its logs give it: the share inside its range, the
    # sensor's gain (0.6 % in the log) beside it
    rows = {r["parameter"]: r for r in fits[()].table(power_w, bins.fit)}
    assert rows[name]["range"] == pytest.approx([0.85, 1.02]) and rows[name]["end"] is None
    assert rows["current sensor gain"]["value"] == pytest.approx(0.006, abs=0.01)
    assert name not in {r["parameter"] for r in fits[(name,)].table(power_w, bins.fit)}
    # three bins at the rating do not pin it: it keeps its configured value
    few = replace(bins, fit=bins.fit & ~(rated & (np.cumsum(rated) > 3)))
    assert name not in fit_bus(model, profiles, few, power_w, voltage, np.ones(len(bins))).box


def test_each_logged_second_is_compared_with_the_model_as_the_logger_took_it(tmp_path):
    """A BMS logs each second's mean current. The model's steps averaged over the same
    second follow the logged power of the bus that made the log to within its sensor's
    noise; the instant at each second's start leaves about a kW while accelerating, as a load
    would (the power moves within the second). A logger whose current lags its time stamp by half a
    second, or leads it by one, is found to the model's step, and so is one that keeps time."""
    case, frame = bms_day(None, hours=2.0, plain=True)
    model = hidden.baseline_bus(case).build(hidden.DT_S)
    profiles = load(frame, tmp_path, "plain")
    every = int(round(1.0 / hidden.DT_S))
    steps = _steps(model, profiles[0], model.params[None, :],
                   np.array([model.trace_names.index("battery_power_w")]))[0]
    run = steps[every:-every]
    bins, logged_w, voltage = bus_bins(model, profiles)
    accelerating = bins.fit & (bins.mode_share[:, MODES.index("accelerating")] > 0.5)
    left = {}
    for name, seconds in (("mean", _logged_seconds(steps, every, 0)[:, 0]),
                          ("instant", run[::every, 0])):
        model_w = bins.means([seconds])
        sensor = sensor_columns(bins, model_w, voltage)
        _, _, coef, _, _ = fit_all(logged_w - model_w, np.ones(len(bins)), sensor)
        left[name] = np.mean((logged_w - model_w - sensor.x @ coef)[accelerating])
    assert abs(left["mean"]) < 200.0  # W
    assert left["instant"] > 700.0
    assert logger_lag(model, profiles, model.params) == 0
    for shift_s, lag in ((0.5, -5), (-1.0, 10)):
        late = frame.copy()
        rows = np.arange(len(late))
        late["battery_current_a"] = np.interp(rows - shift_s, rows, late["battery_current_a"])
        found = logger_lag(model, load(late, tmp_path, f"late{shift_s}"), model.params)
        assert abs(found - lag) <= 1


def test_a_second_of_the_log_averages_the_model_steps_it_stands_for():
    """Ten steps of 0.1 s per logged second; a lag moves the window, cut at the run's ends."""
    steps = np.concatenate([np.zeros(10), np.arange(30.0), np.zeros(10)])[:, None]
    assert _logged_seconds(steps, 10, 0)[:, 0] == pytest.approx([4.5, 14.5, 24.5])
    assert _logged_seconds(steps, 10, -5)[:, 0] == pytest.approx([2.0, 9.5, 19.5])
    assert _logged_seconds(steps, 10, 5)[:, 0] == pytest.approx([9.5, 19.5, 27.0])


def test_the_pack_resistance_comes_from_the_logged_voltage(tmp_path):
    """A pack of twice the model's cell resistance: the logged voltage's drop under load
    gives the model that resistance (within 10 %) before the bus is fitted; a pack as the
    model's keeps its value."""
    name = "rint_battery.cell_resistance_mohm"
    case = bms_day(None, hours=0.1)[0]
    model = hidden.baseline_bus(case).build(hidden.DT_S)
    own = model.params[model.param_index(name)]
    for factor in (2.0, 1.0):
        _, frame = bms_day(None, hours=2.0, params={name: factor * own})
        profiles = load(frame, tmp_path, f"pack{factor}")
        value = pack_resistance(model, profiles, model.params)[name]
        assert value == pytest.approx(factor * own, rel=0.1)


@pytest.mark.slow
def test_a_cabin_heater_hidden_from_the_bus_is_named_and_a_control_day_names_nothing(tmp_path):
    """In-family: the cabin's heating on a cold day, hidden from the 12 m bus, is named with
    about the energy it drew; the same bus on a day with nothing hidden is left alone."""
    case, frame = bms_day("cabin_hvac", hours=3.0)
    run = diagnose_power(hidden.baseline_bus(case), load(frame, tmp_path, "cabin"), [0])
    assert run.bins.lag == 0  # the project's logs stamp the second that follows
    assert run.finding.status == "named" and run.finding.verdict == "cabin_hvac"
    low, high = run.finding.strength["energy_interval_kwh"]
    assert low < run.finding.strength["energy_kwh"] < high
    assert run.finding.fall > 0.5
    case, frame = bms_day(None, hours=3.0)
    quiet = diagnose_power(hidden.baseline_bus(case), load(frame, tmp_path, "control"), [0])
    assert quiet.finding.status == "noise" and quiet.finding.verdict is None
    assert quiet.finding.tests[0].chi2 < quiet.finding.needed


def test_a_load_switching_at_stops_is_read_from_the_steps_the_model_does_not_make():
    """Within a stop the missing power steps by 5 kW and back: those seconds are on; a stop
    with noise only, or with a load that stays on the whole stop, marks nothing, and nothing
    counts while moving or in a stop's first and last seconds."""
    rng = np.random.default_rng(4)
    still = np.zeros(400, bool)
    missing = rng.normal(0.0, 3e3, 400)  # driving: the model's launch and halt, kW off
    for start in (50, 150, 250, 350):
        still[start:start + 30] = True
        missing[start:start + 30] = rng.normal(0.0, 100.0, 30)
    missing[160:170] += 5e3  # switched on 10 s within the second stop
    missing[250:280] += 5e3  # on for the whole fourth stop: no step within it
    on = switched_on(missing, still)
    assert np.array_equal(np.flatnonzero(on), np.arange(160, 170))


def test_a_compressor_at_stops_is_a_load_outside_the_library_where_it_runs(tmp_path):
    """A 5 kW load that runs 8 s in every other stop, added to the log of a day with nothing
    else hidden: no library effect explains it, the switching load does, at its power, and
    its clue is the idle mode."""
    case, frame = bms_day(None, hours=3.0)
    stopped = (frame["speed_kmh"].to_numpy() == 0.0) & (frame["charging"].to_numpy() == 0)
    edges = np.flatnonzero(np.diff(np.r_[0, stopped.astype(int), 0]))
    load_w = np.zeros(len(frame))
    for start, stop in list(zip(edges[::2], edges[1::2], strict=True))[::2]:
        if stop - start >= 19:  # the day's stops: 19-20 s
            load_w[start + 5:start + 13] = 5e3
    assert load_w.sum() > 60 * 5e3  # the day has such stops
    frame["battery_current_a"] += load_w / frame["battery_voltage_v"]
    run = diagnose_power(hidden.baseline_bus(case), load(frame, tmp_path, "compressor"), [0])
    f = run.finding
    assert f.status == "outside library" and f.verdict is None and f.clue == "idle"
    top = f.tests[0]
    assert f.forms[top.name].name == "load switching on and off while standing"
    assert top.chi2 > f.needed
    assert top.beta == pytest.approx(5.0, rel=0.15)  # kW, the signature's unit


def on_day(frame, day: int):
    """The same log ``day`` days later (its time stamps moved)."""
    out = frame.copy()
    out["timestamp"] = [(datetime.datetime.fromisoformat(t) + datetime.timedelta(days=day))
                        .isoformat() for t in frame["timestamp"]]
    return out


@pytest.mark.slow
def test_several_days_of_a_bus_name_the_effect_and_the_day_it_started(tmp_path):
    """Three one-hour days of one bus's BMS logs through ``diagnose``: the cabin's heater,
    which the bus's config lacks, runs from the second day on (on the first the bus is its
    config).
    The diagnosis works in the power domain, fits the bus across the days, names the effect
    and the date it started from, in its sentence and its JSON; three days with nothing
    hidden name no library effect (the model's 1 Hz power and the log's differ by about
    0.5 kW while accelerating, which three like days can show as a load outside the
    library)."""
    from ebus_env.diagnostics import diagnose

    case = bms_day("cabin_hvac", hours=1.0)[0]
    bus = hidden.baseline_bus(case)
    heated = [bms_day("cabin_hvac", hours=1.0, seed=s)[1] for s in (5, 6, 7)]
    plain = [bms_day("cabin_hvac", hours=1.0, seed=s, plain=True)[1] for s in (5, 6, 7)]
    days = [on_day(f, k) for k, f in enumerate([plain[0], *heated[1:]])]
    profiles = [p for k, f in enumerate(days) for p in load(f, tmp_path, f"day{k}")]
    d = diagnose(bus, profiles, domain="auto")
    assert d.domain == "power" and d.days == ["2026-01-14", "2026-01-15", "2026-01-16"]
    assert d.verdict == "cabin_hvac" and d.since == "2026-01-15", (d.sentence, d.ranking[:3])
    assert d.since_interval[0] <= "2026-01-15" <= d.since_interval[1]
    assert d.sentence.startswith("From 2026-01-15 on, ")
    assert d.nrmse["power_held_out_fall"]["cabin_hvac"] > 0.5
    assert d.to_json()["since"] == "2026-01-15"
    fitted = {r["parameter"] for r in d.to_json()["bus_fit"]}
    assert {"vehicle_body.curb_mass_kg", "current sensor gain, day 2"} <= fitted
    d.write_html(tmp_path / "report.html")
    assert "current sensor gain, day 2" in (tmp_path / "report.html").read_text()
    quiet = [p for k, f in enumerate(plain) for p in load(on_day(f, k), tmp_path, f"quiet{k}")]
    q = diagnose(bus, quiet, domain="power")
    assert q.domain == "power" and q.verdict is None, q.sentence
    assert q.status in ("noise", "outside library") and q.since is None, q.sentence


def rising_pack(tmp_path, rise: float, hours: float = 0.5):
    """Four days of one bus (the project's model), its cells' resistance ``1 + rise`` times
    the configured from the third day on: (the case, the profiles, each one's day)."""
    name = "rint_battery.cell_resistance_mohm"
    case = bms_day(None, hours=0.1)[0]
    model = hidden.baseline_bus(case).build(hidden.DT_S)
    own = model.params[model.param_index(name)]
    profiles, day_of = [], []
    for k, seed in enumerate((5, 6, 7, 8)):
        factor = 1.0 + rise if k >= 2 else 1.0
        _, frame = bms_day(None, hours=hours, seed=seed, params={name: factor * own})
        for p in load(on_day(frame, k), tmp_path, f"r{rise}-day{k}"):
            profiles.append(p)
            day_of.append(k)
    return case, profiles, day_of


@pytest.mark.slow
def test_a_pack_whose_resistance_rises_from_a_day_on_is_named_as_ageing_from_then(tmp_path):
    """Four half-hour days of one bus whose cells' resistance is 25 % higher from the third
    day on (a weak cell group): the logged voltage dates the rise and sizes it, the power path
    names the library's ageing from that day with the energy the added resistance costs; the
    same days without the rise show none."""
    from ebus_env.diagnostics.power_path import voltage_evidence

    for rise in (0.25, 0.0):
        case, profiles, day_of = rising_pack(tmp_path, rise)
        model = hidden.baseline_bus(case).build(hidden.DT_S)
        own = model.params[model.param_index("rint_battery.cell_resistance_mohm")]
        check, _ = voltage_evidence(model, profiles, model.params, [], day_of)
        if rise == 0.0:
            assert check.step is None
            continue
        step = check.step
        assert step.since_day == 2 and step.rise == pytest.approx(rise, rel=0.02)
        run = diagnose_power(hidden.baseline_bus(case), profiles, day_of)
        f = run.finding
        assert (f.status, f.verdict, f.since_day) == ("voltage", "static_rcd", 2), f.why
        # ohm * A^2 h: the added resistance's loss over the days from the rise, within 25 %
        series, strings = (model.params[model.param_index(f"rint_battery.cells_{n}")]
                           for n in ("series", "parallel"))
        pack_ohm = own * 1e-3 * series / strings
        amp2_h = sum(np.nansum(p.measured["battery_current_a"] ** 2) * p.dt_s / 3600.0
                     for p, d in zip(profiles, day_of, strict=True) if d >= 2)
        assert f.strength["energy_kwh"] == pytest.approx(rise * pack_ohm * amp2_h / 1e3,
                                                         rel=0.25)
        low, high = f.strength["interval"]["static_rcd.rcd_frac"]
        assert low < rise / 1.5 < high


def _pack_candidate(bus, model):
    """ambient_battery (the library effect that moves the pack's resistance) as a candidate
    of ``bus``, for the voltage's check."""
    from ebus_env.diagnostics.candidates import GRID, Candidate, model_with
    from ebus_env.effects.base import get_effect

    eff = get_effect("ambient_battery")
    values = dict(zip(model.param_names, model.params, strict=True))
    m, params = model_with(bus.with_effect(eff), hidden.DT_S, values)
    i = m.param_index("ambient_battery.initial_offset_k")
    return Candidate("ambient_battery", "missing effect", np.zeros((1, 0)), effect=eff,
                     model=m, params=params, strengths=np.linspace(*m.bounds[i], GRID))


@pytest.mark.slow
def test_a_pack_effect_the_power_names_stands_only_where_the_voltage_reproduces_the_change(
        tmp_path):
    """Four two-hour days whose cells' resistance is 25 % higher from the third day on: the
    voltage shows the rise, flat within each day, which a pack off its ambient reproduces at
    no strength, so that verdict from the power is withdrawn with the reason (and the rise is
    then the library's ageing from its day). On the cold-battery day, whose resistance falls
    as the pack warms by its losses, the same verdict stands."""
    from ebus_env.diagnostics.power_path import (
        MIN_REPRODUCED,
        Finding,
        unreproduced_pack_why,
        voltage_evidence,
    )

    def finding():
        return Finding("named", "ambient_battery", "", 0, (0, 0), None, [], {}, 0.0,
                       strength={"parameters": {"ambient_battery.initial_offset_k": -10.0}},
                       fall=0.3)

    case, profiles, day_of = rising_pack(tmp_path, 0.25, hours=2.0)
    bus = hidden.baseline_bus(case)
    model = bus.build(hidden.DT_S)
    pack = [_pack_candidate(bus, model)]
    named = ("ambient_battery", {"ambient_battery.initial_offset_k": -10.0})
    check, moved = voltage_evidence(model, profiles, model.params, pack, day_of, named)
    assert check.changes and check.step.since_day == 2 and moved > 0.05
    fit = next(f for f in check.explained_by if f.effect == "ambient_battery")
    assert fit.explained < MIN_REPRODUCED
    why = unreproduced_pack_why(finding(), check)
    assert "does not reproduce" in why and f"{100 * max(fit.explained, 0):.0f} %" in why

    cold = hidden.case("cold_battery")
    profile, _ = hidden.day_profile(cold)
    frame = synthetic_log(hidden.true_bus(cold).build(hidden.DT_S), profile,
                          soc_start=cold.soc_start, period_s=1.0, soc_step_pct=0.1,
                          soc_noise_pct=0.02, seed=1)
    bus = hidden.baseline_bus(cold)
    model = bus.build(hidden.DT_S)
    check, _ = voltage_evidence(model, load(frame, tmp_path, "cold"), model.params,
                                [_pack_candidate(bus, model)], [0], named)
    assert check.changes and check.explained_by[0].explained > 0.9
    assert unreproduced_pack_why(finding(), check) == ""


@pytest.mark.slow
def test_in_soc_windows_too_a_resistance_rise_names_ageing_from_its_day(tmp_path):
    """The same four days diagnosed in SoC windows (the default domain): the missing power
    names nothing, the logged voltage names the library's ageing from the third day's date,
    in the sentence, the JSON and the HTML report."""
    from ebus_env.diagnostics import diagnose

    case, profiles, _ = rising_pack(tmp_path, 0.25)
    d = diagnose(hidden.baseline_bus(case), profiles)
    assert d.domain == "soc" and (d.status, d.verdict) == ("voltage", "static_rcd"), d.sentence
    assert d.since == "2026-01-16" and d.sentence.startswith("From 2026-01-16 on, "), d.sentence
    assert d.to_json()["resistance"]["step"]["since_day"] == 2
    low, high = d.named["interval"]["static_rcd.rcd_frac"]
    assert low < 0.25 / 1.5 < high
    d.write_html(tmp_path / "report.html")
    assert "static_rcd" in (tmp_path / "report.html").read_text()


def test_a_folder_of_logs_reads_as_its_days_in_order(tmp_path):
    """``ebus diagnose FOLDER``: the folder's logs, sorted by name (the days of one bus in
    order); other files are not logs; a folder without logs is an error that names it."""
    from ebus_env.errors import ConfigError
    from ebus_env.io.log_reading import logs_in

    days = tmp_path / "bus-17"
    days.mkdir()
    for name in ("2026-01-15.csv", "2026-01-14.csv.gz", "2026-01-16.parquet", "notes.txt"):
        (days / name).write_text("")
    other = tmp_path / "extra.csv"
    assert [p.name for p in logs_in([days, other])] == [
        "2026-01-14.csv.gz", "2026-01-15.csv", "2026-01-16.parquet", "extra.csv"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="empty: no logs in the folder"):
        logs_in([tmp_path / "empty"])


def test_the_power_domain_needs_the_current_and_voltage_or_the_soc_and_a_known_domain(
        tmp_path):
    """``domain="power"`` reads a SoC-only log by window, and a log with neither the pack's
    current and voltage nor the SoC is an error that names the log and the columns; an
    unknown domain is refused."""
    from ebus_env.diagnostics import diagnose
    from ebus_env.diagnostics.soc_power import WINDOW_S
    from ebus_env.errors import ConfigError
    from ebus_env.profile import Profile

    case, frame = bms_day(None, hours=0.5)
    soc_only = load(frame.drop(columns=["battery_current_a", "battery_voltage_v"]), tmp_path,
                    "soc_only")
    bus = hidden.baseline_bus(case)
    run = diagnose_power(bus, soc_only, [0])
    assert run.bins.seconds == WINDOW_S and run.logger_lag_s is None
    bare = Profile({"speed_ref_mps": np.zeros(3000)}, hidden.DT_S, name="bare")
    with pytest.raises(ConfigError, match="bare lack.*battery_current_a.*soc_frac"):
        diagnose(bus, [bare], domain="power")
    with pytest.raises(ConfigError, match="domain='watts' is not one of soc, power, auto"):
        diagnose(bus, soc_only, domain="watts")

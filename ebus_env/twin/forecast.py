"""Predictions while a bus drives: its SoC at each planned charger and at the end of its
block, with a band, and the alarm when the band says it will run below its reserve.

From the bus's newest sample (time ``t``, measured SoC), the rest of its block is built as
the model's inputs: each remaining trip drives the speed trace of a trip of the same
direction the bus has driven (today's or an earlier day's, stretched to the planned
duration); between trips the bus stands, on a charger during the planned sessions; the
ambient is the last measured. The bus's model with its newest fitted values
(:func:`~ebus_env.twin.bus_refit.latest_values`) runs it from the measured SoC.

The point prediction drives the most recent trip of each direction. The band runs
:data:`MEMBERS` members, each drawing every remaining trip from the bus's past trips of that
direction, and adds the model's own error, growing with the energy still to be used:
``sigma_model = MODEL_ERROR_FRAC * (SoC_now - SoC_end)`` (set on the fleet's buses 1-3 and
checked on the others, ``python -m benchmarks.bench_twin``). The 90 % band is the 5th to
95th percentile of the members widened by ``1.645 sigma_model``.

Where no charger lies ahead, the bus's own rate so far is the stronger evidence: the SoC it
used per km since the block's start (or its last charge), times the km the point prediction
drives in the rest of the block, gives a second end-of-block SoC. The prediction combines the
two, ``SoC_end = SoC_model + RATE_WEIGHT (SoC_rate - SoC_model)`` (a forecast combination,
J. M. Bates and C. W. J. Granger, Oper. Res. Q. 20 (1969) 451-468), the correction growing
with the km driven along the way; with a charger ahead the model alone predicts (a rate
cannot say what a charger puts in).

The reserve alarm fires when the band's *top* lies below the bus's reserve somewhere in the
rest of the block: the bus will run below it (95 % one-sided), and says when.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd
import sqlalchemy as sa

from ebus_env.errors import ConfigError
from ebus_env.twin.schedule import DayBlock, read_block, read_stored, trip_key
from ebus_env.twin.store import alarms, buses, predictions, schedules

MEMBERS = 12
MODEL_ERROR = 0.025
"""The model's error [1 sigma] per SoC point the battery still moves (set by
``python -m benchmarks.bench_twin`` on buses it does not report on)."""
Z90 = 1.645
RATE_WEIGHT = 0.9
"""The weight of the bus's own SoC-per-km rate against the model on a block's rest without a
charger (the least-squares weight on buses ``python -m benchmarks.bench_twin`` does not
report on, rounded to 0.05)."""
MIN_RATE_KM = 10.0  # km driven since the block's start or last charge before a rate counts
PAST_DAYS = 3  # days of past trips the band draws from
KEEP_TRIPS = 8  # the newest trips of each kind it keeps
DRAW_FROM = 4  # a band member drives one of the trips this many nearest in duration


@dataclass
class Forecast:
    """A prediction of a bus's SoC along the rest of its block."""

    bus: str
    day: str
    t: float  # the newest sample's time (UTC epoch s)
    soc_now_pct: float
    end_t: float
    end_soc_pct: float
    end_band_pct: tuple[float, float] | None
    min_soc_pct: float
    min_band_top_pct: float | None
    chargers: list[dict] = field(default_factory=list)  # arrival SoC at each charger ahead
    reserve_soc_pct: float = 30.0
    will_not_make_it: bool = False
    below_reserve_t: float | None = None
    trips_left: int = 0
    fitted: bool = False
    from_schedule: int = 0  # trips ahead driven as the block's timetable (none of the bus's)
    band_parts: dict | None = None  # at the block's end: the members' 5-95 %, SoC moved
    model_end_soc_pct: float | None = None  # the model's alone (RATE_WEIGHT 0)
    rate_end_soc_pct: float | None = None  # the bus's rate so far times the km ahead, or None

    def to_json(self) -> dict:
        return asdict(self)


def stored_block(twin, bus_id: int, day: str) -> DayBlock | None:
    """The bus's block stored for ``day``, read (None: none stored)."""
    text = twin.store.schedule_text(bus_id, day)
    return None if text is None else read_stored(text, day)


def _days_around(t: float) -> list[str]:
    """The service days whose block may run at ``t`` [UTC epoch s]: a block's day is its own
    time zone's, which may not be the UTC date (an evening in America, a morning in Asia)."""
    utc = pd.Timestamp(t, unit="s").normalize()
    return [str((utc + pd.Timedelta(days=d)).date()) for d in (-1, 0, 1)]


def _running(blocks: list[DayBlock], t: float) -> DayBlock | None:
    """The block that runs at ``t``, else the last one that started before it."""
    running = [b for b in blocks if b.start_s <= t < b.end_s]
    started = [b for b in blocks if b.start_s <= t]
    return running[0] if running else (max(started, key=lambda b: b.start_s)
                                       if started else None)


def block_at(twin, bus_id: int, t: float) -> DayBlock | None:
    """The bus's stored block that runs at ``t``, else the last one that started before it
    (None: none)."""
    return _running([b for day in _days_around(t)
                     if (b := stored_block(twin, bus_id, day)) is not None], t)


@dataclass
class History:
    """What the bus's own recent days tell its forecast: the traces of the trips it drove
    (1 Hz rows of speed [m/s] and door open [0/1], by :func:`trip_key`, newest last) and how
    much of a layover at a charger its sessions lose to connecting and disconnecting
    (``plug_in_s`` after it arrives, ``plug_out_s`` before it leaves; medians)."""

    trips: dict[tuple, list[np.ndarray]]
    plug_in_s: float = 0.0
    plug_out_s: float = 0.0

    def nearest(self, trip, duration_s: float, k: int = 1) -> list[np.ndarray]:
        """The ``k`` traces of trips like ``trip`` whose duration was nearest
        ``duration_s`` (a trip's time says its traffic: its stops and speeds), the newest
        first among equals."""
        pool = self.trips.get(trip_key(trip), [])
        order = sorted(range(len(pool)), key=lambda i: (abs(pool[i].shape[1] - duration_s),
                                                        -i))
        return [pool[i] for i in order[:k]]

    def like(self, trip, duration_s: float) -> np.ndarray | None:
        found = self.nearest(trip, duration_s)
        return found[0] if found else None

    def draw(self, trip, duration_s: float, rng) -> np.ndarray | None:
        """One of the :data:`DRAW_FROM` traces nearest in duration, at random."""
        found = self.nearest(trip, duration_s, DRAW_FROM)
        return found[int(rng.integers(len(found)))] if found else None


def history(twin, bus: str, bus_id: int, day: str, before_t: float,
            given: DayBlock | None = None) -> History:
    """The bus's :class:`History` from its blocks of this day (what it drove before
    ``before_t``) and the ``PAST_DAYS`` days before; kept per bus until another trip ends
    (the live state a bus costs: a few kinds x 8 trips x ~3000 s x 8 bytes, about 0.5 MB)."""
    with twin.store.engine.connect() as conn:
        rows = conn.execute(sa.select(schedules.c.day, schedules.c.block).where(
            schedules.c.bus_id == bus_id, schedules.c.day <= day)
            .order_by(schedules.c.day.desc()).limit(PAST_DAYS + 1)).all()
    blocks = [read_stored(row.block, row.day) for row in reversed(rows)]
    if given is not None:  # a block given to predict(), stored or not
        blocks = [b for b in blocks if b.day != given.day] + [given]
    driven = sorted(((trip_key(trip), a, b) for blk in blocks for trip, a, b in blk.trips
                     if b <= before_t), key=lambda leg: leg[1])
    keep = []  # the newest KEEP_TRIPS of each kind
    for key in {k for k, _, _ in driven}:
        keep += [leg for leg in driven if leg[0] == key][-KEEP_TRIPS:]
    keep.sort(key=lambda leg: leg[1])
    sessions = [(a, b) for blk in blocks for _, a, b, _ in blk.charger_stops if b <= before_t]
    signature = (tuple(a for _, a, _ in keep), tuple(sessions))
    cached = twin.trip_cache.get(bus)
    if cached is not None and cached[0] == signature:
        return cached[1]
    out = History({})
    spans = [(a, b) for _, a, b in keep] + sessions
    if spans:
        frame = twin.samples(bus, min(a for a, _ in spans), max(b for _, b in spans),
                             ("speed_kmh", "door_open", "charging"))
        t = frame["t"].to_numpy(float)
        speed = frame["speed_kmh"].to_numpy(float) / 3.6
        door = np.nan_to_num(frame["door_open"].to_numpy(float))
        for key, a, b in keep:
            i, j = np.searchsorted(t, [a, b])
            if j - i > 60:
                out.trips.setdefault(key, []).append(
                    np.vstack([speed[i:j], door[i:j]]).astype(np.float32))
        charging = np.nan_to_num(frame["charging"].to_numpy(float)) > 0.5
        lost_in, lost_out = [], []
        for a, b in sessions:
            i, j = np.searchsorted(t, [a, b])
            on = np.flatnonzero(charging[i:j])
            if on.size and j - i > 30:
                lost_in.append(t[i + on[0]] - a)
                lost_out.append(b - t[i + on[-1]])
        if lost_in:
            # the session's own end (at the pack's ceiling) makes the lead longer: the
            # lower half of the leads is the disconnecting
            out.plug_in_s = float(np.median(lost_in))
            out.plug_out_s = float(np.percentile(lost_out, 25))
    twin.trip_cache[bus] = (signature, out)
    return out


def _fit_duration(trace: np.ndarray, n: int, from_frac: float = 0.0) -> np.ndarray:
    """The rows of a 1 Hz ``trace`` (speed [m/s], door open; channels x samples), from
    ``from_frac`` of it on, made ``n`` seconds long by standing longer or shorter at its
    stops: its drives are kept as they were, so the trip's distance and the bus's
    accelerations stay its own (a time-stretched trace would ask for accelerations the bus
    may not have). Where its stops hold too little time to lose, its drives are resampled."""
    trace = np.atleast_2d(trace)[:, int(from_frac * trace.shape[-1]):]
    length = trace.shape[1]
    if n <= 0 or length == 0:
        return np.zeros((trace.shape[0], max(n, 0)))
    standing = np.flatnonzero(trace[0] <= 0.1)
    moving = np.flatnonzero(trace[0] > 0.1)
    keep_standing = n - len(moving)
    if keep_standing < 0 or len(standing) == 0:
        pick = np.linspace(0, length - 1, n).round().astype(int)  # resampled: rare
    else:
        chosen = standing[np.linspace(0, len(standing) - 1, keep_standing).round()
                          .astype(int)] if keep_standing else np.zeros(0, int)
        pick = np.sort(np.concatenate([moving, chosen]), kind="stable")
    return trace[:, pick]


AMBIENT_BIN_S = 60.0  # the day before's ambient is kept as means of this many seconds
SETTLED_S = 3600.0  # samples older than this are taken as complete (late batches aside)


def _ambient_before(twin, bus: str, lo: float, hi: float, t: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The bus's measured ambient [degC] between ``lo`` and ``hi`` (both before ``t``) as
    1-min means (time, value): read from the store once per bus and span, then from the
    cache (a span that ended an hour before ``t`` no longer changes), so that a prediction
    every few minutes does not read the same day again."""
    cached = twin.ambient_cache.get(bus)
    if cached is not None and cached[0] <= lo and hi <= cached[1]:
        return cached[2], cached[3]
    frame = twin.samples(bus, lo, hi, ("ambient_degc",)).dropna()
    t_s = frame["t"].to_numpy(float)
    _, minute = np.unique(np.floor(t_s / AMBIENT_BIN_S), return_inverse=True)
    count = np.bincount(minute)
    times = np.bincount(minute, t_s) / count
    values = np.bincount(minute, frame["ambient_degc"].to_numpy(float)) / count
    if hi <= t - SETTLED_S:
        twin.ambient_cache[bus] = (lo, hi, times, values)
    return times, values


def ambient_ahead(twin, bus: str, t: float, n: int, now_degc: float | None) -> np.ndarray:
    """The ambient [degC] over the ``n`` seconds after ``t``: the bus's own measurement at the
    same clock time the day before (1-min means), moved to meet ``now_degc`` (the day's
    course kept, its level today's); ``now_degc`` throughout where the day before has no
    measurement. (A weather forecast would do better; the bus's yesterday is what the twin
    has.)"""
    if now_degc is None:
        return np.full(n, 15.0)
    then_t = t - 86400.0
    # up to the block's end a day before: later predictions of the block lie in that span
    times, values = _ambient_before(twin, bus, then_t - 600.0, then_t + n, t)
    inside = (times >= then_t - 600.0) & (times <= then_t + n)
    times, values = times[inside], values[inside]
    near = np.abs(times - then_t) <= 300.0
    if not near.any() or times[-1] < then_t + n - 1800.0:
        return np.full(n, now_degc)
    course = np.interp(then_t + np.arange(n), times, values)
    return course - float(np.median(values[near])) + now_degc


def plan_inputs(day_block: DayBlock, t: float, pick, dt_s: float, ambient_degc,
                chargers: bool = True, plug_in_s: float = 0.0, plug_out_s: float = 0.0):
    """The model's input channels [on ``dt_s``] from ``t`` to the block's end, and the
    number of trips ahead and of those driven as the timetable. ``pick(trip)`` gives the
    1 Hz trace (speed [m/s], door open) of a trip the bus drove like it, or None: the trip is
    then driven as the block's own timetable (:func:`ebus_env.blocks.drive_rows`, doors
    shut). Between trips the bus stands, plugged in on a layover at a charger (``chargers``)
    from ``plug_in_s`` after it arrives to ``plug_out_s`` before it leaves."""
    from ebus_env.blocks import drive_rows

    n = int(np.ceil(day_block.end_s - t))
    if n < 2:
        raise ConfigError("the block has ended: nothing left to predict")
    speed = np.zeros(n)
    door = np.zeros(n)
    plugged = np.zeros(n)
    rating = np.full(n, np.nan)
    left = timetable = 0
    for trip, start, end in day_block.trips:
        if end <= t:
            continue
        left += 1
        a = max(int(np.floor(start - t)), 0)
        b = min(int(np.ceil(end - t)), n)
        if b <= a:
            continue
        frac = max(0.0, (t - start) / (end - start))
        trace = pick(trip, end - start)
        if trace is None:
            timetable += 1
            first = int(round(t + a - day_block.start_s))
            speed[a:b] = drive_rows(day_block.block, first, first + b - a, 1.0)["speed_ref_mps"]
        else:
            rows = _fit_duration(trace, b - a, frac)
            speed[a:b] = rows[0]
            if len(rows) > 1:
                door[a:b] = rows[1] > 0.5
    if chargers:
        for _, start, end, power_kw in day_block.charger_stops:
            a = max(int(start + plug_in_s - t), 0)
            b = min(int(end - plug_out_s - t), n)
            if b > a:
                plugged[a:b] = 1.0
                rating[a:b] = 1e3 * power_kw
    plugged[speed > 0.1] = 0.0
    steps = int(round(1.0 / dt_s))
    grid = np.arange(n * steps) * dt_s
    channels = {"speed_ref_mps": np.interp(grid, np.arange(n), speed),
                "charger_connected": np.repeat(plugged, steps),
                "charger_rating_w": np.repeat(rating, steps),
                "door_open": np.repeat(door, steps),
                "ambient_degc": np.interp(grid, np.arange(n),
                                          np.broadcast_to(ambient_degc, (n,)))}
    return channels, left, timetable


def driven_km(samples: pd.DataFrame, max_step_s: float = 10.0) -> float:
    """The km the samples' speed covers (``t`` [s], ``speed_kmh``), each speed held to the
    next sample; a gap longer than ``max_step_s`` counts as that long (it is not driven)."""
    t, v = samples["t"].to_numpy(float), samples["speed_kmh"].to_numpy(float)
    return float(np.sum(v[1:] * np.clip(np.diff(t), 0.0, max_step_s)) / 3600.0)


def rate_end_soc(twin, bus: str, block: DayBlock, t: float, km_ahead: float
                 ) -> float | None:
    """The SoC [%] at the block's end if the bus goes on using what it used per km since the
    block's start or its last charge: ``SoC_now - (SoC_from - SoC_now) / km_from x
    km_ahead``; None where it drove less than :data:`MIN_RATE_KM` since, or its SoC rose."""
    frame = twin.samples(bus, block.start_s, t, ("soc_pct", "speed_kmh", "charging"))
    charged = np.flatnonzero(np.nan_to_num(frame["charging"].to_numpy(float)) > 0.5)
    if charged.size:
        frame = frame.iloc[charged[-1] + 1:]
    frame = frame[frame["soc_pct"].notna() & frame["speed_kmh"].notna()]
    if len(frame) < 2:
        return None
    km = driven_km(frame)
    soc = frame["soc_pct"].to_numpy(float)
    if km < MIN_RATE_KM or soc[0] <= soc[-1]:
        return None
    return float(soc[-1] - (soc[0] - soc[-1]) / km * km_ahead)


def predict_bus(twin, bus: str, schedule: dict | DayBlock | None = None, band: bool = True,
                at_t: float | None = None, settings=None, seed: int = 0,
                model_error: float = MODEL_ERROR, rate_weight: float = RATE_WEIGHT
                ) -> Forecast:
    """The :class:`Forecast` of ``bus`` from its newest sample (or its sample at ``at_t``)
    along ``schedule`` (a block, :mod:`ebus_env.twin.schedule`; default: the one stored for
    the day); ``model_error``: the band's :data:`MODEL_ERROR`; ``rate_weight``: the bus's
    own rate's :data:`RATE_WEIGHT` where no charger lies ahead."""
    from ebus_env.profile import Profile
    from ebus_env.twin.bus_refit import bus_model, latest_values
    from ebus_env.twin.jobs import JobSettings

    settings = settings or JobSettings()
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        head = conn.execute(sa.select(buses).where(buses.c.id == bus_id)).first()
    t_now = head.last_t if at_t is None else at_t
    if t_now is None:
        raise ConfigError(f"bus '{bus}' has sent no samples yet")
    recent = twin.samples(bus, t_now - 900.0, t_now, ("soc_pct", "ambient_degc"))
    soc = recent["soc_pct"].dropna()
    if soc.empty:
        raise ConfigError(f"bus '{bus}' has sent no SoC in its last 15 min")
    ambient = recent["ambient_degc"].dropna()
    if isinstance(schedule, DayBlock):
        block = schedule
    else:
        block = _running([read_block(schedule, day) for day in _days_around(t_now)],
                         t_now) if schedule is not None else block_at(twin, bus_id, t_now)
        if block is None:
            raise ConfigError(f"bus '{bus}' has no block stored that runs at "
                              f"{pd.Timestamp(t_now, unit='s'):%Y-%m-%d %H:%M} UTC: PUT its "
                              f"day's block to /v1/buses/{bus}/schedules/DAY")
    model = bus_model(settings.bus_config, settings.dt_s)
    values = latest_values(twin, bus_id, before_t=t_now)
    vec = model.param_vector(values)
    past = history(twin, bus, bus_id, block.day, t_now, block)
    soc_now = float(soc.iloc[-1])
    amb = ambient_ahead(twin, bus, t_now, int(np.ceil(block.end_s - t_now)),
                        float(ambient.tail(300).median()) if len(ambient) else None)
    every = int(round(10.0 / settings.dt_s))

    def run(pick):
        channels, left, timetable = plan_inputs(block, t_now, pick, settings.dt_s, amb,
                                                plug_in_s=past.plug_in_s,
                                                plug_out_s=past.plug_out_s)
        profile = Profile(channels, settings.dt_s, f"{bus} block", 0.0)
        res = model.simulate(profile, vec, soc_start=soc_now / 100.0, record_every=every)
        km = np.cumsum(channels["speed_ref_mps"])[::every] * settings.dt_s / 1e3
        return 100.0 * res.trace("soc_frac").astype(float), left, timetable, km

    point, left, timetable, km = run(past.like)
    km = km[: len(point)]
    step_s = every * settings.dt_s
    times = t_now + step_s * np.arange(len(point))
    rng = np.random.default_rng(seed)
    members = [point]
    if band:
        for _ in range(MEMBERS):
            members.append(run(lambda trip, duration: past.draw(trip, duration, rng))[0])
    stack = np.vstack([m[: len(point)] for m in members])
    model_end = float(point[-1])
    charger_ahead = any(end > t_now for _, _, end, _ in block.charger_stops)
    by_rate = (None if charger_ahead or km[-1] <= 0 else
               rate_end_soc(twin, bus, block, t_now, float(km[-1])))
    if by_rate is not None:  # the combination, growing with the km driven along the way
        stack = stack + rate_weight * (by_rate - model_end) * km / km[-1]
        point = stack[0]
    # the SoC points the battery still moves (down driving, up charging): the model's error
    # grows with them
    moved = np.concatenate([np.zeros((len(stack), 1)),
                            np.cumsum(np.abs(np.diff(stack, axis=1)), axis=1)], axis=1).max(0)
    spread = Z90 * model_error * moved
    p5, p95 = np.percentile(stack, [5, 95], axis=0)
    low, high = p5 - spread, p95 + spread
    reserve = float(head.reserve_soc_pct)
    chargers = []
    for stop, start, _, _ in block.charger_stops:
        if start > t_now:
            i = min(int((start - t_now) / step_s), len(point) - 1)
            chargers.append({"t": start, "site": stop, "soc_pct": float(point[i]),
                             "band_pct": [float(low[i]), float(high[i])] if band else None})
    under = np.flatnonzero((high if band else point) < reserve)
    return Forecast(
        bus=bus, day=block.day, t=float(t_now), soc_now_pct=soc_now, end_t=block.end_s,
        end_soc_pct=float(point[-1]),
        end_band_pct=(float(low[-1]), float(high[-1])) if band else None,
        min_soc_pct=float(point.min()), min_band_top_pct=float(high.min()) if band else None,
        chargers=chargers, reserve_soc_pct=reserve, will_not_make_it=bool(under.size),
        below_reserve_t=float(times[under[0]]) if under.size else None, trips_left=left,
        fitted=bool(values), from_schedule=timetable,
        band_parts={"members_pct": [float(p5[-1]), float(p95[-1])],
                    "moved_pct": float(moved[-1])} if band else None,
        model_end_soc_pct=model_end, rate_end_soc_pct=by_rate)


def maybe_predict(twin, bus: str, settings) -> Forecast | None:
    """Predict ``bus``'s block when ``predict_every_s`` of data time passed since the last
    prediction and it is in its block; store it; raise the reserve alarm once a day (once
    the bus's model has been fitted: not on the starting model's guess)."""
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        head = conn.execute(sa.select(buses.c.last_t).where(buses.c.id == bus_id)).scalar()
        last = conn.execute(sa.select(sa.func.max(predictions.c.data_t))
                            .where(predictions.c.bus_id == bus_id)).scalar()
    if head is None or (last is not None and head - last < settings.predict_every_s):
        return None
    block = block_at(twin, bus_id, head)
    if block is None or not block.start_s <= head < block.end_s:
        return None
    try:
        fc = predict_bus(twin, bus, block, settings=settings)
    except ConfigError:
        return None  # no SoC yet: the next batch tries again
    store_forecast(twin, bus_id, fc)
    return fc


def store_forecast(twin, bus_id: int, fc: Forecast) -> None:
    with twin.store.engine.begin() as conn:
        conn.execute(predictions.insert().values(
            bus_id=bus_id, day=fc.day, made_at=twin.clock(), data_t=fc.t,
            end_soc_pct=fc.end_soc_pct, end_low_pct=fc.end_band_pct[0],
            end_high_pct=fc.end_band_pct[1], min_high_pct=fc.min_band_top_pct,
            detail=json.dumps({"chargers": fc.chargers, "end_t": fc.end_t,
                               "min_soc_pct": fc.min_soc_pct, "trips_left": fc.trips_left,
                               "will_not_make_it": fc.will_not_make_it,
                               "below_reserve_t": fc.below_reserve_t})))
        if fc.will_not_make_it and fc.fitted:  # not on the starting model's guess
            raised = conn.execute(sa.select(sa.func.count()).select_from(alarms).where(
                alarms.c.bus_id == bus_id, alarms.c.kind == "reserve",
                alarms.c.day == fc.day)).scalar()
            if not raised:
                ahead_min = (fc.below_reserve_t - fc.t) / 60.0
                conn.execute(alarms.insert().values(
                    bus_id=bus_id, kind="reserve", raised_at=twin.clock(), data_t=fc.t,
                    day=fc.day, lead_s=fc.below_reserve_t - fc.t,
                    message=f"{fc.bus} will run below its {fc.reserve_soc_pct:.0f} % reserve "
                            f"in about {ahead_min:.0f} min (at "
                            f"{pd.Timestamp(fc.below_reserve_t, unit='s'):%H:%M} UTC); "
                            f"block end predicted {fc.end_soc_pct:.1f} % "
                            f"({fc.end_band_pct[0]:.1f}-{fc.end_band_pct[1]:.1f} %), "
                            f"known {ahead_min:.0f} min ahead"))


def energy_tomorrow(twin, bus: str, settings=None) -> dict:
    """The battery energy [kWh] the bus's newest stored block needs, without its chargers:
    its trips driven with the bus's newest fitted model (the depot must put it in)."""
    from ebus_env.profile import Profile
    from ebus_env.twin.bus_refit import bus_model, latest_values
    from ebus_env.twin.jobs import JobSettings

    settings = settings or JobSettings()
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        last_t = conn.execute(sa.select(buses.c.last_t).where(buses.c.id == bus_id)).scalar()
        row = conn.execute(sa.select(schedules.c.day, schedules.c.block).where(
            schedules.c.bus_id == bus_id).order_by(schedules.c.day.desc()).limit(1)).first()
    if row is None or last_t is None:
        return {"bus": bus, "day": None, "kwh": None, "why": "no block or no data yet"}
    block = read_stored(row.block, row.day)
    past = history(twin, bus, bus_id, row.day, min(last_t, block.start_s))
    model = bus_model(settings.bus_config, settings.dt_s)
    channels, _, timetable = plan_inputs(block, block.start_s, past.like, settings.dt_s,
                                         15.0, chargers=False)
    res = model.simulate(Profile(channels, settings.dt_s, f"{bus} next block"),
                         latest_values(twin, bus_id), soc_start=0.95, record=False)
    summary = res.summary()
    return {"bus": bus, "day": row.day, "kwh": round(float(summary["battery_energy_kwh"]), 2),
            "km": round(float(summary["distance_km"]), 2),
            "why": "its block's trips on its fitted model, without its chargers"
                   + (f" ({timetable} as the timetable drives them)" if timetable else "")}

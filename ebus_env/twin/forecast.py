"""Predictions while a bus drives: its SoC at each planned charger and at the end of its
block, with a band, and the alarm when the band says it will run below its reserve.

From the bus's newest sample (time ``t``, measured SoC), the rest of its block is built as
the model's inputs: each remaining trip drives the speed trace of a trip of the same
direction the bus has driven (today's or an earlier day's, stretched to the planned
duration); between trips the bus stands, on a charger during the planned sessions; the
ambient is the last measured. The bus's model with its newest fitted values
(:func:`~ebus_env.twin.refit.latest_values`) runs it from the measured SoC.

The point prediction drives the most recent trip of each direction. The band runs
:data:`MEMBERS` members, each drawing every remaining trip from the bus's past trips of that
direction, and adds the model's own error, growing with the energy still to be used:
``sigma_model = MODEL_ERROR_FRAC * (SoC_now - SoC_end)`` (set on the fleet's buses 1-3 and
checked on the others, ``python -m benchmarks.bench_twin``). The 90 % band is the 5th to
95th percentile of the members widened by ``1.645 sigma_model``.

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
from ebus_env.twin.schedule import Block, read_block
from ebus_env.twin.store import alarms, buses, predictions, schedules

MEMBERS = 12
MODEL_ERROR_FRAC = 0.08
Z90 = 1.645
PAST_DAYS = 3  # days of past trips the band draws from
KEEP_TRIPS = 8  # the newest trips of each direction it keeps


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

    def to_json(self) -> dict:
        return asdict(self)


def _trips_driven(twin, bus: str, bus_id: int, day: str, before_t: float,
                  given: Block | None = None) -> dict[int, list]:
    """The 1 Hz speed traces of the trips the bus drove (this day's before ``before_t`` and
    the ``PAST_DAYS`` days before), by direction, newest last."""
    with twin.store.engine.connect() as conn:
        rows = conn.execute(sa.select(schedules.c.day, schedules.c.block).where(
            schedules.c.bus_id == bus_id, schedules.c.day <= day)
            .order_by(schedules.c.day.desc()).limit(PAST_DAYS + 1)).all()
    blocks = [read_block(json.loads(row.block)) for row in reversed(rows)]
    if given is not None:  # a block given to predict(), stored or not
        blocks = [b for b in blocks if b.date != given.date] + [given]
    legs = sorted({leg for blk in blocks for leg in blk.trips if leg.end_s <= before_t},
                  key=lambda leg: leg.start_s)
    out: dict[int, list] = {0: [], 1: []}
    if not legs:
        return out
    # the newest KEEP_TRIPS of each direction; kept per bus until another trip ends (the
    # live state a bus costs: 2 x 8 trips x ~3000 s x 4 bytes, about 0.2 MB)
    legs = [leg for d in (0, 1) for leg in [x for x in legs if x.direction == d][-KEEP_TRIPS:]]
    legs.sort(key=lambda leg: leg.start_s)
    key = (bus, tuple(leg.start_s for leg in legs))
    cached = twin.trip_cache.get(bus)
    if cached is not None and cached[0] == key:
        return cached[1]
    frame = pd.concat([twin.samples(bus, leg.start_s, leg.end_s, ("speed_kmh",))
                       for leg in legs])
    t, v = frame["t"].to_numpy(float), frame["speed_kmh"].to_numpy(float)
    for leg in legs:
        a, b = np.searchsorted(t, [leg.start_s, leg.end_s])
        if b - a > 60:
            out[leg.direction].append((v[a:b] / 3.6).astype(np.float32))
    twin.trip_cache[bus] = (key, out)
    return out


def _stretch(speed_mps: np.ndarray, n: int, from_frac: float = 0.0) -> np.ndarray:
    """``speed_mps`` (1 Hz) mapped onto ``n`` seconds, from ``from_frac`` of it on."""
    x = np.linspace(from_frac, 1.0, max(n, 2)) * (len(speed_mps) - 1)
    return np.interp(x, np.arange(len(speed_mps)), speed_mps)[:n]


def plan_inputs(block: Block, t: float, pick, dt_s: float, ambient_degc: float):
    """The model's input channels [1 s grid on ``dt_s``] from ``t`` to the block's end;
    ``pick(direction)`` gives a trip's 1 Hz speed trace."""
    n = int(np.ceil(block.end_s - t))
    if n < 2:
        raise ConfigError("the block has ended: nothing left to predict")
    speed = np.zeros(n)
    plugged = np.zeros(n)
    rating = np.zeros(n)
    left = 0
    for leg in block.trips:
        if leg.end_s <= t:
            continue
        left += 1
        a = max(int(np.floor(leg.start_s - t)), 0)
        b = min(int(np.ceil(leg.end_s - t)), n)
        frac = max(0.0, (t - leg.start_s) / (leg.end_s - leg.start_s))
        trace = pick(leg.direction)
        if trace is not None and b > a:
            speed[a:b] = _stretch(trace, b - a, frac)
    for ch in block.chargers:
        a, b = max(int(ch.start_s - t), 0), min(int(ch.end_s - t), n)
        if b > a:
            plugged[a:b] = 1.0
            rating[a:b] = 1e3 * ch.power_kw
    plugged[speed > 0.1] = 0.0
    steps = int(round(1.0 / dt_s))
    grid = np.arange(n * steps) * dt_s
    channels = {"speed_ref_mps": np.interp(grid, np.arange(n), speed),
                "charger_connected": np.repeat(plugged, steps),
                "charger_rating_w": np.repeat(rating, steps),
                "ambient_degc": np.full(n * steps, ambient_degc)}
    return channels, left


def predict_bus(twin, bus: str, schedule: dict | None = None, band: bool = True,
                at_t: float | None = None, settings=None, seed: int = 0) -> Forecast:
    """The :class:`Forecast` of ``bus`` from its newest sample (or its sample at ``at_t``)."""
    from ebus_env.profile import Profile
    from ebus_env.twin.jobs import JobSettings
    from ebus_env.twin.refit import bus_model, latest_values

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
    day = str(pd.Timestamp(t_now, unit="s").date())
    if schedule is None:
        schedule = twin.store.schedule(bus_id, day)
        if schedule is None:
            raise ConfigError(f"bus '{bus}' has no block for {day}: PUT it to "
                              f"/v1/buses/{bus}/schedules/{day}")
    block = read_block(schedule)
    model = bus_model(settings.bus_config, settings.dt_s)
    values = latest_values(twin, bus_id, before_t=t_now)
    vec = model.param_vector(values)
    past = _trips_driven(twin, bus, bus_id, day, t_now, block)
    if not past[0] and not past[1]:
        raise ConfigError(f"bus '{bus}' has driven no trip of its block yet: nothing to "
                          "build the rest of the block from")

    def newest(direction):
        return (past[direction] or past[1 - direction])[-1]

    soc_now = float(soc.iloc[-1])
    amb = float(ambient.iloc[-1]) if len(ambient) else 15.0

    def run(pick):
        channels, left = plan_inputs(block, t_now, pick, settings.dt_s, amb)
        profile = Profile(channels, settings.dt_s, f"{bus} block", 0.0)
        every = int(round(10.0 / settings.dt_s))
        res = model.simulate(profile, vec, soc_start=soc_now / 100.0, record_every=every)
        return 100.0 * res.trace("soc_frac").astype(float), every * settings.dt_s, left

    point, step_s, left = run(newest)
    times = t_now + step_s * np.arange(len(point))
    rng = np.random.default_rng(seed)
    members = [point]
    if band:
        for _ in range(MEMBERS):
            members.append(run(lambda d: _draw(past, d, rng))[0])
    stack = np.vstack([m[: len(point)] for m in members])
    used = np.maximum(soc_now - stack, 0.0)
    spread = Z90 * MODEL_ERROR_FRAC * used
    low = np.percentile(stack, 5, axis=0) - spread.max(axis=0)
    high = np.percentile(stack, 95, axis=0) + spread.max(axis=0)
    reserve = float(head.reserve_soc_pct)
    chargers = []
    for ch in block.chargers:
        if ch.start_s > t_now:
            i = min(int((ch.start_s - t_now) / step_s), len(point) - 1)
            chargers.append({"t": ch.start_s, "site": ch.name, "soc_pct": float(point[i]),
                             "band_pct": [float(low[i]), float(high[i])] if band else None})
    under = np.flatnonzero((high if band else point) < reserve)
    return Forecast(
        bus=bus, day=day, t=float(t_now), soc_now_pct=soc_now, end_t=block.end_s,
        end_soc_pct=float(point[-1]),
        end_band_pct=(float(low[-1]), float(high[-1])) if band else None,
        min_soc_pct=float(point.min()), min_band_top_pct=float(high.min()) if band else None,
        chargers=chargers, reserve_soc_pct=reserve, will_not_make_it=bool(under.size),
        below_reserve_t=float(times[under[0]]) if under.size else None, trips_left=left,
        fitted=bool(values))


def _draw(past, direction, rng):
    pool = past[direction] or past[1 - direction]
    return pool[int(rng.integers(len(pool)))]


def maybe_predict(twin, bus: str, settings) -> Forecast | None:
    """Predict ``bus``'s block when ``predict_every_s`` of data time passed since the last
    prediction and it is in its block; store it; raise the reserve alarm once a day."""
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        head = conn.execute(sa.select(buses.c.last_t).where(buses.c.id == bus_id)).scalar()
        last = conn.execute(sa.select(sa.func.max(predictions.c.data_t))
                            .where(predictions.c.bus_id == bus_id)).scalar()
    if head is None or (last is not None and head - last < settings.predict_every_s):
        return None
    day = str(pd.Timestamp(head, unit="s").date())
    schedule = twin.store.schedule(bus_id, day)
    if schedule is None:
        return None
    block = read_block(schedule)
    if not block.start_s <= head < block.end_s:
        return None
    try:
        fc = predict_bus(twin, bus, schedule, settings=settings)
    except ConfigError:
        return None  # nothing driven yet: the next batch tries again
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
        if fc.will_not_make_it:
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
    """The battery energy [kWh] the bus's next stored block needs, without its chargers:
    its trips driven with the bus's newest fitted model (the depot must put it in)."""
    from ebus_env.profile import Profile
    from ebus_env.twin.jobs import JobSettings
    from ebus_env.twin.refit import bus_model, latest_values

    settings = settings or JobSettings()
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        last_t = conn.execute(sa.select(buses.c.last_t).where(buses.c.id == bus_id)).scalar()
        row = conn.execute(sa.select(schedules.c.day, schedules.c.block).where(
            schedules.c.bus_id == bus_id).order_by(schedules.c.day.desc()).limit(1)).first()
    if row is None or last_t is None:
        return {"bus": bus, "day": None, "kwh": None, "why": "no block or no data yet"}
    block = read_block(json.loads(row.block))
    block = Block(block.trips, (), block.end_s, block.date)  # no chargers: what it uses
    past = _trips_driven(twin, bus, bus_id, row.day, min(last_t, block.start_s) + 1e9)
    if not past[0] and not past[1]:
        return {"bus": bus, "day": row.day, "kwh": None, "why": "no trip driven yet"}
    model = bus_model(settings.bus_config, settings.dt_s)
    channels, _ = plan_inputs(block, block.start_s, lambda d: (past[d] or past[1 - d])[-1],
                              settings.dt_s, 15.0)
    res = model.simulate(Profile(channels, settings.dt_s, f"{bus} next block"),
                         latest_values(twin, bus_id), soc_start=0.95, record=False)
    summary = res.summary()
    return {"bus": bus, "day": row.day, "kwh": round(float(summary["battery_energy_kwh"]), 2),
            "km": round(float(summary["distance_km"]), 2),
            "why": "its block's trips on its fitted model, without its chargers"}

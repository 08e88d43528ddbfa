"""``EBus-v0``: one battery-electric bus through one service day, with ECO actions."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import yaml

from ebus_env.config import ROOT, BusConfig, load_bus
from ebus_env.effects.vehicle import COMMUTER_SHAPE
from ebus_env.envs import reference
from ebus_env.envs.course import Course, course_from_cycle, course_from_route
from ebus_env.envs.reward import Reward, comfort_band_degc
from ebus_env.errors import ConfigError
from ebus_env.model.results import battery_energy_j
from ebus_env.units import J_PER_KWH

CONFIG_DIR = ROOT / "configs" / "env"


@dataclass(frozen=True)
class ActionRange:
    name: str
    unit: str
    low: float
    high: float
    meaning: str

    def value(self, a: np.ndarray) -> np.ndarray:
        """[-1, 1] to [low, high], linearly."""
        return self.low + 0.5 * (a + 1.0) * (self.high - self.low)


ACTIONS = (
    ActionRange("speed_cap_kmh", "km/h", 20.0, 80.0, "ECO-driving: cap on the top speed"),
    ActionRange("accel_cap_mps2", "m/s^2", 0.3, 1.5,
                "ECO-driving: cap on the acceleration (reached with a jerk-limited ramp)"),
    ActionRange("setpoint_degc", "degC", 14.0, 28.0, "ECO-comfort: cabin setpoint"),
    ActionRange("charge_power_frac", "1", 0.1, 1.0,
                "ECO-charging: charging power as a fraction of the charger's rating"),
    ActionRange("pulse_duty", "1", 0.2, 1.0,
                "ECO-charging: pulse duty cycle (1: continuous charging)"),
)
OBSERVATIONS = (  # name, unit, low, high
    ("soc", "1", 0.0, 1.0),
    ("cabin_temp_degc", "degC", -40.0, 60.0),
    ("ambient_degc", "degC", -40.0, 50.0),
    ("passengers", "1", 0.0, 250.0),
    ("speed_kmh", "km/h", 0.0, 120.0),
    ("time_of_day_h", "h", 0.0, 24.0),
    ("distance_to_charger_km", "km", 0.0, 200.0),
    ("schedule_delay_min", "min", -60.0, 60.0),
    ("charger_connected", "1", 0.0, 1.0),
    ("course_speed_kmh", "km/h", 0.0, 120.0),
    ("grade_pct", "%", -20.0, 20.0),
    ("service_left_h", "h", 0.0, 24.0),
    ("comfort_low_degc", "degC", -40.0, 60.0),
    ("comfort_high_degc", "degC", -40.0, 60.0),
)


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines an episode (``configs/env/*.yaml`` hold these keys)."""

    bus: str = "12m"  # name in configs/bus or a path
    overlay: str | None = None  # a calibrated overlay (``ebus calibrate --out``)
    cycle: str | None = "sort2"  # laps of a cycle, or
    route: str | None = None  # a King County route (``kc45_out``...)
    laps_per_trip: int | None = None  # cycle laps between terminal layovers (None: ~1 h)
    service_h: float = 13.5
    start_time_h: float = 5.0
    decision_s: float = 60.0
    dt_s: float = 0.1
    soc_start_pct: float = 95.0
    reserve_soc_pct: float = 20.0
    layover_min: float = 6.0  # scheduled layover at the terminal, on the charger
    min_layover_min: float = 2.0  # the shortest layover (plugging in and out)
    charger_kw: float | None = None  # terminal charger rating (None: the bus's charger)
    charge_at_terminal: bool = True
    ambient_mean_degc: float = 15.0  # daily mean
    ambient_amplitude_k: float = 4.0  # half the daily swing (coldest 05:00, warmest 15:00)
    ambient_random_k: float = 2.0  # daily mean drawn +- this per episode
    passengers_base_frac: float = 0.2  # of capacity, between peaks
    passengers_peak_frac: float = 0.8  # at the morning and evening peaks
    passengers_random_frac: float = 0.15  # each drawn +- this per episode
    jerk_mps3: float = 1.0  # ramp of the acceleration (paper App. B.1)
    comfort_decel_mps2: float = 1.0  # braking towards stops
    reward: dict = field(default_factory=dict)  # weights of Reward

    @classmethod
    def load(cls, source: str | Path | dict | None = None, **overrides) -> EnvConfig:
        """From a name in ``configs/env``, a YAML path or a mapping, with overrides."""
        data: dict = {}
        if isinstance(source, dict):
            data = dict(source)
        elif source is not None:
            path = Path(source)
            if not path.suffix:
                path = CONFIG_DIR / f"{source}.yaml"
            if not path.exists():
                names = sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))
                raise ConfigError(f"No env config '{source}' (looked for {path}); shipped: "
                                  f"{', '.join(names)}.")
            data = yaml.safe_load(path.read_text()) or {}
        data.update(overrides)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"Unknown env config key(s) {unknown}; known: {sorted(known)}.")
        return cls(**data)


class EBusEnv(gym.Env):
    """One battery-electric bus through one service day, with ECO-driving, ECO-comfort and
    ECO-charging actions.

    ## Description
    The bus drives laps of a line (a standard cycle or a King County route, described by
    distance: stops stay where they are) for a service day, with a layover on the terminal's
    charger after each trip, through a day of ambient temperature and passengers that rise
    to morning and evening peaks. Each agent step is one decision interval (``decision_s``,
    60 s); inside it the compiled Lo-Fi model (:mod:`ebus_env.model`) advances the physics at
    ``dt_s`` (10 Hz): powertrain, battery, CC/CV charging, cabin HVAC.

    ## Action Space
    ``Box(-1, 1, (5,), float32)``, each mapped linearly onto its range:

    | index | action | range | unit |
    |---|---|---|---|
    | 0 | ECO-driving: speed cap | 20 - 80 | km/h |
    | 1 | ECO-driving: acceleration cap (jerk-limited ramp, 1 m/s^3) | 0.3 - 1.5 | m/s^2 |
    | 2 | ECO-comfort: cabin setpoint | 14 - 28 | degC |
    | 3 | ECO-charging: charging power, fraction of the charger's rating | 0.1 - 1 | 1 |
    | 4 | ECO-charging: pulse duty cycle (period 10 s; 1 = continuous) | 0.2 - 1 | 1 |

    Capped driving keeps the distance: the bus stops at the same stops and takes longer;
    the delay is absorbed by the layover's slack (``layover_min - min_layover_min``) before
    it costs reward. The HVAC power follows from the cabin model and the setpoint; the cabin
    is preconditioned from the grid while on the charger. Charging actions act while
    connected; CC/CV behaviour comes from the model.

    ## Observation Space
    ``Box(float32)`` with finite bounds; names in ``env.observation_names``:

    | index | observation | unit |
    |---|---|---|
    | 0 | state of charge | 1 |
    | 1 | cabin temperature | degC |
    | 2 | ambient temperature | degC |
    | 3 | passengers on board | 1 |
    | 4 | speed | km/h |
    | 5 | time of day | h |
    | 6 | distance to the charger (the terminal) | km |
    | 7 | schedule delay (negative: early) | min |
    | 8 | charger connected | 1 |
    | 9 | the line's reference speed here | km/h |
    | 10 | road grade here | % |
    | 11 | service left | h |
    | 12, 13 | comfort band, low and high | degC |

    ## Rewards
    ``-(cost)`` of :class:`ebus_env.envs.reward.Reward`: battery energy [kWh], grid energy
    [kWh], rise of the peak grid power [kW], comfort violation [K h], delay at departures
    [min], SoC below the reserve [%-points h], each with a documented weight. ``info`` holds
    each term, the step's energy breakdown [kWh] and the grid power [kW].

    ## Starting State
    At the first departure, ``start_time_h``, SoC ``soc_start_pct``, the cabin at its
    setpoint; the day's mean ambient and the passenger base and peak are drawn from the
    seed.

    ## Episode End
    Terminated at the end of service (``service_h``) or when the battery is empty (its SoC
    floor reached with demand unmet). Truncation: ``gymnasium.make`` adds a TimeLimit of
    2000 decisions (``max_episode_steps``; a 24 h day of 60 s decisions fits).

    ## Arguments
    ``gymnasium.make("EBus-v0", config="gothenburg_jan", **overrides)``: ``config`` names a
    file in ``configs/env`` (or a path or a dict); overrides are :class:`EnvConfig` keys
    (``bus``, ``overlay``, ``cycle``/``route``, ``service_h``, ``decision_s``,
    ``ambient_mean_degc``, ``reward``, ...). ``render_mode``: ``"rgb_array"`` or ``"human"``.

    ## Version History
    * v0: first version.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 4}

    def __init__(self, config: str | Path | dict | None = None, render_mode: str | None = None,
                 **overrides):
        self.config = cfg = EnvConfig.load(config, **overrides)
        if cfg.decision_s < cfg.dt_s or abs(cfg.decision_s / cfg.dt_s
                                             - round(cfg.decision_s / cfg.dt_s)) > 1e-6:
            raise ConfigError(f"decision_s = {cfg.decision_s} must be a multiple of dt_s = "
                              f"{cfg.dt_s}.")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ConfigError(f"render_mode '{render_mode}': use one of "
                              f"{self.metadata['render_modes']} or None.")
        self.render_mode = render_mode
        self.bus: BusConfig = load_bus(cfg.bus, overlays=[cfg.overlay] if cfg.overlay else ())
        self.model = self.bus.build(cfg.dt_s)
        self.course: Course = _course(cfg)
        self.reward_fn = Reward(**cfg.reward)
        self.n_rows = int(round(cfg.decision_s / cfg.dt_s))
        self.lap_period_s = self.course.lap_time_s + 60.0 * cfg.layover_min
        self.observation_names = [o[0] for o in OBSERVATIONS]
        self.action_names = [a.name for a in ACTIONS]
        self.action_space = gym.spaces.Box(-1.0, 1.0, (len(ACTIONS),), np.float32)
        self.observation_space = gym.spaces.Box(
            np.array([o[2] for o in OBSERVATIONS], np.float32),
            np.array([o[3] for o in OBSERVATIONS], np.float32), dtype=np.float32)
        m = self.model
        self._rows_at = np.array([m.input_names.index(n) if n in m.input_names else -1
                                  for n in reference.ROW_NAMES], np.int64)
        self._inputs = np.zeros((1, len(m.input_names), self.n_rows))
        # inputs held for a decision (solar stays 0: the input buffer starts zeroed)
        self._fill = {n: m.input_names.index(n) for n in
                      ("ambient_degc", "passenger_count", "time_of_day_h") if n in m.input_names}
        self._row_h = np.arange(self.n_rows) * cfg.dt_s / 3600.0
        self._i = {n: i for i, n in enumerate(m.state_names)}
        self._energy_terms = [n for n, mode in m.layout.accumulators if mode == "sum"]
        capacity = next((p for p in m.param_names if p.endswith(".max_passengers")), "")
        self._param = {a: m.param_index(p) for a, p in (
            ("setpoint_degc", "cabin_hvac.setpoint_degc"), ("pulse_duty", "grid_charger.pulse_duty"),
            ("power", "grid_charger.power_kw"), ("capacity", capacity)) if p in m.param_names}
        self._kernel = m.kernel("run")
        self._charger_w = 1e3 * (cfg.charger_kw if cfg.charger_kw is not None else
                                 m.params[self._param["power"]] if "power" in self._param
                                 else 0.0)
        self._max_decisions = int(math.ceil(cfg.service_h * 3600.0 / cfg.decision_s))
        self._history: list[np.ndarray] = []
        self._states = None

    # -- the day ---------------------------------------------------------------------------
    def _draw_day(self) -> None:
        cfg, rng = self.config, self.np_random
        self._ambient_mean = cfg.ambient_mean_degc + rng.uniform(-1, 1) * cfg.ambient_random_k
        r = cfg.passengers_random_frac
        base = float(np.clip(cfg.passengers_base_frac + rng.uniform(-r, r), 0.0, 1.0))
        self._passengers = (base, float(np.clip(cfg.passengers_peak_frac + rng.uniform(-r, r),
                                                base, 1.0)))

    def ambient_degc(self, time_of_day_h: float) -> float:
        """Daily cycle: coldest at 05:00, warmest at 15:00, half-cosines between."""
        since_min = (time_of_day_h - 5.0) % 24.0
        shape = -math.cos(math.pi * since_min / 10.0) if since_min <= 10.0 else \
            math.cos(math.pi * (since_min - 10.0) / 14.0)
        return self._ambient_mean + self.config.ambient_amplitude_k * shape

    def passengers(self, time_of_day_h: float) -> float:
        x, y = COMMUTER_SHAPE.presets["commuter"].x, COMMUTER_SHAPE.presets["commuter"].y
        base, peak = self._passengers
        return self._capacity * (base + (peak - base) * float(np.interp(time_of_day_h, x, y)))

    # -- gym API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        cfg, m = self.config, self.model
        self._draw_day()
        self._params = m.params[None, :].copy()
        self._capacity = float(self._params[0, self._param["capacity"]]) \
            if "capacity" in self._param else 0.0
        self._ref = reference.new_state()[None, :]
        first = {"speed_ref_mps": 0.0, "ambient_degc": self.ambient_degc(cfg.start_time_h)}
        self._states = m.initial_state(self._params[0], first, soc_start=cfg.soc_start_pct
                                       / 100.0)[None, :]
        self._decision = 0
        self._peak_kw = 0.0
        self._departure_delay_s = 0.0
        self._history = []
        return self._observe(self._delay_s()), {"observation_names": self.observation_names}

    def _mapped(self, action) -> dict[str, float]:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"Action has shape {a.shape}; EBus-v0 takes {self.action_space.shape}"
                             f" ({', '.join(self.action_names)}), each in [-1, 1].")
        bad = ~np.isfinite(a) | (a < -1.0 - 1e-6) | (a > 1.0 + 1e-6)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"Action {i} ({self.action_names[i]}) = {a[i]}: every action must "
                             "be a finite number in [-1, 1] (the env maps it onto its range).")
        return {r.name: float(r.value(v)) for r, v in zip(ACTIONS, np.clip(a, -1.0, 1.0),
                                                           strict=True)}

    def step(self, action):
        if self._states is None:
            raise RuntimeError("Call reset() before step().")
        act = self._mapped(action)
        cfg, m = self.config, self.model
        hour = (cfg.start_time_h + self._decision * cfg.decision_s / 3600.0) % 24.0
        ambient, passengers = self.ambient_degc(hour), self.passengers(hour)
        if "setpoint_degc" in self._param:
            self._params[0, self._param["setpoint_degc"]] = act["setpoint_degc"]
        if "pulse_duty" in self._param:
            self._params[0, self._param["pulse_duty"]] = act["pulse_duty"]
        inputs = self._inputs
        lap_before = self._ref[0, reference.LAP]
        reference.advance(self._ref, self.course.speed_mps, self.course.grade_frac,
                          self.course.step_m, self.course.stop_m, self.course.dwell_s,
                          np.array([act["speed_cap_kmh"] / 3.6]),
                          np.array([act["accel_cap_mps2"]]), cfg.jerk_mps3,
                          cfg.comfort_decel_mps2, self.lap_period_s, 60.0 * cfg.min_layover_min,
                          1.0 if cfg.charge_at_terminal else 0.0,
                          np.array([act["charge_power_frac"] * self._charger_w]), cfg.dt_s,
                          self.n_rows, inputs, self._rows_at)
        for name, value in (("ambient_degc", ambient), ("passenger_count", passengers)):
            if name in self._fill:
                inputs[0, self._fill[name]] = value
        if "time_of_day_h" in self._fill:
            inputs[0, self._fill["time_of_day_h"]] = (hour + self._row_h) % 24.0
        cabin_before = self._cabin()
        distance_before = self._states[0, self._i["distance_m"]]
        acc = m.new_accumulators(1)
        self._kernel(self._params, self._states, inputs, _ZERO, _ZERO, self.n_rows, cfg.dt_s,
                     0, _NO_SEL, _NO_REC, _NO_MASK, acc, 0, 1)
        self._decision += 1
        delay_s = self._delay_s()
        info = self._info(acc, act, ambient, passengers, cabin_before, lap_before, delay_s)
        info["distance_km"] = (self._states[0, self._i["distance_m"]] - distance_before) / 1e3
        info["speed_kmh_mean"] = info["distance_km"] / (cfg.decision_s / 3600.0)
        obs = self._observe(delay_s)
        depleted = bool(info["battery_shortfall_kwh"] > 0.0)
        terminated = depleted or self._decision >= self._max_decisions
        info["depleted"] = depleted
        if self.render_mode is not None:  # the day so far, for render()
            self._history.append(np.array([
                self._decision * cfg.decision_s / 3600.0, info["speed_kmh_mean"],
                self._states[0, self._i["soc_frac"]], info["battery_kw"], info["grid_kw"],
                self._cabin(), act["setpoint_degc"]]))
            if self.render_mode == "human":
                self.render()
        return obs, float(info["reward"]), terminated, False, info

    def _cabin(self) -> float:
        i = self._i.get("cabin_temp_degc")
        return float(self._states[0, i]) if i is not None else float("nan")

    def _info(self, acc, act, ambient, passengers, cabin_before, lap_before,
              delay_s) -> dict:
        cfg, m = self.config, self.model
        hours = cfg.decision_s / 3600.0
        col = dict(zip(m.accumulator_names, acc[0], strict=True))
        _, chemical = battery_energy_j(m, acc)
        battery_kwh = float(chemical[0]) / J_PER_KWH
        grid_kwh = col["grid"] / J_PER_KWH
        grid_kw = grid_kwh / hours
        rise = max(grid_kw - self._peak_kw, 0.0)
        self._peak_kw = max(self._peak_kw, grid_kw)
        low, high = comfort_band_degc(ambient, passengers, self._capacity)
        cabin = 0.5 * (cabin_before + self._cabin())
        outside = max(low - cabin, cabin - high, 0.0) if math.isfinite(cabin) else 0.0
        late_min = 0.0
        if self._ref[0, reference.LAP] > lap_before:  # departed: the new delay at departure
            new = max(self._ref[0, reference.DEP_DELAY], 0.0)
            late_min = max(new - self._departure_delay_s, 0.0) / 60.0
            self._departure_delay_s = new
        soc = self._states[0, self._i["soc_frac"]]
        deficit = max(cfg.reserve_soc_pct - 100.0 * soc, 0.0) * hours
        reward, terms = self.reward_fn(battery_kwh=battery_kwh, grid_kwh=grid_kwh,
                                       peak_rise_kw=rise, comfort_kh=outside * hours,
                                       late_min=late_min, reserve_pct_h=deficit)
        breakdown = {n: col[n] / J_PER_KWH for n in self._energy_terms}
        return {"reward": reward, "reward_terms": terms, "battery_kwh": battery_kwh,
                "grid_kwh": grid_kwh, "grid_kw": grid_kw, "battery_kw": battery_kwh / hours,
                "peak_grid_kw": self._peak_kw, "peak_grid_kw_in_step": col["peak_grid"] / 1e3,
                "breakdown_kwh": breakdown,
                "battery_shortfall_kwh": col["battery_shortfall"] / J_PER_KWH,
                "comfort_band_degc": (low, high), "actions": act,
                "schedule_delay_min": delay_s / 60.0}

    def _delay_s(self) -> float:
        c = self.course
        return reference.schedule_delay_s(self._ref[0], c.baseline_s, c.dwell_s, c.step_m,
                                          self.lap_period_s)

    def _observe(self, delay_s: float) -> np.ndarray:
        cfg, c = self.config, self.course
        t_h = cfg.start_time_h + self._decision * cfg.decision_s / 3600.0
        hour = t_h % 24.0
        passengers = self.passengers(hour)
        low, high = comfort_band_degc(self.ambient_degc(hour), passengers, self._capacity)
        ref = self._ref[0]
        i = min(int(ref[reference.S] / c.step_m), len(c.speed_mps) - 1)
        values = (self._states[0, self._i["soc_frac"]], self._cabin(), self.ambient_degc(hour),
                  passengers, 3.6 * self._states[0, self._i["speed_mps"]], hour,
                  0.0 if ref[reference.MODE] == reference.LAYOVER
                  else (c.length_m - ref[reference.S]) / 1e3,
                  delay_s / 60.0, float(ref[reference.MODE] == reference.LAYOVER
                                                and self.config.charge_at_terminal),
                  3.6 * c.speed_mps[i], 100.0 * c.grade_frac[i],
                  max(cfg.service_h - self._decision * cfg.decision_s / 3600.0, 0.0), low, high)
        obs = np.array([0.0 if not math.isfinite(v) else v for v in values], np.float32)
        return np.clip(obs, self.observation_space.low, self.observation_space.high)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: pass render_mode='rgb_array' or "
                            "'human' to gymnasium.make.")
            return None
        from ebus_env.envs.render import draw

        return draw(self, self.render_mode)


_ZERO = np.zeros(1, np.int64)
_NO_SEL = np.zeros(0, np.int64)
_NO_REC = np.zeros((1, 0, 0), np.float32)
_NO_MASK = np.zeros(1, np.bool_)


def _course(cfg: EnvConfig) -> Course:
    if cfg.route:
        return course_from_route(cfg.route)
    if not cfg.cycle:
        raise ConfigError("An env config needs a 'cycle' or a 'route'.")
    from ebus_env.cycles import load_cycle

    lap = load_cycle(cfg.cycle)
    laps = cfg.laps_per_trip or max(1, int(round(3600.0 / lap.duration_s)))
    trip = lap
    for _ in range(laps - 1):
        trip = trip.then(lap)
    return replace(course_from_cycle(trip), name=f"{laps} x {cfg.cycle}")

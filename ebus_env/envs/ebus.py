"""``EBus-v0``: one battery-electric bus through one service day, with ECO actions."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

import gymnasium as gym
import numpy as np
import yaml

from ebus_env.config import ROOT
from ebus_env.envs.batch import OBS_HIGH, OBS_LOW, OBSERVATIONS, OUT, S_SOC, BusBatch
from ebus_env.envs.climate import climate_of
from ebus_env.envs.reward import QUANTITIES, TERMS, Reward
from ebus_env.errors import ConfigError

CONFIG_DIR = ROOT / "configs" / "env"
SCORED = ("peak_rise_kw", "comfort_kh", "late_min", "reserve_pct_h", "service_lost_h")  # in info, with OUT


@dataclass(frozen=True)
class ActionRange:
    name: str
    unit: str
    low: float
    high: float
    meaning: str  # mapped linearly from [-1, 1] onto [low, high] (``physical``)


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
ACTION_NAMES = tuple(r.name for r in ACTIONS)
ACTION_LOW = np.array([r.low for r in ACTIONS])
ACTION_SPAN = np.array([r.high - r.low for r in ACTIONS])


def checked_actions(actions, shape: tuple[int, ...], names: list[str], env: str) -> np.ndarray:
    """Actions as float64 of ``shape``, each finite and in [-1, 1], or a clear error naming
    the first bad one (``names`` along the last axis)."""
    a = np.asarray(actions, dtype=np.float64)
    if a.shape == shape and a.size:  # the common case, quickly (NaN fails every comparison)
        if a.size <= 16:  # one bus: Python's comparisons beat two numpy reductions (1.6 vs 5 us)
            if all(-1.0 <= x <= 1.0 for x in a.ravel().tolist()):
                return a
        elif -1.0 <= a.min() and a.max() <= 1.0:
            return a
    if a.shape != shape:
        raise ValueError(f"Action has shape {a.shape}; {env} takes {shape} ({', '.join(names)}),"
                         " each in [-1, 1].")
    bad = ~np.isfinite(a) | (a < -1.0 - 1e-6) | (a > 1.0 + 1e-6)
    if bad.any():
        i = np.unravel_index(int(np.flatnonzero(bad)[0]), a.shape)
        where = ", ".join(str(int(k)) for k in i)
        raise ValueError(f"Action [{where}] ({names[i[-1]]}) = {a[i]}: every action must be a "
                         f"finite number in [-1, 1] (the env maps it onto its range).")
    return np.clip(a, -1.0, 1.0)


def physical(actions: np.ndarray) -> np.ndarray:
    """Checked actions (..., 5) in [-1, 1] -> values in the units of ``ACTIONS``; -1 and 1
    give exactly low and high (a pulse duty of exactly 1 is continuous charging)."""
    return ACTION_LOW + 0.5 * (actions + 1.0) * ACTION_SPAN


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines an episode (``configs/env/*.yaml`` hold these keys)."""

    bus: str = "12m"  # name in configs/bus or a path
    overlay: str | None = None  # a calibrated overlay (``ebus calibrate --out``)
    cycle: str | None = "sort2"  # laps of a cycle, or
    route: str | None = None  # a King County route (``kc45_out``...), or
    log: str | None = None  # a measured log (CSV/Parquet): its speed profile is one trip
    log_columns: str | dict | None = None  # the log's column map or preset (configs/logs)
    laps_per_trip: int | None = None  # cycle laps between terminal layovers (None: ~1 h)
    service_h: float = 13.5
    start_time_h: float = 5.0
    decision_s: float = 60.0  # a decision's length (with decide_at_stops: the longest)
    decide_at_stops: bool = False  # decide at each departure (stop-to-stop segments, layovers)
    dt_s: float = 0.1
    soc_start_pct: float = 95.0
    reserve_soc_pct: float = 20.0
    layover_min: float = 6.0  # scheduled layover at the terminal, on the charger
    min_layover_min: float = 2.0  # the shortest layover (plugging in and out)
    charger_kw: float | None = None  # terminal charger rating (None: the bus's charger)
    charge_at_terminal: bool = True
    climate: str | dict | None = None  # monthly normals (ebus_env.envs.climate), with month
    month: int | None = None  # 1-12: the climate's month (sets the two ambient keys below)
    ambient_mean_degc: float | None = None  # daily mean (default 15 without a climate)
    ambient_amplitude_k: float | None = None  # half the daily swing (coldest 05:00,
    # warmest 15:00; default 4 without a climate)
    ambient_random_k: float = 2.0  # daily mean drawn +- this per episode
    passengers_base_frac: float = 0.2  # of capacity, between peaks
    passengers_peak_frac: float = 0.8  # at the morning and evening peaks
    passengers_random_frac: float = 0.15  # each drawn +- this per episode
    jerk_mps3: float = 1.0  # ramp of the acceleration (paper App. B.1)
    comfort_decel_mps2: float = 1.0  # braking towards stops
    reward: dict | Reward = field(default_factory=dict)  # weights of Reward, or one

    def __post_init__(self):
        mean, amplitude = self.ambient_mean_degc, self.ambient_amplitude_k
        if self.climate is not None or self.month is not None:
            if self.climate is None or self.month is None:
                raise ConfigError("climate and month go together: e.g. climate: barcelona, "
                                  "month: 7.")
            if mean is not None or amplitude is not None:
                raise ConfigError("Give either climate and month or ambient_mean_degc and "
                                  "ambient_amplitude_k, not both (the climate sets them).")
            mean, amplitude = climate_of(self.climate).ambient(self.month)
        object.__setattr__(self, "ambient_mean_degc", 15.0 if mean is None else float(mean))
        object.__setattr__(self, "ambient_amplitude_k",
                           4.0 if amplitude is None else float(amplitude))

    @classmethod
    def load(cls, source: str | Path | dict | None = None, **overrides) -> EnvConfig:
        """From a name in ``configs/env``, a YAML path or a mapping, with overrides."""
        return cls(**config_keys(cls, source, overrides, "env"))


def config_keys(cls, source: str | Path | dict | None, overrides: dict, kind: str,
                folder: Path = CONFIG_DIR) -> dict:
    """The keys of a config dataclass ``cls`` from a mapping, a YAML path or a name in
    ``folder``, with overrides on top; a missing file or an unknown key is a clear error."""
    data: dict = {}
    if isinstance(source, dict):
        data = dict(source)
    elif source is not None:
        path = Path(source)
        if not path.suffix:
            path = folder / f"{source}.yaml"
        if not path.exists():
            names = sorted(p.stem for p in folder.glob("*.yaml"))
            raise ConfigError(f"No {kind} config '{source}' (looked for {path}); shipped: "
                              f"{', '.join(names)}.")
        try:
            data = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            raise ConfigError(f"{kind} config {path}{where}: not valid YAML "
                              f"({getattr(exc, 'problem', None) or exc}); fix the file.") from None
        if not isinstance(data, dict):
            raise ConfigError(f"{kind} config {path}: needs key: value lines, got a "
                              f"{type(data).__name__}.")
    data.update(overrides)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"Unknown {kind} config key(s) {unknown}; known: {sorted(known)}.")
    return data


class EBusEnv(gym.Env):
    """One battery-electric bus through one service day, with ECO-driving, ECO-comfort and
    ECO-charging actions.

    ## Description
    The bus drives laps of a line (a standard cycle, a King County route, or a measured log's
    speed profile, described by distance: stops stay where they are) for a service day, with
    a layover on the terminal's charger after each trip, through a day of ambient temperature
    and passengers that rise to morning and evening peaks. Each agent step is one decision
    interval: ``decision_s`` (60 s), or with ``decide_at_stops`` one stop-to-stop segment
    (from a departure to the next, driving and dwelling) or a layover, at most ``decision_s``
    (longer ones are split). Inside it the compiled Lo-Fi model (:mod:`ebus_env.model`)
    advances the physics at ``dt_s`` (10 Hz): powertrain, battery, CC/CV charging, cabin HVAC.
    ``info["duration_s"]`` holds the decision's length.

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
    | 14 | the day's peak grid power so far (decision means; what the peak term charges) | kW |
    | 15 | layover left before the timetable's departure (0 while driving) | min |

    ## Rewards
    ``-(cost)`` of :class:`ebus_env.envs.reward.Reward`: battery energy [kWh], grid energy
    [kWh], rise of the peak grid power [kW], comfort violation [K h], delay at departures
    [min], SoC below the reserve [%-points h], service lost to an empty battery [h], each
    with a documented weight. ``info`` holds
    each term, the step's energy breakdown [kWh] and the grid power [kW].

    ## Starting State
    At the first departure, ``start_time_h``, SoC ``soc_start_pct``, the cabin at its
    setpoint; the day's mean ambient and the passenger base and peak are drawn from the
    seed.

    ## Episode End
    Terminated at the end of service (``service_h``) or when the battery is empty (SoC at the
    pack's floor ``soc_min_frac``, or a demand it cannot deliver): the service hours left are
    charged as lost service. Truncation: ``gymnasium.make`` adds a TimeLimit of
    10,000 decisions (``max_episode_steps``; a 24 h day of 10 s decisions fits).

    ## Arguments
    ``gymnasium.make("EBus-v0", config="kc45_hilly", **overrides)``: ``config`` names a
    file in ``configs/env`` (or a path or a dict); overrides are :class:`EnvConfig` keys
    (``bus``, ``overlay``, ``cycle``/``route``/``log``, ``service_h``, ``decision_s``,
    ``decide_at_stops``, ``climate`` and ``month``, ``ambient_mean_degc``, ``reward``
    (weights, or a :class:`Reward`), ...).
    ``render_mode``: ``"rgb_array"`` or ``"human"``.
    ``gymnasium.make_vec("EBus-v0", num_envs=64, ...)`` gives the native vector env
    (:class:`ebus_env.envs.vector.EBusVectorEnv`: one compiled call for all sub-envs, equal
    to single envs seeded ``seed + i``); :class:`ebus_env.envs.sb3.SB3VecEnv` adapts it to
    stable-baselines3.

    ## Version History
    * v0: first version (the peak so far, the layover left, the lost-service term and
      stop-to-stop decisions were added before the first release).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 4}

    def __init__(self, config: str | Path | dict | None = None, render_mode: str | None = None,
                 **overrides):
        self.config = cfg = EnvConfig.load(config, **overrides)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ConfigError(f"render_mode '{render_mode}': use one of "
                              f"{self.metadata['render_modes']} or None.")
        self.render_mode = render_mode
        self.buses = BusBatch(cfg, 1)
        self.bus, self.model, self.course = self.buses.bus, self.buses.model, self.buses.course
        self.reward_fn = reward_of(cfg)
        self.observation_names = [o[0] for o in OBSERVATIONS]
        self.action_names = list(ACTION_NAMES)
        self.action_space, self.observation_space = spaces()
        self._history: list[np.ndarray] = []
        self._started = False

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.buses.reset(0, self.np_random)
        self._history = []
        self._started = True
        return self.buses.obs[0].copy(), {"observation_names": self.observation_names}

    def step(self, action):
        if not self._started:
            raise RuntimeError("Call reset() before step().")
        values = physical(checked_actions(action, self.action_space.shape, self.action_names,
                                          "EBus-v0"))
        buses = self.buses
        buses.step(values[None])
        reward, costs = self.reward_fn(buses.quantities)
        depleted, end = buses.ended()
        info = bus_info(buses, 0, values, costs[0])
        info["reward"] = float(reward[0])
        info["depleted"] = bool(depleted[0])
        if self.render_mode is not None:  # the day so far, for render()
            self._history.append(np.array([
                buses.elapsed_h()[0], info["speed_kmh_mean"],
                buses.states[0, buses.at[S_SOC]], info["battery_kw"], info["grid_kw"],
                buses.cabin_degc(0), values[2]]))
            if self.render_mode == "human":
                self.render()
        return (buses.obs[0].copy(), info["reward"], bool(depleted[0] or end[0]), False, info)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: pass render_mode='rgb_array' or "
                            "'human' to gymnasium.make.")
            return None
        from ebus_env.envs.render import draw

        return draw(self, self.render_mode)


def spaces() -> tuple[gym.spaces.Box, gym.spaces.Box]:
    """Action and observation space of one bus."""
    return (gym.spaces.Box(-1.0, 1.0, (len(ACTIONS),), np.float32),
            gym.spaces.Box(OBS_LOW, OBS_HIGH, dtype=np.float32))


def reward_of(cfg: EnvConfig) -> Reward:
    """The config's reward: a :class:`Reward` instance as is, a dict as its weights."""
    return cfg.reward if isinstance(cfg.reward, Reward) else Reward(**cfg.reward)


def bus_info(buses: BusBatch, b: int, values: np.ndarray, costs: np.ndarray) -> dict:
    """``info`` of bus ``b``'s last decision: figures with units, reward terms, energy
    breakdown [kWh], the actions in their units."""
    info = dict(zip(OUT, buses.out[b].tolist(), strict=True))
    hours = info["duration_s"] / 3600.0
    info["battery_kw"] = info["battery_kwh"] / hours
    info["speed_kmh_mean"] = info["distance_km"] / hours
    info.update(zip(SCORED, buses.quantities[b, len(QUANTITIES) - len(SCORED):].tolist(),
                    strict=True))
    info["reward_terms"] = dict(zip(TERMS, costs.tolist(), strict=True))
    info["breakdown_kwh"] = buses.breakdown_kwh(b)
    info["actions"] = dict(zip(ACTION_NAMES, values.tolist(), strict=True))
    return info

"""Training for the world outside: the conditions a physical race differs from the simulator by.

A model trained only on the simulator's clean frames meets, in a real room, other light, glare,
another floor, a darker or blurrier camera, a car whose steering pulls to one side or whose
speed is not what the model asked, and a tenth of a second between the picture and the action.
With conditions on (a model setting, off by default), each episode draws its own from named
**families**, each a few parameters. Each parameter has a widest range (what the readiness check
tests up to; a racer's range must lie within it) and a narrower training range, the default
(:meth:`ConditionsSpec.default`: a moderate subset that the racing preset learns under, in
about 1.7 times the clean world's steps; docs/benchmarks.md):

- ``light``: ``brightness`` (an ambient veil added to every pixel, gray levels), ``contrast``
  (about mid-gray), ``gamma``, ``cast`` (warm/cool colour of the light: the orange centre line
  and the blue-black road change brightness differently under it) and ``glare`` (a bright
  reflection of a ceiling light somewhere in the frame, peak gray levels).
- ``look``: how bright the camera sees the ``road``, the border ``line``, the ``centre`` line,
  the ``floor`` beyond the borders and the ``wall`` (the room beyond the floor), each as its
  gray level (DeepRacer's colours keep their hue), and ``texture`` (a grain fixed on the ground
  like a carpet's or a printed mat's, gray levels).
- ``camera``: ``noise`` (sensor noise, gray levels), ``blur`` (Gaussian, pixels),
  ``exposure`` (stops) and the mount: ``yaw_deg``, ``pitch_deg``, ``height_mm``.
- ``car``: ``steering_offset_deg`` (positive pulls left), ``steering_gain``, ``speed_scale``.
- ``latency``: ``frames``: the action applies 0, 1 or 2 frames (1/15 s each) late.

:class:`ConditionsSpec` is what a model trains under (the enabled families and their ranges,
and optionally a curriculum, ``ramp_episodes``: the draws' strength grows from the clean world to
the whole ranges over each env's first episodes); :class:`Conditions` is one episode's draw.
How they are applied: :mod:`racing.conditioned_camera` (the camera's frame) and
:class:`Actuator` (the executed action). Everything is deterministic for a seed: draws come from
the generator the caller passes.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from racing.actions import MAX_SPEED, MAX_STEERING_DEG

FAMILIES: tuple[str, ...] = ("light", "look", "camera", "car", "latency")
IMAGE_FAMILIES: tuple[str, ...] = ("light", "look", "camera")
"""The families that change what the camera gives."""
ACTION_FAMILIES: tuple[str, ...] = ("car", "latency")
"""The families that change the executed action (and so the car's path)."""
RECOMMENDED_FAMILIES: tuple[str, ...] = ("light", "look", "camera", "car")
"""What a racer should turn on (``ConditionsSpec.default(RECOMMENDED_FAMILIES)``): latency
left out. Measured with the racing preset on re:Invent 2018 (docs/benchmarks.md, "Training for
the world outside"), latency in training (0-1 frame) cost steps to the goal (median 29,296
with it, 21,272 without, 12,336 clean) and bought nothing: no trained model completed a lap of
the readiness check's latency cells, though a scripted driver that sees no more than one frame
shows (the car's place and heading; no memory) and uses the racing preset's six actions of
issue 51 completes the 1-frame cells."""


RECOMMENDED_RAMP_EPISODES = 80
"""The curriculum a racer should use with :data:`RECOMMENDED_FAMILIES`
(``ConditionsSpec.default(RECOMMENDED_FAMILIES).with_ramp(RECOMMENDED_RAMP_EPISODES)``): the
draws' strength grows over each env's first 80 episodes. Measured with the racing preset (its
six actions of issue 51) on re:Invent 2018 (docs/benchmarks.md, "Training for the world
outside"), 3 seeds: 10,248 median
steps to the goal (no curriculum 21,272, the clean world 12,336), 52 % of the readiness check's
laps (no curriculum 47 %, clean 44 %)."""


class ConditionsError(ValueError):
    """Conditions that cannot be used; the message names the family and parameter."""


@dataclass(frozen=True)
class ParameterInfo:
    """One tunable of a family: ``label`` and ``unit`` for people, ``help`` (what it stands
    for in a real room), the ``neutral`` value (the simulator as it is), the widest range
    ``(low, high)`` (what the readiness check tests up to; a racer's range lies within it)
    and the training range ``(train_low, train_high)`` (the :attr:`default`: a moderate
    subset of the widest, see :meth:`ConditionsSpec.default`). ``integer``: drawn as a whole
    number."""

    label: str
    unit: str
    help: str
    neutral: float
    low: float
    high: float
    integer: bool = False
    train_low: float | None = None
    train_high: float | None = None
    """The default training range; ``None``: the widest range's end."""

    @property
    def widest(self) -> tuple[float, float]:
        return (self.low, self.high)

    @property
    def default(self) -> tuple[float, float]:
        """The training range a family turned on without ranges draws from."""
        low = self.low if self.train_low is None else self.train_low
        high = self.high if self.train_high is None else self.train_high
        return (low, high)


def _p(label, unit, help_, neutral, low, high, integer=False, *, train) -> ParameterInfo:
    """A parameter; ``train``: its default training range ``(low, high)``."""
    return ParameterInfo(label, unit, help_, float(neutral), float(low), float(high), integer,
                         float(train[0]), float(train[1]))  # fmt: skip


# The neutral look is DeepRacer's colours as the grayscale camera sees them (racing.texture).
_PARAMETERS: dict[str, dict[str, ParameterInfo]] = {
    "light": {
        "brightness": _p("Ambient light", "gray levels", "A darker room, or stray light "
                         "lifting the shadows: added to every pixel.", 0, -50, 50,
                         train=(-25, 25)),
        "contrast": _p("Contrast", "×", "Flat, diffuse light (below 1) or hard light with "
                       "deep shadows (above 1), about mid-gray.", 1, 0.7, 1.4,
                       train=(0.85, 1.2)),
        "gamma": _p("Gamma", "", "How mid-tones come out under the room's light: above 1 "
                    "darker, below 1 lighter.", 1, 0.7, 1.5,
                    train=(0.85, 1.2)),
        "cast": _p("Colour cast", "", "Warm lamps (positive: reds brighter, blues darker) "
                   "or cool daylight and LED panels (negative).", 0, -0.3, 0.3,
                   train=(-0.15, 0.15)),
        "glare": _p("Glare", "gray levels", "The reflection of a ceiling light on a glossy "
                    "track: a bright patch somewhere in the frame, this bright at its "
                    "centre.", 0, 0, 100,
                    train=(0, 50)),
    },
    "look": {
        "road": _p("Track surface", "gray level", "The track's surface as the camera sees "
                   "it: printed vinyl, carpet or painted board.", 53, 20, 140,
                   train=(35, 90)),
        "line": _p("Border lines", "gray level", "The border lines: white tape, "
                   "yellowed or dirty paint.", 208, 130, 255,
                   train=(170, 255)),
        "centre": _p("Centre line", "gray level", "The dashed centre line (orange on "
                     "DeepRacer's tracks).", 139, 60, 230,
                     train=(100, 200)),
        "floor": _p("Floor beyond the borders", "gray level", "The room's floor around "
                    "the track: dark carpet to light wood or concrete.", 133, 20, 230,
                    train=(80, 200)),
        "wall": _p("World beyond", "gray level", "What the camera sees beyond the floor: "
                   "DeepRacer's dark walls, or a bright room with people.", 17, 0, 220,
                   train=(0, 110)),
        "texture": _p("Surface texture", "gray levels", "Grain on the surface and the "
                      "floor (carpet, mat print), fixed on the ground.", 0, 0, 40,
                      train=(0, 15)),
    },
    "camera": {
        "noise": _p("Sensor noise", "gray levels", "The camera's noise in dim light "
                    "(standard deviation).", 0, 0, 12,
                    train=(0, 6)),
        "blur": _p("Blur", "pixels", "A lens slightly out of focus, or motion blur "
                   "(Gaussian standard deviation).", 0, 0, 1.5,
                   train=(0, 0.8)),
        "exposure": _p("Exposure", "stops", "A camera that exposes darker (negative) or "
                       "brighter (positive) than the simulator's.", 0, -1, 1,
                       train=(-0.5, 0.5)),
        "yaw_deg": _p("Mount yaw", "degrees", "The camera turned on its mount "
                      "(positive: to the left).", 0, -3, 3,
                      train=(-1.5, 1.5)),
        "pitch_deg": _p("Mount pitch", "degrees", "The camera tilted further down "
                        "(positive) or up on its mount.", 0, -3, 3,
                        train=(-1.5, 1.5)),
        "height_mm": _p("Mount height", "mm", "The camera higher (positive) or lower "
                        "than the simulator's 132 mm.", 0, -10, 10,
                        train=(-5, 5)),
    },
    "car": {
        "steering_offset_deg": _p("Steering offset", "degrees", "A car that pulls to one "
                                  "side: added to every steering angle (positive: "
                                  "left).", 0, -3, 3,
                                  train=(-1.5, 1.5)),
        "steering_gain": _p("Steering gain", "×", "A car that steers more or less than "
                            "asked (servo calibration).", 1, 0.85, 1.15,
                            train=(0.93, 1.07)),
        "speed_scale": _p("Speed scale", "×", "A car faster or slower than asked "
                          "(battery, throttle calibration, floor grip).", 1, 0.8, 1.2,
                          train=(0.9, 1.05)),
    },
    "latency": {
        "frames": _p("Latency", "frames", "The action applies this many frames (1/15 s "
                     "each) after the picture it answers.", 0, 0, 2, integer=True,
                     train=(0, 1)),
    },
}  # fmt: skip


def parameters() -> dict[str, dict[str, ParameterInfo]]:
    """Every family's parameters: ``{family: {name: ParameterInfo}}`` (for forms and docs)."""
    return {family: dict(params) for family, params in _PARAMETERS.items()}


def _family(family: object) -> dict[str, ParameterInfo]:
    if family not in _PARAMETERS:
        raise ConditionsError(f"unknown conditions family {family!r}; known: {', '.join(FAMILIES)}")
    return _PARAMETERS[family]  # type: ignore[index]


def _info(family: str, name: str) -> ParameterInfo:
    params = _family(family)
    if name not in params:
        raise ConditionsError(
            f"unknown parameter {name!r} of the {family} family; known: {', '.join(params)}"
        )
    return params[name]


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ConditionsError(f"{where} must be a number, not {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ConditionsError(f"{where} must be finite, not {value}")
    return value


def _frozen(data: Mapping[str, Mapping]) -> Mapping[str, Mapping]:
    return MappingProxyType({k: MappingProxyType(dict(v)) for k, v in data.items()})


@dataclass(frozen=True)
class Conditions:
    """One episode's conditions: ``values[family][name]``, every family and parameter (the
    families not drawn hold their neutral values). Build with :meth:`clean`,
    :meth:`from_dict`, :meth:`at_strength` or :meth:`ConditionsSpec.sample`."""

    values: Mapping[str, Mapping[str, float]]

    @classmethod
    def clean(cls) -> Conditions:
        """The simulator as it is: every parameter neutral."""
        return cls(
            _frozen({f: {n: i.neutral for n, i in p.items()} for f, p in _PARAMETERS.items()})
        )

    @classmethod
    def at_strength(cls, family: str, strength: float, rng: np.random.Generator) -> Conditions:
        """Only ``family`` set: each of its parameters ``strength`` (0-1) of the way from
        neutral to one edge of its widest range (which edge, for a parameter whose neutral
        lies inside it, drawn from ``rng``). Integer parameters are rounded. 0 is clean."""
        _family(family)
        strength = _number(strength, "strength")
        if not 0.0 <= strength <= 1.0:
            raise ConditionsError(f"strength must be 0-1, not {strength:g}")
        values = {f: dict(v) for f, v in cls.clean().values.items()}
        for name, info in _PARAMETERS[family].items():
            edges = [e for e in (info.low, info.high) if e != info.neutral]
            if not edges:
                continue
            edge = edges[int(rng.integers(len(edges)))] if len(edges) > 1 else edges[0]
            value = info.neutral + strength * (edge - info.neutral)
            values[family][name] = float(round(value)) if info.integer else value
        return cls(_frozen(values))

    @classmethod
    def from_dict(cls, data: Mapping) -> Conditions:
        """From :meth:`to_dict`'s form; missing families and parameters are neutral. Raises
        :class:`ConditionsError` for an unknown name, a non-finite value or one outside the
        parameter's widest range."""
        if not isinstance(data, Mapping):
            raise ConditionsError(f"conditions must be a mapping of families, not {data!r}")
        values = {f: dict(v) for f, v in cls.clean().values.items()}
        for family, params in data.items():
            _family(family)
            if not isinstance(params, Mapping):
                raise ConditionsError(f"the {family} family must be a mapping of parameters")
            for name, raw in params.items():
                info = _info(family, name)
                value = _number(raw, f"{family}.{name}")
                if not info.low <= value <= info.high:
                    raise ConditionsError(
                        f"{family}.{name} = {value:g} is outside {info.low:g}..{info.high:g}"
                    )
                values[family][name] = float(round(value)) if info.integer else value
        return cls(_frozen(values))

    def to_dict(self) -> dict:
        """``{family: {name: value}}``, every family and parameter (JSON-safe floats)."""
        return {f: {n: float(v) for n, v in p.items()} for f, p in self.values.items()}

    def __hash__(self) -> int:
        return hash(tuple((f, tuple(p.items())) for f, p in self.values.items()))

    def __reduce__(self):  # picklable (worker processes), though its mappings are read-only
        return (_rebuild, (type(self).__name__, self.to_dict()))

    def family_is_neutral(self, family: str) -> bool:
        params = _PARAMETERS[family]
        return all(self.values[family][n] == i.neutral for n, i in params.items())

    @property
    def is_clean(self) -> bool:
        return all(self.family_is_neutral(f) for f in FAMILIES)

    @property
    def changes_image(self) -> bool:
        """Whether the camera's frame differs from the clean one's."""
        return not all(self.family_is_neutral(f) for f in IMAGE_FAMILIES)

    @property
    def changes_action(self) -> bool:
        """Whether the executed action differs from the one asked."""
        return not all(self.family_is_neutral(f) for f in ACTION_FAMILIES)


@dataclass(frozen=True)
class ConditionsSpec:
    """What a model trains under: ``ranges[family][name] = (low, high)`` for each enabled
    family (every parameter of it); families left out stay neutral.

    ``ramp_episodes`` (a curriculum; 0, the default: none): the draws' strength grows over each
    env's first ``ramp_episodes`` episodes, ``min(1, episode / ramp_episodes)``
    (:meth:`strength_at`), every range scaled by it about its parameter's neutral value
    (:meth:`sample`): an env's first episode is clean, its ``ramp_episodes``-th and later draw
    from the whole ranges. Counted per env, it needs no messages between envs and stays
    deterministic for a seed."""

    ranges: Mapping[str, Mapping[str, tuple[float, float]]] = field(
        default_factory=lambda: MappingProxyType({})
    )
    ramp_episodes: int = 0

    @classmethod
    def default(cls, families: Iterable[str] = FAMILIES) -> ConditionsSpec:
        """``families`` enabled, each parameter over its training range
        (:attr:`ParameterInfo.default`): about half the widest range either side of neutral
        and at most one frame of latency. With all five families at their widest the racing
        preset missed bench_training's goal in 31,840-88,880 steps (the clean world reaches
        it in 8,680-12,408); the readiness check still tests up to the widest
        (docs/benchmarks.md, "Training for the world outside"). What a racer should turn
        on: :data:`RECOMMENDED_FAMILIES`."""
        return cls.from_dict({"families": {f: {} for f in families}})

    @classmethod
    def widest(cls, families: Iterable[str] = FAMILIES) -> ConditionsSpec:
        """``families`` enabled, each parameter over its widest range (what the readiness
        check tests up to; a racer who wants it all can ask for it)."""
        info = parameters()
        return cls.from_dict(
            {"families": {f: {n: list(i.widest) for n, i in info[f].items()} for f in families}}
        )

    @classmethod
    def from_dict(cls, data: Mapping) -> ConditionsSpec:
        """From ``{"families": {family: {name: [low, high], ...}, ...}}`` (:meth:`to_dict`'s
        form). A family given as ``{}`` or ``true`` (or ``"families"`` as a list of names)
        takes every parameter's training range (:attr:`ParameterInfo.default`); a parameter
        left out of a family takes its training range. Raises :class:`ConditionsError` for
        an unknown family or parameter, a range that is not two finite numbers, low above
        high, or a range wider than the parameter's widest (a range may be anything within
        the widest, never wider)."""
        if not isinstance(data, Mapping) or "families" not in data:
            raise ConditionsError('conditions must be a mapping with a "families" key')
        unknown = sorted(set(data) - {"families", "ramp_episodes"})
        if unknown:
            raise ConditionsError(
                f"unknown conditions key {unknown[0]!r}; only 'families' and 'ramp_episodes'"
            )
        ramp = _ramp(data.get("ramp_episodes", 0))
        families = data["families"]
        if isinstance(families, list | tuple):
            families = {f: {} for f in families}
        if not isinstance(families, Mapping):
            raise ConditionsError('"families" must map family names to parameter ranges')
        ranges: dict[str, dict[str, tuple[float, float]]] = {}
        for family in FAMILIES:  # the canonical order, whatever the input's
            if family not in families:
                continue
            given = families[family]
            if given is True or given is None:
                given = {}
            if not isinstance(given, Mapping):
                raise ConditionsError(f"the {family} family must map parameters to [low, high]")
            for name in given:
                _info(family, name)
            ranges[family] = {
                name: _range(family, name, info, given.get(name))
                for name, info in _PARAMETERS[family].items()
            }
        for family in families:
            _family(family)
        return cls(_frozen(ranges), ramp)

    def to_dict(self) -> dict:
        """``{"families": {family: {name: [low, high]}}}``, and ``"ramp_episodes": n`` when a
        curriculum is set (left out at 0, so a setting without one reads as before): JSON- and
        YAML-safe."""
        data: dict = {
            "families": {
                f: {n: [float(lo), float(hi)] for n, (lo, hi) in p.items()}
                for f, p in self.ranges.items()
            }
        }
        if self.ramp_episodes:
            data["ramp_episodes"] = self.ramp_episodes
        return data

    def with_ramp(self, ramp_episodes: int) -> ConditionsSpec:
        """The same ranges with a curriculum of ``ramp_episodes`` episodes (0: none)."""
        return ConditionsSpec(self.ranges, _ramp(ramp_episodes))

    def strength_at(self, episode: int) -> float:
        """The draws' strength in an env's ``episode`` (0, 1, ...): ``min(1, episode /
        ramp_episodes)``, 1 without a curriculum."""
        if not self.ramp_episodes:
            return 1.0
        return min(1.0, max(0, episode) / self.ramp_episodes)

    @property
    def families(self) -> tuple[str, ...]:
        return tuple(self.ranges)

    def __hash__(self) -> int:
        ranges = tuple((f, tuple(p.items())) for f, p in self.ranges.items())
        return hash((ranges, self.ramp_episodes))

    def __reduce__(self):  # picklable (worker processes), though its mappings are read-only
        return (_rebuild, (type(self).__name__, self.to_dict()))

    def sample(self, rng: np.random.Generator, strength: float = 1.0) -> Conditions:
        """One episode's draw: each enabled parameter uniform over its range (integer ones
        uniform over the whole numbers in it), from one ``rng.random`` call in a fixed order
        (and, where an integer parameter is enabled, a second one after it).

        ``strength`` (0-1; a curriculum's, :meth:`strength_at`) eases the draw towards the
        clean world. A real-valued parameter's range is scaled about its neutral value:
        ``neutral + strength * (end - neutral)`` for both ends. An integer parameter (latency)
        cannot take a fraction of a frame, and its range scaled down would hold only its
        neutral value until the very end of a curriculum; so it takes its whole-range draw in a
        share ``strength`` of the episodes and its neutral value in the rest (the second call
        decides which): its mean is scaled as a real one's is. 0 draws the clean world. The
        same calls are made at every strength, so what the caller draws after them does not
        depend on it."""
        strength = _number(strength, "strength")
        if not 0.0 <= strength <= 1.0:
            raise ConditionsError(f"strength must be 0-1, not {strength:g}")
        values = {f: dict(v) for f, v in Conditions.clean().values.items()}
        drawn = [(f, n, lo, hi) for f, p in self.ranges.items() for n, (lo, hi) in p.items()]
        uniforms = rng.random(len(drawn))
        integers = sum(_PARAMETERS[f][n].integer for f, n, _, _ in drawn)
        shares = iter(rng.random(integers))  # none drawn where no integer parameter is on
        for (family, name, lo, hi), u in zip(drawn, uniforms, strict=True):
            info = _PARAMETERS[family][name]
            if info.integer:
                first, last = math.ceil(lo), math.floor(hi)
                value = float(min(last, first + math.floor(u * (last - first + 1))))
                if next(shares) >= strength:  # strength 1: always the whole-range draw
                    value = info.neutral
            else:
                if strength != 1.0:
                    lo = info.neutral + strength * (lo - info.neutral)
                    hi = info.neutral + strength * (hi - info.neutral)
                value = lo + float(u) * (hi - lo)
            values[family][name] = value
        return Conditions(_frozen(values))


MAX_RAMP_EPISODES = 100_000
"""The longest curriculum (:attr:`ConditionsSpec.ramp_episodes`), episodes of one env."""


def _ramp(value: object) -> int:
    """A curriculum's length in episodes, validated: a whole number 0..MAX_RAMP_EPISODES."""
    number = _number(value, "ramp_episodes")
    if number != int(number) or not 0 <= number <= MAX_RAMP_EPISODES:
        raise ConditionsError(
            f"ramp_episodes must be a whole number 0..{MAX_RAMP_EPISODES}, not {value!r}"
        )
    return int(number)


def _range(family: str, name: str, info: ParameterInfo, given: object) -> tuple[float, float]:
    if given is None:
        return info.default
    where = f"{family}.{name}"
    if not isinstance(given, list | tuple) or len(given) != 2:
        raise ConditionsError(f"{where} must be a range [low, high], not {given!r}")
    lo, hi = _number(given[0], f"{where} low"), _number(given[1], f"{where} high")
    if lo > hi:
        raise ConditionsError(f"{where}: low {lo:g} is above high {hi:g}")
    if lo < info.low or hi > info.high:
        raise ConditionsError(
            f"{where}: {lo:g}..{hi:g} is wider than its widest range "
            f"{info.low:g}..{info.high:g} (a range may be anything within its widest)"
        )
    if info.integer and math.floor(hi) < math.ceil(lo):
        raise ConditionsError(f"{where}: {lo:g}..{hi:g} holds no whole number")
    return (lo, hi)


class Actuator:
    """The car and latency families between the model's action and the car.

    The car's errors: steering ``gain * asked + offset`` (clipped to ±30°), speed
    ``scale * asked`` (at most 4 m/s). Latency ``k``: the command executed at a step is the
    one asked ``k`` steps before. In an episode's first ``k`` steps nothing has arrived yet and
    the car gets the command it had before the episode: straight ahead at 0 m/s (it stands or
    rolls to a stop). Commands queued before a reset penalty still arrive after it.
    """

    def __init__(self, conditions: Conditions) -> None:
        car = conditions.values["car"]
        self.offset = car["steering_offset_deg"]
        self.gain = car["steering_gain"]
        self.scale = car["speed_scale"]
        self.delay = int(conditions.values["latency"]["frames"])
        self._queue: deque[tuple[float, float]] = deque([(0.0, 0.0)] * self.delay)

    def __call__(self, steering: float, speed: float) -> tuple[float, float]:
        """The command executed this step when the model asks ``(steering°, speed m/s)``."""
        steer = max(-MAX_STEERING_DEG, min(MAX_STEERING_DEG, self.gain * steering + self.offset))
        command = (steer, min(MAX_SPEED, self.scale * speed))
        if not self.delay:
            return command
        self._queue.append(command)
        return self._queue.popleft()


def _rebuild(kind: str, data: dict) -> Conditions | ConditionsSpec:
    """Unpickle a :class:`Conditions` or :class:`ConditionsSpec` from its dict form."""
    return {"Conditions": Conditions, "ConditionsSpec": ConditionsSpec}[kind].from_dict(data)

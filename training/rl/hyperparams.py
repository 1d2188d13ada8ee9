"""DeepRacer's hyperparameters (``hyperparameters.json``): names, ranges, defaults, validation.

Plain library code (no Django): the console's forms, the command line, model import and the
trainer all read hyperparameters through :func:`parse_hyperparameters`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

BATCH_SIZES = (32, 64, 128, 256, 512)
LOSS_TYPES = ("huber", "mean_squared_error")
EXPLORATION_TYPES = ("categorical", "e-greedy", "additive_noise")
ALGORITHMS = ("clipped_ppo", "sac")


class HyperparameterError(ValueError):
    """Hyperparameters out of range; ``field`` names the offending key."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field


@dataclass(frozen=True)
class Hyperparameters:
    """DeepRacer's hyperparameters with the console's defaults for PPO.

    ``batch_size`` one of 32-512 (gradient descent batch), ``num_epochs`` 3-10 (PPO),
    ``lr`` learning rate 1e-8..1e-3, ``beta_entropy`` 0..1 (PPO entropy bonus), ``sac_alpha``
    0..1 (SAC entropy weight), ``discount_factor`` 0..1, ``loss_type`` huber or
    mean_squared_error, ``num_episodes_between_training`` 1..100 (episodes per policy update),
    ``stack_size`` frames stacked (1-4), ``exploration_type``, ``e_greedy_value``,
    ``epsilon_steps``, ``term_cond_max_episodes``, ``term_cond_avg_score``.
    """

    batch_size: int = 64
    num_epochs: int = 10
    lr: float = 0.0003
    beta_entropy: float = 0.01
    sac_alpha: float = 0.2
    discount_factor: float = 0.999
    loss_type: str = "huber"
    num_episodes_between_training: int = 20
    stack_size: int = 1
    exploration_type: str = "categorical"
    e_greedy_value: float = 0.05
    epsilon_steps: int = 10000
    term_cond_max_episodes: int = 100000
    term_cond_avg_score: float = 100000.0

    def to_json(self) -> dict:
        return asdict(self)


SAC_DEFAULTS = {
    "discount_factor": 0.99,
    "loss_type": "mean_squared_error",
    "num_episodes_between_training": 1,
}

RANGES: dict[str, tuple[float, float]] = {
    "num_epochs": (3, 10),
    "lr": (1e-8, 1e-3),
    "beta_entropy": (0.0, 1.0),
    "sac_alpha": (0.0, 1.0),
    "discount_factor": (0.0, 1.0),
    "num_episodes_between_training": (1, 100),
    "stack_size": (1, 4),
    "e_greedy_value": (0.0, 1.0),
    "epsilon_steps": (1, 10_000_000),
    "term_cond_max_episodes": (1, 10_000_000),
    "term_cond_avg_score": (0.0, 1e9),
}
"""Inclusive ranges of the numeric keys."""


def defaults_for(algorithm: str) -> Hyperparameters:
    """The console's defaults for ``clipped_ppo`` or ``sac``."""
    if algorithm not in ALGORITHMS:
        raise HyperparameterError("training_algorithm", f"must be one of {ALGORITHMS}")
    base = Hyperparameters()
    if algorithm == "sac":
        return Hyperparameters(**{**asdict(base), **SAC_DEFAULTS})
    return base


def parse_hyperparameters(data: dict | None, algorithm: str = "clipped_ppo") -> Hyperparameters:
    """Validate a ``hyperparameters.json`` dict; missing keys take the algorithm's defaults.

    Unknown keys are ignored (DeepRacer files carry a few trainer-only ones). Raises
    :class:`HyperparameterError` naming the first bad key.
    """
    values = asdict(defaults_for(algorithm))
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise HyperparameterError("hyperparameters", "must be a JSON object")
    known = {f.name: f.type for f in fields(Hyperparameters)}
    for key, raw in data.items():
        if key not in known:
            continue
        default = values[key]
        if isinstance(default, str):
            if not isinstance(raw, str):
                raise HyperparameterError(key, f"must be text, not {raw!r}")
            values[key] = raw.strip().lower()
            continue
        if isinstance(raw, bool) or not isinstance(raw, int | float | str):
            raise HyperparameterError(key, f"must be a number, not {raw!r}")
        try:
            number = float(raw)
        except ValueError:
            raise HyperparameterError(key, f"must be a number, not {raw!r}") from None
        if not math.isfinite(number):
            raise HyperparameterError(key, f"must be finite, not {raw!r}")
        if isinstance(default, int):
            if number != int(number):
                raise HyperparameterError(key, f"must be a whole number, not {raw!r}")
            values[key] = int(number)
        else:
            values[key] = number
    hp = Hyperparameters(**values)
    validate(hp, algorithm)
    return hp


def validate(hp: Hyperparameters, algorithm: str = "clipped_ppo") -> None:
    if hp.batch_size not in BATCH_SIZES:
        raise HyperparameterError("batch_size", f"must be one of {BATCH_SIZES}")
    for key, (low, high) in RANGES.items():
        value = getattr(hp, key)
        if not low <= value <= high:
            raise HyperparameterError(key, f"must be between {low:g} and {high:g}, not {value:g}")
    if hp.loss_type not in LOSS_TYPES:
        raise HyperparameterError("loss_type", f"must be one of {LOSS_TYPES}")
    if hp.exploration_type not in EXPLORATION_TYPES:
        raise HyperparameterError("exploration_type", f"must be one of {EXPLORATION_TYPES}")
    if algorithm == "clipped_ppo" and hp.num_episodes_between_training < 1:
        raise HyperparameterError("num_episodes_between_training", "must be at least 1")

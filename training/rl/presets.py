"""Starting points for a new model: DeepRacer's defaults, and a racing preset for fast laps.

One place for this knowledge: the create-model wizard offers them ("Start from"), the command
line takes ``--preset``, and the benchmarks (bench/bench_training.py, bench/bench_imported.py)
train with exactly what a user gets. A preset names its example reward by id (the files live
in :mod:`training.rewards.examples`, a layer above this one: read them with
``example_source(preset.reward_example)``).

Why the racing preset aims at a fast lap and DeepRacer's defaults cannot: at 1.0 m/s at most, a
lap of re:Invent 2018 (17.7 m along the centre line) takes 17.7 s however well the car learns.
The racing preset's actions go up to 3.5 m/s (DeepRacer allows 4: why not, below), each steering
angle with the fastest speed its tyres hold: the car turns on a circle of radius L / tan(angle)
(L = 0.165 m wheelbase), and the tyres hold v² / r up to about μg = 9.8 m/s², so 10° allows 3
m/s and 20° 2 m/s. An action beyond that slides off the track whatever the policy learns; an
action space with 3 m/s at 30° (an earlier version of this preset) learnt to drive round at 1.5
m/s and never went under 10.4 s a lap. 20° turns on a circle of 0.45 m. The tightest bend of
DeepRacer's 78 track files measures 0.33 m along its centre line (Tokyo's training track; the
circle through three waypoints), but the car has half the track's width to take a bend wider:
0.67 m at least on every one of them. So 30° at 1.5 m/s (in this preset until issue 26) is gone:
a slow action the policy had to learn not to take. Following the centre line pays for staying on
the track, not for getting round it, so the reward pays speed along the track, anywhere on it
(the racing line cuts corners), and pays its square: with speed itself a metre paid the same at
any speed (the reward per step times the steps a metre takes), and only the discount made a
faster car worth more. A discount of 0.98 weighs about 50 steps (3 simulated seconds) ahead: far
enough to brake for a bend (from 4 to 2 m/s takes a quarter of a second); 0.999 weighs about
1000 (67 s, several laps), so each reward's credit is spread over far more steps and takes more
experience to sort out.
The compact network (4×4 averaging to 40×30, 16 and 16 filters, 128 units) updates in about 0.6
of the lean network's time and, over 10 seeds, reached the preset's goal in fewer steps (median
16,408 against 19,208). Minibatches of 32 instead of 64 (twice the gradient steps an update, at
1.1-1.2 times its cost) steadied the seeds: over 10 seeds a median of 14,572 steps and at most
19,712, against 16,408 and 56,728: docs/benchmarks.md, "The compact network". The six actions,
the squared speed and the discount of 0.98 together drive faster laps at the goal for the same
training (15 seeds: a median qualifying lap of 6.00 against 7.00 s, best lap 5.33 against 5.40
s, a median of 13,448 steps against 14,952): docs/benchmarks.md, "Faster laps".
Why straight ahead stops at 3.5 m/s: the camera's single frame does not show how fast the car
is going, and the car needs time to brake (from 4 to 2 m/s, a quarter of a second). With 4 m/s
the seeds that stalled drove clean laps and then left the track again, update after update,
at the same place: the greedy car took 4 m/s on the short straight between two bends and reached
the second at 3.6 m/s (the median). The same policies with 4 m/s replaced by 3 m/s drove three
clean laps every time (34 of 34 on seeds 0-14, ``bench/bench_stalls.py``). With 3.5 m/s at the
top, over 30 seeds: a median of 12,316 steps to the goal against 13,896, at most 23,632 against
42,120, laps no slower (a median qualifying lap of 5.93 against 6.00 s): docs/benchmarks.md,
"Why seeds stall".
"""

from __future__ import annotations

from dataclasses import dataclass, field

from racing.actions import DEFAULT_DISCRETE
from training.rl.hyperparams import Hyperparameters
from training.rl.policies import COMPACT, LEAN


@dataclass(frozen=True)
class Preset:
    """A model's starting configuration; ``label`` and ``summary`` say what it is to a user.

    ``action_space`` is DeepRacer's discrete list (``steering_angle`` degrees, ``speed`` m/s),
    ``reward_example`` an id of :data:`training.rewards.examples.EXAMPLES`.
    """

    id: str
    label: str
    summary: str
    action_space: tuple[dict, ...]
    reward_example: str
    hyperparameters: Hyperparameters = field(default_factory=Hyperparameters)
    algorithm: str = "clipped_ppo"
    network: str = LEAN

    def actions(self) -> list[dict]:
        """The action space as a fresh list (model_create and EnvSpec take lists)."""
        return [dict(a) for a in self.action_space]


DEEPRACER_DEFAULTS = Preset(
    id="deepracer_defaults",
    label="DeepRacer's defaults",
    summary=(
        "What the AWS console starts you with: 5 steering angles × 0.5 and 1.0 m/s, the "
        "follow-the-centre-line reward, discount 0.999, 20 episodes per update. Learns a "
        "clean lap soon, but a slow one: at 1 m/s a lap of re:Invent 2018 takes 18 s at best."
    ),
    action_space=tuple(DEFAULT_DISCRETE),
    reward_example="follow_center_line",
)

STRAIGHT_TOP_SPEED = 3.5
"""The racing preset's fastest action, straight ahead, in m/s (DeepRacer allows 4): the camera's
single frame does not show the car's speed, and a car at 4 m/s on the short straight between
two bends reaches the second one too fast (module docstring)."""

GRIP_GRADED_ACTIONS: tuple[dict, ...] = (
    {"steering_angle": 0.0, "speed": STRAIGHT_TOP_SPEED},
    {"steering_angle": 0.0, "speed": 3.0},
    {"steering_angle": -10.0, "speed": 3.0},
    {"steering_angle": 10.0, "speed": 3.0},
    {"steering_angle": -20.0, "speed": 2.0},
    {"steering_angle": 20.0, "speed": 2.0},
)
"""Each steering angle with the fastest speed the tyres hold through it, straight ahead at
:data:`STRAIGHT_TOP_SPEED` (module docstring)."""

RACING = Preset(
    id="racing",
    label="Racing preset (fast laps soon)",
    summary=(
        "Built for a fast lap soon: 6 actions, each steering angle with the fastest speed the "
        "tyres hold through it (straight at 3 and 3.5 m/s, 10° at 3, 20° at 2 m/s), a reward "
        "for the square of the speed along the track anywhere on it, discount 0.98 (looks 3 s "
        "ahead), 20 episodes per update in minibatches of 32, and Racecraft's compact network "
        "(the fastest to train on a CPU)."
    ),
    action_space=GRIP_GRADED_ACTIONS,
    reward_example="speed_along_track",
    hyperparameters=Hyperparameters(
        batch_size=32,
        num_epochs=10,
        lr=3e-4,
        discount_factor=0.98,
        num_episodes_between_training=20,
    ),
    network=COMPACT,
)

PRESETS: tuple[Preset, ...] = (DEEPRACER_DEFAULTS, RACING)
DEFAULT_PRESET = DEEPRACER_DEFAULTS.id


class UnknownPreset(KeyError):
    """No preset has this id; the message lists the ones there are."""

    def __str__(self) -> str:
        return f"unknown preset {self.args[0]!r}: use one of {', '.join(p.id for p in PRESETS)}"


def preset(preset_id: str) -> Preset:
    """The preset ``preset_id``; raises :class:`UnknownPreset`."""
    for candidate in PRESETS:
        if candidate.id == preset_id:
            return candidate
    raise UnknownPreset(preset_id)

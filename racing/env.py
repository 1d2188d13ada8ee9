"""The Gymnasium environment: a DeepRacer car on a track, driven one 1/15 s action at a time."""

from __future__ import annotations

import math
from collections.abc import Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from racing import carstep
from racing.actions import ActionSpec
from racing.car import CarSim, Pose
from racing.carstep import CarOnTrack
from racing.conditioned_camera import conditioned
from racing.conditions import Actuator, Conditions, ConditionsError, ConditionsSpec
from racing.lidar import LidarSensor
from racing.objects import RaceObject
from racing.params import build_params
from racing.race import RaceConfig, RaceType
from racing.reward import RewardFunction, RewardValueError, judge_reward, progress_reward
from racing.rules import RaceRules, RaceTracker, Status
from racing.sensors import CameraSensor, ReferenceCamera, ground_for, validate_sensors
from racing.track import Location, Track, TrackError
from racing.tracks import TrackCatalog
from racing.world import RaceWorld

ROUND_ROBIN_ADVANCE = 0.05
"""DeepRacer moves each episode's start this share of the track further on."""
CAMERA_RESOLUTION_M = 0.005
VIEW_RESOLUTION_M = 0.01
CONDITIONS_STREAM = 0xC0D1
"""Mixed with ``reset(seed=...)`` into the conditions' own generator (apart from np_random)."""
Observation = np.ndarray | dict[str, np.ndarray]
__all__ = ["RacingEnv", "RewardValueError", "progress_reward"]


class RacingEnv(gym.Env):
    """A 1/18-scale DeepRacer car racing on a DeepRacer track.

    **Configuration** (keyword arguments): ``track`` (a :class:`Track` or a catalogue id),
    ``direction`` (``'native'``, ``'ccw'`` or ``'cw'``), ``action_space`` (DeepRacer's
    ``model_metadata.json`` form: a list of ``{steering_angle, speed}`` for discrete actions,
    ``{steering_angle: {low, high}, speed: {low, high}}`` for continuous ones; ``None`` is
    DeepRacer's default 10 discrete actions), ``sensors`` (one camera, ``FRONT_FACING_CAMERA``
    or ``STEREO_CAMERAS``, optionally with one of ``LIDAR``, ``SECTOR_LIDAR``,
    ``DISCRETIZED_SECTOR_LIDAR``; see :func:`validate_sensors`), ``race`` (a
    :class:`RaceConfig` or its ``to_dict()`` form: time trial, object avoidance with boxes,
    head-to-bot with bot cars; ``None`` is a time trial), ``reward_function`` (a callable
    taking DeepRacer's ``params`` dict),
    ``rules`` (:class:`RaceRules`: laps, resets, penalties, limits), ``start``
    (``'round_robin'``: each episode starts 5 % of the track further on, as DeepRacer training;
    ``'start_line'``), ``alternate_direction`` (flip the direction every episode),
    ``render_mode`` (``'rgb_array'``), ``render_view`` (``'chase'`` 320×240 or ``'top_down'``),
    ``camera_backend`` (``'fast'``: the homography camera; ``'pybullet'``: the same view rendered
    by PyBullet's ``getCameraImage``, 30-100× slower, for checks and benchmarks).

    **Action space**: ``Discrete(n)`` over the listed actions, or
    ``Box([steer_low, speed_low], [steer_high, speed_high])`` (degrees, m/s). Executed actions are
    clipped to ±30° and 0.1-4 m/s. An action outside the space raises ``ActionSpaceError``.

    **Observation space**: with a camera only, the image ``Box(0, 255, (120, 160, C), uint8)``,
    grayscale, ``C`` = 1 for the front camera and 2 for the stereo pair (left, right). With a
    LIDAR, a ``Dict`` keyed by DeepRacer's sensor ids (gymnasium sorts them): the camera's id
    (``"FRONT_FACING_CAMERA"`` or ``"STEREO_CAMERAS"``) → that image, and the LIDAR's id →
    ``"LIDAR"``: ``Box(0.15, 1.0, (64,), float32)``, ranges in metres clipped at 1 m;
    ``"SECTOR_LIDAR"``: ``Box(0, 1, (8,), float32)``, 1 where a sector has a return nearer than
    0.5 m; ``"DISCRETIZED_SECTOR_LIDAR"``: ``Box(0, 1, (64,), float32)``, 8 sectors × one-hot
    of 8 bins of 0.25 m (see :mod:`racing.lidar`; the scan covers all but the 60° ahead).

    **Objects**: object avoidance puts 1-6 DeepRacer boxes (0.24 × 0.39 × 0.27 m) in the lanes
    (fixed, or placed at random each episode); head-to-bot puts 1-6 bot cars that drive their
    lane at a constant speed and may change lanes (see :mod:`racing.race`, :mod:`racing.objects`).
    They are PyBullet bodies: the car bumps into them and a contact is a crash (a bot only when
    the car ran into it from behind; see :mod:`racing.world`). Cameras and the video show them;
    LIDAR sees them; every object key of ``params`` describes them. A car that would start
    within 1 m of an object starts in the other lane; one respawned near a box goes 1 m behind
    it in the other lane.

    **Step**: 1/15 s of simulated time (DeepRacer's 15 Hz), 4 physics sub-steps, through
    :mod:`racing.carstep` (the head-to-head race drives its cars through the same step).

    **Reward**: ``reward_function(params)`` as a float each step (see :mod:`racing.params`).
    NaN, ±inf or a value outside ±1e5 raises :class:`RewardValueError` naming the step.
    Steps spent in a reset penalty are not rewarded.

    **Termination**: the last lap complete, off track (all four wheels off), crashed (status
    ``crashed``, ``params['is_crashed']``), reversed (progress falls 15 steps in a row) or
    immobilized (≤ 0.3 mm per step for 15 steps), unless ``rules.resets`` forgives it with a
    penalty and a respawn. **Truncation**: ``rules.max_steps`` steps or ``rules.time_limit_s``
    simulated seconds (status ``time_up``).

    **Info**: ``status`` (DeepRacer's episode status), ``progress``, ``lap`` (current lap),
    ``laps`` (finished :class:`LapRecord` s), ``lap_finished``, ``reset`` and ``penalty_s``,
    ``params`` (this step's params) and ``trace`` (a :class:`TraceRow`).

    **Conditions** (``conditions``: a :class:`~racing.conditions.ConditionsSpec` or its
    ``to_dict()`` form; ``None``, the default, is the clean simulator): each episode draws its
    :class:`~racing.conditions.Conditions` at reset, from ``np.random.default_rng([
    conditions_seed, episode])`` when ``conditions_seed`` is given (every env with the same seed
    draws the same sequence: an event's entrants), else from the env's own conditions stream,
    seeded by ``reset(seed=...)`` apart from ``np_random`` (the objects' and the LIDAR's draws
    are the same with or without conditions). :meth:`set_conditions` fixes them for the
    following episodes. A spec's curriculum (``ramp_episodes``) counts this env's episodes
    since its last seeded reset (:meth:`~racing.conditions.ConditionsSpec.strength_at`);
    with a ``conditions_seed`` (an event's entrants) it is ignored: full strength. The
    light, look and camera families change the camera images (front
    and stereo; :mod:`racing.conditioned_camera`); the car and latency families change the
    executed action (:class:`~racing.conditions.Actuator`; in the first ``k`` steps of a
    latency of ``k`` frames the car gets straight ahead at 0 m/s). The LIDAR, the rendered
    views for people (chase, top-down) and the reward's ``params`` stay as without conditions:
    ``params['steering_angle']`` and ``params['speed']``, and the trace's ``steer`` and
    ``throttle``, are the action the model chose, as DeepRacer's; ``object_in_camera`` is the
    true camera's. ``info['conditions']`` at reset is the episode's ``Conditions.to_dict()``
    whenever a spec or fixed conditions are set.

    **Determinism**: the same seed and actions give the same observations and rewards; a
    seeded reset restarts the round-robin start sequence and the alternating direction.

    **Version history**: v0 (first release; objects, bots and LIDAR added without changing
    the camera-only time trial; conditions added without changing an env without them).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15}

    def __init__(
        self,
        track: Track | str = "racecraft_summit",
        *,
        direction: str = "native",
        action_space: list | tuple | dict | None = None,
        sensors: Sequence[str] = ("FRONT_FACING_CAMERA",),
        race: RaceConfig | dict | None = None,
        reward_function: RewardFunction | None = None,
        rules: RaceRules | None = None,
        start: str = "round_robin",
        alternate_direction: bool = False,
        render_mode: str | None = None,
        render_view: str = "chase",
        track_dirs: Sequence[str] = (),
        substeps: int = 4,
        camera_backend: str = "fast",
        conditions: ConditionsSpec | dict | None = None,
        conditions_seed: int | None = None,
    ) -> None:
        super().__init__()
        if isinstance(track, str):
            track = TrackCatalog(list(track_dirs)).load(track)
        elif not isinstance(track, Track):
            raise TrackError(f"track must be a Track or a track id, not {type(track).__name__}")
        if start not in ("round_robin", "start_line"):
            raise ValueError("start must be 'round_robin' or 'start_line'")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', not {render_mode!r}")
        if camera_backend not in ("fast", "pybullet"):
            raise ValueError("camera_backend must be 'fast' or 'pybullet'")
        if render_view not in ("chase", "top_down"):
            raise ValueError("render_view must be 'chase' or 'top_down'")
        self.track = track.in_direction(direction)
        self._tracks = {self.track.is_reversed: self.track}
        self._initial_reverse = self.track.is_reversed
        self.actions = ActionSpec.parse(action_space)
        self.action_space = self.actions.gym_space
        self.sensors = validate_sensors(list(sensors))
        self.reward_function = reward_function or progress_reward
        self.rules = rules or RaceRules()
        if race is None:
            race = RaceConfig()
        self.race = race if isinstance(race, RaceConfig) else RaceConfig.from_dict(race)
        self._has_objects = self.race.race_type is not RaceType.TIME_TRIAL
        self.start_mode = start
        self.alternate_direction = alternate_direction
        self.render_mode = render_mode
        self.render_view = render_view

        ground = ground_for(self.track, resolution=CAMERA_RESOLUTION_M, rgb=False)
        self.camera = CameraSensor(ground, self.sensors[0])
        image_space = spaces.Box(0, 255, self.camera.shape, dtype=np.uint8)
        self.lidar = LidarSensor(self.sensors[1]) if len(self.sensors) > 1 else None
        if self.lidar is None:
            self.observation_space = image_space
        else:
            self.observation_space = spaces.Dict(
                {self.sensors[0]: image_space, self.sensors[1]: self.lidar.space}
            )
        self.sim = CarSim(substeps=substeps)
        self.world = RaceWorld(self.sim, self.race, self.rules)
        if self._has_objects:  # fail now, not at the first reset, if they cannot fit
            self.world.reset(self.track, np.random.default_rng(0))
        if camera_backend == "pybullet":
            if self.sensors[0] != "FRONT_FACING_CAMERA":
                raise ValueError("the pybullet camera backend renders the front camera only")
            reference = ReferenceCamera(
                self.sim.client, ground_for(self.track, resolution=CAMERA_RESOLUTION_M, rgb=True)
            )
            self.camera.observe = lambda pose, objects=(): reference.render(pose)[..., None]
        self.car = CarOnTrack(
            self.sim, RaceTracker(self.rules, self.track.length, self.track.closed)
        )
        if conditions is not None and not isinstance(conditions, ConditionsSpec):
            conditions = ConditionsSpec.from_dict(conditions)
        if conditions is not None and camera_backend != "fast":
            raise ConditionsError("conditions need the fast camera (camera_backend='fast')")
        self.conditions_spec: ConditionsSpec | None = conditions
        if conditions_seed is not None and (
            isinstance(conditions_seed, bool) or int(conditions_seed) < 0
        ):
            raise ConditionsError(
                f"conditions_seed must be a whole number ≥ 0, not {conditions_seed!r}"
            )
        self.conditions_seed = None if conditions_seed is None else int(conditions_seed)
        self.conditions: Conditions | None = None
        """This episode's conditions (``None``: clean, no spec and none fixed)."""
        self._fixed_conditions: Conditions | None = None
        self._conditions_stream: np.random.Generator | None = None
        self._eye = self.camera  # the camera the observations come from this episode
        self._actuator: Actuator | None = None
        self.episode = -1
        self._view = None
        self.params: dict = {}

    @property
    def pose(self) -> Pose:
        """The car's origin (rear-axle middle), heading and speed now."""
        return self.car.pose

    @property
    def tracker(self) -> RaceTracker:
        """This episode's judge: progress, laps, resets, simulated time."""
        return self.car.tracker

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode. ``options`` may set ``start_progress`` (percent of the lap),
        ``offset`` (metres left of the centre line; without it a start within 1 m of an object
        is moved to the other lane) and ``heading_offset_deg``. Boxes and bots are placed
        first, from ``np_random``."""
        super().reset(seed=seed)
        options = options or {}
        if seed is not None:
            # A seed restarts everything, the round-robin start sequence included.
            self.episode = -1
            self._set_track(self._initial_reverse)
            self._conditions_stream = np.random.default_rng([int(seed), CONDITIONS_STREAM])
        self.episode += 1
        if self.alternate_direction and self.track.closed and self.episode > 0:
            self._set_track(not self.track.is_reversed)
        self._draw_conditions()
        if self._has_objects:
            self.world.reset(self.track, self.np_random)
        if "start_progress" in options:
            start_s = float(options["start_progress"]) / 100.0 * self.track.length
        elif self.start_mode == "round_robin":
            start_s = (self.episode * ROUND_ROBIN_ADVANCE * self.track.length) % self.track.length
        else:
            start_s = 0.0
        if "offset" in options:
            offset = float(options["offset"])
        else:
            offset = (self.world.start_offset(start_s) if self._has_objects else None) or 0.0
        loc = carstep.place(
            self.car,
            self.track,
            start_s,
            offset=offset,
            yaw_offset=math.radians(float(options.get("heading_offset_deg", 0.0))),
        )
        self.car.tracker = RaceTracker(self.rules, self.track.length, self.track.closed)
        self.tracker.start(loc.s)
        self.sim_time = 0.0
        self.params = self._params(
            loc=loc,
            wheels_on_track=carstep.wheels_on_track(self.track, self.pose),
            steering_angle=0.0,
            speed=0.0,
            progress=0.0,
            steps=0,
        )
        obs = self._observe()
        info = {
            "status": Status.PREPARE.value,
            "progress": 0.0,
            "lap": 1,
            "laps": [],
            "start_s": loc.s,
            "params": self.params,
        }
        if self.conditions is not None:
            info["conditions"] = self.conditions.to_dict()
        return obs, info

    def step(self, action):
        if self.episode < 0:
            raise RuntimeError("call reset() before step()")
        steering, speed = self.actions.decode(action)
        if self._has_objects:
            self.world.advance(self.sim.dt)  # bots move first: contacts come from this step
        if self._actuator is None:
            step = carstep.drive(self.car, self.track, steering, speed, self._crash)
        else:  # the car's errors and latency: params and the trace keep the chosen action
            executed = self._actuator(steering, speed)
            step = carstep.drive(self.car, self.track, *executed, self._crash,
                                 asked=(steering, speed))  # fmt: skip
        judged, loc = step.judged, step.loc
        self.sim_time = self.tracker.sim_time
        self.params = self._params(
            loc=loc,
            wheels_on_track=step.wheels,
            steering_angle=steering,
            speed=speed,
            progress=step.progress,
            steps=self.tracker.steps,
            is_crashed=judged.status is Status.CRASHED,
            sim_time=self.sim_time,
        )
        reward = judge_reward(self.reward_function, self.params)
        if judged.reset:
            if self._has_objects:
                self.world.advance(judged.penalty_s)  # the bots drive on during the penalty
            spot_near = self.world.respawn_spot if self._has_objects else None
            carstep.respawn(self.car, self.track, step, spot_near=spot_near)
        obs = self._observe()
        done = judged.done
        trace = carstep.trace_row(
            self.car,
            self.track,
            step,
            episode=self.episode,
            action=carstep.trace_action(self.actions, action, (steering, speed)),
            reward=reward,
        )
        info = {
            "status": judged.status.value,
            "progress": self.tracker.progress,
            "lap": self.tracker.lap_number,
            "laps": self.tracker.laps,
            "lap_finished": judged.lap_finished,
            "reset": judged.reset,
            "penalty_s": judged.penalty_s,
            "params": self.params,
            "trace": trace,
        }
        return obs, reward, done, judged.truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._view is None:
            from racing.video import ChaseView, TopDownView

            ground = ground_for(self.track, resolution=VIEW_RESOLUTION_M, rgb=True)
            self._view = ChaseView(ground) if self.render_view == "chase" else TopDownView(ground)
        return self._view.render(self.pose, self.objects)

    @property
    def objects(self) -> tuple[RaceObject, ...]:
        """The boxes or bot cars on the track now (empty in a time trial)."""
        return self.world.objects

    def close(self) -> None:
        self.sim.close()
        super().close()

    def set_conditions(self, conditions: Conditions | None) -> None:
        """Fix the conditions of the following episodes (from the next reset), overriding the
        spec's draws; ``None`` goes back to the spec (or to clean without one)."""
        if conditions is not None and not isinstance(conditions, Conditions):
            raise ConditionsError(f"set_conditions takes Conditions or None, not {conditions!r}")
        self._fixed_conditions = conditions

    # ------------------------------------------------------------------ internals
    def _draw_conditions(self) -> None:
        """This episode's conditions, and the camera and actuator they make."""
        spec, fixed = self.conditions_spec, self._fixed_conditions
        if spec is None and fixed is None:
            self.conditions, self._eye, self._actuator = None, self.camera, None
            return
        if self.conditions_seed is not None:
            rng = np.random.default_rng([self.conditions_seed, self.episode])
        else:
            if self._conditions_stream is None:  # never seeded: fresh entropy
                self._conditions_stream = np.random.default_rng()
            rng = np.random.default_rng(self._conditions_stream.integers(2**63))
        if fixed is not None:
            conditions = fixed
        elif self.conditions_seed is not None:  # an event's: full strength from the first
            conditions = spec.sample(rng)
        else:  # a curriculum's strength grows with this env's own episodes
            conditions = spec.sample(rng, spec.strength_at(self.episode))
        self.conditions = conditions
        self._eye = conditioned(self.camera, self.track, conditions, rng)
        self._actuator = Actuator(conditions) if conditions.changes_action else None

    def _set_track(self, reverse: bool) -> None:
        track = self._tracks.get(reverse)
        if track is None:
            track = self.track.reversed()
            self._tracks[reverse] = track
        self.track = track

    def _crash(self, loc: Location) -> RaceObject | None:
        """What the car ran into this step by DeepRacer's rules (:meth:`RaceWorld.crash`)."""
        if not self._has_objects:
            return None
        return self.world.crash(loc.s, (self.pose.x, self.pose.y))

    def _params(self, *, loc: Location, **state) -> dict:
        """This step's ``params``; ``object_in_camera`` asks the camera about the next object."""
        objects = self.world.objects
        params = build_params(
            track=self.track,
            pose=self.pose,
            loc=loc,
            objects=objects,
            object_locations=self.world.locations,
            **state,
        )
        if objects:
            ahead = objects[params["closest_objects"][1]]
            params["object_in_camera"] = self.camera.sees(self.pose, ahead)
        return params

    def _observe(self) -> Observation:
        """The observation: the image, or the image and the LIDAR reading in a dict."""
        objects = self.world.objects
        image = self._eye.observe(self.pose, objects)
        if self.lidar is None:
            return image
        reading = self.lidar.observe(self.pose, objects, self.np_random)
        return {self.sensors[0]: image, self.sensors[1]: reading}

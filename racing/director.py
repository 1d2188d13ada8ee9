"""The TV director: which car the broadcast camera follows, and how, step by step.

Plain rules on the race's timing (:class:`racing.timing.Timing`, computed once per step) and
its incidents (a crash or an off-track, :class:`racing.timing.Incident`):

1. **Incident**: a car that just crashed or went off track is shown for :attr:`incident_s`
   (wide, from higher up, so the spectator sees what happened around it). An incident stays
   news for :attr:`incident_window_s`: one that happens during a shot too young to cut waits
   for the cut, and is dropped once that old.
2. **Battle**: two cars next to each other in the order, both racing, within
   :attr:`battle_gap_s` on the timing lines (the chaser's ``interval_s``): the camera frames
   the *chaser*, behind it, so both cars are in the picture. The battle highest up the order
   wins.
3. **Leader**: otherwise, behind and above the leading car still racing.

A shot lasts at least :attr:`min_shot_s` of race clock (no flicker) unless the car it follows
leaves the track (finished, out): then the director cuts at once. Deterministic: the same
timing gives the same shots (it reads only the race clock, never the wall clock).
"""

from __future__ import annotations

from dataclasses import dataclass

from racing.timing import RACING, Incident, Timing

LEADER, BATTLE, INCIDENT = "leader", "battle", "incident"
CHASE, WIDE = "chase", "wide"


@dataclass(frozen=True)
class Shot:
    """The camera's subject: ``car`` (index), why (``kind``), how (``camera``: ``chase`` behind
    and above it, ``wide`` higher and further back) and since when (race clock, s)."""

    car: int
    kind: str
    camera: str
    since_s: float

    def to_dict(self) -> dict:
        return {"car": self.car, "kind": self.kind, "camera": self.camera}


class Director:
    """Call :meth:`decide` once per step with the step's timing."""

    def __init__(self, *, min_shot_s: float = 3.0, battle_gap_s: float = 1.0,
                 incident_s: float = 3.0, incident_window_s: float = 4.0) -> None:  # fmt: skip
        self.min_shot_s = min_shot_s
        self.battle_gap_s = battle_gap_s
        self.incident_s = max(incident_s, min_shot_s)
        self.incident_window_s = incident_window_s
        self.shot: Shot | None = None
        self._pending: list[tuple[float, Incident]] = []
        self.cuts = 0

    def decide(self, timing: Timing, incidents: list[Incident] | None = None) -> Shot | None:
        """The shot for this step (``None`` when no car is on track to follow)."""
        now = timing.clock_s
        racing = {c.index for c in timing.cars if c.status == RACING}
        news = timing.incidents if incidents is None else incidents
        self._pending = [(t, i) for t, i in self._pending
                         if now - t <= self.incident_window_s and i.car in racing]  # fmt: skip
        self._pending += [(now, i) for i in news if i.car in racing]
        current = self.shot
        if current is not None and current.car not in racing:
            current = None  # its car left the track: cut now
        if current is not None and now - current.since_s < self._length(current):
            return current
        wanted = self._wanted(timing, racing)
        if wanted is None:
            self.shot = None
            return None
        car, kind = wanted
        if current is not None and (current.car, current.kind) == (car, kind):
            return current
        if kind == INCIDENT:
            self._pending = [(t, i) for t, i in self._pending if i.car != car]
        self.shot = Shot(car, kind, WIDE if kind == INCIDENT else CHASE, now)
        self.cuts += 1
        return self.shot

    def _length(self, shot: Shot) -> float:
        return self.incident_s if shot.kind == INCIDENT else self.min_shot_s

    def _wanted(self, timing: Timing, racing: set[int]) -> tuple[int, str] | None:
        if self._pending:
            return self._pending[-1][1].car, INCIDENT
        order = [c for c in timing.cars if c.index in racing]
        for ahead, chaser in zip(order, order[1:], strict=False):
            if (chaser.interval_s is not None and chaser.interval_s <= self.battle_gap_s
                    and chaser.position == ahead.position + 1):  # fmt: skip
                return chaser.index, BATTLE
        if order:
            return order[0].index, LEADER
        return None

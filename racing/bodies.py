"""Boxes and bot cars as PyBullet bodies in the car's world, and the car's contacts with them.

Every object is a fixed (mass 0) box body: the boxes never move and the bots are moved
kinematically to their pose before each physics step, as DeepRacer's simulator moves its bots
with ``set_model_state``. A crash is what PyBullet reports: a contact point between the car (any
link) and an object's body after the step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial

import pybullet as pb

from racing.car import CarSim
from racing.objects import RaceObject

PARKED_Z_M = -10.0
"""Height where unused bodies wait, far below the floor (nothing there to touch), metres."""


class ObjectBodies:
    """The PyBullet bodies of this episode's objects in one :class:`CarSim`'s world."""

    def __init__(self, sim: CarSim) -> None:
        self.sim = sim
        client_id = sim.client._client
        self._reset_pose = partial(pb.resetBasePositionAndOrientation, physicsClientId=client_id)
        self._contacts = partial(pb.getContactPoints, physicsClientId=client_id)
        self._bodies: list[tuple[tuple[float, float, float], int]] = []
        self._index: dict[int, int] = {}
        self._count = 0

    def sync(self, objects: Sequence[RaceObject]) -> None:
        """Put a body at every object's pose (bodies are made once per size and reused)."""
        for i, obj in enumerate(objects):
            size = (obj.length, obj.width, obj.height)
            if i >= len(self._bodies) or self._bodies[i][0] != size:
                self._replace(i, size)
            half = obj.heading / 2
            quat = (0.0, 0.0, math.sin(half), math.cos(half))
            self._reset_pose(self._bodies[i][1], (obj.x, obj.y, obj.height / 2), quat)
        for i in range(len(objects), self._count):
            self._reset_pose(self._bodies[i][1], (0.0, 0.0, PARKED_Z_M), (0.0, 0.0, 0.0, 1.0))
        self._count = len(objects)
        self._index = {self._bodies[i][1]: i for i in range(self._count)}

    def _replace(self, i: int, size: tuple[float, float, float]) -> None:
        c = self.sim.client
        shape = c.createCollisionShape(pb.GEOM_BOX, halfExtents=[v / 2 for v in size])
        body = c.createMultiBody(
            0, shape, -1, [0.0, 0.0, PARKED_Z_M], [0, 0, 0, 1], useMaximalCoordinates=True
        )
        if i < len(self._bodies):
            c.removeBody(self._bodies[i][1])
            self._bodies[i] = (size, body)
        else:
            self._bodies.append((size, body))

    @property
    def body_ids(self) -> list[int]:
        """PyBullet body ids of the current objects, in the objects' order."""
        return [body for _, body in self._bodies[: self._count]]

    def touching(self) -> int | None:
        """Index of the object the car touched in the last physics step, or ``None``."""
        if not self._index:
            return None
        for contact in self._contacts(bodyA=self.sim.car):
            index = self._index.get(contact[2])
            if index is not None:
                return index
        return None

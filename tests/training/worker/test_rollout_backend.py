"""Which backend a training job gets from the settings: lockstep here by default, streamed
simulation workers here with ``RACECRAFT_SIMULATION=streams``, and on the ``simulation`` queue
of other machines whenever ``RACECRAFT_REMOTE_ROLLOUT_SLOTS`` > 0."""

from __future__ import annotations

import pytest

from training.rl.simulation import launch_local
from training.rollout.backends import LocalRollouts, StreamRollouts
from training.worker.common import rollout_backend, send_simulation


@pytest.mark.parametrize(
    "simulation, slots, expected",
    [("lockstep", 0, "local"), ("streams", 0, "here"), ("lockstep", 3, "queue"),
     ("streams", 3, "queue")],
)  # fmt: skip
def test_the_settings_pick_the_backend(settings, simulation, slots, expected):
    settings.RACECRAFT_SIMULATION = simulation
    settings.RACECRAFT_REMOTE_ROLLOUT_SLOTS = slots
    backend = rollout_backend()
    if expected == "local":
        assert backend == LocalRollouts()
        return
    assert isinstance(backend, StreamRollouts)
    assert backend.redis_url == settings.REDIS_URL
    if expected == "here":
        assert backend.launch is launch_local and backend.workers == 2
    else:
        assert backend.launch is send_simulation and backend.workers == slots

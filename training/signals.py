"""Signals other apps may listen to (training itself never knows who listens).

``evaluation_finished``: sent with ``sender=EvaluationJob`` and ``evaluation_id=<pk>`` after an
evaluation job reaches COMPLETED, FAILED or CANCELED. Jobs finish through ``QuerySet.update``,
which sends no ``post_save``, hence this signal.

``race_finished``: sent with ``sender=RaceJob`` and ``race_id=<pk>`` after a race job reaches
COMPLETED, FAILED or CANCELED (the league advances its brackets on it).
"""

from __future__ import annotations

from django.dispatch import Signal

evaluation_finished = Signal()
race_finished = Signal()

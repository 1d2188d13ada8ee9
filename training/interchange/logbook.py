"""Training logs as DeepRacer writes them, from what the cars report.

The cars of a run drive side by side: their sim-trace rows arrive interleaved, an episode can
straddle a policy update, and every car counts its episodes from 0. DeepRacer (and so the
community's ``deepracer-utils``) reads a training as *iterations of E episodes* (``E`` =
``num_episodes_between_training``), numbered across the run:

* ``training-simtrace/<k>-iteration.csv`` holds the rows of episodes ``k*E .. k*E+E-1``
  (0-based ``episode`` column), each episode's rows together, its first row ``prepare``;
* ``TrainingMetrics.json`` has one entry per episode, ``episode`` from 1, ``trial`` 1..E
  restarting every iteration, and after each iteration the evaluation entries, which carry
  the episode and trial of the iteration's last training entry.

:class:`TrainingLog` keeps each car's rows until its episode ends, queues finished episodes in
the order they finished, and hands them out ``E`` at a time (:meth:`TrainingLog.take`); the
last, shorter iteration comes out with ``final=True``. Django-free: the job's hooks store what
it returns.
"""

from __future__ import annotations

import io
from collections import deque
from dataclasses import dataclass, field

from racing.simtrace import SIMTRACE_COLUMNS, TraceRow

_ROW_FIELDS = len(SIMTRACE_COLUMNS)


@dataclass
class LoggedEpisode:
    """One finished episode: its TrainingMetrics entry (numbered) and its sim-trace rows."""

    entry: dict
    rows: list[TraceRow]


@dataclass
class LoggedIteration:
    """An iteration of the log: ``number`` from 0, as in ``<number>-iteration.csv``."""

    number: int
    episodes: list[LoggedEpisode] = field(default_factory=list)

    def simtrace_csv(self) -> str:
        """The iteration's sim-trace file: DeepRacer's header and one line per step."""
        out = io.StringIO()
        out.write(",".join(SIMTRACE_COLUMNS) + "\n")
        for episode in self.episodes:
            for row in episode.rows:
                out.write(row.format() + "\n")
        return out.getvalue()


def _key(car: object, episode: object) -> tuple[str, str]:
    return (str(car), str(episode))


class TrainingLog:
    """Turns the cars' rows and finished-episode entries into DeepRacer's iterations.

    ``episodes_per_iteration`` is DeepRacer's ``num_episodes_between_training`` (>= 1).
    Reported values are untrusted (they come from sandboxed workers): a malformed row is
    dropped, never trusted.
    """

    def __init__(self, episodes_per_iteration: int, *, logged_episodes: int = 0) -> None:
        self.per_iteration = max(1, int(episodes_per_iteration))
        self.logged = logged_episodes
        self._open: dict[tuple[str, str], list[TraceRow]] = {}
        self._finished: deque[LoggedEpisode] = deque()
        self._entries: dict[tuple[str, str], dict] = {}

    @property
    def queued(self) -> int:
        """Finished episodes not handed out yet."""
        return len(self._finished)

    @property
    def iterations_logged(self) -> int:
        """How many iterations :meth:`take` has handed out."""
        return -(-self.logged // self.per_iteration)

    def add_rows(self, rows: list[list]) -> None:
        """Rows as the cars report them: the 19 sim-trace values, then the car's id."""
        for raw in rows:
            if not isinstance(raw, list | tuple) or len(raw) != _ROW_FIELDS + 1:
                continue
            try:
                row = TraceRow(*raw[:_ROW_FIELDS])
                row.format()
            except (TypeError, ValueError):
                continue
            key = _key(raw[_ROW_FIELDS], row.episode)
            if row.episode_status == "prepare" or key not in self._open:
                self._open[key] = []
            self._open[key].append(row)
        self._match()

    def add_entry(self, entry: dict) -> None:
        """A finished episode's metrics entry (with ``car`` and ``env_episode``)."""
        if isinstance(entry, dict):
            self._entries[_key(entry.get("car"), entry.get("env_episode"))] = entry
        self._match()

    def _match(self) -> None:
        """Finish every episode whose entry and last (``done``) row have both arrived."""
        for key in list(self._entries):
            rows = self._open.get(key)
            if rows and rows[-1].done:
                self._finished.append(LoggedEpisode(self._entries.pop(key), rows))
                del self._open[key]

    def take(self, *, final: bool = False) -> list[LoggedIteration]:
        """The complete iterations queued (``final``: the rest too), numbered entries."""
        out: list[LoggedIteration] = []
        while self._finished and (final or len(self._finished) >= self.per_iteration):
            iteration = LoggedIteration(self.logged // self.per_iteration)
            while self._finished and len(iteration.episodes) < self.per_iteration:
                out_episode = self._finished.popleft()
                iteration.episodes.append(self._number(out_episode))
            out.append(iteration)
        return out

    def _number(self, episode: LoggedEpisode) -> LoggedEpisode:
        number = self.logged  # 0-based, across the run
        self.logged += 1
        entry = {**episode.entry, "episode": number + 1, "trial": number % self.per_iteration + 1}
        rows = [row._replace(episode=number) for row in episode.rows]
        return LoggedEpisode(entry, rows)

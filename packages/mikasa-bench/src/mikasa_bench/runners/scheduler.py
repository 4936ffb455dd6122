"""The order in which a pool's workers get their jobs (`Scheduler`), shared by the local
and the Ray executor."""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Hashable, Sequence

from mikasa_bench.runners.jobs import EpisodeJob

__all__ = ["Scheduler"]


class Scheduler:
    """Hands out jobs scene by scene and task by task.

    A worker gets the episodes of one scene (`EpisodeJob.scene_key`: 5 consecutive
    episodes of a task) in order and alone, so they play on one scene as the protocol
    fixes; then the next unclaimed scene of the same task, keeping its env. A worker that
    needs a new env joins the task with the fewest workers on it (then the one with the
    most env steps left, so long-horizon tasks start early and do not trail the run), so
    workers spread over tasks instead of all building every task's env in turn: measured
    on a machine with one NVIDIA GPU and 16 CPU cores, an env build costs 2-5 s while 16 workers build at once, as much as
    ~40 short episodes. Which worker runs an episode never changes its
    result (the workers replay a scene's earlier episodes if they must)."""

    def __init__(self, jobs: Sequence[EpisodeJob]) -> None:
        self.unclaimed: OrderedDict[Hashable, OrderedDict[Hashable, deque[EpisodeJob]]] = OrderedDict()
        """Env key -> scene key -> the scene's jobs, for scenes no worker has started."""
        for job in jobs:
            scenes = self.unclaimed.setdefault(job.env_key, OrderedDict())
            scenes.setdefault(job.scene_key, deque()).append(job)
        self.claimed: dict[Hashable, deque[EpisodeJob]] = {}
        """Scene key -> jobs left of a scene a worker is playing."""
        self.steps_left: dict[Hashable, int] = {
            key: sum(j.task.max_episode_steps for q in scenes.values() for j in q)
            for key, scenes in self.unclaimed.items()
        }
        """Env key -> env steps of its unclaimed scenes (kept as scenes are claimed)."""
        self.holders: dict[Hashable, int] = {}
        """Env key -> workers whose last job was of that key."""

    def next_for(self, last: EpisodeJob | None) -> EpisodeJob | None:
        """The next job for a worker whose last job was ``last`` (None: a new worker)."""
        scene = self.claimed.get(last.scene_key) if last is not None else None
        if not scene:
            key = last.env_key if last is not None else None
            if key not in self.unclaimed:
                if not self.unclaimed:
                    return None
                # A new env: the least-served task (order of the run as the last tie-break).
                order = {k: i for i, k in enumerate(self.unclaimed)}
                new = min(
                    self.unclaimed, key=lambda k: (self.holders.get(k, 0), -self.steps_left[k], order[k])
                )
                if key is not None and self.holders.get(key):
                    self.holders[key] -= 1
                self.holders[new] = self.holders.get(new, 0) + 1
                key = new
            scenes = self.unclaimed[key]
            scene_key, scene = scenes.popitem(last=False)
            self.steps_left[key] -= sum(j.task.max_episode_steps for j in scene)
            if not scenes:
                del self.unclaimed[key], self.steps_left[key]
            self.claimed[scene_key] = scene
        job = scene.popleft()
        if not scene:
            del self.claimed[job.scene_key]
        return job

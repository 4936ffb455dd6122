"""The render batcher's meeting of threads, with a stand-in for the GPU camera group (the
pixels of a real batched pass are checked on a GPU by benchmarks/gpu_camera_group_check.py):
every env gets its own pictures, waiting threads share passes, a thread outside an episode
holds nobody up, closed envs leave the group, and errors reach the waiting threads."""

from __future__ import annotations

import random
import threading
import time

import pytest
import torch
from mikasa_envs.render_batcher import RenderBatcher


class FakeScene:
    """Stands in for a SAPIEN scene whose 'pose' a thread advances."""

    def __init__(self, value: int) -> None:
        self.value = value


class FakeGroup:
    """Renders each scene as a 1x1 picture holding its current value."""

    built: list[int] = []
    first: list[list[bool]] = []

    def __init__(self, views, device, first_group) -> None:
        self.scenes = [scene for scene, _ in views]
        FakeGroup.built.append(len(views))
        FakeGroup.first.append(list(first_group))

    def render_all(self, refresh):
        # Scenes not in ``refresh`` must not be read (their threads may be stepping them).
        return [
            {"cam": torch.full((1, 1, 1, 3), s.value % 256 if i in refresh else 255, dtype=torch.uint8)}
            for i, s in enumerate(self.scenes)
        ]


class FailingGroup(FakeGroup):
    def render_all(self, refresh):
        raise ValueError("boom")


@pytest.fixture
def batcher():
    FakeGroup.built, FakeGroup.first = [], []
    b = RenderBatcher(group_factory=FakeGroup)
    yield b
    b.close()


def test_threads_get_their_own_pictures_in_shared_passes(batcher):
    n_threads, steps = 4, 30
    seen: dict[int, list[int]] = {}

    def episode(k: int) -> None:
        owner, scene = object(), FakeScene(k * 50)
        rng = random.Random(k)
        got = []
        with batcher.participating():
            for _ in range(steps):
                time.sleep(rng.uniform(0, 0.002))  # physics of uneven length
                scene.value += 1
                got.append(int(batcher.render(owner, (scene, {"cam": None}), "cpu")["cam"][0, 0, 0, 0]))
        seen[k] = got

    threads = [threading.Thread(target=episode, args=(k,)) for k in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert all(not t.is_alive() for t in threads)
    for k in range(n_threads):
        assert seen[k] == [k * 50 + i for i in range(1, steps + 1)]
    assert batcher.pictures == n_threads * steps
    assert batcher.passes < n_threads * steps  # shared: fewer passes than pictures


def test_a_pass_waits_for_episodes_in_progress_and_not_for_idle_threads(batcher):
    in_episode, leave = threading.Event(), threading.Event()

    def busy_episode():  # in an episode, doing something other than rendering
        with batcher.participating():
            in_episode.set()
            leave.wait(timeout=5)

    t = threading.Thread(target=busy_episode)
    t.start()
    assert in_episode.wait(timeout=5)
    rendered = threading.Event()
    r = threading.Thread(
        target=lambda: (batcher.render(object(), (FakeScene(7), {"cam": None}), "cpu"), rendered.set())
    )
    r.start()
    assert not rendered.wait(timeout=0.2)  # the pass waits for the episode in progress
    leave.set()  # that thread's episode ends: it is idle now and holds nobody up
    assert rendered.wait(timeout=5)
    t.join()
    r.join()


def test_forgotten_scenes_leave_the_group(batcher):
    a, b = object(), object()
    batcher.render(a, (FakeScene(1), {"cam": None}), "cpu")
    batcher.render(b, (FakeScene(2), {"cam": None}), "cpu")
    assert FakeGroup.built == [1, 2]  # rebuilt when b's scene arrived
    batcher.forget(a)
    scene_b = FakeScene(2)
    batcher.render(b, (scene_b, {"cam": None}), "cpu")
    batcher.render(b, (scene_b, {"cam": None}), "cpu")
    assert FakeGroup.built == [1, 2, 1]
    # Only scenes new to every group get their first render update (a scene mid-episode
    # must not be updated again).
    assert FakeGroup.first == [[True], [False, True], [True]]


def test_render_errors_reach_the_waiting_thread():
    b = RenderBatcher(group_factory=FailingGroup)
    try:
        with pytest.raises(RuntimeError, match="batched render failed: boom"):
            b.render(object(), (FakeScene(1), {"cam": None}), "cpu")
    finally:
        b.close()
    with pytest.raises(RuntimeError, match="closed"):
        b.render(object(), (FakeScene(1), {"cam": None}), "cpu")

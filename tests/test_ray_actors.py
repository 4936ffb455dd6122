"""mikasa_envs.ray_actors: joining or starting Ray, actor placement and the start-up wait
(shared by the bench's and the collector's Ray executors), against a stand-in ``ray``
module; the executors themselves run on real Ray in test_bench_sim / test_collect."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from mikasa_envs.ray_actors import (
    RayStartError,
    actor_options,
    equal_gpu_share,
    init_ray,
    wait_until_ready,
)


class _RayError(Exception):
    pass


class _GetTimeoutError(_RayError):
    pass


class FakeRay:
    """The parts of ``ray`` the helpers use."""

    exceptions = SimpleNamespace(RayError=_RayError, GetTimeoutError=_GetTimeoutError)

    def __init__(self, initialized: bool = False, get_raises: Exception | None = None) -> None:
        self.initialized = initialized
        self.get_raises = get_raises
        self.init_calls: list[dict] = []

    def is_initialized(self) -> bool:
        return self.initialized

    def init(self, **kwargs) -> None:
        self.init_calls.append(kwargs)
        self.initialized = True

    def get(self, refs, timeout=None):
        if self.get_raises is not None:
            raise self.get_raises
        return list(refs)

    def cluster_resources(self) -> dict:
        return {"CPU": 2.0}


class FakeActor:
    def __init__(self, host: str) -> None:
        self.ready = SimpleNamespace(remote=lambda: host)


def test_init_ray_starts_a_local_instance_with_the_worker_count(monkeypatch):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    ray = FakeRay()
    assert init_ray(ray, None, 3) is True
    assert ray.init_calls == [{"include_dashboard": False, "log_to_driver": False, "num_cpus": 3}]


def test_init_ray_joins_an_address_and_lets_init_kwargs_win(monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", "10.0.0.1:6379")
    ray = FakeRay()
    assert init_ray(ray, None, 3, {"num_cpus": 8}) is True
    assert ray.init_calls == [
        {"address": "10.0.0.1:6379", "include_dashboard": False, "log_to_driver": False,
         "num_cpus": 8}
    ]
    ray = FakeRay()
    init_ray(ray, "head:6379", 3)
    assert ray.init_calls[0]["address"] == "head:6379" and "num_cpus" not in ray.init_calls[0]


def test_init_ray_uses_an_initialised_instance_as_it_is():
    ray = FakeRay(initialized=True)
    assert init_ray(ray, "head:6379", 3) is False
    assert ray.init_calls == []


def test_actor_options_and_gpu_shares():
    assert actor_options() == {"num_cpus": 1, "scheduling_strategy": "SPREAD", "max_restarts": 0}
    assert actor_options(0.25)["num_gpus"] == 0.25
    assert equal_gpu_share(2.0, 3) == 0.6666  # Ray takes 4 decimals
    assert equal_gpu_share(4.0, 2) == 1.0  # a share above one GPU would have to be whole


def test_wait_until_ready_returns_hosts_and_names_the_failure():
    actors = [FakeActor("node-a"), FakeActor("node-b")]
    assert wait_until_ready(FakeRay(), actors) == ["node-a", "node-b"]
    timeout = r"could not start 2 worker\(s\) within 5 s.*lower --workers"
    with pytest.raises(RayStartError, match=timeout):
        wait_until_ready(FakeRay(get_raises=_GetTimeoutError()), actors, timeout_s=5)
    with pytest.raises(RayStartError, match="a Ray worker failed to start:\nboom"):
        wait_until_ready(FakeRay(get_raises=_RayError("boom")), actors)

"""The task manifest: contents, filters, errors, and agreement with the registry."""

from __future__ import annotations

from collections import Counter

import gymnasium as gym
import pytest
from conftest import REGISTERED_IDS
from mani_skill.utils.registration import REGISTERED_ENVS
from mikasa_envs import manifest


def test_ninety_canonical_tasks_with_published_taxonomy():
    tasks = manifest.list_tasks()
    assert len(tasks) == 90
    assert len({t.env_id for t in tasks}) == 90
    assert all(t.canonical and t.env_id.endswith("-VLA-v0") for t in tasks)
    counts = sorted(Counter(t.memory_type for t in tasks).values(), reverse=True)
    assert counts == [18, 14, 12, 12, 9, 6, 6, 5, 4, 4]
    assert Counter(t.split for t in tasks) == {"short": 38, "medium": 30, "long": 22}
    assert {t.data_source for t in tasks} == {"PPO", "MP"}


def test_filters_combine():
    short_object = manifest.list_tasks(split="short", memory_type="Object")
    assert [t.env_id for t in short_object][:3] == [
        "RememberColor3-VLA-v0",
        "RememberColor5-VLA-v0",
        "RememberColor9-VLA-v0",
    ]
    assert all(t.split == "short" and t.memory_type == "Object" for t in short_object)
    assert len(manifest.list_tasks(split="all")) == 90
    assert len(manifest.list_tasks(family="find_imposter_color")) == 3
    assert all(t.data_source == "MP" for t in manifest.list_tasks(data_source="MP"))


def test_extra_variants_are_flagged_non_canonical():
    extra = [t for t in manifest.list_tasks(include_extra=True) if not t.canonical]
    assert {t.env_id for t in extra} >= {"ShellGamePick-VLA-v0", "BatteriesCheckerEasy-9-VLA-v0"}
    assert all(t.split is None for t in extra)


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(split="tiny"), "short, medium, long, all"),
        (dict(memory_type="Episodic"), "Object"),
        (dict(family="nope"), "remember_color"),
        (dict(data_source="human"), "PPO, MP"),
    ],
)
def test_bad_filter_names_accepted_values(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        manifest.list_tasks(**kwargs)


def test_unknown_id_suggests_close_matches():
    with pytest.raises(KeyError, match="RememberColor3-VLA-v0"):
        manifest.get_task("RememberColr3-VLA-v0")
    with pytest.raises(ValueError, match="Did you mean"):
        manifest.get_task("FindImposterColour3-VLA-v0")


def test_registered_horizons_equal_manifest():
    assert len(REGISTERED_IDS) >= 27
    for env_id in REGISTERED_IDS:
        task = manifest.get_task(env_id)
        assert REGISTERED_ENVS[env_id].max_episode_steps == task.max_episode_steps
        assert gym.spec(env_id).max_episode_steps == task.max_episode_steps
        assert REGISTERED_ENVS[env_id].cls.LANGUAGE_INSTRUCTION == task.language_instruction


def test_family_groups_name_manifest_families():
    from mikasa_envs.manifest import SELECTION_FAMILIES, SHELL_GAME_FAMILIES, families

    assert set(SELECTION_FAMILIES) | set(SHELL_GAME_FAMILIES) <= set(families())


def test_every_row_comes_from_its_family_module():
    """One place per family: each id's row is registered by mikasa_envs/tasks/<family>.py,
    whose FAMILY declares it, and the env class it registered is the one ManiSkill has."""
    from mikasa_envs.family import env_class, get_family

    for task in manifest.list_tasks(include_extra=True):
        cls = env_class(task.env_id)
        assert cls.__module__ == f"mikasa_envs.tasks.{task.family}", task.env_id
        assert REGISTERED_ENVS[task.env_id].cls is cls
        assert get_family(task.family).name == task.family
        assert get_family(task.family).hidden, f"{task.family} does not say what is hidden"
        assert cls.LANGUAGE_INSTRUCTION == task.language_instruction


def test_family_registry_rejects_bad_rows():
    from mikasa_envs.family import TaskFamily, TaskSpec, add_task, get_family
    from mikasa_envs.tasks import remember_color

    row = manifest.get_task("RememberColor3-VLA-v0")
    with pytest.raises(ValueError, match="registered twice"):
        add_task(remember_color.FAMILY, row, object, None)
    with pytest.raises(ValueError, match="declared twice"):
        add_task(TaskFamily("remember_color"), row, object, None)
    bad = TaskSpec(**{**vars(row), "env_id": "X-VLA-v0", "split": "Short"})
    with pytest.raises(ValueError, match="unknown split 'Short'; accepted values: short, medium, long"):
        add_task(remember_color.FAMILY, bad, object, None)
    with pytest.raises(KeyError, match="unknown task family 'nope'; known families: .*remember_color"):
        get_family("nope")
    assert "X-VLA-v0" not in [t.env_id for t in manifest.list_tasks(include_extra=True)]

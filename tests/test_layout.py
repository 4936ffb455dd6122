"""The layout rules of ``tests/layout_check.py``: no import circles, no arrow up, no private
names across modules, no source file over 600 lines, declared dependencies == imports."""

import pytest
from layout_check import PACKAGES, report


@pytest.mark.parametrize("rule", list(report()))
def test_layout_rule_holds(rule):
    violations = report()[rule]
    assert not violations, f"{rule}:\n" + "\n".join(violations)


def test_every_package_is_checked():
    assert set(PACKAGES) >= {"mikasa_envs", "mikasa_wrappers", "mikasa_bench", "mikasa_robo_rl"}

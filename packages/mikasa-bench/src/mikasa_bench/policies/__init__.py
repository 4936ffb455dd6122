"""Policies: the interface the runner calls, the built-in policies and the loading of user,
remote and LeRobot policies.

* `mikasa_bench.policies.base`: the policy interface (`ChunkPolicy`, `policy_chunk_size`,
  `reset_policy`) and the action shape;
* `mikasa_bench.policies.builtin`: ``zero``, ``random``, ``oracle``, ``oracle-memoryless``
  and `DummyChunkPolicy`;
* `mikasa_bench.policies.spec`: `PolicySpec`, the picklable description workers build from;
* `mikasa_bench.policies.loading`: `resolve_policy` (main process) and `build_policy`
  (worker);
* `mikasa_bench.policies.oracle_extra`: `require_oracles`, mikasa-oracles (the ``oracles``
  extra) or an error naming the command that installs it;
* `mikasa_bench.policies.remote`: policies served over a websocket (client, wire format,
  server).

The names policy authors use are importable from here too, so a policy target may name
them as ``mikasa_bench.policies:DummyChunkPolicy``. Modules of mikasa_bench import them
from the modules above.
"""

from mikasa_bench.policies.base import ChunkPolicy, policy_chunk_size, reset_policy
from mikasa_bench.policies.builtin import (
    BUILTIN_POLICIES,
    DummyChunkPolicy,
    RandomPolicy,
    ZeroPolicy,
)
from mikasa_bench.policies.loading import build_policy, check_policy_supports, resolve_policy
from mikasa_bench.policies.spec import PolicySpec, is_lerobot_target, is_remote_target

__all__ = [
    "ChunkPolicy",
    "ZeroPolicy",
    "RandomPolicy",
    "DummyChunkPolicy",
    "PolicySpec",
    "BUILTIN_POLICIES",
    "resolve_policy",
    "build_policy",
    "policy_chunk_size",
    "reset_policy",
    "check_policy_supports",
    "is_remote_target",
    "is_lerobot_target",
]

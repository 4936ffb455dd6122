"""A recurrent memory policy for LeRobot (``--policy.type=memory_gru``), as a LeRobot plugin.

LeRobot imports every installed distribution whose name starts with ``lerobot_policy_``
(``register_third_party_plugins``, run by lerobot-train and lerobot-eval); importing this
package registers the config, and lerobot finds the policy class and the processors by the
module names ``modeling_memory_gru`` / ``processor_memory_gru`` beside the config's module.
"""

from lerobot_policy_memory_gru.configuration_memory_gru import POLICY_TYPE, MemoryGRUConfig
from lerobot_policy_memory_gru.modeling_memory_gru import MemoryGRUPolicy
from lerobot_policy_memory_gru.processor_memory_gru import make_memory_gru_pre_post_processors

__all__ = [
    "POLICY_TYPE",
    "MemoryGRUConfig",
    "MemoryGRUPolicy",
    "make_memory_gru_pre_post_processors",
]

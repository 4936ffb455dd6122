"""The oracle of RememberCubePair: the selection families' oracle, registered for it."""

from mikasa_oracles import register_oracle
from mikasa_oracles.families.selection import MemorylessSelectionOracle, SelectionOracle

register_oracle("remember_cube_pair")(SelectionOracle)
register_oracle("remember_cube_pair", memoryless=True)(MemorylessSelectionOracle)

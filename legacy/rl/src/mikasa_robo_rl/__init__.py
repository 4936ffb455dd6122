"""MIKASA-Robo RL: the original 32-task RL release (backward compatibility)."""

__version__ = "0.0.1"

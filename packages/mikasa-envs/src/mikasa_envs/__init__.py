"""MIKASA-Robo VLA environments."""

__version__ = "0.1.0"

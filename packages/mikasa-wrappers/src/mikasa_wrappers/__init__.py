"""MIKASA-Robo wrappers."""

__version__ = "0.1.0"

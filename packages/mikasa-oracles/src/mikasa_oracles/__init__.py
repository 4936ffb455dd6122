"""MIKASA-Robo oracles."""

__version__ = "0.1.0"

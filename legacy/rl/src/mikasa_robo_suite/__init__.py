"""Backward-compatible import paths of the original MIKASA-Robo RL release.

``mikasa-robo-rl`` provides the module paths that user code of the RL release (0.0.5) and
of the 1.0.0 wheel's ``rl`` subpackage imports; every module here re-exports
``mikasa_robo_rl``. (The published ``mikasa-robo-suite`` distribution owns the same
top-level name: install one or the other.)
"""

"""The 1.0.0 wheel's RL subpackage (``mikasa_robo_suite.rl.*``)."""

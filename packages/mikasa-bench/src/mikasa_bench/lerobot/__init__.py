"""LeRobot in mikasa-bench (``pip install 'mikasa-bench[lerobot]'``), both ways round:

* `mikasa_bench.lerobot.policy`: LeRobot pretrained policies evaluated by the bench,
  ``mikasa-bench run --policy lerobot:DIR``;
* `mikasa_bench.lerobot.env`: the MIKASA tasks as lerobot-eval's ``mikasa`` env type,
  ``lerobot-eval --env.discover_packages_path=mikasa_bench.lerobot.env --env.type=mikasa``.

lerobot is imported only by `mikasa_bench.lerobot.env` and by the policy's functions that
need it, so mikasa-bench works without it. Import names from those modules; this package
file imports nothing (lerobot's plugin discovery imports it before the env package).
"""

"""``python -m mikasa_bench.lerobot.env ARGS`` = ``lerobot-eval ARGS`` with the ``mikasa`` env type."""

from mikasa_bench.lerobot.env import main

if __name__ == "__main__":  # lerobot's plugin loader imports this module too: no run then
    main()

"""``lerobot-train`` (lerobot 0.4.x), offline, where its torchvision import would fail.

    python baselines/lerobot/lerobot_train.py ARGS      # = lerobot-train ARGS

The one addition: ``mikasa_bench.lerobot.policy.import_lerobot()`` runs before lerobot's
first import. It switches the Hub off (``HF_HUB_OFFLINE=1``) and makes ``torchvision``
importable where PyPI's CUDA build sits beside a CPU torch (``.venv-datasets``), where plain
``lerobot-train`` dies at ``import torchvision``; it changes nothing in lerobot. Everything
else is lerobot-train's own ``main``, unchanged: its CLI, its output layout, its logs, its
checkpoints and its ``--resume=true --config_path=...``.

Stopping at a time limit, progress and pruning of old checkpoints are the driver's
(`baseline_stages.Driver.train`): it terminates this process and reads lerobot's log lines
and checkpoint files.
"""

from __future__ import annotations

import sys


def main() -> int:
    """Run lerobot-train with ``sys.argv[1:]``; its exit status."""
    from mikasa_bench.lerobot.policy import import_lerobot

    import_lerobot()  # offline, torchvision importable: before any lerobot module
    from lerobot.scripts.lerobot_train import main as lerobot_train_main

    lerobot_train_main()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``python -m mikasa_bench.cli``: same as the ``mikasa-bench`` script."""

from mikasa_bench.cli.main import main

raise SystemExit(main())

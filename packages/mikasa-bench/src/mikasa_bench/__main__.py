"""``python -m mikasa_bench``: same as the ``mikasa-bench`` script."""

from .cli import main

raise SystemExit(main())

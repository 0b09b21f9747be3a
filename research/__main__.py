"""``python -m research``: see ``research.cli``."""

from research.cli import main

raise SystemExit(main())

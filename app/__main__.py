"""``python -m app``: see ``app.entrypoints.cli``."""

from app.entrypoints.cli import main

raise SystemExit(main())

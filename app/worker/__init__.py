"""The fleet-sizing worker (``python -m app worker``; docs/FLEET.md): re-solves DRO_RH every hour and
serves admin solve requests, publishing recommendations through the store."""

from app.worker.cli import main

__all__ = ["main"]

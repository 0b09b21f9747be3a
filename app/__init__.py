"""The shell: HTTP API, stores, settings, CLI. Turns requests into calls on ``services``."""

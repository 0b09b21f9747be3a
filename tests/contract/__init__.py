"""Contract tests: one suite run against every ``app.ports.Store`` implementation."""

"""Simulation: demand sets, the fleet simulator and its KPIs (docs/METHOD.md sections 6, 7 and 10)."""

"""Simulation: demand sets, the fleet simulator and its KPIs (METHOD sections 6, 7 and 10)."""

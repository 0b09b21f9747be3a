"""Models of the coverage route (``app.api.cities``): grid counts of one sensing interval."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from app.schemas.common import ResponseModel
from app.usecases import Coverage

__all__ = ["CellCountOut", "CoverageOut"]


class CellCountOut(ResponseModel):
    """Lambda of one cell."""

    cell: tuple[int, int]
    count: int


class CoverageOut(ResponseModel):
    """Grid counts of one sensing interval."""

    city: str
    interval: str = Field(description="Local start of the interval, YYYY-MM-DDTHH:MM.")
    interval_key: int
    in_horizon: bool
    cells: list[CellCountOut] = Field(description="Cells with a non-zero count.")
    coverage_rate: float = Field(description="Share of the network's cells with Lambda >= 1.")
    gamma_so_far: float = Field(description="Gamma over that day's horizon intervals, as counted so far.")
    n_cells_covered: int
    n_cells_touched: int

    @classmethod
    def of(cls, cov: Coverage) -> CoverageOut:
        """Render the counts of one interval: the cells with a non-zero count, by [col, row]."""
        city, k = cov.city, cov.interval
        nz = np.flatnonzero(cov.counts)
        return cls(
            city=city.name,
            interval=city.horizon.label(k),
            interval_key=int(k),
            in_horizon=city.horizon.in_horizon(k),
            cells=[CellCountOut(cell=city.grid.col_row(int(c)), count=int(cov.counts[c])) for c in nz],
            coverage_rate=cov.coverage_rate,
            gamma_so_far=cov.gamma_so_far,
            n_cells_covered=int(nz.size),
            n_cells_touched=city.n_cells_touched,
        )

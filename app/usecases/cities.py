"""The served cities, as the use cases see them: a catalog by name
(``app.adapters.city_registry.CityRegistry``)."""

from __future__ import annotations

from typing import Protocol

from services.city import City

__all__ = ["CityCatalog"]


class CityCatalog(Protocol):
    """The served cities (implemented by ``app.adapters.city_registry.CityRegistry``)."""

    def names(self) -> list[str]:
        """The served cities' names, sorted."""
        ...

    def get(self, name: str) -> City:
        """The city; raises ``app.errors.UnknownCity`` when not served."""

"""Source mappers behind one interface; ``make_mapper`` picks one by ``mapping.method``."""

from __future__ import annotations

from typing import TYPE_CHECKING

from service.core.mapping.bayes import BayesMapper
from service.core.mapping.hmm import HmmMapper
from service.core.mapping.mapper import Estimate, MapperParams, SourceMapper
from service.core.mapping.pomdp import PomdpMapper

if TYPE_CHECKING:
    from service.core.config import Config
    from service.core.grid import Grid

MAPPERS: dict[str, type[SourceMapper]] = {
    HmmMapper.name: HmmMapper,
    BayesMapper.name: BayesMapper,
    PomdpMapper.name: PomdpMapper,
}


def make_mapper(method: str, grid: Grid, params: MapperParams | None = None) -> SourceMapper:
    """The mapper registered under ``method`` (``hmm``, ``bayes``, ``pomdp``)."""
    try:
        cls = MAPPERS[method]
    except KeyError:
        raise ValueError(f"unknown mapping method {method!r}; choose one of {sorted(MAPPERS)}") from None
    return cls(grid, params)


def mapper_from_config(config: Config, grid: Grid) -> SourceMapper:
    return make_mapper(str(config.mapping.method), grid, MapperParams.from_config(config))


__all__ = [
    "MAPPERS",
    "Estimate",
    "MapperParams",
    "SourceMapper",
    "make_mapper",
    "mapper_from_config",
]

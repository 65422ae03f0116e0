"""Plants: one file per plant, each a CasADi ``rhs`` plus labels and parameters."""

from mpclab.plants.base import Plant, register_plant

__all__ = ["Plant", "register_plant"]

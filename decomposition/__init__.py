"""Who owns which particle: partitioning, halo exchange, migration, global numbering.

This package owns every communicator and MPI tag of parsph and knows no physics: it
moves rows of named numpy arrays between ranks.
"""
from decomposition.comm import Tag, world, collective, raise_if_any
from decomposition.box import Box
from decomposition.partition import RCB, imbalance
from decomposition.exchange import migrate
from decomposition.halo import Halo

__all__ = ["Tag", "world", "collective", "raise_if_any", "Box", "RCB", "imbalance", "migrate",
           "Halo"]

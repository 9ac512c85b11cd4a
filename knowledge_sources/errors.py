"""Every mapinterp error, for catching them all in one ``except``.

Each layer has its own exception root: the domain models :class:`models.errors.ModelError`, the
blackboard :class:`blackboard.errors.BlackboardError` (neither layer imports the other). This
module, in the layer that sees both, puts them together::

    from knowledge_sources.errors import MAPINTERP_ERRORS

    try:
        results = run_mission("scenarios/hills.yaml")
    except MAPINTERP_ERRORS as err:   # a malformed scenario, a missing image, a dead agent, ...
        print(f"error: {err}")

A tuple rather than a common base class: a base class shared by both layers would have to live
in a module both import, i.e. in one of them or in a fourth package.
"""

from __future__ import annotations

from blackboard.errors import BlackboardError
from models.errors import ModelError

__all__ = ["MAPINTERP_ERRORS"]

#: the root of every layer's errors: ``except MAPINTERP_ERRORS`` catches each mapinterp error
MAPINTERP_ERRORS: tuple[type[Exception], ...] = (ModelError, BlackboardError)

"""Helpers of the ranker tests (indexer, skyline): the small map's hypotheses reposted on an
in-memory board, camera frames that are viewframes, and tracks that predict one route point."""

from __future__ import annotations

import numpy as np

from blackboard.hypothesis import Hypothesis
from blackboard.memory_board import MemoryBlackboard
from knowledge_sources import levels


def repost(bb: MemoryBlackboard, h: Hypothesis) -> None:
    """Post ``h`` again on ``bb`` (same level, body and id)."""
    bb.post(h.level, h.body, id=h.id)


def post_map(bb: MemoryBlackboard, small_rendered: dict, **memory: object) -> None:
    """Post the small map's viewframes and its map, with these ``memory`` settings changed."""
    for h in small_rendered["viewframes"]:
        repost(bb, h)
    body = dict(small_rendered["map"].body)
    body["memory"] = {**body["memory"], **memory}
    bb.post(levels.MAP, body, id=levels.map_id())


def frames_from_viewframes(bb: MemoryBlackboard, small_rendered: dict, ks: list[int]) -> None:
    """Camera frames that are exactly viewframes ``ks`` (each must rank its own viewframe first)."""
    for k in ks:
        vf = levels.Viewframe.from_hypothesis(small_rendered["viewframes"][k])
        levels.post(bb.user, levels.SensorFrame(frame=k, image=vf.pixels(agent="test").image, source="test"))


def track(frame: int, state: str, point: int, n: int) -> levels.Track:
    """The track of ``frame`` on a route of ``n`` points, predicting ``point`` for the next frame."""
    prior = np.zeros(n, np.float32)
    prior[point] = 1.0
    return levels.Track(
        frame=frame,
        route_point=point,
        arc_m=0.0,
        position=[0.0, 0.0],
        heading_deg=0.0,
        confidence=0.9 if state == "tracking" else 0.1,
        state=state,
        evidence=True,
        belief=prior,
        prior_next=prior,
        loglik=None,
        dt=None,
        window_next=[point, point],
    )

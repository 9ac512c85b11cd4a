"""The blackboard levels of mapinterp and what lives on each.

=============  ==========================  ============================================================
level          posted by                   body
=============  ==========================  ============================================================
scenario       user (``mapinterp run``)    ``path``: absolute scenario file; ``strategy``
viewframe      map renderer                ``index``, ``pose`` [x, y, z, heading_deg, pitch_deg],
                                           ``image`` (H, W, 3) uint8, ``mask`` (H, W) int16,
                                           ``description`` (symbolic, plain data)
map            map renderer                ``viewframes`` count, ``priors`` P(L), ``landmarks``,
                                           ``route`` [[x, y], ...], ``visible`` {index: [ids]}
index          associative indexer(s)      ``shard``, ``shards``, ``viewframes``: this shard is stored
sensor_frame   camera                      ``frame``, ``image`` (H, W, 3) uint8
truth          camera                      ``frame``, ``pose`` [x, y, heading_deg] (evaluation only:
                                           no agent consumes it)
ranking        associative indexer(s)      ``frame``, ``shard``, ``shards``, ``viewframes``, ``variances``,
                                           ``reliability``
query          scheduler                   ``frame``, ``landmark``, ``kind``, ``viewframe``, ``p``
answer         landmark detector           ``frame``, ``landmark``, ``viewframe``, ``present``
                                           (true/false/null), ``score``, ``reason``
position       scheduler                   the frame's decision (see :mod:`knowledge_sources.results`)
=============  ==========================  ============================================================
"""

from __future__ import annotations

__all__ = ["SCENARIO", "VIEWFRAME", "MAP", "INDEX", "SENSOR_FRAME", "TRUTH", "RANKING", "QUERY", "ANSWER", "POSITION",
           "frame_id", "viewframe_id"]

SCENARIO = "scenario"
VIEWFRAME = "viewframe"
MAP = "map"
INDEX = "index"
SENSOR_FRAME = "sensor_frame"
TRUTH = "truth"
RANKING = "ranking"
QUERY = "query"
ANSWER = "answer"
POSITION = "position"


def frame_id(frame: int) -> str:
    """Hypothesis id of camera frame ``frame`` on the sensor_frame level."""
    return f"sf-{frame:06d}"


def viewframe_id(index: int) -> str:
    """Hypothesis id of viewframe ``index`` on the viewframe level."""
    return f"vf-{index:06d}"

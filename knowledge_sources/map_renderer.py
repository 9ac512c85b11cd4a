"""The map renderer: from a scenario to the a-priori viewframes on the blackboard."""

from __future__ import annotations

import logging
from typing import Any, ClassVar

import numpy as np

from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels
from knowledge_sources.errors import input_error_message
from models.route_views import route_points_of

__all__ = ["MapRenderer"]

log = logging.getLogger(__name__)


class MapRenderer(KnowledgeSource):
    """Builds the environment model F*, renders a viewframe at every route point and posts each
    with its symbolic description, then posts the ``map`` hypothesis (count, priors P(L),
    landmarks, route, visible landmarks per viewframe and where they appear: what the agents use
    of the descriptions) that tells the others the map is complete.

    When the viewframes are in a viewframe cache entry (:attr:`models.world.World.entry`), each
    ``viewframe`` message names the entry instead of carrying the image, mask, background and
    description (the readers get the pixels with :meth:`knowledge_sources.levels.Viewframe.pixels`;
    the descriptions are in the entry's ``meta.json``), unless the scenario says
    ``render: {inline: true}`` or the option ``inline`` is true (``mapinterp run
    --inline-viewframes``: :func:`knowledge_sources.mission.agent_plan` passes it).
    """

    def __init__(self, name: str, *, inline: bool = False, **options: Any) -> None:
        super().__init__(name, **options)
        #: post the pixels inline even when they are in a cache entry (hosts without a shared folder)
        self.inline = bool(inline)

    consumes: ClassVar[tuple[str, ...]] = (levels.SCENARIO,)
    produces: ClassVar[tuple[str, ...]] = (levels.VIEWFRAME, levels.MAP)
    exclusive: ClassVar[tuple[str, ...]] = (levels.VIEWFRAME, levels.MAP)

    def precondition(self, event: Event) -> float | None:
        return 1.0 if event.kind is EventKind.POSTED else None

    def input_error(self, err: Exception) -> str | None:
        return input_error_message(err)  # the scenario's files: the run stops with their error

    def act(self, event: Event, board: Board) -> None:
        from models.viewframe_cache import entry_field, release_behind
        from models.world import World

        source = event.hypothesis
        request = levels.Scenario.from_hypothesis(source)
        with World.from_scenario(request.path) as world:
            scenario = world.scenario
            inline = self.inline or scenario.render.inline
            # by reference from a filled cache: the entry's summary, not the viewframes (no
            # description parsed: 2 to 5 s of the warm setup of a route of 10,000 viewframes)
            summary = None if inline else world.summary()
            if summary is not None:
                entry = str(world.entry.resolve()) if world.entry is not None else None
                n = len(summary.viewframes)
                skylines = None if entry is None else entry_field(entry, "skyline", count=n)
                images = None if entry is None else entry_field(entry, "image", count=n)
                if (
                    entry is None
                    or skylines is None
                    or images is None
                    or not np.array_equal(summary.viewframes, np.arange(n))
                ):
                    summary = None  # an entry of another layout: from its viewframes
            if summary is None:
                viewframes = world.viewframes
                entry = None if world.entry is None else str(world.entry.resolve())
            priors = world.priors
        fov_y_deg = scenario.camera.fov_y_deg
        # per viewframe: {landmark id: pixels} and {landmark id: placement} (arrays in the map)
        visible: dict[int, dict[str, int]]
        placements: dict[int, dict[str, tuple[float, float, float]]]
        if summary is not None:
            assert entry is not None and skylines is not None and images is not None
            poses, visible, placements = self._post_summary(
                board, source, entry, summary, skylines, shape=images.shape[1:], fov_y_deg=fov_y_deg
            )
            count = n
        else:
            by_reference = entry is not None and not inline
            if entry is not None and not by_reference:
                log.info("%s: viewframe pixels posted inline (inline asked), not by reference to %s", self.name, entry)
            poses = []
            # from the descriptions' plain data (a description read from the cache builds no graph for them)
            visible, placements = {}, {}
            for k, vf in enumerate(viewframes):
                message = (
                    levels.Viewframe.of(vf, entry=entry, count=len(viewframes))
                    if by_reference
                    else levels.Viewframe.of(vf)
                )
                poses.append(message.pose)
                # by reference the message carries no description (it is in the entry): from the viewframe
                description = vf.description.to_dict() if message.description is None else message.description
                nodes, shown = description["nodes"], description["visible"]
                visible[int(vf.index)] = {n: int(nodes[n]["pixels"]) for n in shown}
                placements[int(vf.index)] = {n: _placement(nodes[n], vf.image.shape, fov_y_deg) for n in shown}
                levels.post(
                    board,
                    message,
                    links=(source.id,),
                )
                del message
                # viewframes from the cache are memory-mapped: the pages read to post them are given
                # back batch by batch
                if release_behind(k, viewframes, lambda v: (v.image, v.mask, v.background, v.depth, v.skyline)):
                    # flow control: a read is answered once the node has received every post this agent
                    # sent (the read barrier), so the node's queue holds at most a batch of viewframes; a
                    # renderer reading a filled cache outruns the node, whose queue of 150 KB messages
                    # (inline) otherwise grew by gigabytes on a route of 10,000 viewframes (by reference
                    # a message is about 0.6 KB, and the subscribers' queues stay short too)
                    board.get(levels.viewframe_id(k))
            count = len(viewframes)
        levels.post(
            board,
            levels.Map.of(
                scenario=scenario.name,
                path=request.path,
                priors=priors,
                landmarks=[
                    {"id": lm.id, "kind": lm.kind, "index": i, "x": lm.x, "y": lm.y}
                    for i, lm in enumerate(scenario.landmarks)
                ],
                route=[[float(x), float(y)] for x, y in scenario.route],
                poses=poses,
                visible=visible,
                placements=placements,
                memory=scenario.memory.model_dump(),
                entry=entry,
                route_points=route_points_of(scenario),
            ),
            links=(source.id,),
        )
        log.info("%s: posted %d viewframes of scenario %s", self.name, count, scenario.name)

    def _post_summary(
        self,
        board: Board,
        source: Any,
        entry: str,
        summary: Any,
        skylines: Any,
        *,
        shape: tuple[int, ...],
        fov_y_deg: float,
    ) -> tuple[list[list[float]], dict[int, dict[str, int]], dict[int, dict[str, tuple[float, float, float]]]]:
        """Post every viewframe of the cache entry ``entry`` by reference, from its summary
        (:class:`models.viewframe_cache.EntrySummary`) and stacked ``skylines`` (V, n) (memory-mapped),
        images of ``shape`` (H, W, 3): the messages the viewframes themselves would give
        (:meth:`levels.Viewframe.of`). Returns the map's poses, ``{k: {landmark id: pixels}}`` and
        ``{k: {landmark id: placement}}``."""
        import mmap

        from models import viewframe_cache
        from models.placement import placement

        n = len(summary.viewframes)
        visible: dict[int, dict[str, int]] = {k: {} for k in range(n)}
        placements: dict[int, dict[str, tuple[float, float, float]]] = {k: {} for k in range(n)}
        for k, lm, px, (row, col) in zip(
            summary.rows.tolist(), summary.landmarks.tolist(), summary.pixels.tolist(), summary.centroids.tolist()
        ):
            visible[k][lm] = px
            placements[k][lm] = placement(row, col, px, shape=shape, fov_y_deg=fov_y_deg)
        poses = summary.poses.tolist()
        every = viewframe_cache.RELEASE_EVERY
        for k in range(n):
            message = levels.Viewframe(
                index=k, pose=poses[k], skyline=np.array(skylines[k]), entry=entry, entry_count=n
            )
            levels.post(board, message, links=(source.id,))
            if (k + 1) % every == 0 or k + 1 == n:
                board.get(levels.viewframe_id(k))  # flow control, as for the viewframes (act)
        viewframe_cache.release_pages([skylines], advice=mmap.MADV_DONTNEED)  # the entry's pages, read once
        return poses, visible, placements


def _placement(node: dict, shape: tuple[int, ...], fov_y_deg: float) -> tuple[float, float, float]:
    """A symbolic description node's placement (:mod:`models.placement`) from its ``centroid``
    (row, col) and ``pixels`` (a node of the description's plain data, SymbolicDescription.to_dict)."""
    from models.placement import placement

    row, col = node["centroid"]
    return placement(row, col, node["pixels"], shape=shape, fov_y_deg=fov_y_deg)

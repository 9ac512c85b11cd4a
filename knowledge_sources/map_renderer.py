"""The map renderer: from a scenario to the a-priori viewframes on the blackboard."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, ClassVar

from blackboard.knowledge_source import Board, Event, EventKind, KnowledgeSource
from knowledge_sources import levels
from knowledge_sources.errors import input_error_message

if TYPE_CHECKING:
    from models.scenario import Scenario

__all__ = ["MapRenderer"]

log = logging.getLogger(__name__)


class MapRenderer(KnowledgeSource):
    """Builds the environment model F*, renders a viewframe at every route point and posts each
    with its symbolic description, then posts the ``map`` hypothesis (count, priors P(L),
    landmarks, route, visible landmarks per viewframe) that tells the others the map is complete.

    When the viewframes are in a viewframe cache entry (:attr:`models.world.World.entry`), each
    ``viewframe`` message names the entry instead of carrying the image, mask and background
    (the readers get them with :meth:`knowledge_sources.levels.Viewframe.pixels`), unless the
    scenario says ``render: {inline: true}`` or the option ``inline`` is true (``mapinterp run
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
        from models.viewframe_cache import release_behind
        from models.world import World

        source = event.hypothesis
        request = levels.Scenario.from_hypothesis(source)
        with World.from_scenario(request.path) as world:
            scenario = world.scenario
            viewframes = world.viewframes
            priors = world.priors
            entry = None if world.entry is None else str(world.entry.resolve())
        inline = self.inline or scenario.render.inline
        by_reference = entry is not None and not inline
        if entry is not None and not by_reference:
            log.info("%s: viewframe pixels posted inline (inline asked), not by reference to %s", self.name, entry)
        poses = []
        # per viewframe: {landmark id: pixels} and {landmark id: placement}, from the description's
        # plain data (a description read from the cache builds no graph for them); arrays in the map
        visible: dict[int, dict[str, int]] = {}
        placements: dict[int, dict[str, tuple[float, float, float]]] = {}
        fov_y_deg = scenario.camera.fov_y_deg
        for k, vf in enumerate(viewframes):
            message = (
                levels.Viewframe.of(vf, entry=entry, count=len(viewframes)) if by_reference else levels.Viewframe.of(vf)
            )
            poses.append(message.pose)
            nodes = message.description["nodes"]
            shown = message.description["visible"]
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
                # a message is about 3 KB, and the subscribers' queues stay short too)
                board.get(levels.viewframe_id(k))
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
                route_points=_route_points(scenario),
            ),
            links=(source.id,),
        )
        log.info("%s: posted %d viewframes of scenario %s", self.name, len(viewframes), scenario.name)


def _route_points(scenario: Scenario) -> list[int] | None:
    """The route point of each viewframe (:func:`models.route_views.view_route`), or None when
    the viewframes are the route points (one per leg)."""
    from models.route_views import view_route

    if scenario.views_per_leg == 1:
        return None
    return view_route(scenario.route, scenario.views_per_leg)[2].tolist()


def _placement(node: dict, shape: tuple[int, ...], fov_y_deg: float) -> tuple[float, float, float]:
    """A symbolic description node's placement (:mod:`models.placement`) from its ``centroid``
    (row, col) and ``pixels`` (a node of the description's plain data, SymbolicDescription.to_dict)."""
    from models.placement import placement

    row, col = node["centroid"]
    return placement(row, col, node["pixels"], shape=shape, fov_y_deg=fov_y_deg)

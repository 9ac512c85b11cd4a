"""The map's views for the agents that render it again: the pose refiner and the verifier.

Each of them loads the scenario the ``map`` hypothesis names (its own camera emulator, in its own
process if need be) and starts from a viewframe's pose; the view there is the viewframe's own,
read from the map's viewframe cache entry when that entry holds what this emulator renders (the
entry's name is the world's cache key, :meth:`models.world.World.renders_entry`: the same
pixels), otherwise rendered.
"""

from __future__ import annotations

import mmap
from typing import TYPE_CHECKING

import numpy as np

from blackboard.knowledge_source import Board
from knowledge_sources import levels

if TYPE_CHECKING:
    from models.camera_emulator import CameraEmulator, Pose, View
    from models.world import World

__all__ = ["MapViews", "skyline_profile"]


class MapViews:
    """The scenario of ``mp`` (a ``map`` message) as a world with its camera emulator, and the
    map's cache entry's depths (memory-mapped) when the entry is this emulator's (``depths``,
    else None: every view rendered). :meth:`close` when done."""

    def __init__(self, mp: levels.Map) -> None:
        from models.viewframe_cache import entry_field
        from models.world import World

        self.map = mp
        self.world: World = World.from_scenario(mp.path)
        self.emulator: CameraEmulator = self.world.emulator
        self.depths: np.ndarray | None = None
        if mp.entry is not None and self.world.renders_entry(mp.entry):
            depths = entry_field(mp.entry, "depth", count=mp.viewframes)
            if depths is not None and depths.ndim == 3:
                self.depths = depths

    def start_pose(self, viewframe: int) -> Pose:
        """The camera pose of ``viewframe``: its route point (x, y) on the ground, its heading and pitch."""
        x, y, _, heading, pitch = self.map.pose(int(viewframe))
        return self.emulator.pose_at(float(x), float(y), float(heading), pitch_deg=float(pitch))

    def own_view(self, viewframe: int, pose: Pose) -> View | None:
        """The view of ``viewframe`` at ``pose`` (its own) from the map's cache entry: copies, the
        entry's pages given back; None when the entry is not this emulator's (render it)."""
        from models.camera_emulator import View
        from models.viewframe_cache import read_pixels, release_pages

        if self.depths is None or self.map.entry is None:
            return None
        pixels = read_pixels(self.map.entry, int(viewframe), count=self.map.viewframes)
        depth = np.array(self.depths[viewframe], dtype=np.float32)
        release_pages([self.depths[viewframe]], advice=mmap.MADV_DONTNEED)
        return View(image=pixels.image, depth=depth, mask=pixels.mask.astype(np.int32), pose=pose)

    def pattern(self, image: np.ndarray) -> np.ndarray:
        """The memory pattern of ``image`` (H, W[, 3], indexed (row, col)) with the map scenario's
        memory settings (:func:`models.preprocess.preprocess`): what the indexers store and the
        render-and-compare and the refiner's memory alignment correlate."""
        from models.preprocess import preprocess

        mem = self.world.scenario.memory
        return preprocess(image, size=mem.size, edge=mem.edge, blur_sigma=mem.blur_sigma, whiten=mem.whiten)

    def release(self) -> None:
        """Give the emulator's rendering context back (after each activation: shutdown closes it
        from another thread)."""
        self.emulator.release()

    def close(self) -> None:
        self.world.close()


def skyline_profile(board: Board, frame: int) -> np.ndarray | None:
    """The camera ``frame``'s skyline profile as the skyline ranker extracted it (its ranking of the
    frame carries it), or None (no skyline ranker: the caller extracts it)."""
    from knowledge_sources.skyline import SKYLINE_SOURCE

    got = board.get(levels.ranking_id(frame, 0, SKYLINE_SOURCE))
    return None if got is None else levels.Ranking.from_hypothesis(got).profile

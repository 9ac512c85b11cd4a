"""The typed level messages: round trips through the codec, validation naming the field, ids, the docs table."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from blackboard.codec import decode, encode
from blackboard.hypothesis import Hypothesis
from knowledge_sources import levels
from models.associative import Ranking as MemoryRanking

README = Path(__file__).resolve().parents[2] / "README.md"


def _image(h: int = 6, w: int = 8) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _map_between(route_points, *, memory: dict | None = None):
    """A map of 3 viewframes on a route of 2 points (render.views_per_leg: 2) with ``route_points``
    and ``memory`` settings."""
    return levels.Map.of(
        scenario="s",
        path="/tmp/s.yaml",
        priors={},
        landmarks=[],
        route=[[0.0, 0.0], [10.0, 0.0]],
        poses=[[0.0, 0.0, 2.0, 0.0, 0.0], [5.0, 0.0, 2.0, 0.0, 0.0], [10.0, 0.0, 2.0, 0.0, 0.0]],
        visible={},
        memory=memory or {},
        route_points=route_points,
    )


#: one valid message of every level
SAMPLES: list[levels.Message] = [
    levels.Scenario(path="/tmp/s.yaml", strategy="associative"),
    levels.Viewframe(
        index=7,
        pose=[1.0, 2.0, 3.0, 90.0, 0.0],
        image=_image(),
        mask=np.full((6, 8), -1, np.int16),
        description={"visible": ["H1"]},
        skyline=np.array([0.5, 1.5, 2.0], np.float32),
    ),
    levels.Map.of(
        scenario="s",
        path="/tmp/s.yaml",
        priors={"H1": 0.5},
        landmarks=[{"id": "H1", "kind": "house", "index": 0, "x": 1.0, "y": 2.0}],
        route=[[0.0, 0.0], [10.0, 0.0]],
        poses=[[0.0, 0.0, 2.0, 0.0, 0.0], [10.0, 0.0, 2.0, 180.0, 0.0]],
        visible={0: {"H1": 80}, 1: {}},
        placements={0: {"H1": [1.0, -2.0, 3.5]}},
        memory={"size": 64},
    ),
    _map_between([0, 0, 1], memory={"size": 64}),  # viewframes between the route points
    levels.Index(shard=1, shards=3, viewframes=12),
    levels.SensorFrame(frame=4, image=_image(), source="simulated"),
    levels.Truth(frame=4, pose=[1.0, 2.0, 45.0]),
    levels.Ranking(
        frame=4, frame_time=1.5, shard=0, shards=1, viewframes=[2, 0], variances=[1e-5, 2e-4], reliability=3.0
    ),
    levels.Ranking(
        frame=4,
        frame_time=1.5,
        shard=0,
        shards=1,
        viewframes=[0, 2],
        variances=[0.2, 1.1],
        reliability=2.0,
        source="skyline",
        shifts=[[1.5, -0.5], [0.0, 0.0]],
    ),
    levels.Query(frame=4, number=2, landmark="H1", landmark_index=0, kind="house", viewframe=2, p=0.7),
    levels.Answer(
        query="q-000004-2",
        frame=4,
        landmark="H1",
        viewframe=2,
        present=None,
        score=0.3,
        location=None,
        detector="edges",
        reason="undecided",
    ),
    levels.Position(
        frame=4,
        viewframe=2,
        position=[1.0, 2.0],
        heading_deg=90.0,
        confidence=0.9,
        queries=1,
        backtracks=0,
        latency_ms=12.0,
        ranking=[[2, 1e-5]],
        reason="accepted",
        degraded=[],
        steps=[],
        strategy="associative",
    ),
    levels.Pose(
        frame=4,
        position="pos-000004",
        viewframe=2,
        x=1.5,
        y=2.5,
        heading_deg=91.0,
        pitch_deg=0.5,
        sigma_along_m=2.0,
        sigma_across_m=1.0,
        sigma_heading_deg=0.2,
        score=0.4,
        start_score=0.8,
        renders=40,
        route_position=[1.0, 2.0],
        route_heading_deg=90.0,
    ),
    levels.Track(
        frame=4,
        route_point=2,
        arc_m=81.5,
        position=[80.0, 3.0],
        heading_deg=0.0,
        confidence=0.7,
        state="tracking",
        evidence=True,
        belief=np.array([0.1, 0.2, 0.7], np.float32),
        prior_next=np.array([0.05, 0.15, 0.8], np.float32),
        loglik=np.zeros(9, np.float32),
        dt=None,
    ),
    levels.TrackQuery(frame=4, position="pos-000004"),
    levels.VerifyQuery(frame=4, viewframes=[7, 3, 9]),
    levels.Verification(
        frame=4,
        query="vq-000004",
        viewframes=[7, 3, 9],
        correlations=[0.41, 0.55, 0.2],
        headings_deg=[61.0, 58.5, 70.0],
        renders=3,
    ),
]


def test_every_level_has_a_sample() -> None:
    assert [type(m).level for m in SAMPLES] != [] and {type(m).level for m in SAMPLES} == set(levels.MESSAGES)


@pytest.mark.parametrize("message", SAMPLES, ids=lambda m: type(m).level)
def test_round_trip_through_codec_and_hypothesis(message: levels.Message) -> None:
    h = Hypothesis.new(message.level, message.to_body(), source="t", id=message.id())
    wire = Hypothesis.from_record(decode(encode({"hyp": h.to_record()}))["hyp"])
    back = type(message).from_hypothesis(wire)
    for f in dataclasses.fields(message):  # type: ignore[arg-type]
        a, b = getattr(message, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            assert b.dtype == a.dtype and np.array_equal(a, b)
        else:
            assert a == b, f.name
    assert back.id() == message.id()


@pytest.mark.parametrize("message", SAMPLES, ids=lambda m: type(m).level)
def test_id_follows_its_documented_pattern(message: levels.Message) -> None:
    pattern = re.escape(type(message).id_pattern)
    pattern = re.sub(r"<[a-z_]+:06d>", r"[0-9]{6}", pattern)
    pattern = re.sub(r"<[a-z_]+>", r"[A-Za-z0-9_-]+", pattern)
    assert re.fullmatch(pattern, message.id()), (message.id(), type(message).id_pattern)


def test_arrays_are_not_copied() -> None:
    frame = levels.SensorFrame(frame=1, image=_image(), source="x")
    body = frame.to_body()
    assert body["image"] is frame.image
    decoded = decode(encode(body))
    again = levels.SensorFrame.from_body(decoded)
    assert again.image is decoded["image"]


@pytest.mark.parametrize(
    ("cls", "body", "field", "problem"),
    [
        (levels.Index, {"shard": 0, "shards": 1}, "viewframes", "missing"),
        (levels.Index, {"shard": 0, "shards": 1, "viewframes": 2, "extra": 1}, "extra", "not a field"),
        (levels.Index, {"shard": "0", "shards": 1, "viewframes": 2}, "shard", "integer"),
        (levels.Index, {"shard": True, "shards": 1, "viewframes": 2}, "shard", "integer"),
        (levels.Truth, {"frame": 1, "pose": [1.0, 2.0]}, "pose", "3 entries"),
        (levels.Truth, {"frame": 1, "pose": "north"}, "pose", "list"),
        (levels.SensorFrame, {"frame": 1, "image": np.zeros((4, 4), np.uint8), "source": "x"}, "image", "dimensions"),
        (levels.SensorFrame, {"frame": 1, "image": np.zeros((4, 4, 3), np.float32), "source": "x"}, "image", "dtype"),
        (levels.SensorFrame, {"frame": 1, "image": [[0]], "source": "x"}, "image", "numpy array"),
        (
            levels.Answer,
            {
                "query": "q",
                "frame": 1,
                "landmark": "H",
                "viewframe": 0,
                "present": "yes",
                "score": 0.1,
                "location": None,
                "detector": "d",
                "reason": "",
            },
            "present",
            "true or false",
        ),
    ],
)
def test_bad_bodies_name_level_field_and_hypothesis(
    cls: type[levels.Message], body: dict, field: str, problem: str
) -> None:
    with pytest.raises(levels.MessageError) as info:
        cls.from_body(body, hypothesis_id="h-1")
    err = info.value
    assert (err.level, err.field, err.hypothesis_id) == (cls.level, field, "h-1")
    assert problem in str(err) and "h-1" in str(err) and cls.level in str(err)


def test_constructing_a_bad_message_fails_at_the_poster() -> None:
    with pytest.raises(levels.MessageError, match="frame: must be an integer"):
        levels.Truth(frame=1.5, pose=[0.0, 0.0, 0.0])  # type: ignore[arg-type]


def test_wrong_level_is_refused() -> None:
    h = Hypothesis.new("truth", {"frame": 1, "pose": [0.0, 0.0, 0.0]}, source="t")
    with pytest.raises(levels.MessageError, match="is on level truth"):
        levels.Position.from_hypothesis(h)


def test_scalars_are_normalised() -> None:
    t = levels.Truth(frame=np.int64(3), pose=[0.0, 0.0, 0.0])  # type: ignore[arg-type]
    assert type(t.frame) is int
    r = levels.Ranking(frame=1, frame_time=2, shard=0, shards=1, viewframes=[], variances=[], reliability=np.float32(1))
    assert type(r.frame_time) is float and type(r.reliability) is float


def test_ranking_message_and_memory_ranking_agree() -> None:
    memory = MemoryRanking(np.array([3, 1, 2]), np.array([1e-5, 2e-5, 9e-5]), 2.5)
    msg = levels.Ranking.of(memory, frame=5, frame_time=0.0, shard=1, shards=2)
    back = msg.ranking()
    assert msg.id() == "rk-000005-1"
    assert back.top(3) == memory.top(3) and back.reliability == memory.reliability


def test_position_at_a_viewframe_pose() -> None:
    assert levels.Position.at(None) == (None, None)
    assert levels.Position.at([3.0, 4.0, 2.0, 270.0, 0.0]) == ([3.0, 4.0], 270.0)


def test_a_second_class_for_a_level_is_refused() -> None:
    with pytest.raises(TypeError, match="already has message class"):

        @dataclasses.dataclass(frozen=True, slots=True)
        class Other(levels.Message):
            level = "truth"  # type: ignore[misc]
            posted_by = "x"  # type: ignore[misc]
            id_pattern = "x"  # type: ignore[misc]

            def id(self) -> str:
                return "x"


def test_a_new_level_must_say_who_posts_it_and_its_ids() -> None:
    with pytest.raises(TypeError, match="must define posted_by, id_pattern, id()"):

        @dataclasses.dataclass(frozen=True, slots=True)
        class Track(levels.Message):
            level = "track-test"  # type: ignore[misc]

    assert "track-test" not in levels.MESSAGES


def test_a_new_level_is_one_class() -> None:
    @dataclasses.dataclass(frozen=True, slots=True)
    class Pose(levels.Message):
        """A refined pose of one frame."""

        level = "pose-test"  # type: ignore[misc]
        posted_by = "refiner"  # type: ignore[misc]
        id_pattern = "pose-<frame:06d>"  # type: ignore[misc]
        frame: int = dataclasses.field(metadata={"doc": "frame number"})
        xy: list = dataclasses.field(metadata={"doc": "[x, y]", "length": 2})

        def id(self) -> str:
            return f"pose-{self.frame:06d}"

    try:
        assert levels.message_class("pose-test") is Pose
        assert Pose.from_body(Pose(frame=3, xy=[1.0, 2.0]).to_body()).id() == "pose-000003"
        with pytest.raises(levels.MessageError, match="xy: must have 2 entries"):
            Pose.from_body({"frame": 3, "xy": [1.0]})
        assert "| `pose-test` | refiner | `pose-<frame:06d>` | `frame` | int | frame number |" in levels.levels_table()
    finally:
        del levels.MESSAGES["pose-test"]


def test_readme_levels_table_is_the_generated_one() -> None:
    text = README.read_text()
    m = re.search(r"<!-- levels table: generated -->\n(.*?)\n<!-- end levels table -->", text, re.DOTALL)
    assert m is not None, "README.md lacks the generated levels table"
    assert m.group(1).strip() == levels.levels_table(), (
        "README levels table drifted: run python -m knowledge_sources.levels"
    )


def test_table_lists_every_field_of_every_level() -> None:
    rows = [line.split("|")[1:-1] for line in levels.levels_table().splitlines()[2:]]
    seen: dict[str, list[str]] = {}
    level = ""
    for cells in rows:
        level = cells[0].strip().strip("`") or level
        seen.setdefault(level, []).append(cells[3].strip().strip("`"))
    assert seen == {lv: [f.name for f in dataclasses.fields(cls)] for lv, cls in levels.MESSAGES.items()}  # type: ignore[arg-type]


def test_module_docstring_carries_the_table() -> None:
    assert levels.__doc__ is not None and levels.levels_table().splitlines()[2] in levels.__doc__


OF_SCENARIO = {
    "name": "of",
    "terrain": {"cell_size": 10.0, "procedural": {"size": 48, "relief": 20.0, "seed": 1}},
    "landmarks": [{"id": "H1", "kind": "house", "x": 230.0, "y": 240.0, "width": 16, "depth": 10, "height": 8}],
    "route": [[170.0, 240.0], [200.0, 240.0], [330.0, 240.0]],
    "camera": {"width": 64, "height": 48, "fov_y_deg": 45, "eye_height": 2.0, "near": 1.0, "far": 800.0},
    "render": {"views_per_leg": 1},  # a viewframe per route point (which of them see H1, below)
}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> tuple[list, list, str]:
    """OF_SCENARIO's viewframes rendered without a cache, the same read back from a cache entry,
    and that entry's absolute path."""
    from models.scenario import scenario_from_dict
    from models.viewframe_cache import ViewframeCache
    from models.world import World

    with World(scenario_from_dict(OF_SCENARIO), cache=None) as world:
        plain = world.viewframes
    with World(scenario_from_dict(OF_SCENARIO), cache=ViewframeCache(tmp_path_factory.mktemp("of"))) as world:
        cached = world.viewframes
        assert world.entry is not None
        entry = str(world.entry.resolve())
    return plain, cached, entry


@pytest.mark.parametrize("by_reference", [False, True], ids=["inline", "by-reference"])
def test_a_rendered_viewframe_becomes_its_message_and_survives_the_codec(rendered, by_reference):
    """Inline, the message carries the pixels; by reference it names the cache entry and carries
    no pixel array, and :meth:`levels.Viewframe.pixels` gives the same arrays either way."""
    plain, cached, entry = rendered
    assert plain[1].background is not None and plain[2].background is None
    for vf, vc in zip(plain, cached):
        msg = levels.Viewframe.of(vc, entry=entry, count=len(cached)) if by_reference else levels.Viewframe.of(vf)
        assert msg.id() == levels.viewframe_id(vf.index)
        assert msg.pose == [vf.pose.x, vf.pose.y, vf.pose.z, vf.pose.heading_deg, vf.pose.pitch_deg]
        # inline the description travels with the pixels; by reference both stay in the entry
        assert msg.description == (None if by_reference else vf.description.to_dict())
        wire = encode(msg.to_body())
        back = levels.Viewframe.from_body(decode(wire))
        np.testing.assert_array_equal(back.skyline, vf.skyline)
        if by_reference:
            assert (back.image, back.mask, back.background) == (None, None, None)
            assert (back.entry, back.entry_count) == (entry, len(cached))
            assert len(wire) < vf.image.nbytes / 4  # no pixels on the wire
        else:
            assert back.mask.dtype == np.int16 and back.entry is None
        px = back.pixels(agent="test")
        np.testing.assert_array_equal(px.image, vf.image)
        assert px.mask.dtype == np.int16 and np.array_equal(px.mask, vf.mask)
        assert (px.background is None) == (vf.background is None)
        if vf.background is not None:
            np.testing.assert_array_equal(px.background, vf.background)


_IMAGE = np.zeros((4, 6, 3), np.uint8)
_MASK = np.full((4, 6), -1, np.int16)
BAD_VIEWFRAMES = {
    "inline-without-image": ({"mask": _MASK}, "image: missing"),
    "inline-without-mask": ({"image": _IMAGE}, "mask: missing"),
    "inline-without-description": (
        {"image": _IMAGE, "mask": _MASK, "description": None},
        "description: missing: a viewframe without an entry carries its description",
    ),
    "count-without-entry": ({"image": _IMAGE, "mask": _MASK, "entry_count": 3}, "entry_count: given without"),
    "entry-and-image": ({"image": _IMAGE, "entry": "/e", "entry_count": 3}, "image: a viewframe naming a cache"),
    "entry-and-background": ({"background": _IMAGE, "entry": "/e", "entry_count": 3}, "background: a viewframe"),
    "entry-and-description": (
        {"description": {"visible": []}, "entry": "/e", "entry_count": 3},
        "description: a viewframe naming a cache entry carries no description",
    ),
    "relative-entry": ({"entry": "cache/e", "entry_count": 3}, "entry: must be an absolute path"),
    "entry-without-count": ({"entry": "/e"}, "entry_count: must be a count above the index 2"),
    "row-beyond-count": ({"entry": "/e", "entry_count": 2}, "entry_count: must be a count above the index 2"),
}


@pytest.mark.parametrize(("extra", "problem"), BAD_VIEWFRAMES.values(), ids=BAD_VIEWFRAMES.keys())
def test_a_viewframe_is_inline_or_a_reference_never_both_nor_neither(extra, problem) -> None:
    """Inline a viewframe carries its pixels and description; by reference neither (both in the entry)."""
    inline = "entry" not in extra
    body = {
        "index": 2,
        "pose": [0.0] * 5,
        "skyline": np.zeros(3, np.float32),
        **({"description": {}} if inline else {}),
    }
    body.update(extra)
    with pytest.raises(levels.MessageError, match=f"level viewframe hypothesis vf-000002: {problem}"):
        levels.Viewframe.from_body(body, hypothesis_id="vf-000002")


@pytest.mark.parametrize("change", ["deleted", "other-count"])
def test_pixels_of_a_reference_this_host_cannot_read_name_entry_viewframe_and_agent(rendered, tmp_path, change):
    """A reference to an entry that is not there (another host, a deleted cache) or not the one it
    names (another count: stale) is a CacheEntryError naming the entry, the viewframe and the agent."""
    from models.errors import CacheEntryError

    _, cached, entry = rendered
    where, count = (str(tmp_path / "gone"), len(cached)) if change == "deleted" else (entry, len(cached) + 4)
    msg = levels.Viewframe.of(cached[1], entry=where, count=count)
    with pytest.raises(CacheEntryError) as err:
        msg.pixels(agent="indexer-7")
    text = str(err.value)
    assert text.startswith(f"{where}: agent indexer-7, viewframe vf-000001: ") and "render: {inline: true}" in text


def _route_map(n: int, per: int, *, seed: int = 4) -> tuple[levels.Map, dict, dict]:
    """A map of ``n`` viewframes showing ``per`` of 40 landmarks each (seeded), and its
    ``visible`` and ``placements`` as maps."""
    rng = np.random.default_rng(seed)
    landmarks = [{"id": f"L{i}", "kind": "house", "index": i, "x": float(i), "y": 0.0} for i in range(40)]
    visible = {k: {f"L{i}": int(rng.integers(1, 5000)) for i in rng.choice(40, per, replace=False)} for k in range(n)}
    placements = {k: {lm: tuple(rng.normal(size=3).tolist()) for lm in v} for k, v in visible.items()}
    mp = levels.Map.of(
        scenario="s",
        path="/tmp/s.yaml",
        priors={lm["id"]: 0.5 for lm in landmarks},
        landmarks=landmarks,
        route=rng.normal(size=(n, 2)).tolist(),
        poses=rng.normal(size=(n, 5)).tolist(),
        visible=visible,
        placements=placements,
        memory={"size": 128},
    )
    return mp, visible, placements


def test_the_map_is_a_few_arrays_of_bounded_size_per_viewframe() -> None:
    """A long route's map travels as arrays: its encoded size is the arrays' bytes (7 float64 a
    viewframe, 3 int32 and 3 float64 a visible landmark) and a little, it decodes into those
    arrays (no object per viewframe: nested maps of 10,000 viewframes were 3.2 MB to parse into
    18.5 MB), and reads back as the maps it was made of, bit for bit."""
    n, per = 2000, 6
    mp, visible, placements = _route_map(n, per)
    data = encode({"hyp": Hypothesis.new(mp.level, mp.to_body(), source="t", id=mp.id()).to_record()})
    assert len(data) < n * (8 * 7 + per * (4 * 3 + 8 * 3)) + 8192
    back = levels.Map.from_hypothesis(Hypothesis.from_record(decode(data)["hyp"]))
    for name in ("route", "poses", "visible", "placements"):
        assert isinstance(getattr(back, name), np.ndarray), name
    assert back.seen() == visible
    assert back.placement_table() == placements
    assert back.visible_sets(min_pixels=2500) == {
        k: frozenset(lm for lm, px in v.items() if px >= 2500) for k, v in visible.items()
    }
    assert [back.pose(k) for k in range(n)] == mp.poses.tolist()


@pytest.mark.parametrize(
    ("change", "field", "problem"),
    [
        ({"visible": {0: {"nope": 3}}}, "visible", "not a landmark of the map"),
        ({"placements": {0: {}}}, "placements", "no placement of landmark"),
    ],
)
def test_a_bad_map_names_its_field(change: dict, field: str, problem: str) -> None:
    base = dict(
        scenario="s",
        path="/tmp/s.yaml",
        priors={"H1": 0.5},
        landmarks=[{"id": "H1", "kind": "house", "index": 0, "x": 1.0, "y": 2.0}],
        route=[[0.0, 0.0]],
        poses=[[0.0, 0.0, 2.0, 0.0, 0.0]],
        visible={0: {"H1": 80}},
        placements={0: {"H1": [1.0, -2.0, 3.5]}},
        memory={},
    )
    with pytest.raises(levels.MessageError) as info:
        levels.Map.of(**{**base, **change})
    assert (info.value.level, info.value.field) == ("map", field) and problem in str(info.value)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"poses": np.zeros((3, 5))}, "poses"),
        ({"poses": np.zeros((2, 4))}, "poses"),
        ({"visible": np.array([[0, 1, 5]], np.int32)}, "visible"),  # landmark 1 of 1
        ({"visible": np.array([[1, 0, 5], [0, 0, 5]], np.int32)}, "visible"),  # out of order
        ({"visible": np.array([[0, 0, 5]], np.int64)}, "visible"),  # dtype
        ({"placements": np.zeros((2, 3))}, "placements"),
    ],
)
def test_a_bad_map_body_names_its_field(change: dict, field: str) -> None:
    one = levels.Map.of(
        scenario="s",
        path="/tmp/s.yaml",
        priors={"H1": 0.5},
        landmarks=[{"id": "H1", "kind": "house", "index": 0, "x": 1.0, "y": 2.0}],
        route=[[0.0, 0.0], [1.0, 0.0]],
        poses=[[0.0, 0.0, 2.0, 0.0, 0.0], [1.0, 0.0, 2.0, 0.0, 0.0]],
        visible={0: {"H1": 5}},
        placements={0: {"H1": [1.0, -2.0, 3.5]}},
        memory={},
    )
    levels.Map.from_body(one.to_body())  # valid as it is
    body = {**one.to_body(), **change}
    with pytest.raises(levels.MessageError) as info:
        levels.Map.from_body(body, hypothesis_id="map")
    assert (info.value.level, info.value.field, info.value.hypothesis_id) == ("map", field, "map")


def test_sensor_frame_columns_are_checked_against_the_image():
    image = np.zeros((12, 16, 3), np.uint8)
    ok = levels.SensorFrame(frame=0, image=image, source="f.png", columns=[4, 12])
    assert levels.SensorFrame.from_body(ok.to_body()).columns == [4, 12]
    assert levels.SensorFrame(frame=0, image=image, source="f.png").columns is None
    for bad in ([12, 4], [0, 17], [-1, 8], [1.5, 8], ["a", 8]):
        with pytest.raises(levels.MessageError, match="columns"):
            levels.SensorFrame(frame=0, image=image, source="f.png", columns=bad)


@pytest.mark.parametrize(
    "route_points, problem",
    [
        (None, "needed when the viewframes"),  # 3 viewframes, 2 route points, no mapping
        ([0, 1], "one per viewframe"),
        ([0, 2, 1], "non-decreasing"),
        ([0, 1, 2], r"in \[0, 2\)"),
    ],
)
def test_a_map_with_viewframes_between_route_points_names_a_bad_route_points_field(route_points, problem):
    with pytest.raises(levels.MessageError, match=problem) as err:
        _map_between(route_points)
    assert "route_points" in str(err.value)
    assert _map_between([0, 1, 1]).route_points.tolist() == [0, 1, 1]

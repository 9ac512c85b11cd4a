"""The skyline ranker and the pose refiner through the real blackboard, in one process and in processes."""

from __future__ import annotations

import math

import pytest
import yaml

from blackboard.trace import read_trace
from knowledge_sources.mission import agent_plan, run_mission
from models.scenario import load_scenario

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("processes", [False, True], ids=["inprocess", "processes"])
def test_skyline_rankings_are_fused_and_positions_refined(small_data, tmp_path, processes):
    small_data["refine"] = {"position": True}  # the position search too (default: heading and pitch only)
    small = tmp_path / "small.yaml"
    small.write_text(yaml.safe_dump(small_data))
    trace = tmp_path / "run.trace"
    results = run_mission(small, processes=processes, trace_path=trace)
    n = len(small_data["route"])
    records = read_trace(trace)
    posts = [r for r in records if r["kind"] == "post"]
    sky = [r for r in posts if r.get("level") == "ranking" and r["id"].endswith("-skyline")]
    assert (
        len(sky) == n and {r["agent"] for r in sky} == {"skyline"} and {r["body"]["source"] for r in sky} == {"skyline"}
    )
    # the scheduler waited for both sources: every position links the skyline ranking of its frame
    positions = {r["id"]: r for r in posts if r.get("level") == "position"}
    for p in positions.values():
        frame = int(p["id"].split("-")[1])
        assert f"rk-{frame:06d}-skyline" in p["links"] and f"rk-{frame:06d}-0" in p["links"]
    # one pose per localized frame, linked to its position and its camera frame
    poses = [r for r in posts if r.get("level") == "pose"]
    # the refinement is the single-frame decision's (frame_only; the track is the final answer)
    localized = [f for f in results["frames"] if f["frame_only"]["viewframe"] is not None]
    assert len(poses) == len(localized) > 0
    for r in poses:
        frame = int(r["id"].split("-")[1])
        assert r["links"][:2] == [f"pos-{frame:06d}", f"sf-{frame:06d}"]
    for f in localized:
        assert f["pose"] is not None and f["route_position"] is not None and f["pose"]["renders"] > 10
        assert math.dist(f["frame_only"]["position"], f["route_position"]) < 25
    # the small scenario's frames are close to their route points: refinement keeps them close
    assert results["summary"]["median_error_m"] < 6.0
    assert results["summary"]["median_heading_error_deg"] < 1.5


def test_disabled_skyline_and_refiner_leave_todays_pipeline(small_data, tmp_path):
    small_data["skyline"] = {"enabled": False}
    small_data["refine"] = {"enabled": False}
    path = tmp_path / "plain.yaml"
    path.write_text(yaml.safe_dump(small_data))
    names = [name for _, name, _ in agent_plan(load_scenario(path))]
    assert "skyline" not in names and "refiner" not in names
    results = run_mission(path)
    for f in results["frames"]:
        assert f["pose"] is None
        only = f["frame_only"]  # the single-frame decision: its route point's position, unrefined
        if only["viewframe"] is not None:
            assert only["position"] == pytest.approx(small_data["route"][only["viewframe"]])


def test_scenario_skyline_and_refine_blocks_reach_the_agents(small_data, tmp_path):
    small_data["skyline"] = {"weight": 2.5, "max_heading_deg": 8.0, "max_roll_deg": 1.5}
    small_data["memory"] = {"weight": 0.5}
    small_data["refine"] = {"along_m": 12.0, "grid": 3, "position": True, "max_roll_deg": 0.5, "recheck": False}
    path = tmp_path / "opts.yaml"
    path.write_text(yaml.safe_dump(small_data))
    plan = {name: opts for _, name, opts in agent_plan(load_scenario(path))}
    assert plan["scheduler"]["sources"] == {"associative": 0.5, "skyline": 2.5}
    assert plan["skyline"]["max_heading_deg"] == 8.0 and plan["skyline"]["fov_y_deg"] == 45
    assert plan["skyline"]["max_roll_deg"] == 1.5 and plan["refiner"]["max_roll_deg"] == 0.5
    assert plan["refiner"]["along_m"] == 12.0 and plan["refiner"]["grid"] == 3 and plan["refiner"]["position"]
    assert plan["refiner"]["recheck"] is False


def test_the_refiner_reuses_the_skyline_rankers_profile_of_the_frame(small_data, tmp_path, monkeypatch):
    """The skyline ranking of a frame carries the camera frame's profile it matched; the refiner
    takes it from there instead of extracting the same horizon again (in one process, the
    refiner's own extraction is made to fail: every frame is still refined)."""
    import numpy as np

    import models.refine as refine
    from knowledge_sources import levels
    from models.skyline import skyline_from_image

    def no_extraction(*args, **kwargs):
        raise AssertionError("the refiner extracted the frame's skyline again")

    monkeypatch.setattr(refine, "skyline_from_image", no_extraction)
    small = tmp_path / "small.yaml"
    small.write_text(yaml.safe_dump(small_data))
    seen: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def on_hypothesis(level, body, stamp):
        if level == levels.RANKING and body.get("source") == "skyline":
            seen[body["frame"]] = body["profile"]

    results = run_mission(small, on_hypothesis=on_hypothesis)
    assert not [d for d in results["degraded"] if d.startswith("agent refiner")], results["degraded"]
    localized = [f for f in results["frames"] if f["frame_only"]["viewframe"] is not None]
    assert localized and all(f["pose"] is not None for f in localized)
    scenario = load_scenario(small)
    from models.world import World

    with World(scenario) as world:
        frames = {f.index: f.image for f in world.sensor_frames}
    assert sorted(seen) == sorted(frames)
    for k, profile in seen.items():  # the profile is the frame's, as the refiner would have extracted it
        want = skyline_from_image(frames[k], fov_y_deg=scenario.camera.fov_y_deg, step_deg=scenario.skyline.step_deg)
        np.testing.assert_array_equal(profile, want)

"""The verifier through the real blackboard, in one process and in processes; the option off leaves today's pipeline."""

from __future__ import annotations

import pytest
import yaml

from blackboard.trace import read_trace
from knowledge_sources.mission import agent_plan, run_mission
from models.scenario import VerifySpec, load_scenario

pytestmark = pytest.mark.slow


def _write(data: dict, path) -> object:
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("processes", [False, True], ids=["inprocess", "processes"])
def test_every_uncertain_frame_is_verified_through_the_blackboard(small_data, tmp_path, processes):
    small_data["verify"] = {"enabled": True, "candidates": 3, "margin": 1000.0}  # every frame is uncertain
    path = _write(small_data, tmp_path / "verify.yaml")
    trace = tmp_path / "run.trace"
    results = run_mission(path, trace_path=trace, track=False, processes=processes)
    posts = [r for r in read_trace(trace) if r["kind"] == "post"]
    queries = {r["id"]: r for r in posts if r.get("level") == "verify_query"}
    verifications = [r for r in posts if r.get("level") == "verification"]
    n = len(results["frames"])
    assert len(queries) == len(verifications) == n > 0
    assert {r["agent"] for r in queries.values()} == {"scheduler"}
    assert {r["agent"] for r in verifications} == {"verifier"}
    positions = {int(r["id"].split("-")[1]): r for r in posts if r.get("level") == "position"}
    for v in verifications:
        body = v["body"]
        q = queries[body["query"]]
        frame = body["frame"]
        assert v["links"][:2] == [body["query"], f"sf-{frame:06d}"]
        assert body["viewframes"] == q["body"]["viewframes"] and len(body["viewframes"]) == 3
        assert len(body["correlations"]) == 3 and all(-1.0 <= c <= 1.0 for c in body["correlations"])
        assert body["renders"] >= 3
        assert v["id"] in positions[frame]["links"]  # the decision used it
        assert "verified 3 candidates" in positions[frame]["body"]["reason"]
    assert not results["degraded"]


def test_verification_off_is_todays_pipeline(small_data, tmp_path):
    small_data["verify"] = {"enabled": False}
    off = _write(small_data, tmp_path / "off.yaml")
    plan = {name: opts for _, name, opts in agent_plan(load_scenario(off))}
    assert "verifier" not in plan and not any(k.startswith("verify") for k in plan["scheduler"])
    small_data["verify"] = {"enabled": True, "margin": 0.0}  # on, but no frame is uncertain enough
    never = _write(small_data, tmp_path / "never.yaml")
    plan = {name: opts for _, name, opts in agent_plan(load_scenario(never))}
    assert plan["scheduler"]["verify_candidates"] == VerifySpec().candidates and "verifier" in plan
    a, b = run_mission(off, track=False), run_mission(never, track=False)
    keys = ("viewframe", "position", "reason")
    assert [[f.get(k) for k in keys] for f in a["frames"]] == [[f.get(k) for k in keys] for f in b["frames"]]
    for fa, fb in zip(
        a["frames"], b["frames"]
    ):  # the same rankings (to rounding: two runs of one scenario differ by ~1e-7 relative, float32 memory)
        assert [k for k, _ in fa["ranking"]] == [k for k, _ in fb["ranking"]]
        assert fa["confidence"] == pytest.approx(fb["confidence"], rel=1e-5)
        assert [v for _, v in fa["ranking"]] == pytest.approx([v for _, v in fb["ranking"]], rel=1e-5, abs=1e-6)


def test_the_track_observes_the_verified_ranking(small_data, tmp_path):
    """With the tracker on, every frame whose position was verified is tracked from the verified
    ranking: the track links the frame's verification (the tracker re-scores its observation as
    the scheduler did), and the tracker's plan carries the verification's weight."""
    small_data["verify"] = {"enabled": True, "candidates": 3, "margin": 1000.0, "weight": 23.0, "when": "always"}
    path = _write(small_data, tmp_path / "verify-track.yaml")
    plan = {name: opts for _, name, opts in agent_plan(load_scenario(path))}
    assert plan["tracker"]["verify_weight"] == 23.0
    trace = tmp_path / "run.trace"
    results = run_mission(path, trace_path=trace, track=True)
    posts = [r for r in read_trace(trace) if r["kind"] == "post"]
    verified = {r["body"]["frame"]: r["id"] for r in posts if r.get("level") == "verification"}
    positions = {r["body"]["frame"]: r["body"] for r in posts if r.get("level") == "position"}
    tracks = {r["body"]["frame"]: r for r in posts if r.get("level") == "track"}
    assert len(tracks) == len(results["frames"]) > 0
    assert verified and all(positions[f]["verified"] for f in verified)
    for frame, vid in verified.items():
        assert vid in tracks[frame]["links"], (frame, tracks[frame]["links"])
    small_data["verify"] = {"enabled": False}
    off = _write(small_data, tmp_path / "off.yaml")
    assert {name: opts for _, name, opts in agent_plan(load_scenario(off))}["tracker"]["verify_weight"] == 0.0


@pytest.mark.parametrize("when", ["blind", "always"])
def test_blind_verifies_only_the_frames_without_a_track_prior(small_data, tmp_path, when):
    """``verify.when: blind`` (the default) asks the verifier about a frame only when the
    scheduler has no track prior for it (the first frame, a lost track); "always" about every
    uncertain frame, tracked or not."""
    small_data["verify"] = {"enabled": True, "candidates": 3, "margin": 1000.0, "when": when}
    path = _write(small_data, tmp_path / f"verify-{when}.yaml")
    assert load_scenario(path).verify.when == when
    trace = tmp_path / "run.trace"
    results = run_mission(path, trace_path=trace, track=True)
    posts = [r for r in read_trace(trace) if r["kind"] == "post"]
    asked = {r["body"]["frame"] for r in posts if r.get("level") == "verify_query"}
    positions = {r["body"]["frame"]: r["body"] for r in posts if r.get("level") == "position"}
    n = len(results["frames"])
    assert len(positions) == n > 2
    blind = {f for f, body in positions.items() if not body["track_prior"]}
    assert 0 in blind and len(blind) < n  # the first frame is blind; the track conditions later ones
    assert asked == (blind if when == "blind" else set(range(n)))

"""The tracker knowledge source: frame ordering (pure), and the track through the blackboard."""

from __future__ import annotations

from knowledge_sources.tracker import FrameOrder, answers_of


def test_frames_are_released_in_order_once_complete():
    order = FrameOrder()
    order.position(1, {"frame": 1, "steps": []}, "pos-1")
    order.ranking(1, 0, 2, [0, 2], [0.1, 0.2], 1.0, "rk-1-0")
    order.ranking(1, 1, 2, [1, 3], [0.3, 0.4], 1.0, "rk-1-1")
    assert order.ready() == []  # frame 1 is complete, but frame 0 is not here yet
    order.ranking(0, 0, 2, [0, 2], [0.1, 0.2], 0.0, "rk-0-0")
    order.position(0, {"frame": 0, "steps": []}, "pos-0")
    assert order.ready() == []  # frame 0 still lacks shard 1
    order.ranking(0, 1, 2, [1, 3], [0.3, 0.4], 0.0, "rk-0-1")
    ready = order.ready()
    assert [f for f, _ in ready] == [0, 1]
    assert sorted(ready[0][1].rankings) == [("associative", 0), ("associative", 1)] and ready[1][1].time == 1.0
    assert ready[0][1].links == ["rk-0-0", "pos-0", "rk-0-1"]
    assert order.ready() == [] and order.next == 2


def test_a_frame_waits_for_every_source_the_decision_fuses():
    order = FrameOrder(("associative", "skyline"))
    order.ranking(0, 0, 1, [0, 1, 2], [0.1, 0.2, 0.3], None, "rk-0-0")
    order.position(0, {"frame": 0, "steps": []}, "pos-0")
    assert order.ready() == []  # the skyline's ranking is not in yet
    order.ranking(0, 0, 1, [2, 1, 0], [1.0, 2.0, 3.0], None, "rk-0-other", source="other")  # not fused: ignored
    assert order.ready() == []
    order.ranking(0, 0, 1, [2, 1, 0], [1.0, 2.0, 3.0], None, "rk-0-skyline", source="skyline")
    (frame, p), *rest = order.ready()
    assert frame == 0 and rest == []
    assert p.by_source() == {"associative": [([0, 1, 2], [0.1, 0.2, 0.3])], "skyline": [([2, 1, 0], [1.0, 2.0, 3.0])]}
    assert "rk-0-other" not in p.links


def test_with_await_query_a_frame_waits_for_the_schedulers_track_query_whenever_it_comes():
    order = FrameOrder(await_query=True)
    order.ranking(0, 0, 1, [0, 1], [0.1, 0.2], None, "rk-0-0")
    order.position(0, {"frame": 0, "steps": []}, "pos-0")
    assert order.ready() == []  # the query may come after the position: the track must link it
    order.query(0, "tq-0")
    ((frame, p),) = order.ready()
    assert frame == 0 and p.links == ["rk-0-0", "pos-0", "tq-0"]
    order.query(0, "tq-0-late")  # a frame already tracked: nothing to link any more
    assert order.pending == {}


def test_answers_of_a_position_leave_undecided_out():
    steps = [
        {"landmark": "H1", "present": True},
        {"landmark": "T1", "present": None},
        {"landmark": "H2", "present": False},
    ]
    assert answers_of(steps) == [("H1", True), ("H2", False)]


# -- through the blackboard --------------------------------------------------------------------

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import yaml  # noqa: E402

from blackboard.trace import read_trace  # noqa: E402
from knowledge_sources import levels  # noqa: E402
from knowledge_sources.cli import main as cli_main  # noqa: E402
from knowledge_sources.mission import agent_plan, run_mission  # noqa: E402
from models.scenario import load_scenario  # noqa: E402

DECISION = ("frame", "viewframe", "queries", "backtracks", "correct")


def _drive(tmp_path, small_data, **tracking) -> Path:
    data = small_data
    data["sensor"] = {
        "simulate": {
            "drive": {
                "interval_s": 2.0,
                "speed_mps": [12, 22],
                "p_stop": 0.1,
                "frames": 14,
                "lateral_m": 1.0,
                "heading_deg": 2.0,
            },
            "seed": 11,
        }
    }
    if tracking:
        data["tracking"] = tracking
    path = tmp_path / "drive.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.slow
@pytest.mark.parametrize("processes", [False, True], ids=["inprocess", "processes"])
def test_track_through_the_blackboard(tmp_path, small_data, processes):
    path = _drive(tmp_path, small_data)
    results = run_mission(path, processes=processes, trace_path=tmp_path / "run.trace")
    frames = results["frames"]
    assert results["tracking"] is True and len(frames) == 14
    route = small_data["route"]
    for f in frames:
        # the results contract: the final answer on top, the single-frame decision beside it
        assert f["state"] in ("tracking", "lost")
        assert set(f["frame_only"]) >= {"viewframe", "position", "heading_deg", "confidence"}
        assert 0 <= f["viewframe"] < len(route) and len(f["position"]) == 2
        assert len(f["belief"]) == len(route) and abs(sum(f["belief"]) - 1.0) < 1e-3
        assert f["confidence"] == pytest.approx(f["belief"][f["viewframe"]], abs=1e-4)
    assert frames[0]["track_prior"] is False  # nothing came before frame 0
    assert any(f["track_prior"] for f in frames[1:])  # later frames were conditioned on the track
    s = results["summary"]
    assert {"top1", "top1_frame_only", "median_error_m", "tracking", "lost"} <= set(s)
    assert s["tracking"] + s["lost"] == 14 and s["tracking"] >= 10
    # the pre-run count of a drive's frames is the camera's: none reported missing, nothing degraded
    assert s["frames_expected"] == 14 and s["missing"] == 0 and results["degraded"] == []
    # the track follows the drive: times increase, positions advance along the route
    assert s["top1"] >= 0.6 and s["median_error_m"] < 25.0
    # every track links the evidence it used: the frame's rankings and its position
    records = read_trace(tmp_path / "run.trace")
    tracks = [r for r in records if r["kind"] == "post" and r.get("level") == "track"]
    assert len(tracks) == 14
    # without tracking.smoothing the frame's evidence on the route is not posted (160 KB a frame at 10k points)
    assert all(r["body"].get("loglik") is None for r in tracks)
    # ... of every ranking source the single-frame decision fuses: the memory's and the skyline's
    for r in tracks:
        frame = r["body"]["frame"]
        assert {levels.ranking_id(frame, 0), levels.ranking_id(frame, 0, "skyline")} <= set(r["links"])
    assert {name for _, name, _ in agent_plan(load_scenario(path))} >= {"tracker"}


@pytest.mark.slow
def test_a_killed_tracker_leaves_the_later_frames_to_the_blind_ranking(tmp_path, small_data):
    """kill -9 of the tracker's process after its 4th track: every frame is still decided, the
    frames after it from the blind ranking, and the results and the trace name the tracker."""
    import time

    path = _drive(tmp_path, small_data)
    trace = tmp_path / "killed.trace"
    t0 = time.monotonic()
    results = run_mission(path, processes=True, trace_path=trace, kill_after=("tracker", "track", 4), timeout_s=120)
    assert time.monotonic() - t0 < 100  # no frame waited for the dead tracker's deadline, let alone for ever
    assert results["agents"]["tracker"].startswith("dead"), results["agents"]
    frames = results["frames"]
    assert len(frames) == 14 and all(not f["missing"] and f["frame_only"]["viewframe"] is not None for f in frames)
    untracked = [f for f in frames if "belief" not in f]
    assert untracked and [f["frame"] for f in untracked] == list(range(14 - len(untracked), 14))
    assert {f["frame"] for f in frames if "belief" in f} >= {0, 1, 2, 3}  # the tracks posted before the kill
    for f in untracked:  # the final answer is the single-frame decision, and the frame says it is not tracked
        assert f["state"] == "lost" and f["viewframe"] == f["frame_only"]["viewframe"]
        assert "no track was posted" in f["reason"]
    blind = [f for f in frames if any(d.startswith("tracker:") for d in f.get("degraded", []))]
    assert blind and all(not f["track_prior"] for f in blind)
    assert {f["frame"] for f in blind} <= {f["frame"] + 1 for f in untracked}
    # the run is degraded, naming the tracker
    assert any(d.startswith("agent tracker dead") for d in results["degraded"])
    assert any(d.startswith("tracker:") and "analysed blind" in d for d in results["degraded"])
    # the scheduler's track queries to the dead tracker timed out with its name
    records = read_trace(trace)
    timed_out = [r for r in records if r["kind"] == "timeout" and r.get("level") == levels.TRACK_QUERY]
    assert timed_out and all("tracker" in r["reason"] for r in timed_out)


@pytest.mark.slow
def test_no_track_is_the_single_frame_run(tmp_path, small_data):
    path = _drive(tmp_path, small_data)
    off = run_mission(path, track=False)
    assert "tracker" not in {name for _, name, _ in agent_plan(load_scenario(path), track=False)}
    assert off["tracking"] is False
    for f in off["frames"]:
        assert f["state"] is None and not f["track_prior"]
        assert {k: f[k] for k in ("viewframe", "position", "heading_deg", "confidence", "correct")} == {
            k: f["frame_only"][k] for k in ("viewframe", "position", "heading_deg", "confidence", "correct")
        }
    # the scenario's own switch gives the same decisions (and the single-frame decisions are deterministic)
    disabled = run_mission(_drive(tmp_path, small_data, enabled=False))
    assert [{k: f[k] for k in DECISION} for f in off["frames"]] == [
        {k: f[k] for k in DECISION} for f in disabled["frames"]
    ]
    assert [f["confidence"] for f in off["frames"]] == pytest.approx(
        [f["confidence"] for f in disabled["frames"]], rel=1e-4
    )  # rendering rounds in the last bits
    assert off["summary"]["top1"] == off["summary"]["top1_frame_only"]


@pytest.mark.slow
def test_cli_no_track_and_smoothing(tmp_path, small_data):
    path = _drive(tmp_path, small_data, smoothing=True)
    out_off, out_on = tmp_path / "off.json", tmp_path / "on.json"
    assert cli_main(["run", str(path), "--no-track", "--no-progress", "--out", str(out_off)]) == 0
    assert cli_main(["run", str(path), "--no-progress", "--out", str(out_on)]) == 0
    off, on = json.loads(out_off.read_text()), json.loads(out_on.read_text())
    assert off["tracking"] is False and on["tracking"] is True and on["smoothing"] is True
    assert all(f["state"] in ("tracking", "lost") for f in on["frames"])
    assert on["summary"]["top1"] >= on["summary"]["top1_frame_only"] - 0.15


def test_expectations_judge_the_track_and_the_single_frames_apart():
    from knowledge_sources.pytest_plugin import check_expectations
    from models.scenario import ExpectSpec

    results = {"summary": {"top1": 0.95, "top1_frame_only": 0.7, "mean_queries": 1.0, "mean_error_m": 5.0}}
    assert check_expectations(ExpectSpec(top1_min=0.9, top1_frame_only_min=0.6), results) == []
    misses = check_expectations(ExpectSpec(top1_min=0.9, top1_frame_only_min=0.8), results)
    assert [m[0] for m in misses] == ["top1_frame_only_min"] and misses[0][3] == "0.100 short"


@pytest.mark.slow
def test_no_track_equals_the_reference_results_of_the_code_before_tracking(tmp_path):
    """table_a (camera frames on file) with --no-track decides as the code before the tracker did
    (bench/reference/results_before.json, produced from 11d7ded by bench/compare_results.py), given
    the memory settings of that code (max_shift [2, 16]: the default changed since; no roll search,
    roll_search_deg [0]; table_a sets its own bank size) and its scene-analysis rule (hard backtracking, questions by probability: the
    default became soft backtracking and information-gain questions since)."""
    root = Path(__file__).resolve().parents[2]
    reference = json.loads((root / "bench" / "reference" / "results_before.json").read_text())
    data = yaml.safe_load((root / "scenarios" / "table_a.yaml").read_text())
    data["memory"] = {**data.get("memory", {}), "max_shift": [2, 16], "roll_search_deg": [0.0]}
    data["scheduler"] = {**data.get("scheduler", {}), "backtracking": "hard", "questions": "probability"}
    data["skyline"] = {"enabled": False}  # that code had one ranking source (the skyline merge added a second)
    data["render"] = {**data.get("render", {}), "views_per_leg": 1}  # and a viewframe per route point
    data["verify"] = {"enabled": False}  # and no render-and-compare verification
    for f in data["sensor"]["frames"]:
        f["image"] = str(root / "scenarios" / f["image"])
    data["terrain"] = {
        k: (str(root / "scenarios" / v) if k in ("dem", "contours") else v) for k, v in data["terrain"].items()
    }
    path = tmp_path / "table_a.yaml"
    path.write_text(yaml.safe_dump(data))
    results = run_mission(path, track=False)
    got = [
        {
            "frame": f["frame"],
            "viewframe": f["viewframe"],
            "queries": f["queries"],
            "backtracks": f["backtracks"],
            "ranking": [int(k) for k, _ in f["ranking"]],
        }
        for f in results["frames"]
    ]
    assert got == reference["scenarios"]["table_a"]["frames"]


def test_belief_plot_shows_the_belief_and_says_when_there_is_none():
    import numpy as np

    from knowledge_sources.report import plot_belief

    frames = []
    for t in range(6):
        belief = np.full(8, 0.01)
        belief[min(t, 7)] = 1.0 - 0.07
        frames.append(
            {
                "frame": t,
                "belief": belief.tolist(),
                "truth_viewframe": t,
                "viewframe": t,
                "state": "lost" if t == 0 else "tracking",
            }
        )
    fig = plot_belief({"frames": frames})
    ax = fig.axes[0]
    image = ax.images[0].get_array()
    assert image.shape == (6, 8) and image[3, 3] > 0.9  # rows: frames in time order, columns: route points
    assert {t.get_text() for t in ax.get_legend().get_texts()} >= {"true route point", "track", "lost"}
    empty = plot_belief({"frames": [{"frame": 0, "truth_viewframe": None, "viewframe": 1}]})
    assert "no track" in empty.axes[0].texts[0].get_text()


def _child_agent_pid(name: str) -> int:
    """The pid of this process's child hosting agent ``name`` (processes mode: its spec is on its command line)."""
    import os

    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            argv = (entry / "cmdline").read_bytes().split(b"\0")
        except (OSError, IndexError, ValueError):
            continue
        if ppid == os.getpid() and b"blackboard.agent_host" in argv and f'"name": "{name}"'.encode() in b" ".join(argv):
            return int(entry.name)
    raise AssertionError(f"no child process hosts agent {name!r}")


@pytest.mark.slow
def test_a_late_tracker_costs_the_frames_it_missed_and_then_tracks_again(tmp_path, small_data):
    """The tracker's process stopped (SIGSTOP) after its 4th track for longer than the scheduler's
    ``track_timeout_s``, then continued (SIGCONT): alive all along (its zenoh lease outlives the
    pause), late. The frames whose previous track did not come in time are decided blind and say
    so; once the tracker is back, the frames are conditioned on its tracks again; nothing is dead."""
    import os
    import signal
    import threading

    small_data["scheduler"] = {**small_data.get("scheduler", {}), "track_timeout_s": 1.5}
    path = _drive(tmp_path, small_data)
    pause_s = 5.0  # well under zenoh's 10 s lease: the tracker is late, not dead
    paused: list[int] = []

    def on_hypothesis(level: str, body: object, timestamp: float) -> None:
        if level == levels.TRACK and not paused and body["frame"] == 3:  # type: ignore[index]
            pid = _child_agent_pid("tracker")
            os.kill(pid, signal.SIGSTOP)
            paused.append(pid)
            threading.Timer(pause_s, os.kill, (pid, signal.SIGCONT)).start()

    results = run_mission(path, processes=True, on_hypothesis=on_hypothesis, timeout_s=120)
    assert paused, "the tracker's 4th track never came"
    assert results["agents"]["tracker"] == "ok", results["agents"]
    frames = results["frames"]
    assert len(frames) == 14 and all(not f["missing"] and f["frame_only"]["viewframe"] is not None for f in frames)
    blind = [
        f["frame"] for f in frames if any(d.startswith("tracker: no track of frame") for d in f.get("degraded", []))
    ]
    assert blind, [f.get("degraded") for f in frames]
    assert 5 in blind and min(blind) >= 4  # frame 5 waited for the paused track 4; the ones before had theirs
    assert all(not frames[k]["track_prior"] for k in blind)
    # back: the frames after the blind ones are conditioned on the tracker's tracks again
    after = [f for f in frames if f["frame"] > max(blind)]
    assert after and all(f["track_prior"] for f in after), [(f["frame"], f["track_prior"]) for f in after]
    assert not any(d.startswith("agent tracker dead") for d in results["degraded"])


def test_the_tracker_observes_the_viewframes_where_they_stand():
    """``views_per_leg_of``: a map with F viewframes a leg (models.route_views) gives F, so the
    tracker's filter observes each viewframe at its own arc length; one a point, or route points
    that are not the views' layout, give 1 (the route points' totals, as before)."""
    import numpy as np

    from knowledge_sources import levels
    from knowledge_sources.tracker import views_per_leg_of
    from models.route_views import view_points

    route = [(0.0, 0.0), (40.0, 0.0), (80.0, 0.0), (120.0, 0.0)]

    def map_of(route_points):
        views = len(route) if route_points is None else len(route_points)
        return levels.Map.of(
            scenario="s",
            path="/nonexistent/s.yaml",
            priors={},
            landmarks=[],
            route=route,
            poses=[[0.0, 0.0, 2.0, 0.0, 0.0]] * views,
            visible={},
            memory={},
            route_points=route_points,
        )

    assert views_per_leg_of(map_of(None)) == 1
    assert views_per_leg_of(map_of(view_points(4, 3).tolist())) == 3
    assert views_per_leg_of(map_of([0, 0, 1, 1, 2, 2, 3])) == 2  # two a leg: the second at half, still k's
    assert views_per_leg_of(map_of([0, 1, 1, 1, 2, 2, 3])) == 1  # 7 views, not a layout of view_route
    np.testing.assert_array_equal(view_points(4, 3), [0, 0, 1, 1, 1, 2, 2, 2, 3, 3])

"""A run that no signal, dead agent or input met mid-run can silently break (real processes,
real zenoh sessions on loopback)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from blackboard.config import ZenohOptions, loopback_endpoint
from blackboard.errors import AgentInputError, BlackboardError
from blackboard.runtime import Runtime
from blackboard.trace import TraceError, read_trace
from knowledge_sources import levels
from knowledge_sources.cli import main
from knowledge_sources.mission import run_mission
from models.preflight import check_scenario
from models.scenario import load_scenario

pytestmark = pytest.mark.slow
pytest_plugins = ["pytester"]

#: the small scenario made unlocalizable: a wall in every view, and detectors that answer
#: "absent" to everything, so under the hard rule every candidate is discarded (the run itself
#: is healthy; the soft default would keep the best candidate), and no tracker (its track, from
#: the rankings alone, would localize every frame)
NOTHING_LOCALIZED = {
    "tracking": {"enabled": False},
    "scheduler": {
        "backtracking": "hard",
        "detector_threshold": 1.0,
        "absent_threshold": 1.0,
        "candidates": 8,
        "min_pixels": 1,
        "query_timeout_s": 3.0,
    },
    "landmarks": [
        {"id": "W1", "kind": "wall", "x": 700, "y": 560, "width": 300, "depth": 20, "height": 150, "yaw_deg": -60}
    ],
}


def _cli(*argv: str) -> list[str]:
    return [sys.executable, "-m", "knowledge_sources.cli", *argv]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), *sys.path])}


def _records(trace: Path) -> list[dict]:
    try:
        return read_trace(trace)
    except TraceError:
        return []


def _wait_for(trace: Path, proc: subprocess.Popen, predicate, timeout_s: float = 120.0) -> list[dict]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[1]
        records = _records(trace) if trace.exists() else []
        if predicate(records):
            return records
        time.sleep(0.1)
    raise AssertionError("the run never got there")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its parent, which is gone too) counts as gone
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize(
    "mode, signum",
    [
        ("inprocess", signal.SIGINT),
        ("inprocess", signal.SIGTERM),
        ("processes", signal.SIGINT),
        ("processes", signal.SIGTERM),
    ],
)
def test_a_signal_stops_the_run_within_2s_keeping_what_is_done(mode, signum, small, tmp_path) -> None:
    out, trace = tmp_path / "r.json", tmp_path / "t.trace"
    argv = ["run", str(small), "--no-progress", "--out", str(out), "--trace", str(trace), "--rate", "1"]
    if mode == "processes":
        argv.append("--processes")
    proc = subprocess.Popen(
        _cli(*argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=tmp_path
    )
    try:
        records = _wait_for(
            trace, proc, lambda rs: any(r["kind"] == "post" and r.get("level") == levels.SENSOR_FRAME for r in rs)
        )
        children = [r["pid"] for r in records if r["kind"] == "agent_join" and r.get("pid") != proc.pid]
        assert (len(children) >= 5) == (mode == "processes")
        sent = time.monotonic()
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signum, err
    assert took < 2.0, f"took {took:.2f} s to stop"
    assert "Traceback" not in err and f"interrupted by {signal.Signals(signum).name}" in err
    assert not [pid for pid in children if _alive(pid)], "an agent process outlived the run"
    results = json.loads(out.read_text())  # strict JSON, written although interrupted
    assert results["interrupted"] == signal.Signals(signum).name
    s = results["summary"]
    assert s["frames_expected"] == 8 and len(results["frames"]) == 8 and s["localized"] < 8
    undone = [f for f in results["frames"] if f["viewframe"] is None]
    assert undone and all(f["interrupted"] and "interrupted" in f["reason"] for f in undone)
    ends = [r for r in read_trace(trace) if r["kind"] == "run_end"]
    assert len(ends) == 1 and ends[0]["reason"] == f"interrupted by {signal.Signals(signum).name}"


def test_a_second_ctrl_c_exits_at_once(small, tmp_path) -> None:
    trace = tmp_path / "t.trace"
    proc = subprocess.Popen(
        _cli("run", str(small), "--no-progress", "--processes", "--trace", str(trace)),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        cwd=tmp_path,
    )
    try:
        # while the agents start: the first Ctrl-C's clean-up is slowest there
        records = _wait_for(trace, proc, lambda rs: sum(r["kind"] == "agent_join" for r in rs) >= 2)
        children = [r["pid"] for r in records if r["kind"] == "agent_join"]
        proc.send_signal(signal.SIGINT)
        time.sleep(0.05)
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert took < 1.0, f"took {took:.2f} s"
    time.sleep(0.2)
    assert not [pid for pid in children if _alive(pid)]


def test_a_dead_camera_degrades_the_run_visibly(small, tmp_path, capsys) -> None:
    results = run_mission(small, kill_after=("camera", levels.SENSOR_FRAME, 3), frame_rate=2.0, processes=True)
    s = results["summary"]
    assert s["frames_expected"] == 8 and s["posted"] == 3 and s["missing"] == 5 and len(results["frames"]) == 8
    missing = [f for f in results["frames"] if f["missing"]]
    assert [f["frame"] for f in missing] == [3, 4, 5, 6, 7]
    assert all("the camera never posted it" in f["reason"] and "camera" in f["reason"] for f in missing)
    assert any("agent camera dead" in d for d in results["degraded"])
    assert "5 of 8 frames never posted" in results["degraded"]


def test_a_run_that_localizes_no_frame_fails(small_data, tmp_path, capsys) -> None:
    path = tmp_path / "none.yaml"
    path.write_text(yaml.safe_dump({**small_data, **NOTHING_LOCALIZED}))
    out = tmp_path / "r.json"
    assert main(["run", str(path), "--no-progress", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "mapinterp run: error: no frame localized (8 expected, 8 posted)" in err and "Traceback" not in err
    assert json.loads(out.read_text())["summary"]["localized"] == 0  # the results are still written


def test_the_pytest_plugin_fails_a_scenario_that_localized_no_frame(pytester, small_data) -> None:
    # expectations that say nothing about accuracy: the item must still fail
    data = {**small_data, **NOTHING_LOCALIZED, "expect": {"mean_queries_max": 100.0}}
    (pytester.path / "none.yaml").write_text(yaml.safe_dump(data))
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(failed=1)
    assert "none.yaml: no frame localized" in result.stdout.str()
    assert "Traceback" not in result.stdout.str()


def test_an_input_error_met_by_an_agent_is_the_pre_run_message(small_data, tmp_path) -> None:
    """Bypassing the pre-run check (the scenario posted straight to the blackboard), the map
    renderer meets the bad DEM itself: it dies of it at once (no retries), and the run reports
    the very message the pre-run check gives."""
    import numpy as np

    np.save(tmp_path / "dem.npy", np.array([["a", "b"], ["c", "d"]]))
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({**small_data, "terrain": {"cell_size": 10.0, "dem": "dem.npy"}}))
    with pytest.raises(Exception) as expected:
        check_scenario(load_scenario(path))
    with Runtime() as rt:
        rt.add("knowledge_sources.map_renderer:MapRenderer", name="map-renderer")
        rt.post(levels.SCENARIO, {"path": str(path), "strategy": "associative"})
        outcome = rt.run(timeout_s=60)
    assert outcome.input_errors == {"map-renderer": str(expected.value)}
    assert "terrain.dem" in str(expected.value) and "real numbers" in str(expected.value)
    assert outcome.agents["map-renderer"].startswith("dead")
    assert isinstance(AgentInputError("map-renderer", str(expected.value)), BlackboardError)


def test_an_input_error_met_during_a_run_exits_2_with_one_line(small_data, tmp_path) -> None:
    """The camera image is spoiled after the pre-run check, before the camera reads it: the run
    stops with exit 2 and the one line naming the scenario, the field and the file."""
    import cv2
    import numpy as np

    image = tmp_path / "f0.png"
    cv2.imwrite(str(image), np.full((120, 160, 3), 90, np.uint8))
    path = tmp_path / "late.yaml"
    path.write_text(yaml.safe_dump({**small_data, "sensor": {"frames": [{"image": "f0.png"}]}}))

    def spoil(commands: dict) -> None:  # called once the pre-run check passed
        image.write_text("not an image any more")
        argv = commands["camera"]
        spoil.proc = subprocess.Popen(
            [sys.executable, "-m", "knowledge_sources.cli", *argv[1:]],
            env=_env(),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )

    endpoint = loopback_endpoint()
    try:
        with pytest.raises(AgentInputError) as err:
            run_mission(
                path, remote=["camera"], zenoh=ZenohOptions(listen=[endpoint]), on_wait_remote=spoil, timeout_s=120
            )
    finally:
        if hasattr(spoil, "proc"):
            spoil.proc.wait(timeout=30)
    assert (
        str(err.value) == f"{path}: sensor.frames[0].image: {image}: not a readable image (PNG, JPEG or TIFF expected)"
    )


#: a viewframe reference an agent cannot follow: the entry is not on this host (another machine
#: without the shared folder, a deleted cache), or it is not the entry the reference was made for
UNREADABLE = {"entry-missing": "no such viewframe cache entry", "other-count": "the reference says 99 (stale)"}


#: (agent, its options, the change): an indexer reading its images from the map's entry (the
#: default with a cache) meets a missing one; one keeping each message's reference (as without a
#: cache in its own process) and a detector meet either
CANNOT_READ = {
    "indexer-entry-missing": ("indexer-0", {}, "entry-missing"),
    "indexer-keeping-entry-missing": ("indexer-0", {"keep_images": True}, "entry-missing"),
    "indexer-keeping-other-count": ("indexer-0", {"keep_images": True}, "other-count"),
    "detector-entry-missing": ("detector-house", {}, "entry-missing"),
    "detector-other-count": ("detector-house", {}, "other-count"),
}


@pytest.mark.parametrize(("agent", "options", "change"), CANNOT_READ.values(), ids=CANNOT_READ.keys())
def test_a_viewframe_reference_an_agent_cannot_read_stops_the_run_naming_it(
    small_rendered, tmp_path, agent: str, options: dict, change: str
) -> None:
    """The viewframes are posted by reference to a cache entry the agent cannot read (the map names
    it too, as a host without the folder would see it): the agent dies of it at once (no retry
    helps) and the run reports the entry, the viewframe and the agent; nothing hangs or crashes."""
    from models.viewframe_cache import ViewframeCache
    from models.world import World
    from tests.knowledge_sources.conftest import inline_viewframe

    vfs = [levels.Viewframe.from_hypothesis(h) for h in small_rendered["viewframes"]]
    if change == "entry-missing":
        entry, count = str(tmp_path / "elsewhere"), len(vfs)
    else:  # a real entry of this route (fresh: no stored index beside it), named with another count
        with World(load_scenario(small_rendered["path"]), cache=ViewframeCache(tmp_path / "cache")) as world:
            _ = world.viewframes
            assert world.entry is not None
            entry, count = str(world.entry.resolve()), 99
    with Runtime() as rt:
        if agent == "indexer-0":
            rt.add("knowledge_sources.indexer:AssociativeIndexer", name=agent, options=options)
        else:
            rt.add("knowledge_sources.detector:LandmarkDetectorAgent", name=agent, options=options)
        for v in vfs:
            forged = levels.Viewframe(index=v.index, pose=v.pose, skyline=v.skyline, entry=entry, entry_count=count)
            rt.post(levels.VIEWFRAME, forged.to_body(), id=forged.id())
        if agent == "indexer-0":
            rt.post(levels.MAP, {**small_rendered["map"].body, "entry": entry}, id=levels.map_id())
            first = 0
        else:
            mp = levels.Map.from_hypothesis(small_rendered["map"])
            first, (lm, _) = next((k, next(iter(seen.items()))) for k, seen in mp.seen().items() if seen)
            landmark = next(x for x in mp.landmarks if x["id"] == lm)
            image = inline_viewframe(vfs[first]).image
            rt.post(
                levels.SENSOR_FRAME, levels.SensorFrame(frame=0, image=image, source="test").to_body(), id="sf-000000"
            )
            query = levels.Query(
                frame=0,
                number=1,
                landmark=lm,
                landmark_index=landmark["index"],
                kind=landmark["kind"],
                viewframe=first,
                p=0.5,
            )
            rt.post(levels.QUERY, query.to_body(), id=query.id(), addressed_to=agent, deadline_s=30.0)
        outcome = rt.run(timeout_s=120)
    assert list(outcome.input_errors) == [agent] and outcome.agents[agent].startswith("dead")
    message = outcome.input_errors[agent]
    assert message.startswith(f"{entry}: agent {agent}, viewframe {levels.viewframe_id(first)}: ")
    assert UNREADABLE[change] in message and "render: {inline: true}" in message


@pytest.mark.parametrize("via", ["flag", "config-file"])
def test_a_second_run_with_a_run_id_in_use_is_refused_untouched(tmp_path, via: str) -> None:
    endpoint = loopback_endpoint()
    if via == "flag":
        second = ZenohOptions(connect=[endpoint])
    else:  # the network reached through a zenoh config file's own connect endpoints
        (tmp_path / "z.json5").write_text(f'{{connect: {{endpoints: ["{endpoint}"]}}}}')
        second = ZenohOptions(config_file=tmp_path / "z.json5")
    with Runtime(run_id="taken", zenoh=ZenohOptions(listen=[endpoint]), trace_path=tmp_path / "a.trace") as first:
        first.add("tests.blackboard.agents:Doubler", name="doubler")
        started = time.monotonic()
        with pytest.raises(BlackboardError, match="run id 'taken' is already in use"):
            with Runtime(run_id="taken", zenoh=second):
                pass
        assert time.monotonic() - started < 10
        first.post("number", {"x": 21})
        outcome = first.run(timeout_s=30)
        assert [h.body["x"] for h in outcome.hypotheses if h.level == "doubled"] == [42]
        assert outcome.agents == {"doubler": "ok"}
    kinds = [r["kind"] for r in read_trace(tmp_path / "a.trace")]
    assert "rejected" not in kinds and kinds.count("agent_join") == 1
    # another run id on the same network is fine
    with Runtime(run_id="taken", zenoh=ZenohOptions(listen=[endpoint])):
        with Runtime(run_id="other", zenoh=ZenohOptions(connect=[endpoint])):
            pass


def test_an_agent_whose_activation_raised_degrades_the_run_naming_it(small, monkeypatch) -> None:
    """An agent that raised once and went on (it lost that frame's work) is named in the run's
    ``degraded`` list with its error, so the run does not look clean (`mapinterp run` exits 1, not 0)."""
    from knowledge_sources.refiner import PoseRefiner

    plain = PoseRefiner._refine

    def refine(self, hypothesis, board):
        if levels.Position.from_hypothesis(hypothesis).frame == 2:
            raise RuntimeError("emulator lost its context")
        return plain(self, hypothesis, board)

    monkeypatch.setattr(PoseRefiner, "_refine", refine)
    results = run_mission(small)
    assert results["summary"]["localized"] == results["summary"]["frames_expected"]
    (line,) = [d for d in results["degraded"] if d.startswith("agent refiner")]
    assert line.startswith("agent refiner: 1 failed activation, the last: act raised RuntimeError: emulator lost")

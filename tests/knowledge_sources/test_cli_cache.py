"""``mapinterp run --cache-dir`` and ``--no-cache``: a second run of the same map reads its
viewframes from the cache folder given; ``--no-cache`` neither reads nor fills one."""

from __future__ import annotations

import json

import pytest

from knowledge_sources.cli import main

pytestmark = pytest.mark.slow


def test_cache_dir_is_filled_then_read_and_no_cache_writes_nothing(small, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MAPINTERP_CACHE", str(tmp_path / "env-cache"))  # restored after the test
    cache = tmp_path / "cache"
    first, second = tmp_path / "first.json", tmp_path / "second.json"
    assert main(["run", str(small), "--cache-dir", str(cache), "--out", str(first), "--no-progress"]) == 0
    entries = [p for p in cache.iterdir()]
    assert len(entries) == 1 and (entries[0] / "meta.json").is_file()
    stamp = (entries[0] / "meta.json").stat().st_mtime_ns
    assert main(["run", str(small), "--cache-dir", str(cache), "--out", str(second), "--no-progress"]) == 0
    assert [p for p in cache.iterdir()] == entries and (entries[0] / "meta.json").stat().st_mtime_ns == stamp
    a, b = json.loads(first.read_text()), json.loads(second.read_text())
    assert [f["viewframe"] for f in a["frames"]] == [f["viewframe"] for f in b["frames"]]  # same map, same answers
    assert not (tmp_path / "env-cache").exists()

    assert main(["run", str(small), "--no-cache", "--no-progress"]) == 0
    assert not (tmp_path / "env-cache").exists() and [p for p in cache.iterdir()] == entries
    capsys.readouterr()


#: the runs compared: (extra flags, pixels posted by reference)
RUNS = {
    "no-cache": (["--no-cache"], False),
    "cache-by-reference": ([], True),
    "cache-by-reference-processes": (["--processes"], True),
    "cache-inline-viewframes": (["--inline-viewframes"], False),
}


def test_a_mission_with_viewframes_by_reference_gives_the_results_of_one_without_cache(
    small, tmp_path, monkeypatch, capsys
) -> None:
    """The same scenario run without a cache (pixels inline in every viewframe message), from a
    filled cache (by reference: the indexers and detectors read the pixels from the entry, in this
    process or each agent in its own), and from the cache with ``--inline-viewframes``: every
    frame's answer, queries and ranking are the same."""
    from blackboard.trace import read_trace

    # --no-cache sets its environment variable for the runs: restored after the test
    monkeypatch.setenv("MAPINTERP_CACHE", str(tmp_path / "env-cache"))
    cache = tmp_path / "cache"
    assert main(["run", str(small), "--cache-dir", str(cache), "--no-progress"]) == 0  # fills it
    keys = ("frame", "viewframe", "queries", "backtracks", "correct")
    got = {}
    for name, (flags, by_reference) in RUNS.items():
        out, trace = tmp_path / f"{name}.json", tmp_path / f"{name}.trace"
        cached = [] if "--no-cache" in flags else ["--cache-dir", str(cache)]
        argv = ["run", str(small), *cached, *flags, "--out", str(out), "--trace", str(trace), "--no-progress"]
        assert main(argv) == 0, name
        results = json.loads(out.read_text())
        got[name] = [({k: f[k] for k in keys}, [k for k, _ in f["ranking"]]) for f in results["frames"]]
        posts = [r for r in read_trace(trace) if r.get("kind") == "post" and r.get("level") == "viewframe"]
        assert len(posts) == 8 and all((r["body"]["entry"] is not None) == by_reference for r in posts), name
        assert all(isinstance(r["body"]["image"], dict) != by_reference for r in posts), name  # a summary, or null
    assert all(f[0]["viewframe"] is not None for f in got["no-cache"])
    for name in RUNS:
        assert got[name] == got["no-cache"], name
    capsys.readouterr()


def test_a_second_run_loads_each_shards_stored_index_and_answers_alike(small_data, tmp_path, caplog, capsys):
    """The second run of a map with the cache indexes nothing: every shard (two here) loads the
    index the first run stored beside the viewframe cache entry, and the run gives the same answers."""
    import logging

    import yaml

    small = tmp_path / "small.yaml"
    small.write_text(yaml.safe_dump({**small_data, "memory": {"shard_size": 4}}))
    cache = tmp_path / "cache"
    first, second = tmp_path / "first.json", tmp_path / "second.json"
    args = ["run", str(small), "--cache-dir", str(cache), "--no-progress"]
    with caplog.at_level(logging.INFO, logger="knowledge_sources.indexer"):
        assert main([*args, "--out", str(first)]) == 0
    built = [r.getMessage() for r in caplog.records if "holds" in r.getMessage()]
    (entry,) = [p for p in cache.iterdir()]
    stored = sorted((entry / "index").iterdir())
    assert len(built) == 2 and all("(indexed)" in m for m in built) and len(stored) == len(built)
    stamps = [(p / "rows.npy").stat().st_mtime_ns for p in stored]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="knowledge_sources.indexer"):
        assert main([*args, "--out", str(second)]) == 0
    loaded = [r.getMessage() for r in caplog.records if "holds" in r.getMessage()]
    assert len(loaded) == len(built) and all("(a stored index)" in m for m in loaded)
    assert (
        sorted((entry / "index").iterdir()) == stored
        and [(p / "rows.npy").stat().st_mtime_ns for p in stored] == stamps
    )
    a, b = json.loads(first.read_text()), json.loads(second.read_text())
    assert [f["viewframe"] for f in a["frames"]] == [f["viewframe"] for f in b["frames"]]
    capsys.readouterr()

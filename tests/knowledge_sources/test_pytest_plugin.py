"""The scenario pytest plugin, run by pytest itself (pytester) on scenario files."""

from __future__ import annotations

import pytest
import yaml

pytest_plugins = ["pytester"]
pytestmark = pytest.mark.slow


def _write(pytester, name: str, data: dict) -> None:
    (pytester.path / name).write_text(yaml.safe_dump(data))


def test_met_and_missed_expectations(pytester, small_data):
    _write(pytester, "easy.yaml", {**small_data, "expect": {"mean_queries_max": 50.0, "top1_min": 0.05}})
    _write(pytester, "hard.yaml", {**small_data, "name": "hard", "expect": {"mean_queries_max": 0.001}})
    _write(pytester, "plain.yaml", small_data)  # no expect: block, not a test
    # a user's project (pytester's folder: no mapinterp pyproject) that runs with --strict-markers
    result = pytester.runpytest_subprocess(
        "-p", "no:cacheprovider", "-W", "ignore::DeprecationWarning", "--strict-markers"
    )
    result.assert_outcomes(passed=1, failed=1)
    out = result.stdout.str()
    assert "hard.yaml: expectations missed" in out
    assert "mean_queries_max" in out and "<= 0.001" in out and "over" in out
    assert "Traceback" not in out
    # the summary is a readable line, not a dict
    summary = next(line for line in out.splitlines() if "summary:" in line)
    assert "{" not in summary and "top-1 " in summary and "mean queries " in summary and "latency p50 " in summary


def test_markers_are_registered(pytester):
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--markers")
    out = result.stdout.str()
    assert "@pytest.mark.slow:" in out and "@pytest.mark.scenario:" in out


def test_malformed_scenario_fails_its_item_naming_the_field(pytester, small_data):
    bad = {**small_data, "expect": {"top1_min": 0.5}}
    bad["landmarks"][0]["height"] = -3
    _write(pytester, "bad.yaml", bad)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(failed=1)
    out = result.stdout.str()
    assert "landmarks[0].height" in out
    assert "Traceback" not in out


def test_expectations_comparing_with_prior(pytester, small_data):
    _write(pytester, "cmp.yaml", {**small_data, "expect": {"fewer_queries_than_prior": True}})
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-v")
    result.assert_outcomes(passed=1)
    assert "cmp.yaml::expect PASSED" in result.stdout.str()


def test_an_empty_expect_block_fails_its_item_naming_the_file(pytester, small_data):
    _write(pytester, "empty.yaml", {**small_data, "expect": None})
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(failed=1)
    out = result.stdout.str()
    assert "empty.yaml: the expect block is empty" in out
    assert "Traceback" not in out and "AttributeError" not in out

"""pytest plugin: scenario files with an ``expect:`` block are test items.

Registered through the ``pytest11`` entry point, so installing mapinterp is enough: any
``*.yaml`` scenario that pytest walks past (``testpaths`` or a path on the command line) and that
has a top-level ``expect:`` block runs end to end through the blackboard and must meet it::

    expect:
      strategy: associative        # which strategy to run (default: the scenario's)
      top1_min: 0.9                # fraction of frames on the right route point
      mean_queries_max: 3          # detector questions per frame
      mean_error_m_max: 20         # metres
      fewer_queries_than_prior: true   # also run 'prior' and ask fewer questions than it
      processes: false             # run every agent in its own process

A miss is reported as a table of expectation, wanted, got and by how much. A malformed scenario
fails its item with the scenario error (file and field), not with a traceback; so does a run
that localized no frame, whatever its expectations (``top1_min`` or not).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

__all__ = ["MARKERS", "ScenarioFile", "ScenarioItem", "ExpectationMissed", "check_expectations", "summary_line"]


class ExpectationMissed(Exception):
    """One or more expectations of a scenario were not met."""

    def __init__(self, misses: list[tuple[str, str, str, str]]) -> None:
        self.misses = misses
        super().__init__(f"{len(misses)} expectation(s) missed")


def check_expectations(
    expect: Any, results: dict[str, Any], prior: dict[str, Any] | None = None
) -> list[tuple[str, str, str, str]]:
    """Compare results with an ``ExpectSpec``; returns rows (name, wanted, got, by how much)."""
    s = results["summary"]
    misses = []
    if expect.top1_min is not None:
        got = s.get("top1")
        if got is None:
            misses.append(("top1_min", f">= {expect.top1_min:g}", "no truth poses", "-"))
        elif got < expect.top1_min:
            misses.append(("top1_min", f">= {expect.top1_min:g}", f"{got:.3f}", f"{expect.top1_min - got:.3f} short"))
    if expect.top1_frame_only_min is not None:
        got = s.get("top1_frame_only")
        if got is None:
            misses.append(("top1_frame_only_min", f">= {expect.top1_frame_only_min:g}", "no truth poses", "-"))
        elif got < expect.top1_frame_only_min:
            misses.append(
                (
                    "top1_frame_only_min",
                    f">= {expect.top1_frame_only_min:g}",
                    f"{got:.3f}",
                    f"{expect.top1_frame_only_min - got:.3f} short",
                )
            )
    if expect.mean_queries_max is not None and s["mean_queries"] > expect.mean_queries_max:
        misses.append(
            (
                "mean_queries_max",
                f"<= {expect.mean_queries_max:g}",
                f"{s['mean_queries']:.3f}",
                f"{s['mean_queries'] - expect.mean_queries_max:.3f} over",
            )
        )
    if expect.mean_error_m_max is not None:
        got = s.get("mean_error_m")
        if got is None or got > expect.mean_error_m_max:
            misses.append(
                (
                    "mean_error_m_max",
                    f"<= {expect.mean_error_m_max:g} m",
                    "no truth poses" if got is None else f"{got:.2f} m",
                    "-" if got is None else f"{got - expect.mean_error_m_max:.2f} m over",
                )
            )
    if expect.fewer_queries_than_prior and prior is not None:
        a, p = s["mean_queries"], prior["summary"]["mean_queries"]
        if not a < p:
            misses.append(("fewer_queries_than_prior", f"< {p:.3f} (prior)", f"{a:.3f}", f"{a - p:.3f} over"))
    return misses


def _check_ran(results: dict[str, Any]) -> None:
    """A run that localized no frame fails its item whatever the expectations say; an
    interrupted one stops pytest as the Ctrl-C would have."""
    from knowledge_sources.errors import RunFailed

    if results.get("interrupted"):
        raise KeyboardInterrupt(results["interrupted"])
    s = results["summary"]
    if s["localized"] == 0:
        degraded = "; ".join(results.get("degraded") or [])
        raise RunFailed(
            f"no frame localized ({s.get('frames_expected', s['frames'])} expected, "
            f"{s.get('posted', s['frames'])} posted{'; ' + degraded if degraded else ''})"
        )


#: markers the plugin puts on its items, registered so that ``--strict-markers`` accepts them
MARKERS = {
    "slow": "takes more than a few seconds (rendering a whole scenario, multi-process runs)",
    "scenario": "a scenario YAML file's expect: block, run end to end by the mapinterp plugin",
}


def pytest_configure(config: pytest.Config) -> None:
    for name, text in MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {text}")


def summary_line(summary: dict[str, Any]) -> str:
    """A results summary as one readable line: ``frames 30, localized 30, top-1 83.3%, ...``."""

    def pct(v: Any) -> str:
        return "n/a" if v is None else f"{v:.1%}"

    def num(v: Any, unit: str = "", spec: str = ".2f") -> str:
        return "n/a" if v is None else f"{v:{spec}}{unit}"

    return (
        f"frames {summary.get('frames')}, localized {summary.get('localized', 'n/a')}, "
        f"top-1 {pct(summary.get('top1'))}, mean queries {num(summary.get('mean_queries'))}, "
        f"mean backtracks {num(summary.get('mean_backtracks'))}, "
        f"mean error {num(summary.get('mean_error_m'), ' m', '.1f')}, "
        f"latency p50 {num(summary.get('latency_ms_p50'), ' ms', '.0f')}"
    )


def pytest_collect_file(parent: pytest.Collector, file_path: Path):
    if file_path.suffix not in (".yaml", ".yml"):
        return None
    try:
        head = yaml.safe_load(file_path.read_text())
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return None
    if isinstance(head, dict) and "expect" in head and "route" in head:
        return ScenarioFile.from_parent(parent, path=file_path)
    return None


class ScenarioFile(pytest.File):
    """A scenario YAML file with an ``expect:`` block."""

    def collect(self):
        yield ScenarioItem.from_parent(self, name="expect")


class ScenarioItem(pytest.Item):
    """Runs the scenario through the blackboard and checks its expectations."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.add_marker(pytest.mark.slow)
        self.add_marker(pytest.mark.scenario)
        self.results: dict[str, Any] | None = None

    def runtest(self) -> None:
        from knowledge_sources.mission import run_mission
        from models.scenario import load_scenario

        scenario = load_scenario(self.path)
        expect = scenario.expect
        if expect is None:
            pytest.fail(f"{self.path}: the expect block is empty (give at least one expectation)", pytrace=False)
        strategy = expect.strategy or scenario.scheduler.strategy
        self.results = run_mission(scenario, strategy=strategy, processes=expect.processes)
        _check_ran(self.results)
        prior = None
        if expect.fewer_queries_than_prior:
            prior = run_mission(scenario, strategy="prior", processes=expect.processes)
            _check_ran(prior)
        misses = check_expectations(expect, self.results, prior)
        if misses:
            raise ExpectationMissed(misses)

    def repr_failure(self, excinfo, style=None):
        from knowledge_sources.errors import MAPINTERP_ERRORS

        if isinstance(excinfo.value, ExpectationMissed):
            rows = [("expectation", "wanted", "got", "missed by"), *excinfo.value.misses]
            widths = [max(len(r[i]) for r in rows) for i in range(4)]
            lines = [f"scenario {self.path.name}: expectations missed"]
            lines += ["  " + "  ".join(c.ljust(widths[i]) for i, c in enumerate(r)) for r in rows]
            if self.results is not None:
                s = self.results["summary"]
                lines.append(f"  summary: {summary_line(s)}")
            return "\n".join(lines)
        if isinstance(excinfo.value, MAPINTERP_ERRORS):
            return f"scenario {self.path.name}: {excinfo.value}"
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self):
        return self.path, 0, f"scenario {self.path.name}"

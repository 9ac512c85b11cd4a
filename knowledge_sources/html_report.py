"""One HTML page per report: ``DIR/index.html``, opened from disk (no server, no scripts).

What a person looking for why a frame went wrong needs, on one page:

* the summary of every results file side by side (strategy, top-1, queries, error, latency);
* the map with legend and elevation colour bar (``positions.png``, :func:`~knowledge_sources.report.plot_positions`);
* a table of frames sorted wrong-first (then not localized, then right), with the chosen and the
  true viewframe, the rank the truth had in the associative ranking, confidence, queries and the
  reason, and one column per further results file;
* per frame (wrong ones first, up to ``max_frames``): the camera image with the landmark
  questions and answers drawn as boxes (green present, red absent, yellow uncertain), the true
  viewframe, and per results file the chosen viewframe with the answers about it, the reason
  when not localized and the ranking.

Images are PNG files beside the page (``frames/``); every ``src`` and ``href`` is relative.
"""

from __future__ import annotations

import html
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from models.route_views import shown_view, view_on_point

__all__ = ["write_html_report", "frame_order", "truth_rank", "draw_answers"]

_COLOUR = {True: (40, 200, 60), False: (230, 40, 40), None: (240, 200, 0)}  # RGB per answer
_VERDICT = {True: "present", False: "absent", None: "uncertain"}
_SCALE = 2  # images are small: show them at twice their size, pixels kept sharp


def frame_order(frames: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Frames wrong-first: wrong, then not localized (or without truth), then right; by frame within."""

    def key(f: dict[str, Any]) -> tuple[int, int]:
        if f.get("correct") is False and f.get("viewframe") is not None:
            return 0, f["frame"]
        if f.get("viewframe") is None:
            return 1, f["frame"]
        return (2 if f.get("correct") else 1), f["frame"]

    return sorted(frames, key=key)


def truth_rank(frame: dict[str, Any]) -> int | None:
    """1-based rank of the true viewframe in the frame's ranking (the first five), None when not in it."""
    truth = frame.get("truth_viewframe")
    for i, (k, _) in enumerate(frame.get("ranking") or []):
        if truth is not None and int(k) == int(truth):
            return i + 1
    return None


def draw_answers(image: np.ndarray, boxes: Sequence[tuple[tuple[int, int, int, int], str, bool | None]]) -> np.ndarray:
    """``image`` (RGB, H x W x 3) enlarged, with each ((row0, col0, row1, col1), label, present) drawn."""
    big = cv2.resize(np.ascontiguousarray(image), None, fx=_SCALE, fy=_SCALE, interpolation=cv2.INTER_NEAREST)
    for (r0, c0, r1, c1), label, present in boxes:
        colour = _COLOUR[present]
        p0, p1 = (c0 * _SCALE, r0 * _SCALE), ((c1 + 1) * _SCALE - 1, (r1 + 1) * _SCALE - 1)
        cv2.rectangle(big, p0, p1, colour, 1)
        y = max(9, p0[1] - 3)
        cv2.putText(big, label, (p0[0], y), cv2.FONT_HERSHEY_PLAIN, 0.8, (0, 0, 0), 2, cv2.LINE_AA)
        cv2.putText(big, label, (p0[0], y), cv2.FONT_HERSHEY_PLAIN, 0.8, colour, 1, cv2.LINE_AA)
    return big


def _save(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        from models.errors import InputError

        raise InputError(path, "cannot write the image")


def _answer_boxes(frame: dict[str, Any], replay: Any, *, viewframe: int | None = None) -> list:
    """Boxes of the frame's landmark questions (from its ``steps``), optionally only about ``viewframe``."""
    from knowledge_sources.replay import answer_box

    out = []
    for step in frame.get("steps") or []:
        vf = step.get("viewframe")
        if vf is None or not 0 <= int(vf) < len(replay.viewframes) or (viewframe is not None and int(vf) != viewframe):
            continue
        box = answer_box(replay.viewframes[int(vf)], str(step.get("landmark")))
        if box is None:
            continue
        present = step.get("present")
        score = step.get("score")
        label = f"{step.get('landmark')} {_VERDICT[present]}" + (f" {float(score):.2f}" if score is not None else "")
        out.append((box, label + ("" if viewframe is not None else f" V{vf}"), present))
    return out


def _fmt(value: Any, spec: str = "") -> str:
    if value is None:
        return "–"
    return format(value, spec) if spec else str(value)


_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: right; vertical-align: top; }
th { background: #f0f0f0; }
td.text { text-align: left; max-width: 40em; }
tr.wrong { background: #fde8e8; } tr.none { background: #fff6d6; } tr.right { background: #eefaee; }
figure { display: inline-block; margin: 0 1em 1em 0; vertical-align: top; }
figcaption { font-size: 0.85em; max-width: 22em; }
img { image-rendering: pixelated; border: 1px solid #999; }
section.frame { border-top: 1px solid #bbb; padding-top: 0.5em; }
.legend span { display: inline-block; margin-right: 1em; }
"""


def write_html_report(
    out: Path,
    runs: Sequence[dict[str, Any]],
    names: Sequence[str],
    replay: Any,
    *,
    figures: Sequence[str] = (),
    extra_links: Sequence[tuple[str, str]] = (),
    max_frames: int = 40,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write ``out/index.html`` (and its frame images under ``out/frames``) for ``runs`` (results
    dicts; ``names`` their file names, the first is the main run) on the scenario rebuilt in
    ``replay``. ``figures`` are image files already in ``out`` (the map first), ``extra_links``
    (href, text) pairs such as the GeoJSON. Returns the page's path."""
    main = runs[0]
    by_frame = [{f["frame"]: f for f in run["frames"]} for run in runs]
    ordered = frame_order(main["frames"])
    detailed = ordered[: max(0, max_frames)]
    e = html.escape
    parts = [
        "<!doctype html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>mapinterp report: {e(str(main['scenario']))}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>mapinterp report: {e(str(main['scenario']))}</h1>",
    ]
    # summaries side by side
    rows = [
        ("strategy", lambda r: r["strategy"]),
        ("mode", lambda r: r.get("mode")),
        ("frames", lambda r: r["summary"]["frames"]),
        ("localized", lambda r: r["summary"].get("localized")),
        ("top-1", lambda r: None if r["summary"]["top1"] is None else f"{r['summary']['top1']:.1%}"),
        ("mean queries", lambda r: f"{r['summary']['mean_queries']:.2f}"),
        ("mean backtracks", lambda r: f"{r['summary'].get('mean_backtracks', 0.0):.2f}"),
        (
            "mean error (m)",
            lambda r: None if r["summary"]["mean_error_m"] is None else f"{r['summary']['mean_error_m']:.1f}",
        ),
        ("latency p50 (ms)", lambda r: f"{r['summary']['latency_ms_p50']:.0f}"),
        ("crs", lambda r: r.get("crs")),
    ]
    parts.append("<h2>Results compared</h2><table><tr><th></th>" + "".join(f"<th>{e(n)}</th>" for n in names) + "</tr>")
    for label, get in rows:
        parts.append(f"<tr><th>{e(label)}</th>" + "".join(f"<td>{e(_fmt(get(r)))}</td>" for r in runs) + "</tr>")
    parts.append("</table>")
    if figures:
        parts.append("<h2>Map and figures</h2>")
        for name in figures:
            parts.append(f'<figure><img src="{e(name)}" alt="{e(name)}"><figcaption>{e(name)}</figcaption></figure>')
    if extra_links:
        parts.append("<p>" + " · ".join(f'<a href="{e(h)}">{e(t)}</a>' for h, t in extra_links) + "</p>")
    # frames table, wrong first
    parts.append(
        "<h2>Frames, wrong first</h2>"
        '<p class="legend"><span style="background:#fde8e8">wrong</span>'
        '<span style="background:#fff6d6">not localized or no truth</span>'
        '<span style="background:#eefaee">right</span> · truth rank: where the true viewframe stood in the '
        "associative ranking (of its first five)</p>"
    )
    head = ["frame", "chosen", "truth", "truth rank", "confidence", "queries", "backtracks", "error (m)", "reason"]
    head += [f"{n}: chosen / ok / queries" for n in names[1:]]
    parts.append("<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr>")
    with_section = {f["frame"] for f in detailed}
    for f in ordered:
        cls = (
            "right"
            if f.get("correct")
            else ("wrong" if f.get("correct") is False and f.get("viewframe") is not None else "none")
        )
        frame_cell = (
            f'<a href="#frame-{f["frame"]}">{f["frame"]}</a>' if f["frame"] in with_section else str(f["frame"])
        )
        cells = [
            frame_cell,
            e(_fmt(f.get("viewframe"))),
            e(_fmt(f.get("truth_viewframe"))),
            e(
                _fmt(truth_rank(f), "d")
                if truth_rank(f) is not None
                else ("–" if f.get("truth_viewframe") is None else ">5")
            ),
            e(f"{f['confidence']:.2f}"),
            e(str(f["queries"])),
            e(str(f["backtracks"])),
            e(_fmt(f.get("error_m"), ".1f")),
        ]
        row = "".join(f"<td>{c}</td>" for c in cells) + f'<td class="text">{e(str(f.get("reason", "")))}</td>'
        for other in by_frame[1:]:
            g = other.get(f["frame"])
            row += (
                "<td>–</td>"
                if g is None
                else (
                    f"<td>{e(_fmt(g.get('viewframe')))} / {e({True: 'yes', False: 'no', None: '–'}[g.get('correct')])}"
                    f" / {g['queries']}</td>"
                )
            )
        parts.append(f'<tr class="{cls}">{row}</tr>')
    parts.append("</table>")
    # per-frame sections
    parts.append("<h2>Frames in detail</h2>")
    for n, f in enumerate(detailed):
        idx = f["frame"]
        sensor = replay.frames.get(idx)
        parts.append(f'<section class="frame" id="frame-{idx}"><h3>frame {idx}: ')
        verdict = {True: "right", False: "wrong", None: "no truth"}[f.get("correct")]
        if f.get("viewframe") is None:
            verdict = "not localized"
        parts.append(
            f"{e(verdict)} — chosen {e(_fmt(f.get('viewframe')))}, truth {e(_fmt(f.get('truth_viewframe')))}, "
            f"truth rank {e(_fmt(truth_rank(f)))}</h3>"
        )
        if sensor is not None:
            name = f"frames/frame_{idx:03d}_camera.png"
            _save(out / name, draw_answers(sensor.image, _answer_boxes(f, replay)))
            parts.append(
                f'<figure><img src="{name}" alt="camera frame {idx}"><figcaption>camera frame {idx} '
                f"({e(str(sensor.source))}); boxes: the landmarks asked about, where the candidate viewframe "
                "shows them</figcaption></figure>"
            )
        truth = f.get("truth_viewframe")  # a route point; shown: the viewframe on it
        on_truth = None if truth is None else view_on_point(truth, replay.scenario.views_per_leg)
        if on_truth is not None and 0 <= on_truth < len(replay.viewframes):
            name = f"frames/viewframe_{on_truth:03d}.png"
            if not (out / name).exists():
                _save(out / name, draw_answers(replay.viewframes[on_truth].image, []))
            parts.append(
                f'<figure><img src="{name}" alt="true viewframe {truth}"><figcaption>true viewframe {truth}'
                "</figcaption></figure>"
            )
        for run_name, frames in zip(names, by_frame):
            g = frames.get(idx)
            if g is None:
                continue
            chosen = g.get("viewframe")  # a route point; shown: its viewframe (models.route_views.shown_view)
            shown = shown_view(g, replay.scenario.views_per_leg)
            caption = f"{e(run_name)} ({e(str(runs[names.index(run_name)]['strategy']))}): "
            if shown is None or not 0 <= shown < len(replay.viewframes):
                parts.append(
                    f"<figure><figcaption>{caption}not localized: {e(str(g.get('reason', '')))}</figcaption></figure>"
                )
                continue
            name = f"frames/frame_{idx:03d}_{names.index(run_name)}_chosen.png"
            _save(
                out / name,
                draw_answers(replay.viewframes[shown].image, _answer_boxes(g, replay, viewframe=shown)),
            )
            ranking = ", ".join(f"V{int(k)} {float(v):.3g}" for k, v in g.get("ranking") or [])
            ok = {True: "right", False: "wrong", None: ""}[g.get("correct")]
            parts.append(
                f'<figure><img src="{name}" alt="chosen viewframe {chosen}"><figcaption>{caption}chosen viewframe '
                f"{chosen} {ok}, confidence {g['confidence']:.2f}, {g['queries']} queries; reason: "
                f"{e(str(g.get('reason', '')))}; ranking: {e(ranking)}</figcaption></figure>"
            )
        parts.append("</section>")
        if progress is not None:
            progress(n + 1, len(detailed))
    parts.append("</body></html>")
    page = out / "index.html"
    page.write_text("\n".join(parts) + "\n", encoding="utf-8")
    return page

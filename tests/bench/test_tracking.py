"""bench/tracking.py: the extra tuning drives stay on tuning seeds, apart from the held-out split."""

from __future__ import annotations

from bench.evalset import TERRAINS, cases, seeds
from bench.evalset.cases import _case_seed


def test_extra_tuning_drives_are_tuning_seeds_apart_from_the_held_out():
    from bench.tracking import DRIVE_KINDS, extra_tuning_drives

    extra = extra_tuning_drives()
    tuning = [t for t in TERRAINS if t.split == "tuning"]
    assert len(extra) == 2 * len(tuning)
    held = seeds("heldout")
    for t in extra:
        assert t.split == "tuning" and 1000 <= t.seed < 2000 and t.seed not in held
        assert t.drives and set(t.drives) <= set(DRIVE_KINDS)
        assert not {_case_seed(t, k) for k in ("sweep", *t.drives)} & held
    assert not {t.name for t in extra} & {t.name for t in TERRAINS}  # their own cache folders
    # every tuning terrain gets the drive kinds it lacks, and a second instance with both
    for t in tuning:
        (x,) = [e for e in extra if e.name == f"{t.name}-x"]
        assert set(x.drives) == set(DRIVE_KINDS) - set(t.drives) and x.seed == t.seed
        (s,) = [e for e in extra if e.name == f"{t.name}-s"]
        assert s.seed != t.seed and set(s.drives) == set(DRIVE_KINDS)


def test_cases_of_other_terrains_are_generated_from_them(tmp_path):
    from bench.tracking import extra_tuning_drives

    (x,) = [t for t in extra_tuning_drives() if t.name == "t-jacksboro-nw-x"]  # 200x150 frames: quick
    (case,) = list(cases("tuning", out_dir=tmp_path, terrains=[x], kinds=("drive",), max_frames=3))
    assert case.name == "t-jacksboro-nw-x/drive" and case.kind == "drive" and len(case.frames) == 3
    times = [f.time_s for f in case.frames]
    assert times == sorted(times) and len(set(times)) == 3
    assert tmp_path in case.folder.parents


def test_more_tuning_drives_are_tuning_seeds_apart_from_the_held_out_and_the_extra():
    from bench.tracking import DRIVE_KINDS, MORE_SEED_OFFSETS, extra_tuning_drives, more_tuning_drives

    more = more_tuning_drives()
    tuning = [t for t in TERRAINS if t.split == "tuning"]
    assert len(more) == len(MORE_SEED_OFFSETS) * len(tuning)
    held = seeds("heldout")
    others = {t.seed for t in (*TERRAINS, *extra_tuning_drives()) if t.split == "tuning"}
    for t in more:
        assert t.split == "tuning" and 1000 <= t.seed < 2000 and t.seed not in held and t.seed not in others
        assert set(t.drives) == set(DRIVE_KINDS)
        assert not {_case_seed(t, k) for k in ("sweep", *t.drives)} & held
    names = {t.name for t in more}
    assert len(names) == len(more) and not names & {t.name for t in (*TERRAINS, *extra_tuning_drives())}


def _straight_drive(truth_arcs: list[float]) -> dict:
    """A ranked drive on a straight route of 6 points 40 m apart, the camera at ``truth_arcs``
    (metres along it), each frame's ranking a seeded noisy bowl around the truth (lower is better)."""
    import numpy as np

    route = np.c_[np.arange(6) * 40.0, np.zeros(6)]
    rng = np.random.default_rng(7)
    truth = np.array([(a, 0.0, 0.0) for a in truth_arcs])
    obs = np.array([((route[:, 0] - a) / 40.0) ** 2 + 0.1 * rng.random(6) for a in truth_arcs])
    tp = np.array([int(np.argmin(np.abs(route[:, 0] - a))) for a in truth_arcs])
    return {
        "name": "straight",
        "route": route,
        "truth": truth,
        "true_point": tp,
        "times": np.arange(len(truth_arcs)) * 1.0,
        "obs": obs,
    }


def test_a_track_between_two_route_points_is_scored_by_its_route_point_and_by_half_a_spacing():
    """The track's top-1 names the route point nearest its estimate; a track a few metres from the
    truth on the other side of the middle of a leg is wrong by top-1 and within half a spacing."""
    import numpy as np

    from bench.tracking import score
    from models.scenario import TrackingSpec
    from models.tracking import TrackEstimate

    d = _straight_drive([58.0, 58.0])  # nearest route point 1 (at 40 m): 18 m from it, 22 m from point 2
    ests = [
        TrackEstimate(2, 62.0, 62.0, 0.0, 0.0, 0.6, "tracking"),
        TrackEstimate(1, 50.0, 50.0, 0.0, 0.0, 0.6, "tracking"),
    ]
    obs = np.tile(np.where(np.arange(6) == 1, 0.0, 5.0), (2, 1))  # the single frame says point 1
    r = score(d, {"fused": (obs, {"online": ests, "smoothed": ests, "cost_ms": [0.0, 0.0]})}, TrackingSpec())
    assert r["single[fused]"]["right"] == [True, True] and r["single[fused]"]["within_half"] == [True, True]
    assert r["tracked[fused]"]["right"] == [False, True]
    assert r["tracked[fused]"]["within_half"] == [True, True]  # 4 m and 8 m from the truth
    assert r["tracked[fused]"]["error_m"] == [4.0, 8.0]


def test_the_frame_table_says_where_the_track_and_the_frame_stood():
    import numpy as np

    from bench.tracking import frame_table, track_drive
    from models.scenario import TrackingSpec

    d = _straight_drive([5.0, 45.0, 85.0, 85.0, 125.0])
    tracked = track_drive(d, TrackingSpec(), d["obs"], priors=True)
    assert tracked["prior"].shape == (5, 6)
    np.testing.assert_allclose(tracked["prior"].sum(axis=1), 1.0)
    rows = frame_table(d, d["obs"], tracked)
    assert [r["true_point"] for r in rows] == [0, 1, 2, 2, 3]
    assert rows[0]["move_spacings"] is None
    np.testing.assert_allclose([r["move_spacings"] for r in rows[1:]], [1.0, 1.0, 0.0, 1.0])
    for r, e in zip(rows, tracked["online"]):
        assert r["tracked"] == e.route_point and r["confidence"] == e.confidence
        assert 0.0 <= r["prior_true"] <= 1.0 and 0.0 <= r["posterior_true"] <= 1.0
        assert r["single"] == r["true_point"] and r["error_single_m"] == abs(
            40.0 * r["single"] - d["truth"][r["frame"], 0]
        )
    # every frame names the true point: its evidence raises the mass there above the prediction
    assert all(r["posterior_true"] > r["prior_true"] for r in rows), rows

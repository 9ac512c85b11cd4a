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

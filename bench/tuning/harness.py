"""Offline tuning of the scheduler/detector parameters: real memory, real detectors, real SceneAnalysis,
on simulated frames with seeds other than the bundled scenarios' (no overfitting to them)."""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
from knowledge_sources.results import nearest_viewframe
from knowledge_sources.scene_analysis import SceneAnalysis
from models.detectors import CandidateView, default_registry
from models.index import ViewframeIndex
from models.scenario import SchedulerSpec, load_scenario
from models.world import World

#: the grid's starting point: the shipped scheduler and detector defaults
_DEFAULTS = SchedulerSpec()

#: detector scores by (scenario, frame, landmark, viewframe): the grid re-thresholds the same
#: scores, so each detection runs once per process
_SCORES: dict[tuple, tuple[float, bool]] = {}


def with_sensor_seed(sc, seed):
    """The scenario with its simulated camera drawn from another seed (same frames as
    ``simulate_frames(..., rng=seed)``)."""
    simulate = sc.sensor.simulate.model_copy(update={"seed": seed})
    return sc.model_copy(update={"sensor": sc.sensor.model_copy(update={"simulate": simulate})})


def prepare(path, seed):
    sc = with_sensor_seed(load_scenario(path), seed)
    with World(sc) as world:
        env, vfs, frames = world.environment, world.viewframes, world.sensor_frames
        cam = world.emulator
        fmasks = [cam.render(cam.pose_at(*f.truth)).mask for f in frames]
    index = ViewframeIndex(sc.memory)
    index.add([v.image for v in vfs], [v.index for v in vfs])
    ranks = [index.rank(f.image) for f in frames]
    truth = [nearest_viewframe(f.truth[0], f.truth[1], sc.route) for f in frames]  # the results' criterion
    idx = {lm.id: i for i, lm in enumerate(env.landmarks)}
    kinds = {lm.id: lm.kind for lm in env.landmarks}
    pixels = {v.index: {n: v.description.graph.nodes[n]["pixels"] for n in v.description.visible} for v in vfs}
    # pixels of each landmark at each frame's true pose: for the oracle (ceiling) run only
    fvis = [{lm.id: int((fm == i).sum()) for i, lm in enumerate(env.landmarks)} for fm in fmasks]
    return dict(
        fvis=fvis,
        name=sc.name,
        vfs=[(v.image, v.mask) for v in vfs],
        frames=[f.image for f in frames],
        ranks=ranks,
        truth=truth,
        idx=idx,
        kinds=kinds,
        pixels=pixels,
    )


def evaluate(
    d,
    *,
    oracle=False,
    min_pixels=_DEFAULTS.min_pixels,
    beta=_DEFAULTS.beta,
    reliability=_DEFAULTS.reliability,
    thr=_DEFAULTS.detector_threshold,
    athr=_DEFAULTS.absent_threshold,
    candidates=_DEFAULTS.candidates,
    accept=_DEFAULTS.accept,
    strategy=_DEFAULTS.strategy,
    priors=None,
):
    reg = default_registry(threshold=thr, absent_threshold=athr)
    cache = _SCORES
    visible = {k: {lm for lm, px in pl.items() if px >= min_pixels} for k, pl in d["pixels"].items()}
    ok = 0
    queries = 0
    for fi, (rk, t) in enumerate(zip(d["ranks"], d["truth"])):
        sa = SceneAnalysis(
            [(int(k), float(v)) for k, v in zip(rk.viewframes, rk.variances)],
            visible,
            strategy=strategy,
            candidates=candidates,
            accept=accept,
            reliability=reliability,
            priors=priors,
            beta=beta,
        )
        while (q := sa.next_question()) is not None:
            key = (d["name"], fi, q.landmark, q.viewframe)
            if key not in cache:
                img, mask = d["vfs"][q.viewframe]
                det = reg.for_kind(d["kinds"][q.landmark])
                r = det.detect(d["frames"][fi], view=CandidateView.from_mask(img, mask, d["idx"][q.landmark]))
                cache[key] = (r.score, r.location is None)
            s, unsearched = cache[key]
            # the detector's own three-way rule, re-applied to the cached score for this grid point
            present = None if unsearched else (True if s >= thr else (False if s < athr else None))
            if oracle:
                present = d["fvis"][fi][q.landmark] >= 10
            sa.answer(q, present)
        ok += sa.decision.viewframe == t
        queries += sa.decision.queries
    n = len(d["truth"])
    return ok / n, queries / n

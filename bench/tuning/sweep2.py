import pickle
import sys

sys.path.insert(0, __import__("os").path.dirname(__file__))
from harness import evaluate

data = pickle.load(open("/tmp/tune_data.pkl", "rb"))
n = [len(d["truth"]) for d in data]
rank1 = sum(int(r.viewframes[0]) == t for d in data for r, t in zip(d["ranks"], d["truth"])) / sum(n)
print("ranking top-1", round(rank1, 3))


def total(**kw):
    res = [evaluate(d, **kw) for d in data]
    return round(sum(a * k for (a, _), k in zip(res, n)) / sum(n), 3), round(
        sum(b * k for (_, b), k in zip(res, n)) / sum(n), 2
    )


rows = []
for mp in (24, 60, 150):
    for beta in (3.0, 10.0, 30.0):
        for athr in (0.15, 0.25):
            for thr in (0.55, 0.65):
                for rel in (0.7, 0.8):
                    for acc in (0.6, 0.8):
                        a, q = total(min_pixels=mp, beta=beta, athr=athr, thr=thr, reliability=rel, accept=acc)
                        o, oq = total(
                            oracle=True, min_pixels=mp, beta=beta, athr=athr, thr=thr, reliability=rel, accept=acc
                        )
                        rows.append((a, -q, mp, beta, athr, thr, rel, acc, q, o, oq))
rows.sort(reverse=True)
for r in rows[:15]:
    print(
        f"top1 {r[0]:.3f} queries {r[8]:.2f} | min_px {r[2]} beta {r[3]} athr {r[4]} thr {r[5]} rel {r[6]} accept {r[7]} | oracle {r[9]:.3f} q {r[10]:.2f}"
    )

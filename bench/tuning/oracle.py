import pickle
import sys

sys.path.insert(0, __import__("os").path.dirname(__file__))
from harness import evaluate

data = pickle.load(open("/tmp/tune_data.pkl", "rb"))
n = [len(d["truth"]) for d in data]


def total(**kw):
    res = [evaluate(d, **kw) for d in data]
    return (
        round(sum(a * k for (a, _), k in zip(res, n)) / sum(n), 3),
        round(sum(b * k for (_, b), k in zip(res, n)) / sum(n), 2),
        [round(a, 2) for a, _ in res],
    )


print("ranking alone", total(accept=1e-9))
print("oracle detector", total(oracle=True))
print("oracle detector min_px 60", total(oracle=True, min_pixels=60))
print("oracle detector cand 4", total(oracle=True, candidates=4))
print("real detector", total())
print("prior+oracle", total(oracle=True, strategy="prior"))

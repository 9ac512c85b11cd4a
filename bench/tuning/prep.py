import pickle
import sys

sys.path.insert(0, __import__("os").path.dirname(__file__))
from harness import prepare

data = [prepare(f"scenarios/{s}.yaml", seed) for s in ("hills", "jacksboro", "contours") for seed in (101, 202)]
pickle.dump(data, open("/tmp/tune_data.pkl", "wb"))
print(
    "prepared",
    [
        (d["name"], len(d["truth"]), sum(int(r.viewframes[0]) == t for r, t in zip(d["ranks"], d["truth"])))
        for d in data
    ],
)

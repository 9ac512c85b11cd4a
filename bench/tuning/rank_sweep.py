import pickle
import sys
import time

sys.path.insert(0, __import__("os").path.dirname(__file__))
from models.index import ViewframeIndex
from models.scenario import MemorySpec

data = pickle.load(open("/tmp/tune_data.pkl", "rb"))
for size, sigma, bank, ms in [
    (128, 1.0, 4, (2, 16)),
    (128, 1.0, 2, (2, 16)),
    (128, 1.0, 1, (2, 16)),
    (128, 1.5, 2, (2, 16)),
    (128, 0.7, 2, (2, 16)),
    (128, 1.0, 2, (3, 16)),
    (64, 0.5, 2, (1, 8)),
    (128, 1.0, 8, (2, 16)),
]:
    ok, tot, t = 0, 0, 0.0
    for d in data:
        index = ViewframeIndex(MemorySpec(size=size, blur_sigma=sigma, bank_size=bank, max_shift=ms))
        index.add([img for img, _ in d["vfs"]], range(len(d["vfs"])))
        for f, tr in zip(d["frames"], d["truth"]):
            q = index.pattern(f)
            t0 = time.perf_counter()
            r = index.rank_pattern(q)
            t += time.perf_counter() - t0
            ok += int(r.viewframes[0]) == tr
            tot += 1
    print(f"N {size} sigma {sigma} bank {bank} shift {ms}: ranking top1 {ok / tot:.3f}  {1000 * t / tot:.1f} ms/query")

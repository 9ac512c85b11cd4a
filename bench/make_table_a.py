"""Generate the camera images of scenarios/table_a.yaml (run once, by hand; the PNGs are committed).

    /tmp/venv/bin/python bench/make_table_a.py

The seed paper's Table A stored four very similar synthetic images and presented four real
ones. Here the four route points of ``table_a.yaml`` stand ~20 m apart on one drive; for each,
the camera image is rendered at a slightly different pose (about 1 m off, 1-2 degrees of
heading; the offsets below are fixed, not drawn), under different sunlight, then degraded:
brightness gain and offset, a little blur, seeded gaussian noise. The true poses written into
the scenario's ``sensor.frames[i].truth`` are those shifted poses.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# bench/blackboard.py would shadow the blackboard package: repository root first, bench/ out
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "bench"]

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from models.scenario import scenario_from_dict  # noqa: E402
from models.world import World  # noqa: E402

SCENARIO = ROOT / "scenarios" / "table_a.yaml"
OUT = ROOT / "scenarios" / "data" / "table_a"

#: per frame: (metres forward, metres left, heading offset deg, relative sun strength, gain, offset,
#: noise sigma)
PERTURB = [
    (0.8, 0.6, 1.5, 0.87, 0.85, 12.0, 5.0),
    (-0.7, -0.7, -1.2, 1.10, 1.05, -10.0, 6.0),
    (0.6, -0.8, 2.0, 0.93, 0.80, 20.0, 4.0),
    (-0.9, 0.5, -1.8, 1.07, 0.95, -15.0, 7.0),
]


def main() -> int:
    data = yaml.safe_load(SCENARIO.read_text())
    data.pop("sensor", None)
    scenario = scenario_from_dict(data, path=SCENARIO)
    rng = np.random.default_rng(scenario.seed)
    OUT.mkdir(parents=True, exist_ok=True)
    truths = []
    with World(scenario) as world:
        cam = world.emulator
        for i, (pose, (fwd, left, dh, light, gain, offset, noise)) in enumerate(zip(world.poses, PERTURB)):
            th = math.radians(pose.heading_deg)
            x = pose.x + fwd * math.cos(th) - left * math.sin(th)
            y = pose.y + fwd * math.sin(th) + left * math.cos(th)
            shifted = cam.pose_at(x, y, pose.heading_deg + dh)
            view = cam.render(shifted, light_intensity=light, light_direction=(-0.35, 0.45, -0.82))
            img = view.image.astype(np.float32)
            img = cv2.GaussianBlur(img, (0, 0), 0.6) * gain + offset + rng.normal(0.0, noise, img.shape)
            img = np.clip(img + 0.5, 0, 255).astype(np.uint8)
            path = OUT / f"frame_{i}.png"
            cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            truths.append((round(x, 2), round(y, 2), round(pose.heading_deg + dh, 2)))
            print(f"{path.relative_to(ROOT)}: truth x={x:.2f} y={y:.2f} heading={pose.heading_deg + dh:.2f}")
    print("sensor.frames truths:", truths, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How often the diagnosis finds what is there, and raises alarms where nothing is (issue 40 item 4).

Seed 000's 28-image nadir block at its point density (3.5 points per mm^2), over ``--seeds`` seeds per scenario:

* ``clean``: no distortion, ``--ap none``, Type 1 control (the model right: alarms are false);
* ``brown``: a Brown lens adjusted with ``brown``, Type 1 control (the model right in the image; a nadir block
  whose self-calibration may still leave a dome: James & Robson 2014);
* ``gnss``: no distortion, ``--ap none``, GNSS/IMU positions as the only datum (every mark a check point);
* ``local``: the simulator's two Gaussian bumps scaled to 0.3 px, ``--ap none`` (a local lens defect; the field
  test must find it);
* ``dome``: a Brown lens scaled to 2.2 px of radial distortion in the corners left unmodelled (``--ap none``),
  GNSS/IMU as the only datum (the dome test must find it);
* ``convergent``, ``convergent-brown``, ``convergent-dome``: ``gnss``, ``brown`` and ``dome`` with every image pitched
  forwards and backwards along its strip in turn by 20° (``simulate_uav(tilt_deg=20)``): a convergent block without
  the error (its alarms are false), and with the unmodelled lens (convergent images bend the block less: James &
  Robson 2014).

Printed per scenario: how often the residual-field test and the dome test found something, and the mean and
spread of the dome's t.

    python benchmarks/study_diagnosis.py [--seeds 30] [--scenarios clean,brown,gnss,local,dome,convergent,...]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from selfcal.block import prune
from selfcal.simulate import simulate_uav
from selfcal.workflows.api import bundle_adjust


def gnss_only(block):
    role = np.where(block.points.role == "gcp", "chk", block.points.role)
    return replace(block, points=replace(block.points, role=role))


#: scenario -> (simulator's distortion, its scale, block type, GNSS-only datum, AP model, tilt of the images (deg))
SCENARIOS = {
    "clean": ("none", 1.0, "type1", False, "none", 0.0),
    "brown": ("brown", 1.0, "type1", False, "brown", 0.0),
    "gnss": ("none", 1.0, "type2", True, "none", 0.0),
    "local": ("local", 0.3 / 2.88, "type1", False, "none", 0.0),
    "dome": ("brown", 0.2, "type2", True, "none", 0.0),
    "convergent": ("none", 1.0, "type2", True, "none", 20.0),
    "convergent-brown": ("brown", 1.0, "type1", False, "brown", 20.0),
    "convergent-dome": ("brown", 0.2, "type2", True, "none", 20.0),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    args = parser.parse_args()
    for name in args.scenarios.split(","):
        distortion, scale, scenario, gnss, ap, tilt = SCENARIOS[name]
        field = dome = 0
        t_values = []
        began = time.perf_counter()
        for seed in range(args.seeds):
            sim = simulate_uav(seed=seed, distortion=distortion, distortion_scale=scale, tilt_deg=tilt)
            block = prune(sim.blocks[scenario])
            extra = {}
            if gnss:
                block = gnss_only(block)
                extra = {"gnss_drift": -1, "imu_drift": -1}
            d = bundle_adjust(block, ap, max_iterations=30, control_loo=False, half_block=False,
                              **extra).files["summary.json"]["diagnosis"]
            field += any(f["found"] for f in d["residual_field"])
            dome += bool(d["dome"] and d["dome"]["found"])
            if d["dome"]:
                t_values.append(d["dome"]["t"])
        t = np.array(t_values)
        print(f"{name:6s}: field found {field}/{args.seeds}, dome found {dome}/{args.seeds}, dome t mean "
              f"{t.mean():+.2f} sd {t.std():.2f} ({time.perf_counter() - began:.0f} s)", flush=True)


if __name__ == "__main__":
    main()

"""Sample preparation speed: micro-lens mesh, ray casting and MLCT tip dilation.

Writes ``benchmarks/results/samples.json`` (median of ``--repeats`` runs, seconds).

    python benchmarks/bench_samples.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import machine_info, median_seconds  # noqa: E402
from afmsim.samples import MicroLensArray, grating_heightmap  # noqa: E402
from afmsim.tip import dilate, mlct_tip  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "samples.json")
    args = parser.parse_args()
    lens = MicroLensArray()
    mesh = lens.mesh()
    lens_map = lens.heightmap((256, 256), (5e-6, 5e-6), mesh=mesh)
    grating = grating_heightmap((256, 256), (5e-6, 5e-6), sidewall_angle_deg=90)
    tip = mlct_tip()
    for hm in (lens_map, grating):  # correctness check: the image never lies below the sample
        if not np.all(dilate(hm, tip).z >= hm.z):
            raise SystemExit("dilation went below the sample")
    results = {
        "microlens_mesh_s": median_seconds(lens.mesh, args.repeats)[0],
        "raycast_256_s": median_seconds(lambda: lens.heightmap((256, 256), mesh=mesh), args.repeats)[0],
        "raycast_512_s": median_seconds(lambda: lens.heightmap((512, 512), mesh=mesh), args.repeats)[0],
        "dilation_lens_256_s": median_seconds(lambda: dilate(lens_map, tip), args.repeats)[0],
        "dilation_grating_256_s": median_seconds(lambda: dilate(grating, tip), args.repeats)[0],
        "machine": machine_info(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()

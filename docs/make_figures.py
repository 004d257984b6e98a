"""Regenerate the gallery docs/figures/ID.png from the quick runs (seed 0) of every experiment.

    PYTHONPATH=src python docs/make_figures.py [ID ...]     # every experiment, or those named

The PNGs are quantized to 256 colours so that each stays under 150 kB.
"""

import sys
import tempfile
from pathlib import Path

from PIL import Image

from nlfilter.experiments import registry
from nlfilter.plots import plot_result

OUT = Path(__file__).parent / "figures"


def main(ids=()):
    OUT.mkdir(exist_ok=True)
    tmp = Path(tempfile.mkdtemp())
    unknown = sorted(set(ids) - set(registry()))
    if unknown:
        raise SystemExit(f"make_figures.py: unknown experiment(s) {unknown}; expected ids from {sorted(registry())}")
    for id, exp in registry().items():
        if ids and id not in ids:
            continue
        raw = tmp / f"{id}.png"  # plot_result writes a file (atomically), then quantized here
        plot_result(exp.run({}, quick=True, seed=0), raw, dpi=90)
        img = Image.open(raw).convert("RGB").quantize(256)
        path = OUT / f"{id}.png"
        img.save(path, optimize=True)
        print(f"{path}: {path.stat().st_size // 1000} kB")


if __name__ == "__main__":
    main(sys.argv[1:])

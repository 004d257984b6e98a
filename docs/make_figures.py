"""Regenerate the gallery docs/figures/ID.png from the quick runs (seed 0) of every experiment.

    PYTHONPATH=src python docs/make_figures.py

The PNGs are quantized to 256 colours so that each stays under 150 kB.
"""

import io
from pathlib import Path

from PIL import Image

from nlfilter.experiments import registry
from nlfilter.plots import plot_result

OUT = Path(__file__).parent / "figures"


def main():
    OUT.mkdir(exist_ok=True)
    for id, exp in registry().items():
        buf = io.BytesIO()
        plot_result(exp.run({}, quick=True, seed=0), buf, dpi=90)
        img = Image.open(buf).convert("RGB").quantize(256)
        path = OUT / f"{id}.png"
        img.save(path, optimize=True)
        print(f"{path}: {path.stat().st_size // 1000} kB")


if __name__ == "__main__":
    main()

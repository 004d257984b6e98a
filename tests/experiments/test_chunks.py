"""Every Monte Carlo experiment gives the same rows for any chunk of paths (per-path streams,
nlfilter.streams): ``Experiment.run(chunk=2)`` (CLI ``--chunk 2``) equals one batch.

Every one states its Monte Carlo in blocks (nlfilter.montecarlo: ``cubic-sensor``,
``cubic-sensor-closures``, ``linear-gaussian``, ``moment-first-order``, ``moment-second-order``,
``oh-shin``, ``phase-tracking``, ``second-order``, ``zero-order``, ``zero-order-adaptive``,
``zero-order-robustness``; ``smoothing`` through ``compare(block=...)``; ``BLOCKS`` below) and
computes every block as its own batch whatever the chunk, so their rows for ``chunk=1`` and
``chunk=4`` are identical, bitwise. The two differ from no chunk in complementary ways: ``chunk=1``
sends one block per task (as no chunk does) but runs each path of a block as its own batch (the
experiments' ``in_chunks`` and ``Filter.run(chunk=)``); ``chunk=4`` runs each block as one batch (as
no chunk does) but sends both blocks in one task. A fault in either grouping moves one run and not
the other, so the pair stands for all three (a third run, of no chunk, would add a third of these
tests' minute and a half of CPU and no fault it could catch alone)."""

import re

import pytest

from nlfilter.experiments import get

# quick runs, small --runs (3 paths: a block of 2 and one of 1, so chunk=1 makes two tasks and chunk=4
# one task of both blocks), the cheapest parameters of each (shorter
# horizons than the quick runs' where a parameter sets them: how the blocks are grouped into tasks
# does not depend on the number of steps)
CASES = {
    "cubic-sensor": ({"q": [2.0], "r": [1.0], "dt": 0.1}, 3),  # 50 steps of the quick T = 5, not the automatic ~1400
    "cubic-sensor-closures": ({"q": [1.0], "r": [1.0]}, 3),
    "linear-gaussian": ({"steps": 20}, 3),
    "moment-first-order": ({"laws": ["uniform"], "N": [2]}, 3),
    "moment-second-order": ({"laws": ["uniform"], "N": [2], "particles": 200, "T": 30, "skip": 10}, 3),
    "oh-shin": ({"t_end": 0.5}, 3),
    "phase-tracking": ({}, 3),
    "second-order": ({"steps": 6}, 3),  # each problem's first 6 steps (of 50, 200, 60)
    "smoothing": ({"steps": 8}, 3),
    "zero-order": ({"J": [2], "N": [2]}, 2500),  # 3 paths of 1000 samples
    "zero-order-adaptive": ({"J": [0], "N": [2]}, 3),
    "zero-order-robustness": ({"r": [0.3], "beta": [0.2], "N": [2]}, 3),
}
# Monte Carlo in blocks, bitwise the same for any chunk: the extra parameters of the test (blocks of
# 2 paths: 2, 1; a chunk of 4 puts both blocks in one task)
BLOCKS = {"cubic-sensor": {"block": 2}, "cubic-sensor-closures": {"block": 2}, "oh-shin": {"block": 2},
          "linear-gaussian": {"block": 2}, "phase-tracking": {"block": 2, "sweep": 3, "grid": 0}, "second-order": {"block": 2},
          "smoothing": {"block": 2}, "zero-order": {"block": 2}, "zero-order-adaptive": {"block": 2},
          "zero-order-robustness": {"block": 2}, "moment-first-order": {"block": 2},
          "moment-second-order": {"block": 2}}


def _rows(res):
    return [(r.filter, r.quantity, repr(sorted(r.params.items())), r.value, r.stderr) for r in res.rows]


def _exact(res):
    """The rows with every value as its exact hexadecimal float (NaN equal to NaN): == is bitwise."""
    return [r[:3] + tuple(None if v is None else float(v).hex() for v in r[3:]) for r in _rows(res)]


def _timeless(notes):
    """The notes without the wall-clock seconds some report (compare's reference certificate)."""
    return [re.sub(r"\b[0-9.]+ s\)", "s)", n) for n in notes]


@pytest.mark.parametrize("eid", sorted(BLOCKS))
def test_block_experiments_give_bitwise_the_same_rows_for_any_chunk(eid):
    params, runs = CASES[eid]
    params = {**params, **BLOCKS[eid]}
    exp = get(eid)
    one = exp.run(params, quick=True, runs=runs, seed=3, chunk=1)  # a block per task, a path per batch
    assert one.meta["execution"]["blocks_computed"] >= 2 and one.meta["execution"]["chunk"] == 1
    res = exp.run(params, quick=True, runs=runs, seed=3, chunk=4)  # two blocks per task, a block per batch
    assert _exact(res) == _exact(one)
    assert _timeless(res.notes) == _timeless(one.notes)


def test_chunk_is_checked():
    with pytest.raises(ValueError, match="chunk"):
        get("linear-gaussian").run({}, quick=True, runs=3, chunk=0)

"""The compiled loops' disk cache (:mod:`nlfilter.filters.compiled.cache`): a second process loads
the loop instead of compiling it; a damaged, stale or foreign entry is compiled again, never
trusted; an unwritable cache folder compiles in memory.

Whether numba compiled or loaded is read from the loop's own counters (``_cache_hits``,
``_cache_misses``: numba's, per signature), not from a clock. The model is the scalar cubic sensor,
whose loop (the scalar batch loop) compiles in about a second.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import compiled
from nlfilter.filters.compiled import cache
from nlfilter.filters.ekf import EKF

pytestmark = pytest.mark.skipif(not compiled.available(), reason="numba does not import")

YS = np.random.default_rng(3).normal(size=(4, 12, 1))


def _model(a=0.9):
    x = sp.Symbol("x")
    return DiscreteModel([x], f=[a * x], h=[x**3], Q=0.1, R=0.2)  # a new model: a new kernel store


def _run(model):
    """The compiled run, the loop it ran and its cache entry."""
    from nlfilter.filters.compiled.kernels import KERNELS
    est = EKF(model).run(YS, 0.1, 1.0, backend="numba", loglik=True)
    (loop, entry), = [v for k, v in KERNELS[model._kernels["f"]].items() if isinstance(k, tuple) and k[0] == "steps"]
    return est, loop, entry


def _counts(loop):
    return sum(loop._cache_hits.values()), sum(loop._cache_misses.values())


@pytest.fixture
def root(tmp_path, monkeypatch):
    """A cache folder of this test's own, and no module of this process remembered."""
    monkeypatch.setenv("NLFILTER_CACHE", str(tmp_path / "compiled"))
    monkeypatch.setattr(cache, "_MODULES", {})
    monkeypatch.setattr(cache, "_OFF", {})
    return tmp_path / "compiled"


def test_a_second_process_loads_the_loop(root):
    """The first process compiles (one miss) and seals the entry; a second process, the same
    model, loads it (one hit, no miss) and gives the same numbers, bit for bit."""
    script = textwrap.dedent("""
        import numpy as np, sympy as sp
        from nlfilter import DiscreteModel
        from nlfilter.filters.ekf import EKF
        from nlfilter.filters.compiled.kernels import KERNELS
        x = sp.Symbol("x")
        md = DiscreteModel([x], f=[0.9 * x], h=[x**3], Q=0.1, R=0.2)
        ys = np.random.default_rng(3).normal(size=(4, 12, 1))
        est = EKF(md).run(ys, 0.1, 1.0, backend="numba", loglik=True)
        (loop, entry), = [v for k, v in KERNELS[md._kernels["f"]].items() if isinstance(k, tuple)]
        print(sum(loop._cache_hits.values()), sum(loop._cache_misses.values()), repr(float(est.loglik.sum())))
    """)
    env = {**os.environ, "NLFILTER_CACHE": str(root)}
    out = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True,
                          timeout=300).stdout.split() for _ in range(2)]
    assert out[0][:2] == ["0", "1"] and out[1][:2] == ["1", "0"], out
    assert out[0][2] == out[1][2]
    (entry,) = root.iterdir()
    assert (entry / "sealed.json").is_file() and entry.name.startswith("taylor1-scalar-")


def test_a_new_model_in_a_second_process_loads_the_model_free_loop(root):
    """``backend="numba-shared"``: the first process compiles the model-free loop of its shape (the
    scalar EKF's: a short compile) and its model's functions; a second process with *another* model
    of that shape loads the loop (a hit, no miss), compiles its own functions only, and gives the
    NumPy loop's numbers; the cache then holds one loop entry and one functions entry per model."""
    script = textwrap.dedent("""
        import sys
        import numpy as np, sympy as sp
        from nlfilter import DiscreteModel
        from nlfilter.filters.ekf import EKF
        from nlfilter.filters.compiled import template
        x = sp.Symbol("x")
        md = DiscreteModel([x], f=[float(sys.argv[1]) * x + 0.1 * sp.sin(x)], h=[x**3], Q=0.1, R=0.2)
        ys = np.random.default_rng(3).normal(size=(4, 12, 1))
        flt = EKF(md)
        est = flt.run(ys, 0.1, 1.0, backend="numba-shared", loglik=True)
        ref = flt.run(ys, 0.1, 1.0, backend="numpy", loglik=True)
        (loop, _), = template._LOOPS.values()
        close = np.allclose(est.means, ref.means, rtol=1e-12, atol=0) and np.allclose(est.loglik, ref.loglik, rtol=1e-12)
        print(sum(loop._cache_hits.values()), sum(loop._cache_misses.values()), close)
    """)
    env = {**os.environ, "NLFILTER_CACHE": str(root)}
    out = [subprocess.run([sys.executable, "-c", script, a], env=env, capture_output=True, text=True, check=True,
                          timeout=300).stdout.split() for a in ("0.9", "0.7")]
    assert out == [["0", "1", "True"], ["1", "0", "True"]], out
    names = sorted(p.name.split("-")[0] for p in root.iterdir())
    assert names == ["functions", "functions", "taylor1"], names
    assert all((p / "sealed.json").is_file() for p in root.iterdir())


@pytest.mark.parametrize("damage", ["numba data truncated", "numba index truncated", "source truncated",
                                    "source foreign", "unsealed"])
def test_a_damaged_entry_is_compiled_again(root, damage):
    """Each damage makes the next load compile again (a miss, no hit) with the same numbers, and
    the entry is sealed again; numba alone would raise on its truncated files (it does not check
    them: hence the seal)."""
    est, loop, entry = _run(_model())
    assert _counts(loop) == (0, 1)
    pyc = entry / "__pycache__"
    nbc, = pyc.glob("*.nbc")
    nbi, = pyc.glob("*.nbi")
    if damage.startswith("numba"):
        target = nbc if "data" in damage else nbi
        target.write_bytes(target.read_bytes()[:40])
    elif damage == "source truncated":
        src = entry / "module.py"
        src.write_text(src.read_text()[:200])
    elif damage == "source foreign":
        (entry / "module.py").write_text("raise SystemExit('not nlfilter')\n")
    else:
        (entry / "sealed.json").unlink()
    cache._MODULES.clear()
    again, loop2, entry2 = _run(_model())
    assert entry2 == entry and _counts(loop2) == (0, 1)
    np.testing.assert_array_equal(again.means, est.means)
    np.testing.assert_array_equal(again.extras["loglik"], est.extras["loglik"])
    assert (entry / "sealed.json").is_file()
    cache._MODULES.clear()  # and the entry, sealed again, is now loaded
    _, loop3, _ = _run(_model())
    assert _counts(loop3) == (1, 0)


def test_another_model_or_version_is_another_entry(root, monkeypatch):
    """The key is the whole source and the versions: a changed model, or a numba (or nlfilter,
    NumPy, Python) upgrade, makes a new entry and never reads the old one."""
    _, _, e1 = _run(_model(0.9))
    cache._MODULES.clear()
    _, loop2, e2 = _run(_model(0.8))
    assert e2 != e1 and _counts(loop2) == (0, 1)
    cache._MODULES.clear()
    real = cache.versions()
    monkeypatch.setattr(cache, "versions", lambda: real.replace("numba ", "numba 99."))
    _, loop3, e3 = _run(_model(0.9))
    assert e3 not in (e1, e2) and _counts(loop3) == (0, 1)
    assert sorted(p.name.split("-")[0] for p in root.iterdir()) == ["taylor1"] * 3


def test_an_unwritable_cache_compiles_in_memory(root, tmp_path, monkeypatch):
    """A cache path that cannot be a folder (under a file): one warning naming the folder and
    NLFILTER_CACHE, the loop compiled in memory, the same numbers; nothing written."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("NLFILTER_CACHE", str(blocker / "compiled"))
    with pytest.warns(RuntimeWarning, match="NLFILTER_CACHE"):
        est, loop, entry = _run(_model())
    assert entry is None and _counts(loop)[0] == 0  # compiled, not loaded
    ref = EKF(_model()).run(YS, 0.1, 1.0, backend="numpy", loglik=True)
    np.testing.assert_allclose(est.means, ref.means, rtol=1e-12, atol=0)
    assert blocker.read_text() == "" and not Path(str(blocker) + "compiled").exists()


def _owner(entry, pid, host=None, age=0.0):
    import json
    import socket
    import time
    (entry / "owner.json").write_text(json.dumps({"pid": pid, "host": host or socket.gethostname(),
                                                  "time": time.time() - age}))


def test_an_entry_another_living_process_is_writing_is_left_alone(root):
    """An unsealed entry claimed by another process that still runs (it compiled, numba wrote its
    files, it has not sealed them yet) is not touched: this process compiles in memory, same
    numbers. Once the owner is gone, the entry is compiled again, sealed, and the claim removed."""
    est, loop, entry = _run(_model())
    assert not (entry / "owner.json").exists()  # sealed: the claim is gone
    (entry / "sealed.json").unlink()
    files = {p.name: p.read_bytes() for p in (entry / "__pycache__").iterdir()}
    _owner(entry, os.getppid())  # alive, and not this process
    cache._MODULES.clear()
    again, loop2, entry2 = _run(_model())
    assert entry2 is None and _counts(loop2)[0] == 0
    assert {p.name: p.read_bytes() for p in (entry / "__pycache__").iterdir()} == files
    assert not (entry / "sealed.json").exists()
    np.testing.assert_array_equal(again.means, est.means)
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    _owner(entry, int(done.stdout))  # a process that has ended
    cache._MODULES.clear()
    _, loop3, entry3 = _run(_model())
    assert entry3 == entry and _counts(loop3) == (0, 1)
    assert (entry / "sealed.json").is_file() and not (entry / "owner.json").exists()


def test_a_claim_from_another_host_holds_for_an_hour(tmp_path):
    """No pid can be asked on another host (a shared cache folder): its claim holds OWNER_SECONDS;
    a claim that cannot be read claims nothing."""
    _owner(tmp_path, 1, host="another-host", age=60.0)
    assert cache._busy(tmp_path)
    _owner(tmp_path, 1, host="another-host", age=cache.OWNER_SECONDS + 60.0)
    assert not cache._busy(tmp_path)
    (tmp_path / "owner.json").write_text("{not json")
    assert not cache._busy(tmp_path)
    _owner(tmp_path, os.getpid())  # this process's own claim does not stop it
    assert not cache._busy(tmp_path)

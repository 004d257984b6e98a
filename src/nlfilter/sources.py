"""The source papers as a reader names them: "Vallot (1981)", "Henriksen (1979)", "Oh & Shin (1995)".

The code cites the papers nlfilter was built from by their file numbers (``seed 001``, ``001
eqs. 5.1-5.4``; the copies in the project's seed folder), and "seed" is also the random seed of
``--seed``. Every user-facing text — the command line's tables and notes, ``nlfilter list``, the
report and the figures' titles — goes through :func:`cite`, which writes each such reference as
the paper's name; results stored before the names (the committed report's JSON) read the same.

>>> cite("seed 001, Tables 5.1-5.2")
'Vallot (1981), Tables 5.1-5.2'
>>> cite("seed 004 (Henriksen 1979) eqs. 11, 18-23; mqlf (003 eqs. 25-33), dt=0.001")
'Henriksen (1979) eqs. 11, 18-23; mqlf (Oh & Shin (1995) eqs. 25-33), dt=0.001'
"""

from __future__ import annotations

import re

#: file number -> the paper as a reader names it (author (year); the dissertation has no author
#: or year in its copy: named by its subject)
PAPERS = {
    "000": "the moment-algorithm dissertation",
    "001": "Vallot (1981)",
    "002": "Henriksen (1979)",  # a worse copy of 004
    "003": "Oh & Shin (1995)",
    "004": "Henriksen (1979)",
}

#: file number -> the full reference
REFERENCES = {
    "000": 'Dissertation, "A moment algorithm for estimating the states of noisy linear discrete systems '
           'having non-Gaussian disturbances"',
    "001": 'L. C. Vallot, "Filtering for bilinear systems", M.S. thesis, MIT, 1981',
    "003": 'M. Oh and V. I. Shin, "Modified quasilinear filtering method for estimation of processes in '
           'multidimensional nonlinear stochastic systems", 1995',
    "004": 'R. Henriksen, "A note on truncated second-order nonlinear filters", 1979',
}

_NUM = "|".join(PAPERS)
# "seed 004 (Henriksen 1979)": the name stated beside the number
_NAMED = re.compile(rf"\bseeds? ({_NUM}) \([^()]*?\b(?:1[89]\d\d)\)")
# "seed 001", "seed 000's"
_SEED = re.compile(rf"\bseeds? ({_NUM})\b")
# a bare file number before what it points at: "001 eqs. 5.1-5.4", "003 Fig. 2", "000's Fig. 10"
_BARE = re.compile(rf"(?<![\w.]){'(' + _NUM + ')'}(?=\s+(?:eqs?\.|Tables?\b|Figs?\.|§|ch\.|Chapter\b|Section\b|"
                   rf"p\.|abstract\b|family\b)|'s\b)")


def cite(text: str) -> str:
    """``text`` with every reference to a source paper by its file number (``seed 001``, ``001
    Table 5.1``, ``seed 004 (Henriksen 1979)``) written as the paper's name (:data:`PAPERS`)."""
    if not isinstance(text, str) or "00" not in text:
        return text
    text = _NAMED.sub(lambda m: PAPERS[m.group(1)], text)
    text = _SEED.sub(lambda m: PAPERS[m.group(1)], text)
    return _BARE.sub(lambda m: PAPERS[m.group(1)], text)
